"""Images from outside: header sizes bounded before decoding, structure checked, then decoded.

:func:`image_size` reads width and height from a PNG, JPEG, BMP, TIFF or PNM header without decoding;
:func:`read_image` and :func:`decode_image_bytes` bound them (side and pixel count), check the
structure (PNG chunk CRCs, a JPEG's end marker) and only then decode: the rig's own PNG frames with
:func:`~tactile_rig.rig.files.png.decode_rgb8_bgr`, anything else with OpenCV.
"""

from __future__ import annotations

import io
import re
import struct
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Iterator

import cv2
import numpy as np

from tactile_rig.core.errors import BadFile
from tactile_rig.rig.files.checks import check_file, read_bytes
from tactile_rig.rig.files.png import PNG_SIGNATURE, decode_rgb8_bgr, png_chunks, png_problem

MAX_IMAGE_SIDE_PX = 16384
MAX_IMAGE_PIXELS = 1 << 26        # 67 Mpx: a 65535 x 65535 header is refused before decoding


def jpeg_problem(data: bytes) -> str | None:
    """A JPEG that does not end with its EOI marker is cut off. (JPEG has no checksum: a flipped bit
    in the compressed scan decodes to a slightly different picture and cannot be detected.)"""
    if not data.rstrip(b"\0").endswith(b"\xff\xd9"):
        return "no end-of-image marker (truncated)"
    return None


def _png_size(h: bytes) -> tuple[int, int] | None:
    if len(h) < 24 or h[12:16] != b"IHDR":
        return None
    w, hh = struct.unpack(">II", h[16:24])
    return w, hh


def _jpeg_size(f: Any) -> tuple[int, int] | None:
    f.seek(2)
    for _ in range(10000):  # markers before the frame header; bounded against garbage
        b = f.read(1)
        while b and b != b"\xff":
            b = f.read(1)
        while b == b"\xff":
            b = f.read(1)
        if not b:
            return None
        marker = b[0]
        if marker in (0xD8, 0x01) or 0xD0 <= marker <= 0xD7:
            continue  # no length field
        seg = f.read(2)
        if len(seg) < 2:
            return None
        length = struct.unpack(">H", seg)[0]
        if 0xC0 <= marker <= 0xCF and marker not in (0xC4, 0xC8, 0xCC):
            body = f.read(5)
            if len(body) < 5:
                return None
            hh, w = struct.unpack(">HH", body[1:5])
            return w, hh
        if length < 2:
            return None
        f.seek(length - 2, 1)
    return None


def _bmp_size(h: bytes) -> tuple[int, int] | None:
    if len(h) < 26:
        return None
    w, hh = struct.unpack("<ii", h[18:26])
    return abs(w), abs(hh)


def _pnm_size(h: bytes) -> tuple[int, int] | None:
    text = re.sub(rb"#[^\n]*", b" ", h[2:512])
    nums = re.findall(rb"\d+", text)
    return (int(nums[0]), int(nums[1])) if len(nums) >= 2 else None


def _tiff_size(f: Any, h: bytes) -> tuple[int, int] | None:
    end = "<" if h[:2] == b"II" else ">"
    f.seek(4)
    off = struct.unpack(end + "I", f.read(4))[0]
    f.seek(off)
    raw = f.read(2)
    if len(raw) < 2:
        return None
    n = struct.unpack(end + "H", raw)[0]
    w = hh = None
    for _ in range(min(n, 4096)):
        e = f.read(12)
        if len(e) < 12:
            return None
        tag, typ = struct.unpack(end + "HH", e[:4])
        val = struct.unpack(end + "H", e[8:10])[0] if typ == 3 else struct.unpack(end + "I", e[8:12])[0]
        if tag == 256:
            w = val
        elif tag == 257:
            hh = val
    return (w, hh) if w is not None and hh is not None else None


def image_size(path: str | Path, what: str = "image") -> tuple[int, int, str]:
    """``(width_px, height_px, format)`` from an image file's header, without decoding it."""
    p = check_file(path, what)
    with open(p, "rb") as f:
        head = f.read(32)
        try:
            if head.startswith(PNG_SIGNATURE):
                size, fmt = _png_size(head), "PNG"
            elif head.startswith(b"\xff\xd8"):
                size, fmt = _jpeg_size(f), "JPEG"
            elif head.startswith(b"BM"):
                size, fmt = _bmp_size(head), "BMP"
            elif head[:2] in (b"II", b"MM") and head[2:4] in (b"*\x00", b"\x00*"):
                size, fmt = _tiff_size(f, head), "TIFF"
            elif head[:1] == b"P" and head[1:2] in b"123456" and len(head) > 2:
                size, fmt = _pnm_size(head + f.read(480)), "PNM"
            else:
                raise BadFile(p, f"{what} is not an image this rig reads (it starts with {head[:8]!r})",
                              "a PNG, JPEG, BMP, TIFF or PNM image")
        except BadFile:
            raise
        except (struct.error, OSError, ValueError) as exc:
            raise BadFile(p, f"{what} has a malformed header ({exc})", "a PNG, JPEG, BMP, TIFF or PNM image") from None
    if size is None:
        raise BadFile(p, f"{what} has a truncated or malformed {fmt} header", f"a complete {fmt} image")
    return int(size[0]), int(size[1]), fmt


def check_image_dims(path: str | Path, what: str, w: int, h: int, max_side_px: int = MAX_IMAGE_SIDE_PX,
                     max_pixels: int = MAX_IMAGE_PIXELS) -> None:
    """Refuse an image (or image-shaped array) of ``w`` x ``h`` pixels outside the bounds."""
    p = Path(path)
    if w <= 0 or h <= 0:
        raise BadFile(p, f"{what} declares {w}x{h} pixels", "a positive width and height")
    if w > max_side_px or h > max_side_px or w * h > max_pixels:
        raise BadFile(p, f"{what} declares {w}x{h} pixels",
                      f"at most {max_side_px} px a side and {max_pixels} pixels")


