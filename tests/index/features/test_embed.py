"""The embedder runs each output of a model on a graph cut to that output, with the answers of the whole."""

from pathlib import Path

import numpy as np
import onnxruntime as ort
import pytest

from index.features.embed import LOCAL_NAME, MASK_NAME, OUTPUT_NAME, Embedder

SHIPPED_RGB = Path(__file__).resolve().parents[3] / "models" / "posedesc-rgb.onnx"


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


def test_concatenations_into_convolutions_are_padded_to_whole_blocks_without_changing_outputs():
    """`pad_concat_channels`: the mask head's concatenations (trunk maps and two channels of image
    coordinates) widened to a multiple of `CHANNEL_BLOCK` channels by zero channels, the convolutions'
    weights by zero rows: the logits as before, to float rounding."""
    import onnx
    import onnx.shape_inference
    import onnx.utils

    from index.features.embed import CHANNEL_BLOCK, pad_concat_channels

    mask = onnx.utils.Extractor(onnx.load(str(SHIPPED_RGB))).extract_model(["patch"], [MASK_NAME])
    padded = pad_concat_channels(mask)

    def concat_channels(model: onnx.ModelProto) -> list[int]:
        info = onnx.shape_inference.infer_shapes(model).graph.value_info
        dims = {v.name: v.type.tensor_type.shape.dim for v in info}
        return [
            dims[n.output[0]][1].dim_value
            for n in model.graph.node
            if n.op_type == "Concat" and len(dims.get(n.output[0], [])) == 4
        ]

    before, after = concat_channels(mask), concat_channels(padded)
    assert any(c % CHANNEL_BLOCK for c in before)  # the shipped head has such concatenations
    assert len(after) == len(before) and all(c % CHANNEL_BLOCK == 0 for c in after if c > 2), after
    x = np.random.default_rng(1).normal(size=(4, 3, 64, 64)).astype(np.float32)
    a = ort.InferenceSession(mask.SerializeToString(), providers=["CPUExecutionProvider"])
    b = ort.InferenceSession(padded.SerializeToString(), providers=["CPUExecutionProvider"])
    np.testing.assert_allclose(b.run(None, {"patch": x})[0], a.run(None, {"patch": x})[0], atol=1e-4)


@pytest.mark.parametrize("model", ["rgb", "depth"])
def test_runs_of_any_size_give_the_same_outputs(model):
    """Registration embeds templates a few at a time (`index.templates.register.EMBED_BATCH`, for speed): the outputs
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
