"""Uploaded images decode to the pixels Pillow reads, whichever library decodes them (OpenCV for PNG)."""

from __future__ import annotations

import io
import re

import cv2
import numpy as np
import pytest
from PIL import Image

from service.errors import ApiError
from service.inputs.images import read_depth, read_rgb

MAX = 4096 * 4096


def _encoded(im: Image.Image, fmt: str = "PNG") -> bytes:
    buf = io.BytesIO()
    im.save(buf, format=fmt)
    return buf.getvalue()


def _colour(seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 256, (24, 32, 3), dtype=np.uint8)


@pytest.mark.parametrize("mode", ["RGB", "RGBA", "P"])
def test_a_png_of_any_colour_mode_reads_as_pillow_converts_it(mode):
    im = Image.fromarray(_colour()).convert(mode)
    expected = np.asarray(im.convert("RGB"))
    got = read_rgb(_encoded(im), MAX)
    assert got.shape == (24, 32, 3) and got.dtype == np.uint8
    np.testing.assert_array_equal(got, expected)


@pytest.mark.parametrize(("mode", "fmt"), [("L", "PNG"), ("LA", "PNG"), ("1", "PNG"), ("L", "JPEG")])
def test_a_greyscale_image_is_refused_as_colour(mode, fmt):
    """Grey read as colour would be answered as if it were colour: refused, saying what to send."""
    with pytest.raises(ApiError) as e:
        read_rgb(_encoded(Image.fromarray(_colour()).convert(mode), fmt), MAX)
    assert e.value.status_code == 422 and "greyscale" in e.value.detail and "colour image" in e.value.detail


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
    got, scale = read_depth(_encoded(Image.fromarray(d)), 0.1, MAX)
    assert got.dtype == np.float32 and scale == 0.1
    assert read_depth(_encoded(Image.fromarray(d)), None, MAX)[1] == 1.0  # a 16-bit PNG's own unit: mm
    np.testing.assert_allclose(got, d.astype(np.float32) * np.float32(0.1), rtol=1e-6)
    with pytest.raises(ApiError, match="truncated or corrupt"):
        read_depth(_encoded(Image.fromarray(d))[:-30], 1.0, MAX)


def _float_tiff(d_m: np.ndarray) -> bytes:
    ok, data = cv2.imencode(".tiff", d_m)
    assert ok
    return data.tobytes()


def _npy(d_m: np.ndarray) -> bytes:
    buf = io.BytesIO()
    np.save(buf, d_m)
    return buf.getvalue()


def _pfm(d_m: np.ndarray) -> bytes:
    ok, data = cv2.imencode(".pfm", d_m)
    assert ok
    return data.tobytes()


@pytest.mark.parametrize(("encode", "name", "file"), [(_pfm, "a PFM image", "depth.pfm")])
def test_depth_as_float_metres_is_told_how_to_convert_and_the_recipe_works(
    tmp_path, monkeypatch, encode, name, file
):
    d_m = np.random.default_rng(2).uniform(0.4, 1.5, (24, 32)).astype(np.float32)
    d_m[3, 4] = np.nan  # a hole, as float depth often marks one
    data = encode(d_m)
    with pytest.raises(ApiError) as e:
        read_depth(data, 1.0, MAX)
    detail = e.value.detail
    assert e.value.status_code == 422 and detail.startswith(f"depth: {name}, not a 16-bit PNG;"), detail
    # the conversion the message gives, run as a user would paste it, makes depth the service reads in mm
    (tmp_path / file).write_bytes(data)
    recipe = re.search(r"for depth in metres: (.*)\)$", detail)
    assert recipe is not None, detail
    monkeypatch.chdir(tmp_path)
    exec(recipe.group(1), {"np": np, "cv2": cv2})  # the message's own one-liner
    got, _ = read_depth((tmp_path / "depth.png").read_bytes(), 1.0, MAX)
    expected = np.round(np.nan_to_num(d_m) * 1000)
    np.testing.assert_array_equal(got, expected)
    assert got[3, 4] == 0  # the hole: no measurement


def test_other_formats_are_named_by_their_first_bytes():
    exr = b"v/1\x01" + bytes(100)
    with pytest.raises(
        ApiError, match="depth: an OpenEXR image .*OPENCV_IO_ENABLE_OPENEXR.*16-bit PNG of mil"
    ):
        read_depth(exr, 1.0, MAX)
    with pytest.raises(ApiError, match="^rgb: a TIFF, not a PNG or JPEG$"):
        read_rgb(_float_tiff(np.zeros((8, 8), np.float32)), MAX)
    with pytest.raises(ApiError, match=r"^depth: not an image \(PNG or JPEG expected\)$"):
        read_depth(b"hello", 1.0, MAX)


def test_float_depth_is_metres_as_sdks_write_it_npy_or_tiff():
    """Depth as ROS and camera SDKs give it: float32 metres, NaN where nothing was measured."""
    d_m = np.random.default_rng(2).uniform(0.4, 2.0, (24, 32)).astype(np.float32)
    d_m[3, 4], d_m[5, 6], d_m[7, 8] = np.nan, np.inf, -1.0
    tiff = io.BytesIO()
    Image.fromarray(d_m, mode="F").save(tiff, format="TIFF")
    for data in (_npy(d_m), _npy(d_m.astype(np.float64)), tiff.getvalue()):
        got, scale = read_depth(data, None, MAX)
        assert scale == 1000.0 and got.dtype == np.float32 and got.shape == (24, 32)
        assert got[3, 4] == got[5, 6] == got[7, 8] == 0  # no measurement
        ok = np.isfinite(d_m) & (d_m > 0)
        np.testing.assert_allclose(got[ok], d_m[ok] * 1000, rtol=1e-6)
    got, scale = read_depth(_npy(d_m * 1000), 1.0, MAX)  # float mm, said so
    assert scale == 1.0 and np.nanmax(np.abs(got[ok] - d_m[ok] * 1000)) < 1e-3


@pytest.mark.parametrize(
    ("data", "status", "said"),
    [
        (_npy(np.zeros((24, 32, 3), np.float32)), 422, "one channel of float32 or float64"),
        (_npy(np.zeros((24, 32), np.int64)), 422, "one channel of float32 or float64"),
        (_npy(np.zeros((24, 32), np.float32))[:-20], 422, "truncated"),
        (_npy(np.zeros((5000, 5000), np.float32))[:200], 413, "over the limit"),
        (b"\x93NUMPY\x01\x00garbage", 422, "header"),
    ],
)
def test_a_float_depth_that_is_none_is_refused(data, status, said):
    with pytest.raises(ApiError) as e:
        read_depth(data, None, MAX)
    assert e.value.status_code == status and said in e.value.detail
