"""Uploaded images: PNG or JPEG colour, 16-bit PNG depth. The header is read (and its size checked)
before any pixel is decoded, so a small file that claims to be gigapixels is refused cheaply. Pillow
reads the header and decodes JPEG; OpenCV decodes PNG, about twice as fast (a 640 x 480 frame: ~11 ms
against ~21 ms here), which is most of what a frame's trip through `POST /recognize` costs."""

from __future__ import annotations

import io
import warnings

import cv2
import numpy as np
from PIL import Image, UnidentifiedImageError

from service.errors import ApiError

Image.MAX_IMAGE_PIXELS = None  # our own limit, checked below, replaces Pillow's warning-then-error

#: Formats people hold depth in, told by their first bytes (never parsed: only PNG and JPEG are decoded),
#: with how NumPy / OpenCV read them.
OTHER_FORMATS = (
    (
        (b"II*\x00", b"MM\x00*", b"II+\x00", b"MM\x00+"),
        "a TIFF",
        "cv2.imread('depth.tif', cv2.IMREAD_UNCHANGED)",
    ),
    ((b"\x93NUMPY",), "a NumPy .npy array", "np.load('depth.npy')"),
    (
        (b"v/1\x01",),
        "an OpenEXR image (OpenCV reads it with OPENCV_IO_ENABLE_OPENEXR=1 in the environment)",
        "cv2.imread('depth.exr', cv2.IMREAD_UNCHANGED)",
    ),
    ((b"PF\n", b"Pf\n"), "a PFM image", "cv2.imread('depth.pfm', cv2.IMREAD_UNCHANGED)"),
)


def to_mm_png(read: str) -> str:
    """How to turn depth in metres, read by `read`, into what the service takes: a 16-bit PNG of mm."""
    return (
        f"for depth in metres: d = {read}; "
        "cv2.imwrite('depth.png', np.round(np.nan_to_num(d) * 1000).astype(np.uint16))"
    )


def other_format(data: bytes) -> tuple[str, str] | None:
    """(what the file is, how to read it) for a format people hold depth in, by its magic bytes."""
    for magics, name, how in OTHER_FORMATS:
        if data.startswith(magics):
            return name, how
    return None


def _not_an_image(data: bytes, what: str) -> str:
    found = other_format(data)
    if found is None:
        return f"{what}: not an image (PNG or JPEG expected)"
    name, how = found
    if what == "depth":
        return (
            f"depth: {name}, not a 16-bit PNG; send depth as a 16-bit PNG of millimetres ({to_mm_png(how)})"
        )
    return f"{what}: {name}, not a PNG or JPEG"


def _open(data: bytes, what: str, max_pixels: int) -> Image.Image:
    """The image's header, checked; no pixel decoded yet."""
    if not data:
        raise ApiError(422, f"{what}: the file is empty")
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            # parses the header only; and only Pillow's PNG and JPEG code ever sees an upload (a camera's
            # JPEG with several pictures comes back as MPO, Pillow's JPEG code too): anything else is refused
            im = Image.open(io.BytesIO(data), formats=("PNG", "JPEG"))
    except (UnidentifiedImageError, OSError, ValueError, SyntaxError):
        raise ApiError(422, _not_an_image(data, what)) from None
    _sized(*im.size, what, max_pixels)
    return im


#: an image's least side, px: fewer is no frame or patch (and cut, resized or searched it breaks OpenCV)
MIN_SIDE_PX = 8


def _sized(w: int, h: int, what: str, max_pixels: int) -> None:
    """Refuses an image of `w` x `h` px that is over the pixel limit (413) or under `MIN_SIDE_PX` a side (422):
    PNG, JPEG, `.npy` and TIFF alike."""
    if w * h > max_pixels:
        raise ApiError(413, f"{what}: {w} x {h} px is over the limit of {max_pixels} pixels")
    if w < MIN_SIDE_PX or h < MIN_SIDE_PX:
        raise ApiError(422, f"{what}: {w} x {h} px is too small (at least {MIN_SIDE_PX} px a side)")


def _load(im: Image.Image, what: str) -> Image.Image:
    try:
        im.load()
    except Exception:  # truncated or corrupt data: Pillow raises OSError, SyntaxError, ValueError...
        raise ApiError(422, f"{what}: the {im.format} data is truncated or corrupt") from None
    return im


def _decode_png(data: bytes, what: str, flags: int) -> np.ndarray:
    """A PNG's pixels by OpenCV (libpng checks every chunk: a truncated or damaged file gives None)."""
    out = cv2.imdecode(np.frombuffer(data, np.uint8), flags | cv2.IMREAD_IGNORE_ORIENTATION)
    if out is None:
        raise ApiError(422, f"{what}: the PNG data is truncated or corrupt")
    return out


