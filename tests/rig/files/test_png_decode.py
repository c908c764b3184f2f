"""read_image's own PNG decode (8-bit RGB, rows filtered None or Sub) gives OpenCV's pixels; any other
PNG goes to OpenCV, and a damaged file is refused by its chunk CRCs before any decoder sees it."""

from __future__ import annotations

import struct
import zlib

import cv2
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from tactile_rig.core.errors import BadFile
from tactile_rig.rig import files
from tactile_rig.rig.files import deflate, png


@pytest.fixture(params=["default", "zlib"])
def inflater(request, monkeypatch):
    """Both inflaters: the fast extra's if installed, and the standard library's."""
    if request.param == "zlib":
        monkeypatch.setattr(deflate, "_decompressobj", zlib.decompressobj)
        monkeypatch.setattr(deflate, "_crc", zlib.crc32)
    return request.param


def _chunk(tag: bytes, body: bytes) -> bytes:
    return struct.pack(">I", len(body)) + tag + body + struct.pack(">I", zlib.crc32(tag + body))


def _png(rgb_rows: np.ndarray, filters: list[int], extra: list[tuple[bytes, bytes]] = (), ctype: int = 2,
         stream: bytes | None = None) -> bytes:
    """A PNG written here byte by byte: rows already filtered, each prefixed by its filter type."""
    h, w = rgb_rows.shape[:2]
    raw = b"".join(bytes([f]) + rgb_rows[i].tobytes() for i, f in enumerate(filters))
    ihdr = struct.pack(">IIBBBBB", w, h, 8, ctype, 0, 0, 0)
    body = [_chunk(b"IHDR", ihdr)] + [_chunk(t, b) for t, b in extra]
    body.append(_chunk(b"IDAT", zlib.compress(raw) if stream is None else stream))
    return b"\x89PNG\r\n\x1a\n" + b"".join(body) + _chunk(b"IEND", b"")


def _sub(rgb: np.ndarray) -> np.ndarray:
    """PNG's Sub filter of an HxWx3 image: each byte minus the one 3 to its left, mod 256."""
    out = rgb.astype(np.int16)
    out[:, 1:] -= rgb[:, :-1]
    return (out % 256).astype(np.uint8)


def _read(tmp_path, data: bytes) -> np.ndarray:
    p = tmp_path / "f.png"
    p.write_bytes(data)
    return files.read_image(p)


def _opencv(data: bytes) -> np.ndarray:
    return cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)


@settings(deadline=None, max_examples=40, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(st.integers(1, 70), st.integers(1, 90), st.sampled_from([None, 0, 1, 3, 9]), st.integers(0, 2**31 - 1))
def test_opencv_written_pngs_decode_to_opencvs_pixels(tmp_path, h, w, level, seed) -> None:
    img = np.random.default_rng(seed).integers(0, 256, (h, w, 3), dtype=np.uint8)
    ok, buf = cv2.imencode(".png", img, [] if level is None else [cv2.IMWRITE_PNG_COMPRESSION, level])
    assert ok
    got = _read(tmp_path, buf.tobytes())
    assert got.dtype == np.uint8 and got.shape == (h, w, 3)
    np.testing.assert_array_equal(got, img)
    if level is None:  # OpenCV's default writes Sub rows: decoded here, not by OpenCV
        assert png.decode_rgb8_bgr(png.png_chunks(buf.tobytes())[1]) is not None


@pytest.mark.parametrize("filters", ["sub", "none", "mixed", "up", "paeth"])
def test_each_filter_mix_decodes_like_opencv(tmp_path, inflater, filters) -> None:
    rng = np.random.default_rng(3)
    rgb = rng.integers(0, 256, (9, 13, 3), dtype=np.uint8)
    kinds = {"sub": [1] * 9, "none": [0] * 9, "mixed": [0, 1, 1, 0, 1, 0, 0, 1, 1],
             "up": [1, 2] + [1] * 7, "paeth": [4] * 9}[filters]
    rows = np.stack([_sub(rgb[i:i + 1])[0] if k == 1 else rgb[i] for i, k in enumerate(kinds)])
    if filters in ("up", "paeth"):  # rows OpenCV decodes: the filtered bytes need not be realistic
        rows = rng.integers(0, 256, rgb.shape, dtype=np.uint8)
    data = _png(rows, kinds)
    got = _read(tmp_path, data)
    np.testing.assert_array_equal(got, _opencv(data))
    ours = png.decode_rgb8_bgr(png.png_chunks(data)[1])
    if filters in ("sub", "none", "mixed"):
        np.testing.assert_array_equal(got, rgb[:, :, ::-1])
        assert ours is not None
    else:
        assert ours is None


@pytest.mark.parametrize("extra", [[(b"gAMA", struct.pack(">I", 45455))], [(b"tEXt", b"Software\0test")],
                                   [(b"sBIT", b"\x08\x08\x08")], [(b"tRNS", b"\x00\x01\x00\x02\x00\x03")]])
def test_ancillary_chunks_decode_like_opencv(tmp_path, extra) -> None:
    rgb = np.random.default_rng(1).integers(0, 256, (6, 7, 3), dtype=np.uint8)
    data = _png(_sub(rgb), [1] * 6, extra)
    np.testing.assert_array_equal(_read(tmp_path, data), _opencv(data))


@pytest.mark.parametrize("kind", ["grey", "rgba", "16bit", "palette"])
def test_other_png_kinds_go_to_opencv(tmp_path, kind) -> None:
    rng = np.random.default_rng(2)
    img = {"grey": rng.integers(0, 256, (5, 6), dtype=np.uint8),
           "rgba": rng.integers(0, 256, (5, 6, 4), dtype=np.uint8),
           "16bit": rng.integers(0, 65536, (5, 6, 3), dtype=np.uint16),
           "palette": rng.integers(0, 256, (5, 6, 3), dtype=np.uint8)}[kind]
    ok, buf = cv2.imencode(".png", img, [cv2.IMWRITE_PNG_BILEVEL, 0])
    assert ok
    np.testing.assert_array_equal(_read(tmp_path, buf.tobytes()), _opencv(buf.tobytes()))


@pytest.mark.parametrize("stream", ["corrupt", "short", "long", "bomb"])
def test_a_bad_stream_with_good_crcs_is_opencvs_to_judge(tmp_path, inflater, stream) -> None:
    rgb = np.random.default_rng(4).integers(0, 256, (8, 10, 3), dtype=np.uint8)
    raw = b"".join(b"\x01" + r.tobytes() for r in _sub(rgb))
    body = {"corrupt": zlib.compress(raw)[:-9] + b"\x00" * 9, "short": zlib.compress(raw[:-31]),
            "long": zlib.compress(raw + b"\x00" * 500), "bomb": zlib.compress(b"\x00" * 20_000_000)}[stream]
    data = _png(rgb, [1] * 8, stream=body)
    ref = _opencv(data)
    if ref is None:
        with pytest.raises(BadFile, match="cannot be decoded"):
            _read(tmp_path, data)
    else:
        np.testing.assert_array_equal(_read(tmp_path, data), ref)


def test_a_flipped_bit_is_still_refused_by_its_crc(tmp_path, inflater) -> None:
    img = np.random.default_rng(5).integers(0, 256, (20, 30, 3), dtype=np.uint8)
    data = bytearray(cv2.imencode(".png", img)[1].tobytes())
    data[60] ^= 0x10
    with pytest.raises(BadFile, match="fails its CRC"):
        _read(tmp_path, bytes(data))
    assert files.png_problem(bytes(data)) is not None
    assert files.png_problem(cv2.imencode(".png", img)[1].tobytes()) is None
