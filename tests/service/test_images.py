"""Uploaded images decode to the pixels Pillow reads, whichever library decodes them (OpenCV for PNG)."""

from __future__ import annotations

import io

import numpy as np
import pytest
from PIL import Image

from service.errors import ApiError
from service.images import read_depth, read_rgb

MAX = 4096 * 4096


def _encoded(im: Image.Image, fmt: str = "PNG") -> bytes:
    buf = io.BytesIO()
    im.save(buf, format=fmt)
    return buf.getvalue()


def _colour(seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 256, (24, 32, 3), dtype=np.uint8)


@pytest.mark.parametrize("mode", ["RGB", "RGBA", "L", "LA", "P"])
def test_a_png_of_any_colour_mode_reads_as_pillow_converts_it(mode):
    im = Image.fromarray(_colour()).convert(mode)
    expected = np.asarray(im.convert("RGB"))
    got = read_rgb(_encoded(im), MAX)
    assert got.shape == (24, 32, 3) and got.dtype == np.uint8
    np.testing.assert_array_equal(got, expected)


def test_jpeg_reads_and_a_truncated_png_or_jpeg_is_one_clear_error():
    rgb = _colour()
    jpeg = _encoded(Image.fromarray(rgb), "JPEG")
    np.testing.assert_array_equal(
        read_rgb(jpeg, MAX), np.asarray(Image.open(io.BytesIO(jpeg)).convert("RGB"))
    )
    big = _encoded(Image.fromarray(np.tile(rgb, (10, 10, 1))), "JPEG")  # a header, then lots of data
    for data in (_encoded(Image.fromarray(rgb))[:-30], big[: 3 * len(big) // 4]):
        with pytest.raises(ApiError, match="truncated or corrupt"):
            read_rgb(data, MAX)


def test_depth_is_the_16_bit_values_times_the_scale():
    d = np.random.default_rng(1).integers(0, 65535, (24, 32), dtype=np.uint16)
    got = read_depth(_encoded(Image.fromarray(d)), 0.1, MAX)
    assert got.dtype == np.float32
    np.testing.assert_allclose(got, d.astype(np.float32) * np.float32(0.1), rtol=1e-6)
    with pytest.raises(ApiError, match="truncated or corrupt"):
        read_depth(_encoded(Image.fromarray(d))[:-30], 1.0, MAX)
