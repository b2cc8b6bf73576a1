"""posedesc serve refuses to start, in one line, without models or with a bad setting (running it is
tests/promises/test_serve_register_recognise_restart.py)."""

from __future__ import annotations

from posedesc.cli import main


def test_serve_errors(tmp_path, capsys, monkeypatch):
    empty = tmp_path / "models"
    empty.mkdir()
    assert main(["serve", "--models", str(empty), "--data-dir", str(tmp_path / "d")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "no models in" in err and "posedesc-rgb.onnx" in err
    monkeypatch.setenv("POSEDESC_MAX_K", "-3")
    assert main(["serve", "--models", str(empty)]) == 2
    assert "max_k" in capsys.readouterr().err
    blocker = tmp_path / "file"
    blocker.write_text("")
    monkeypatch.delenv("POSEDESC_MAX_K")
    (empty / "posedesc-rgb.onnx").write_bytes(b"")
    assert main(["serve", "--models", str(empty), "--data-dir", str(blocker / "d")]) == 2
    assert "data dir" in capsys.readouterr().err
