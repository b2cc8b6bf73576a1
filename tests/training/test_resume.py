"""Resuming: which settings differ, and `posedesc train` refusing what it cannot resume or should not
overwrite, in one line and before any data is loaded (the --data folder below holds no data at all)."""

import argparse
import json
from dataclasses import asdict

import pytest
import torch

from posedesc.cli import main
from posedesc.commands.train import add_arguments, configs
from training.data import DataConfig
from training.render_cache import build
from training.resume import config_differences, describe
from training.train import load_checkpoint, train


def test_config_differences_name_nested_fields_and_skip_threads():
    theirs = {"dim": 8, "threads": 2, "data": {"split": {"val": ((0.2, 0.4),)}, "roll": 5.0}}
    ours = {"dim": 16, "threads": 1, "data": {"split": {"val": [[0.2, 0.4]]}, "roll": 6.0}}
    differ = config_differences(theirs, ours)
    assert differ == [("data.roll", 5.0, 6.0), ("dim", 8, 16)]
    assert describe(differ, {"dim": "--dim"}) == "data.roll: was 5.0, now 6.0; dim (--dim): was 8, now 16"


def test_a_checkpoint_from_before_a_setting_existed_counts_as_its_old_behaviour():
    """A local run saved before `--hard-negatives` existed resumes without it, and only without it."""
    from dataclasses import asdict

    from training.heads.local import LocalConfig

    before = {
        k: v for k, v in asdict(LocalConfig()).items() if not k.startswith("hard") and k != "mask_jitter"
    }
    assert config_differences(before, asdict(LocalConfig())) == []
    assert [d[0] for d in config_differences(before, asdict(LocalConfig(mask_jitter=2.0)))] == ["mask_jitter"]
    assert [d[0] for d in config_differences(before, asdict(LocalConfig(hard_model="m.onnx")))] == [
        "hard_model"
    ]


def posedesc_train(*options: str) -> int:
    return main(["train", "--modality", "rgb", *options])


@pytest.fixture
def bop(tmp_path):
    """What `posedesc train` checks a BOP folder by, and nothing else: any data loading fails."""
    (tmp_path / "bop" / "models").mkdir(parents=True)
    (tmp_path / "bop" / "models" / "models_info.json").write_text("{}")
    return tmp_path / "bop"


def test_resume_refuses_an_empty_folder_and_pca(bop, tmp_path, capsys):
    for options, says in [
        ((), "no checkpoint.pt in"),
        (("--arch", "mask"), "no mask.pt in"),
        (("--arch", "local"), "no local.pt in"),
        (
            ("--arch", "local", "--query-mask", str(tmp_path)),
            "has no mask.pt: not a `posedesc train --arch mask` run nor an .onnx model",
        ),
        (("--arch", "trunk", "--query-mask", str(tmp_path)), "--query-mask is for --arch local"),
        (("--arch", "mask", "--hard-negatives", str(bop)), "--hard-negatives is for --arch local"),
        (("--arch", "local", "--hard-negatives", str(tmp_path / "no.onnx")), "no such model file"),
        (("--arch", "local", "--query-mask", str(tmp_path / "no.onnx")), "--query-mask: no such model file"),
        (("--arch", "mask", "--mask-jitter", "2"), "--mask-jitter is for --arch local"),
        (("--arch", "local", "--mask-jitter", "-1"), "--mask-jitter must be >= 0"),
        (("--arch", "trunk", "--local-others", "9"), "--local-others is for --arch local"),
        (("--arch", "mask", "--local-far", "15"), "--local-far is for --arch local"),
        (("--arch", "local", "--local-same", "-1"), "--local-same and --local-others must be >= 0"),
        (("--arch", "local", "--local-far", "0"), "--local-far is an angle in (0, 180) deg"),
        (("--arch", "local", "--local-others-real", "1.5"), "--local-others-real is a share in [0, 1]"),
        (("--arch", "local", "--mask-outline", "2"), "--mask-outline is for --arch mask"),
        (("--arch", "trunk", "--mask-soft-edges", "0.5"), "--mask-soft-edges is for --arch mask"),
        (("--arch", "mask", "--mask-colour-jitter", "-1"), "--mask-colour-jitter must be >= 0"),
        (("--arch", "mask", "--mask-soft-edges", "2"), "--mask-soft-edges is a chance, at most 1"),
        (("--arch", "pca"), "fitted in one pass"),
    ]:
        assert posedesc_train("--data", str(bop), "--out", str(tmp_path / "run"), "--resume", *options) == 2
        err = capsys.readouterr().err
        assert says in err and err.count("\n") == 1, err


@pytest.mark.slow
def test_the_command_neither_overwrites_nor_resumes_a_run_it_should_not(bop, tmp_path, capsys):
    """A real run (2 steps, with the command's settings, on two small shapes: `train` takes the data it
    is given) is finished: without --resume the command refuses to train over it, with --resume it says
    the budget is spent, with another --dim, --minutes or --data it names what differs; a checkpoint of
    before resuming (no "resume" state) cannot be resumed but still loads."""
    options = ["--data", str(bop), "--out", str(tmp_path / "run"), "--arch", "paper", "--dim", "8",
               "--batch", "4", "--max-steps", "2", "--minutes", "600", "--threads", "1"]  # fmt: skip
    parser = argparse.ArgumentParser()
    add_arguments(parser)
    cfg, _ = configs(parser.parse_args(["--modality", "rgb", *options]))
    torch.set_num_threads(1)
    small = DataConfig(shapes=2, shape_views=20, template_inplane_step=0.0, seed=3)
    train(cfg, build([], small), tmp_path / "run")
    capsys.readouterr()  # its progress bars

    def refused(*extra: str) -> str:
        assert posedesc_train(*options, *extra) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and "Traceback" not in err, err
        return err

    assert "already holds a run (checkpoint.pt): add --resume" in refused()
    assert "already used its whole budget (" in refused("--resume")
    assert "descriptor_dim (--dim): was 8, now 16" in refused("--resume", "--dim", "16")
    assert "minutes (--minutes): was 600.0, now 700.0" in refused("--resume", "--minutes", "700")
    old = torch.load(tmp_path / "run" / "checkpoint.pt", weights_only=False)
    torch.save({k: v for k, v in old.items() if k != "resume"}, tmp_path / "run" / "checkpoint.pt")
    assert "written before training could resume" in refused("--resume")  # as checkpoints were
    assert load_checkpoint(tmp_path / "run")[1]["step"] == 2  # and export still reads them
    # config.json as the command writes it when a run starts: its settings and data folders
    (tmp_path / "run" / "config.json").write_text(json.dumps({"config": asdict(cfg), "data": ["elsewhere"]}))
    assert "was trained on --data elsewhere" in refused("--resume")