def _checked_image(p: Path, what: str, max_side_px: int, max_pixels: int,
                   png: list | None = None) -> tuple[int, int, str, bytes]:
    """Size, format and bytes of an image whose header is bounded and whose structure is intact.
    A PNG is opened once: its header's width x height is bounded, then the rest is read from the same
    handle; ``png`` (a list) receives its CRC-checked chunks."""
    p = check_file(p, what)
    raw = b""
    dims: tuple[int, int] | None = None
    try:
        with open(p, "rb") as fh:
            head = fh.read(32)
            if head.startswith(PNG_SIGNATURE):
                dims = _png_size(head)
                if dims is None:
                    raise BadFile(p, f"{what} has a truncated or malformed PNG header", "a complete PNG image")
                check_image_dims(p, what, dims[0], dims[1], max_side_px, max_pixels)
                raw = head + fh.read()
    except OSError as exc:
        raise BadFile(p, f"{what} cannot be read ({exc.strerror or exc})", "a readable file") from None
    if dims is not None:
        w, h, fmt = dims[0], dims[1], "PNG"
        problem, chunks = png_chunks(raw)
        if png is not None:
            png[:] = chunks
    else:
        w, h, fmt = image_size(p, what)
        check_image_dims(p, what, w, h, max_side_px, max_pixels)
        raw = read_bytes(p, what)
        problem = jpeg_problem(raw) if fmt == "JPEG" else None
    if problem:
        raise BadFile(p, f"{what} is a damaged {fmt}: {problem}", f"an intact {fmt} image")
    return w, h, fmt, raw


def check_image_file(path: str | Path, what: str = "image", *, max_side_px: int = MAX_IMAGE_SIDE_PX,
                     max_pixels: int = MAX_IMAGE_PIXELS) -> tuple[int, int, str]:
    """``(width_px, height_px, format)`` of an image file whose header is bounded and whose structure
    is intact (PNG chunk CRCs, JPEG end marker), without decoding it: for code that decodes later."""
    w, h, fmt, _ = _checked_image(Path(path), what, max_side_px, max_pixels)
    return w, h, fmt


@contextmanager
def quiet_opencv() -> Iterator[None]:
    """OpenCV's decoder warnings off for the block (a refused file is reported once, by us)."""
    log = getattr(getattr(cv2, "utils", None), "logging", None)
    if log is None:  # pragma: no cover - OpenCV without the logging module
        yield
        return
    old = log.getLogLevel()
    log.setLogLevel(log.LOG_LEVEL_ERROR)
    try:
        yield
    finally:
        log.setLogLevel(old)


def read_image(path: str | Path, what: str = "image", *, color: bool = True,
               max_side_px: int = MAX_IMAGE_SIDE_PX, max_pixels: int = MAX_IMAGE_PIXELS,
               shape: tuple[int, int] | None = None) -> np.ndarray:
    """Decode an image (BGR uint8 with ``color``, else grey) after its header's width x height is
    bounded; a file OpenCV cannot decode is a :class:`BadFile`. ``shape`` (rows, cols) must match."""
    p = Path(path)
    chunks: list = []
    w, h, fmt, raw = _checked_image(p, what, max_side_px, max_pixels, chunks)
    img = decode_rgb8_bgr(chunks) if color and fmt == "PNG" else None
    if img is None:
        with quiet_opencv():
            img = cv2.imdecode(np.frombuffer(raw, np.uint8), cv2.IMREAD_COLOR if color else cv2.IMREAD_GRAYSCALE)
    if img is None or img.size == 0:
        raise BadFile(p, f"{what} cannot be decoded as {fmt} (corrupt or truncated)", f"a valid {fmt} image")
    if img.shape[1] != w or img.shape[0] != h:
        raise BadFile(p, f"{what} decodes to {img.shape[1]}x{img.shape[0]} px but its header says {w}x{h}",
                      "a consistent image")
    if shape is not None and tuple(img.shape[:2]) != tuple(shape):
        raise BadFile(p, f"{what} is {img.shape[1]}x{img.shape[0]} px", f"{shape[1]}x{shape[0]} px")
    return img


def decode_image_bytes(data: bytes, source: str | Path, what: str = "image", *,
                       max_side_px: int = MAX_IMAGE_SIDE_PX, max_pixels: int = MAX_IMAGE_PIXELS) -> np.ndarray:
    """Decode an in-memory PNG/JPEG (e.g. a recorded frame) after bounding its header's size."""
    p = Path(str(source))
    bio = io.BytesIO(data)
    head = data[:32]
    if head.startswith(PNG_SIGNATURE):
        size, problem = _png_size(head), png_problem(data)
    elif head.startswith(b"\xff\xd8"):
        size, problem = _jpeg_size(bio), jpeg_problem(data)
    else:
        raise BadFile(p, f"{what} is neither PNG nor JPEG (starts with {head[:8]!r})", "a PNG or JPEG image")
    if size is None:
        raise BadFile(p, f"{what} has a truncated or malformed header", "a complete PNG or JPEG image")
    if problem:
        raise BadFile(p, f"{what} is damaged: {problem}", "an intact PNG or JPEG image")
    check_image_dims(p, what, size[0], size[1], max_side_px, max_pixels)
    with quiet_opencv():
        img = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    if img is None or img.size == 0:
        raise BadFile(p, f"{what} cannot be decoded (corrupt or truncated)", "a valid PNG or JPEG image")
    return img
