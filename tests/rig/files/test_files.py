"""rig.files: whatever bytes a file holds, a loader returns a checked value or raises BadFile
(never another exception, never an allocation the header asked for)."""

from __future__ import annotations

import io
import json
import struct
import zlib
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import cv2

from tactile_rig.core.errors import BadFile, MissingFile
from tactile_rig.rig import files

SETTINGS = settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])


def _npy(arr: np.ndarray) -> bytes:
    b = io.BytesIO()
    np.save(b, arr)
    return b.getvalue()


def _npz(**arrays: np.ndarray) -> bytes:
    b = io.BytesIO()
    np.savez_compressed(b, **arrays)
    return b.getvalue()


def _npz_stored(**arrays: np.ndarray) -> bytes:
    b = io.BytesIO()
    np.savez(b, **arrays)  # uncompressed members: read by files.load_npz itself, CRC and all
    return b.getvalue()


def _png(img: np.ndarray) -> bytes:
    return cv2.imencode(".png", img)[1].tobytes()


GOOD = {
    "npy": _npy(np.linspace(0, 1, 64 * 48, dtype=np.float32).reshape(48, 64)),
    "npz": _npz(a=np.arange(100, dtype=np.float64), b=np.ones((4, 4), np.int16)),
    "npz_stored": _npz_stored(a=np.arange(100, dtype=np.float64), f=np.asfortranarray(np.ones((3, 5), np.int16))),
    "json": b'{"a": [1, 2, {"b": 3.5}], "c": "text"}',
    "png": _png(np.arange(48 * 64 * 3, dtype=np.uint8).reshape(48, 64, 3)),
}
LOAD = {
    "npy": lambda p: files.load_npy(p, "array", ndim=2),
    "npz": lambda p: files.load_npz(p, "archive"),
    "npz_stored": lambda p: files.load_npz(p, "archive"),
    "json": lambda p: files.load_json(p, "doc"),
    "png": lambda p: files.read_image(p, "frame"),
}


def _mutate(data: bytes, pos: float, bit: int, cut: float, mode: str) -> bytes:
    i = int(pos * len(data))
    if mode == "flip":
        b = bytearray(data)
        b[i] ^= 1 << bit
        return bytes(b)
    return data[: int(cut * len(data))]


def _npz_arrays(data: bytes) -> dict[str, np.ndarray]:
    with np.load(io.BytesIO(data), allow_pickle=False) as z:
        return {k: z[k] for k in z.files}


# What the field's own reader makes of the same bytes: a loader that returns a value returns this.
REFERENCE = {
    "npy": lambda data: np.load(io.BytesIO(data), allow_pickle=False),
    "npz": _npz_arrays,
    "npz_stored": _npz_arrays,
    "json": json.loads,
    "png": lambda data: cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR),
}


def _assert_same(kind: str, value: object, data: bytes) -> None:
    """A loader's value is exactly what the reference reader decodes from the same bytes."""
    ref = REFERENCE[kind](data)
    if kind in ("npz", "npz_stored"):
        assert isinstance(value, dict) and sorted(value) == sorted(ref)
        for k in ref:
            assert value[k].dtype == ref[k].dtype
            np.testing.assert_array_equal(value[k], ref[k])
    elif kind == "json":
        assert value == ref
    else:
        assert isinstance(value, np.ndarray) and value.dtype == ref.dtype
        np.testing.assert_array_equal(value, ref)


def _assert_names_the_file(exc: BadFile, p: Path) -> None:
    assert exc.path == str(p) and exc.problem and str(exc).startswith(str(p))


@SETTINGS
@given(kind=st.sampled_from(sorted(GOOD)), pos=st.floats(0, 1, exclude_max=True), bit=st.integers(0, 7),
       cut=st.floats(0, 1, exclude_max=True), mode=st.sampled_from(["flip", "cut"]))
def test_a_damaged_file_is_a_value_or_a_badfile(tmp_path: Path, kind: str, pos: float, bit: int, cut: float,
                                                 mode: str) -> None:
    """A flipped bit or a cut file: a BadFile naming it, or (damage the format cannot see, such as a
    flipped bit in a .npy's data) exactly the value the bytes now hold."""
    p = tmp_path / f"x.{kind}"
    data = _mutate(GOOD[kind], pos, bit, cut, mode)
    p.write_bytes(data)
    try:
        value = LOAD[kind](p)
    except BadFile as exc:
        _assert_names_the_file(exc, p)
        return
    assert kind != "png", "a damaged PNG was decoded: every chunk carries a CRC and the file ends with IEND"
    _assert_same(kind, value, data)