def read_rgb(data: bytes, max_pixels: int) -> np.ndarray:
    """A colour image. Shape: (H, W, 3) uint8, RGB order."""
    im = _open(data, "rgb", max_pixels)
    if im.mode in ("I", "I;16", "I;16B", "I;16L", "F"):
        raise ApiError(422, "rgb: a 16-bit single-channel image; send depth as `depth`, colour as `rgb`")
    if im.mode in ("L", "LA", "1"):
        raise ApiError(
            422,
            f"rgb: a greyscale image ({im.mode}): the colour model reads colour, and grey taken for colour "
            "would be answered as if it were; send the camera's colour image (or depth alone as `depth`)",
        )
    if im.format == "PNG":
        return _decode_png(data, "rgb", cv2.IMREAD_COLOR_RGB)  # RGB as decoded: no BGR pass to turn
    im = _load(im, "rgb")  # JPEG: Pillow's libjpeg-turbo
    return np.asarray(im if im.mode == "RGB" else im.convert("RGB"))  # an RGB one as is: no copy to convert


def read_depth(data: bytes, scale: float | None, max_pixels: int) -> tuple[np.ndarray, float]:
    """A depth image in mm (0 = no measurement) and the scale it was read with (mm per unit). A 16-bit PNG
    holds integers of `scale` mm (None: mm); a float32 or float64 array, `.npy` or a 32-bit float TIFF as
    depth SDKs and ROS write them, holds metres unless `scale` says otherwise (NaN, inf and negative values
    are no measurement). Shape: (H, W) float32."""
    if data[:6] == NUMPY_MAGIC:
        return _float_depth(_read_npy(data, max_pixels), scale)
    if data[:4] in TIFF_MAGIC:
        return _float_depth(_read_tiff(data, max_pixels), scale)
    im = _open(data, "depth", max_pixels)
    if im.format != "PNG":
        raise ApiError(422, f"depth: {im.format} holds 8-bit values; depth must be a 16-bit PNG in mm")
    if im.mode not in ("I", "I;16", "I;16B", "I;16L"):
        kind = "colour" if im.mode in ("RGB", "RGBA", "P", "CMYK", "YCbCr") else "8-bit"
        raise ApiError(
            422, f"depth: a {kind} image ({im.mode}); depth must be a single-channel 16-bit PNG in mm"
        )
    d = _decode_png(data, "depth", cv2.IMREAD_UNCHANGED)
    if d.ndim != 2 or d.dtype != np.uint16:  # Pillow's "I" mode: a 16-bit PNG is all the header allows
        raise ApiError(422, "depth: not a single-channel 16-bit PNG in mm")
    scale = 1.0 if scale is None else scale
    out = d.astype(np.float32)  # unsigned: never negative
    out *= np.float32(scale)  # in place: no second frame-sized array
    return out, scale


NUMPY_MAGIC = b"\x93NUMPY"
TIFF_MAGIC = (b"II*\x00", b"MM\x00*")
FLOAT_DEPTH = "depth: a float depth is one channel of float32 or float64 values (metres, as SDKs write them)"


def _read_npy(data: bytes, max_pixels: int) -> np.ndarray:
    """A `.npy` array, its header checked before its data is read (no pickles)."""
    buf = io.BytesIO(data)
    try:
        major, _ = np.lib.format.read_magic(buf)
        header = np.lib.format.read_array_header_1_0 if major == 1 else np.lib.format.read_array_header_2_0
        shape, _, dtype = header(buf)  # shape and dtype, no data read yet
    except (ValueError, SyntaxError, TypeError):
        raise ApiError(422, "depth: a .npy file whose header does not read") from None
    if len(shape) != 2 or dtype not in (np.float32, np.float64):
        raise ApiError(422, f"{FLOAT_DEPTH}; this .npy holds {dtype} of shape {shape}")
    _sized(shape[1], shape[0], "depth", max_pixels)
    buf.seek(0)
    try:
        return np.load(buf, allow_pickle=False)
    except (ValueError, EOFError, OSError):
        raise ApiError(422, "depth: the .npy data is truncated or corrupt") from None


def _read_tiff(data: bytes, max_pixels: int) -> np.ndarray:
    """A 32-bit float TIFF (Pillow's mode F), its size checked from the header first."""
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            im = Image.open(io.BytesIO(data), formats=("TIFF",))
    except (UnidentifiedImageError, OSError, ValueError, SyntaxError):
        raise ApiError(422, "depth: a TIFF that does not read") from None
    _sized(*im.size, "depth", max_pixels)
    if im.mode != "F":
        raise ApiError(422, f"{FLOAT_DEPTH}; this TIFF is {im.mode} (a 16-bit depth goes as PNG)")
    return np.asarray(_load(im, "depth"), np.float32)


def _float_depth(values: np.ndarray, scale: float | None) -> tuple[np.ndarray, float]:
    scale = 1000.0 if scale is None else scale  # metres, unless told
    out = np.asarray(values, np.float32) * np.float32(scale)
    out[~np.isfinite(out) | (out < 0)] = 0.0  # NaN (ROS's "no reading"), inf, below zero: no measurement
    return out, scale
