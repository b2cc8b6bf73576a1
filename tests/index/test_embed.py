"""The embedder runs each output of a model on a graph cut to that output, with the answers of the whole."""

from pathlib import Path

import numpy as np
import onnxruntime as ort
import pytest

from index.embed import LOCAL_NAME, MASK_NAME, OUTPUT_NAME, Embedder

SHIPPED_RGB = Path(__file__).resolve().parents[2] / "models" / "posedesc-rgb.onnx"


def test_each_output_is_the_whole_graphs_and_runs_only_its_nodes():
    e = Embedder(SHIPPED_RGB, threads=1)
    assert e.has_local and e.has_mask
    whole = ort.InferenceSession(str(SHIPPED_RGB), providers=["CPUExecutionProvider"])
    x = np.random.default_rng(0).normal(size=(3, 3, 64, 64)).astype(np.float32)
    desc, local, mask = whole.run([OUTPUT_NAME, LOCAL_NAME, MASK_NAME], {"patch": x})
    np.testing.assert_allclose(e(x), desc, atol=1e-5)
    np.testing.assert_allclose(e.local(x), local.astype(np.float16), atol=1e-3)
    np.testing.assert_array_equal(e.mask(x), mask[:, 0] > 0)
    # the local features' graph is the trunk alone: a fraction of the whole graph's nodes
    assert set(e.sessions) == {OUTPUT_NAME, LOCAL_NAME, MASK_NAME}
    assert e.nodes[LOCAL_NAME] < e.nodes[MASK_NAME] / 2 and e.nodes[LOCAL_NAME] < e.nodes[OUTPUT_NAME]


@pytest.mark.parametrize("model", ["rgb", "depth"])
def test_runs_of_any_size_give_the_same_outputs(model):
    """Registration embeds templates a few at a time (`index.register.EMBED_BATCH`, for speed): the outputs
    are, bit for bit, those of one run of them all."""
    e = Embedder(SHIPPED_RGB.with_name(f"posedesc-{model}.onnx"), threads=1)
    channels = 3 if model == "rgb" else 1
    x = np.random.default_rng(1).normal(size=(37, channels, 64, 64)).astype(np.float32)
    for batch in (1, 8, 16):
        np.testing.assert_array_equal(e(x, batch=batch), e(x, batch=512))
        if e.has_local:
            np.testing.assert_array_equal(e.local(x, batch=batch), e.local(x, batch=256))


def test_a_file_that_is_no_model_is_one_line(tmp_path):
    bad = tmp_path / "posedesc-rgb.onnx"
    bad.write_bytes(b"not an onnx file at all")
    with pytest.raises(ValueError, match="cannot load ONNX model") as e:
        Embedder(bad)
    assert "\n" not in str(e.value)