@SETTINGS
@given(data=st.binary(max_size=400), kind=st.sampled_from(sorted(GOOD)))
def test_arbitrary_bytes_are_a_badfile(tmp_path: Path, data: bytes, kind: str) -> None:
    """Bytes that are not a file of the kind raise BadFile naming it; bytes that happen to be one
    (``{}`` is a JSON object) give exactly what the field's own reader makes of them."""
    p = tmp_path / f"y.{kind}"
    p.write_bytes(data)
    try:
        value = LOAD[kind](p)
    except BadFile as exc:
        _assert_names_the_file(exc, p)
        return
    _assert_same(kind, value, data)


def test_arbitrary_bytes_that_are_no_file_of_the_kind_are_refused(tmp_path: Path) -> None:
    """The refusal is not left to chance: bytes no reader accepts are a BadFile for every kind."""
    for kind in sorted(GOOD):
        for data in (b"", b"\x00" * 40, b"not a file", GOOD[kind][: len(GOOD[kind]) // 2]):
            p = tmp_path / f"z.{kind}"
            p.write_bytes(data)
            with pytest.raises(BadFile) as info:
                LOAD[kind](p)
            _assert_names_the_file(info.value, p)


def test_uncompressed_npz_members_read_in_place_and_every_data_flip_is_refused(tmp_path: Path) -> None:
    a = np.linspace(-1.0, 1.0, 600, dtype=np.float32).reshape(20, 30)
    f = np.asfortranarray(np.arange(15, dtype=np.int64).reshape(3, 5))
    p = tmp_path / "s.npz"
    np.savez(p, a=a, f=f, t=np.array("meta"))
    got = files.load_npz(p, "archive", arrays={"t": {"kinds": "U", "ndim": 0, "finite": False}})
    np.testing.assert_array_equal(got["a"], a)
    np.testing.assert_array_equal(got["f"], f)
    assert str(got["t"]) == "meta" and got["a"].dtype == np.float32
    assert got["a"].flags.writeable and got["f"].flags.writeable  # callers may work on them in place
    data = p.read_bytes()
    start = data.index(a.tobytes()[:64])
    for i in range(start, start + a.nbytes, 37):  # flips inside the member's data: its CRC-32 catches each
        b = bytearray(data)
        b[i] ^= 0x10
        p.write_bytes(bytes(b))
        with pytest.raises(BadFile, match="CRC"):
            files.load_npz(p, "archive", arrays={"t": {"kinds": "U", "ndim": 0, "finite": False}})


def test_png_flips_never_reach_the_decoder(tmp_path: Path) -> None:
    """PNG keeps a CRC per chunk: every single-bit flip in the file is refused by name."""
    data = GOOD["png"]
    for i in range(8, len(data), max(1, len(data) // 300)):
        b = bytearray(data)
        b[i] ^= 0x04
        p = tmp_path / "f.png"
        p.write_bytes(bytes(b))
        with pytest.raises(BadFile):
            files.read_image(p)


@pytest.mark.parametrize("w,h", [(65535, 65535), (99999, 99999), (0, 5), (20000, 1)])
def test_image_headers_are_bounded_before_decoding(tmp_path: Path, w: int, h: int) -> None:
    def chunk(tag: bytes, d: bytes) -> bytes:
        return struct.pack(">I", len(d)) + tag + d + struct.pack(">I", zlib.crc32(tag + d))

    p = tmp_path / "big.png"
    p.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 2, 0, 0, 0))
                  + chunk(b"IEND", b""))
    with pytest.raises(BadFile, match=f"{w}x{h}"):
        files.read_image(p)


def test_npy_headers_dtypes_and_values(tmp_path: Path) -> None:
    cases = {
        "c.npy": (np.zeros((4, 4), np.complex64), "complex"),
        "s.npy": (np.zeros(3, dtype=[("a", "f4")]), "structured"),
        "n.npy": (np.full((4, 4), np.nan), "NaN"),
        "b.npy": (np.ones((4, 4), bool), "bool"),
    }
    for name, (arr, word) in cases.items():
        np.save(tmp_path / name, arr)
        with pytest.raises(BadFile, match=word):
            files.load_npy(tmp_path / name)
    big = GOOD["npy"].replace(b"(48, 64)", b"(99999, 99999)"[:8])
    (tmp_path / "h.npy").write_bytes(big)
    with pytest.raises(BadFile):
        files.load_npy(tmp_path / "h.npy")
    with pytest.raises(MissingFile):
        files.load_npy(tmp_path / "missing.npy")
    (tmp_path / "d.npy").mkdir()
    with pytest.raises(BadFile, match="directory"):
        files.load_npy(tmp_path / "d.npy")


def test_json_depth_is_bounded_without_recursion(tmp_path: Path) -> None:
    p = tmp_path / "deep.json"
    p.write_text("[" * 200000 + "]" * 200000)
    with pytest.raises(BadFile, match="200000 levels deep"):
        files.load_json(p, expect=None)
    assert files.json_depth('{"a": "[[[[", "b": [[1]]}') == 3  # brackets inside strings do not count
