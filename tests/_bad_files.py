"""Malformed input files for every CLI command that reads files, made deterministically from a seed.

Each *kind* names one command and the file it reads; :func:`generate` writes 100+ malformed files of
that kind (zero bytes, truncations, flipped bits, hostile headers, wrong dtypes and shapes, NaN,
nesting, folders in place of files) plus the valid companions the command needs, and returns
:class:`BadCase` rows whose ``argv`` runs the command on one file. Every case is malformed by
construction: the command must refuse it with exit code 2 and one line on stderr. :func:`good_case`
writes the same command's valid input, which it must accept (exit 0).

    cases = generate("npy", tmp_dir, seed=0)
    for case in cases:
        code = tactile_rig.cli.main(case.argv)

Used by ``benchmarks/bench_bad_files.py`` (the soak) and ``tests/cli/test_bad_files.py`` (a subset).
"""

from __future__ import annotations

import base64
import io
import json
import random
import struct
import zipfile
import zlib
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import cv2
import numpy as np
from mcap.writer import CompressionType, Writer

from tactile_rig.perception.gelsight import TactileMap
from tactile_rig.sim.render.fingervision import FingerVisionRenderer

__all__ = ["KINDS", "BadCase", "generate", "generate_all", "good_case"]

MM_PER_PX = "0.0634"


@dataclass(frozen=True)
class BadCase:
    """One input of a file-reading command: the kind, a short name of the malformation, the file, the
    argv, and the exit code the command must give (2 for a malformed input; a valid one's own)."""

    kind: str
    name: str
    path: str
    argv: tuple[str, ...]
    exit_code: int = 2


# -- valid companions -------------------------------------------------------------------------
def good_height_mm(rng: np.random.Generator, shape: tuple[int, int] = (60, 80)) -> np.ndarray:
    """A small smooth height map (mm) with texture, float32."""
    y, x = np.mgrid[0:shape[0], 0:shape[1]].astype(np.float32)
    h = 0.2 * np.sin(x / 5.0) * np.cos(y / 7.0) + 0.05 * rng.standard_normal(shape).astype(np.float32)
    return np.clip(h, 0, None).astype(np.float32)


def _png(img: np.ndarray) -> bytes:
    ok, buf = cv2.imencode(".png", img)
    assert ok
    return buf.tobytes()


def _jpeg(img: np.ndarray) -> bytes:
    ok, buf = cv2.imencode(".jpg", img)
    assert ok
    return buf.tobytes()


def good_image(rng: np.random.Generator, shape: tuple[int, int] = (48, 64)) -> np.ndarray:
    return rng.integers(0, 255, (*shape, 3), dtype=np.uint8)


def _npy_bytes(arr: np.ndarray, allow_pickle: bool = False) -> bytes:
    b = io.BytesIO()
    np.save(b, arr, allow_pickle=allow_pickle)
    return b.getvalue()


def npy_with_header(header: str, body: bytes) -> bytes:
    """A version-1 ``.npy`` file with ``header`` (padded as NumPy does) followed by ``body``."""
    pad = (64 - (10 + len(header) + 1) % 64) % 64
    hb = (header + " " * pad + "\n").encode("latin1")
    return b"\x93NUMPY\x01\x00" + struct.pack("<H", len(hb)) + hb + body


def _chunk(tag: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + tag + data + struct.pack(">I", zlib.crc32(tag + data))


def png_header_only(width: int, height: int) -> bytes:
    """A PNG whose IHDR claims ``width`` x ``height`` pixels (and holds no data)."""
    ihdr = struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)
    return b"\x89PNG\r\n\x1a\n" + _chunk(b"IHDR", ihdr) + _chunk(b"IDAT", zlib.compress(b"\0" * 64)) + \
        _chunk(b"IEND", b"")


def jpeg_with_size(good_jpeg: bytes, width: int, height: int) -> bytes:
    """``good_jpeg`` with its frame header's size replaced."""
    data = bytearray(good_jpeg)
    i = 2
    while i < len(data) - 9:
        if data[i] == 0xFF and 0xC0 <= data[i + 1] <= 0xCF and data[i + 1] not in (0xC4, 0xC8, 0xCC):
            struct.pack_into(">HH", data, i + 5, height, width)
            return bytes(data)
        if data[i] == 0xFF and data[i + 1] not in (0xD8, 0x01) and not 0xD0 <= data[i + 1] <= 0xD7:
            i += 2 + struct.unpack(">H", data[i + 2:i + 4])[0]
        else:
            i += 1
    return bytes(data)


# -- generic corruptions ----------------------------------------------------------------------
def _truncations(data: bytes, rng: random.Random, n: int) -> list[tuple[str, bytes]]:
    cuts = sorted({1, 2, 7, 8, 10, 16, len(data) // 2, len(data) - 1,
                   *(rng.randrange(1, max(2, len(data))) for _ in range(n))})
    return [(f"truncated@{c}", data[:c]) for c in cuts if 0 < c < len(data)][:n + 8]


def _flips(data: bytes, rng: random.Random, n: int, head: int | None = None) -> list[tuple[str, bytes]]:
    out = []
    for _ in range(n):
        pos = rng.randrange(0, min(len(data), head) if head else len(data))
        b = bytearray(data)
        b[pos] ^= 1 << rng.randrange(8)
        out.append((f"bitflip@{pos}", bytes(b)))
    return out


def _common(rng: random.Random) -> list[tuple[str, bytes | None]]:
    """Malformations any file kind can suffer (``None``: a folder in the file's place)."""
    return [("zero-bytes", b""), ("one-byte", b"\0"), ("garbage", bytes(rng.randrange(256) for _ in range(512))),
            ("text", b"hello, this is not the file you want\n"), ("folder", None)]


# -- kinds ------------------------------------------------------------------------------------
def _npy_cases(rng: random.Random, nrng: np.random.Generator) -> list[tuple[str, bytes | None]]:
    good = _npy_bytes(good_height_mm(nrng))
    cases: list[tuple[str, bytes | None]] = list(_common(rng))
    bad_arrays = {
        "complex": good_height_mm(nrng).astype(np.complex64),
        "structured": np.zeros(100, dtype=[("a", "f4"), ("b", "i4")]),
        "bool": np.ones((60, 80), bool),
        "strings": np.array([["a", "b"], ["c", "d"]]),
        "nan": np.where(good_height_mm(nrng) > 0.1, np.nan, 0.0).astype(np.float32),
        "inf": np.full((60, 80), np.inf, np.float32),
        "neg-inf-one": np.pad(np.array([[-np.inf]], np.float32), ((0, 59), (0, 79))),
        "1-d": np.zeros(4800, np.float32),
        "3-d": np.zeros((4, 60, 80), np.float32),
        "0-d": np.array(1.0, np.float32),
        "empty": np.zeros((0, 80), np.float32),
        "tiny": np.zeros((2, 2), np.float32),
        "datetime": np.zeros((60, 80), "datetime64[s]"),
    }
    cases += [(k, _npy_bytes(v)) for k, v in bad_arrays.items()]
    cases.append(("object-pickle", _npy_bytes(np.array([{"a": 1}, None], dtype=object), allow_pickle=True)))
    body = good[10 + struct.unpack("<H", good[8:10])[0]:]
    for shape in ("(65535, 65535)", "(99999, 99999)", "(1, 1000000000000)", "(-1, 5)", "(60, 80, 0, 9999999999)",
                  "(60, 'x')", "(60.5, 80)"):
        cases.append((f"header-shape{shape}", npy_with_header(
            f"{{'descr': '<f4', 'fortran_order': False, 'shape': {shape}, }}", body)))
    for header in ("[1, 2, 3]", "{'descr': '<f4'}", "{'descr': 'O', 'fortran_order': False, 'shape': (60, 80), }",
                   "{'descr': '<c8', 'fortran_order': False, 'shape': (60, 40), }",
                   "{'descr': [('a', '<f4')], 'fortran_order': False, 'shape': (4800,), }",
                   "__import__('os')",
                   "{'descr': '<f4', 'fortran_order': False, 'shape': (60, 80), 'extra': " + "[" * 3000 + "]" * 3000 + "}"):
        cases.append((f"header-{header[:24]}", npy_with_header(header, body)))
    cases.append(("header-version-9", b"\x93NUMPY\x09\x00" + good[8:]))
    cases.append(("header-huge-length", good[:8] + b"\xff\xff" + good[10:]))
    cases += _truncations(good, rng, 30)
    cases += _flips(good, rng, 40, head=128)
    return cases


def _write_npz(members: dict[str, bytes]) -> bytes:
    b = io.BytesIO()
    with zipfile.ZipFile(b, "w", zipfile.ZIP_DEFLATED) as z:
        for k, v in members.items():
            z.writestr(k, v)
    return b.getvalue()


def _map_members(nrng: np.random.Generator, **over: object) -> dict[str, bytes]:
    total = good_height_mm(nrng, (180, 240))
    meta = {"format": "tactile_rig.gelsight.tactile_map", "version": 1, "mm_per_px": 0.0634, "canvas_factor": 3.0,
            "accept_confidence": 0.98, "touches": 1, "touch_shape": [60, 80]}
    meta.update({k: v for k, v in over.items() if k in meta or k.startswith("meta_")})
    arrays = {"total": total, "count": np.ones_like(total), "g_T_m": np.zeros((1, 2, 3)),
              "meta": np.array(json.dumps(meta))}
    for k, v in over.items():
        if k.startswith("arr_"):
            if v is None:
                arrays.pop(k[4:], None)
            else:
                arrays[k[4:]] = v  # type: ignore[assignment]
    return {f"{k}.npy": _npy_bytes(v, allow_pickle=v.dtype == object) for k, v in arrays.items()}


def _map_cases(rng: random.Random, nrng: np.random.Generator) -> list[tuple[str, bytes | None]]:
    good = _write_npz(_map_members(nrng))
    cases: list[tuple[str, bytes | None]] = list(_common(rng))
    variants: dict[str, dict[str, object]] = {
        "no-meta": {"arr_meta": None}, "no-total": {"arr_total": None}, "no-poses": {"arr_g_T_m": None},
        "meta-not-json": {"arr_meta": np.array("{not json")}, "meta-deep": {"arr_meta": np.array("[" * 5000 + "]" * 5000)},
        "meta-list": {"arr_meta": np.array("[1, 2]")}, "meta-nan": {"arr_meta": np.array('{"mm_per_px": NaN}')},
        "meta-number": {"arr_meta": np.array(3.0)},
        "mm-per-px-zero": {"mm_per_px": 0.0}, "mm-per-px-huge": {"mm_per_px": 1e300}, "mm-per-px-text": {"mm_per_px": "x"},
        "canvas-zero": {"canvas_factor": 0.0}, "confidence-2": {"accept_confidence": 2.0},
        "wrong-format": {"format": "other"}, "wrong-version": {"version": 99},
        "total-nan": {"arr_total": np.full((180, 240), np.nan, np.float32)},
        "total-complex": {"arr_total": np.zeros((180, 240), np.complex64)},
        "total-1d": {"arr_total": np.zeros(10, np.float32)},
        "count-shape": {"arr_count": np.ones((10, 10), np.float32)},
        "poses-shape": {"arr_g_T_m": np.zeros((1, 3, 3))}, "poses-nan": {"arr_g_T_m": np.full((1, 2, 3), np.nan)},
        "object-member": {"arr_total": np.array([None, {"a": 1}], dtype=object)},
        "structured": {"arr_count": np.zeros(5, dtype=[("a", "f4")])},
        "touch-shape-bad": {"touch_shape": "x"},
    }
    for name, over in variants.items():
        cases.append((name, _write_npz(_map_members(nrng, **over))))
    members = _map_members(nrng)
    members["evil.pkl"] = b"cos\nsystem\n(S'echo pwned'\ntR."
    cases.append(("non-npy-member", _write_npz(members)))
    members = _map_members(nrng)
    members["total.npy"] = _npy_bytes(np.zeros((60, 80), np.float32))[:50]
    cases.append(("member-truncated", _write_npz(members)))
    # A member whose header claims a huge array (a bomb without the bytes).
    members = _map_members(nrng)
    raw = members["total.npy"]
    members["total.npy"] = raw.replace(b"(180, 240)", b"(99999, 99999)"[:10].ljust(10)) if b"(180, 240)" in raw else raw
    cases.append(("member-header-huge", _write_npz(members)))
    cases += _truncations(good, rng, 25)
    cases += _flips(good, rng, 35)
    return cases


def _image_cases(rng: random.Random, nrng: np.random.Generator) -> list[tuple[str, bytes | None]]:
    img = good_image(nrng)
    png, jpg = _png(img), _jpeg(img)
    cases: list[tuple[str, bytes | None]] = list(_common(rng))
    for w, h in ((65535, 65535), (99999, 99999), (0, 10), (10, 0), (100000, 1), (2**31 - 1, 2**31 - 1)):
        cases.append((f"png-header-{w}x{h}", png_header_only(w, h)))
    for w, h in ((65535, 65535), (0, 48), (64, 0), (60000, 60000)):
        cases.append((f"jpeg-header-{w}x{h}", jpeg_with_size(jpg, w, h)))
    bmp = bytearray(b"BM" + b"\0" * 52)
    struct.pack_into("<ii", bmp, 18, 65535, 65535)
    cases.append(("bmp-header-65535x65535", bytes(bmp)))
    cases.append(("pnm-header-huge", b"P6\n99999 99999\n255\n" + b"\0" * 30))
    cases.append(("tiff-garbage", b"II*\0" + b"\xff" * 20))
    cases.append(("png-signature-only", png[:8]))
    cases.append(("gif", b"GIF89a" + b"\0" * 40))
    cases += [(f"png-{n}", d) for n, d in _truncations(png, rng, 20)]
    cases += [(f"jpeg-{n}", d) for n, d in _truncations(jpg, rng, 15)]
    cases += [(f"png-{n}", d) for n, d in _flips(png, rng, 20, head=40)]
    # No JPEG bit flips: JPEG has no checksum, a flipped bit decodes to another valid picture.
    return cases


def _json_config_cases(rng: random.Random) -> list[tuple[str, bytes | None]]:
    cases: list[tuple[str, bytes | None]] = list(_common(rng))
    docs = ["[" * 100000 + "]" * 100000, '{"a":' * 5000 + "1" + "}" * 5000, "[1, 2, 3]", '"text"', "null", "3.5",
            '{"detector": NaN}', '{"detector": Infinity}', '{"detector": 5}', '{"detector": {"min_area_px": "x"}}',
            '{"detector": {"min_area_px": -1e300}}', '{"tracker": [1, 2]}', '{"n_calib_frames": -5}',
            '{"n_calib_frames": 1e300}', '{"n_calib_frames": "ten"}', '{"unknown_section": {}}',
            '{"force": {"nonsense": 1}}', '{"proximity": null}', "{", '{"a": 1,}', "\ufeff{}", '{"a": "\\ud800"}']
    cases += [(f"json-{i}", d.encode("utf-8", "surrogatepass")) for i, d in enumerate(docs)]
    cases.append(("latin1", '{"detector": "é"}'.encode("latin-1")))
    good = json.dumps({"n_calib_frames": 3, "detector": {}}).encode()
    cases += _truncations(good, rng, 20)
    cases += [(n, d) for n, d in _flips(good, rng, 150) if not _parses_as_json(d)][:60]  # a digit flip stays valid
    return cases


def _parses_as_json(data: bytes) -> bool:
    try:
        json.loads(data)
    except (ValueError, UnicodeDecodeError):
        return False
    return True


def _toml_cases(rng: random.Random, good: bytes) -> list[tuple[str, bytes | None]]:
    cases: list[tuple[str, bytes | None]] = list(_common(rng))
    docs = ["x = " + "[" * 5000 + "]" * 5000, "a = {b = " * 3000 + "1" + "}" * 3000, "[[[", "= 3", "a = \"unterminated",
            "[scale]\nport = 1e999\n", "[scale]\nport = \"rigsim://scale\"\nmax_force_n = inf\n",
            "[scale]\nport = \"rigsim://scale\"\nmax_force_n = nan\n", "[gripper]\nport = \"rigsim://dynamixel\"\nids = [1, 1]\n",
            "[scale]\nport = \"\"\n", "[camera]\nport = \"rigsim://camera\"\nwidth = 100000000000\n",
            "[jig]\nport = \"rigsim://jig\"\nx_limits_mm = [-inf, inf]\n", "[bench]\nseed = -1\n", "[bench]\nseed = 1e3\n",
            "[nonsense]\nport = \"x\"\n", "bench = 5\n", "[scale]\n", "[scale]\nport = [1, 2]\n",
            "[camera]\nport = \"rigsim://camera\"\nfps = -1\n", "[camera]\nport = \"rigsim://camera\"\nheight = 0\n"]
    cases += [(f"toml-{i}", d.encode()) for i, d in enumerate(docs)]
    cases.append(("not-utf8", b"\xff\xfe[scale]\n"))
    cases += _truncations(good, rng, 20)
    cases += _flips(good, rng, 50)
    return cases


def _good_mcap(nrng: np.random.Generator) -> bytes:
    b = io.BytesIO()
    w = Writer(b, chunk_size=1024, compression=CompressionType.ZSTD, enable_data_crcs=True)
    w.start(profile="", library="bad_files")
    sid = w.register_schema(name="tactile_rig.ScaleReading", encoding="jsonschema", data=b"{}")
    cid = w.register_channel(topic="/scale/force", message_encoding="json", schema_id=sid)
    iid = w.register_schema(name="foxglove.CompressedImage", encoding="jsonschema", data=b"{}")
    icid = w.register_channel(topic="/camera/c/compressed", message_encoding="json", schema_id=iid)
    for i in range(80):
        t = i * 50_000_000
        w.add_message(channel_id=cid, log_time=t, publish_time=t, sequence=i,
                      data=json.dumps({"t_s": i * 0.05, "force_n": float(nrng.normal())}).encode())
        if i % 20 == 0:
            img = base64.b64encode(_png(good_image(nrng, (8, 8)))).decode()
            w.add_message(channel_id=icid, log_time=t, publish_time=t, sequence=i,
                          data=json.dumps({"t_s": i * 0.05, "format": "png", "data": img}).encode())
    w.add_metadata("bench", {"name": "bad_files"})
    w.finish()
    return b.getvalue()


def _mcap_with_message(data: bytes) -> bytes:
    b = io.BytesIO()
    w = Writer(b, enable_data_crcs=True)
    w.start(profile="", library="bad_files")
    sid = w.register_schema(name="tactile_rig.Json", encoding="jsonschema", data=b"{}")
    cid = w.register_channel(topic="/evil", message_encoding="json", schema_id=sid)
    w.add_message(channel_id=cid, log_time=0, publish_time=0, data=data)
    w.finish()
    return b.getvalue()


def _mcap_cases(rng: random.Random, nrng: np.random.Generator) -> list[tuple[str, bytes | None]]:
    good = _good_mcap(nrng)
    cases: list[tuple[str, bytes | None]] = list(_common(rng))
    cases.append(("magic-only", good[:8]))
    cases.append(("wrong-magic", b"\x89MCAP1\r\n" + good[8:]))
    cases.append(("deep-json-message", _mcap_with_message(b"[" * 50000 + b"]" * 50000)))
    cases.append(("deep-object-message", _mcap_with_message(b'{"a":' * 20000 + b"1" + b"}" * 20000)))
    cases.append(("huge-record-length", good[:9] + struct.pack("<Q", 2**62) + good[17:]))
    # Bit flips inside a complete file: every one must be refused (the CRCs cover the data section).
    cases += _flips(good[: len(good) // 2] + good[len(good) // 2:], rng, 100, head=len(good) // 2)
    return cases


def _press_folder_cases(rng: random.Random, nrng: np.random.Generator) -> list[tuple[str, dict[str, bytes] | None]]:
    """Press folders: ``{file name: bytes}`` (``None``: a file where the folder should be)."""
    bg = good_image(nrng)
    press = _png(np.clip(bg.astype(int) + 20, 0, 255).astype(np.uint8))
    labels = "file,center_x_px,center_y_px,contact_radius_px\npress_00.png,32,24,8\n"
    base = {"background.png": _png(bg), "press_00.png": press, "labels.csv": labels.encode()}
    out: list[tuple[str, dict[str, bytes] | None]] = [("file-not-folder", None), ("empty-folder", {})]
    out.append(("no-labels", {k: v for k, v in base.items() if k != "labels.csv"}))
    out.append(("no-background", {k: v for k, v in base.items() if k != "background.png"}))
    out.append(("missing-press", {**base, "press_00.png": b""}))
    for n, img in _image_cases(rng, nrng):
        if img is not None:
            out.append((f"background-{n}", {**base, "background.png": img}))
    for n, img in _image_cases(rng, nrng)[:30]:
        if img is not None:
            out.append((f"press-{n}", {**base, "press_00.png": img}))
    rows = ["file,center_x_px\npress_00.png,1\n", "nonsense\n", "", "file,center_x_px,center_y_px,contact_radius_px\n",
            "file,center_x_px,center_y_px,contact_radius_px\npress_00.png,nan,24,8\n",
            "file,center_x_px,center_y_px,contact_radius_px\npress_00.png,32,24,-8\n",
            "file,center_x_px,center_y_px,contact_radius_px\npress_00.png,1e300,24,8\n",
            "file,center_x_px,center_y_px,contact_radius_px\n../../etc/passwd,32,24,8\n",
            "file,center_x_px,center_y_px,contact_radius_px\n/etc/passwd,32,24,8\n",
            "file,center_x_px,center_y_px,contact_radius_px\nmissing.png,32,24,8\n",
            "file,center_x_px,center_y_px,contact_radius_px\npress_00.png,x,24,8\n",
            "file,center_x_px,center_y_px,contact_radius_px\npress_00.png,32,24\n"]
    out += [(f"labels-{i}", {**base, "labels.csv": r.encode()}) for i, r in enumerate(rows)]
    out.append(("labels-binary", {**base, "labels.csv": bytes(rng.randrange(256) for _ in range(300))}))
    return out


def _calibration_cases(rng: random.Random, nrng: np.random.Generator) -> list[tuple[str, dict[str, bytes] | None]]:
    """GelSight calibrations: ``{".json": ..., ".npz": ...}`` pairs (a missing key: that file absent)."""
    meta = {"format": "tactile_rig.gelsight.calibration", "version": 1, "model": "lut", "mm_per_px_x": 0.0634,
            "mm_per_px_y": 0.0634, "ball_radius_mm": 2.0, "sensor": "gelsight"}
    bg = good_image(nrng)
    arrays = {"background": bg, "model_hyper": np.array([8.0, 128.0]), "model_table": np.zeros((8, 8, 8, 2), np.float32),
              "model_filled": np.ones((8, 8, 8), bool)}

    def npz(**over: object) -> bytes:
        a = {**arrays, **over}
        return _write_npz({f"{k}.npy": _npy_bytes(np.asarray(v), allow_pickle=np.asarray(v).dtype == object)
                           for k, v in a.items() if v is not None})

    good_json, good_npz = json.dumps(meta).encode(), npz()
    out: list[tuple[str, dict[str, bytes] | None]] = [("absent", {}), ("json-only", {".json": good_json}),
                                                      ("npz-only", {".npz": good_npz})]
    for n, d in _json_config_cases(rng):
        if d is not None:
            out.append((f"meta-{n}", {".json": d, ".npz": good_npz}))
    for k, v in (("format", "x"), ("version", 9), ("model", "nope"), ("mm_per_px_x", 0), ("mm_per_px_x", "x"),
                 ("mm_per_px_y", 1e300), ("ball_radius_mm", -1), ("ball_radius_mm", None)):
        out.append((f"meta-{k}={v}", {".json": json.dumps({**meta, k: v}).encode(), ".npz": good_npz}))
    for n, d in _map_cases(rng, nrng)[:40]:
        if d is not None:
            out.append((f"npz-{n}", {".json": good_json, ".npz": d}))
    npz_members: tuple[tuple[str, np.ndarray | None], ...] = (
                 ("background", np.zeros((10, 10), np.uint8)), ("background", np.zeros((10, 10, 3), np.float32)),
                 ("background", None), ("model_table", np.full((8, 8, 8, 2), np.nan, np.float32)),
                 ("model_table", np.zeros((3,), np.float32)), ("model_hyper", np.array([1e300, 1.0])),
                 ("model_hyper", np.array([])), ("model_table", None), ("model_filled", np.zeros(2, np.complex64)),
                 ("background", np.zeros((1, 70000, 3), np.uint8)))
    for key, arr in npz_members:
        shape = "none" if arr is None else f"{arr.dtype}{arr.shape}"
        out.append((f"npz-{key}-{shape}", {".json": good_json, ".npz": npz(**{key: arr})}))
    return out


KINDS: dict[str, str] = {
    "npy": "gelsight register FILE GOOD.npy --mm-per-px 0.0634",
    "tactile-map": "gelsight localize FILE GOOD.npy",
    "image": "fingervision track FILE",
    "fv-config": "fingervision track GOOD.png --config FILE.json",
    "mcap": "replay FILE (and replay FILE --dump --json)",
    "bench": "run jig-accuracy --bench FILE --no-record --no-report",
    "press-folder": "gelsight calibrate DIR --mm-per-px 0.0634 --ball-radius-mm 2 -o OUT",
    "calibration": "gelsight height CALIB GOOD.png -o OUT.npy",
    "gripper-calibration": "gripper state --port rigsim://dynamixel --calibration FILE.json",
    "arguments": "bounded numeric arguments and output paths of the gelsight and fingervision commands",
}


def _write(path: Path, data: bytes | None) -> None:
    if data is None:
        path.mkdir(parents=True, exist_ok=True)
    else:
        path.write_bytes(data)


def generate(kind: str, out_dir: str | Path, *, seed: int = 0) -> list[BadCase]:
    """Write the malformed files of ``kind`` (a key of :data:`KINDS`) into ``out_dir``; return the cases."""
    if kind not in KINDS:
        raise ValueError(f"kind={kind!r} must be one of {', '.join(KINDS)}")
    out = Path(out_dir) / kind
    out.mkdir(parents=True, exist_ok=True)
    rng = random.Random(f"{kind}:{seed}")
    nrng = np.random.default_rng(seed)
    good_npy = out / "GOOD.npy"
    np.save(good_npy, good_height_mm(np.random.default_rng(seed + 1)))
    good_png = out / "GOOD.png"
    good_png.write_bytes(_png(good_image(np.random.default_rng(seed + 2))))
    work = out / "out"
    work.mkdir(exist_ok=True)
    cases: list[BadCase] = []

    def add(name: str, path: Path, argv: list[str]) -> None:
        cases.append(BadCase(kind, name, str(path), tuple(argv)))

    def files(items: list[tuple[str, bytes | None]], suffix: str, argv: Callable[[Path], list[str]]) -> None:
        for i, (name, data) in enumerate(items):
            p = out / f"{i:03d}-{_slug(name)}{suffix}"
            _write(p, data)
            add(name, p, argv(p))

    if kind == "npy":
        files(_npy_cases(rng, nrng), ".npy", lambda p: ["gelsight", "register", str(p), str(good_npy), "--mm-per-px", MM_PER_PX])
        add("missing", out / "missing.npy", ["gelsight", "register", str(out / "missing.npy"), str(good_npy),
                                             "--mm-per-px", MM_PER_PX])
    elif kind == "tactile-map":
        files(_map_cases(rng, nrng), ".npz", lambda p: ["gelsight", "localize", str(p), str(good_npy)])
    elif kind == "image":
        files(_image_cases(rng, nrng), ".png", lambda p: ["fingervision", "track", str(p)])
        jpgs = [(n, d) for n, d in _image_cases(rng, nrng) if n.startswith("jpeg")]
        files(jpgs, ".jpg", lambda p: ["fingervision", "track", str(p)])
    elif kind == "fv-config":
        files(_json_config_cases(rng), ".json", lambda p: ["fingervision", "track", str(good_png), "--config", str(p)])
        # TOML configs: the syntax and value cases only (an empty TOML file is a valid, empty config, and
        # a flipped bit in TOML text is often another valid setting).
        toml = [(n, d) for n, d in _toml_cases(rng, b"[detector]\n") if n.startswith("toml-") or n in ("garbage", "folder", "not-utf8")]
        files(toml, ".toml", lambda p: ["fingervision", "track", str(good_png), "--config", str(p)])
    elif kind == "mcap":
        items = _mcap_cases(rng, nrng)
        files(items, ".mcap", lambda p: ["replay", str(p)])
        for i, (name, data) in enumerate(items[:40]):
            p = out / f"{i:03d}-{_slug(name)}.mcap"
            add(name + " (dump)", p, ["replay", str(p), "--dump", "--json"])
    elif kind == "bench":
        # The bad line comes first: a truncation never leaves a valid bench behind.
        good = b'[camera]\nport = "rigsim://camera"\nwidth = 100000\nsensor = "gelsight"\n[jig]\nport = "rigsim://jig"\n'
        files(_toml_cases(rng, good), ".toml",
              lambda p: ["run", "jig-accuracy", "--bench", str(p), "--no-record", "--no-report", "--sweep", "rotation",
                         "--rotations", "0", "0", "10", "--out", str(work / "run")])
    elif kind == "press-folder":
        for i, (name, content) in enumerate(_press_folder_cases(rng, nrng)):
            d = out / f"{i:03d}-{_slug(name)}"
            if content is None:
                d.write_bytes(b"not a folder")
            else:
                d.mkdir(exist_ok=True)
                for fname, data in content.items():
                    (d / fname).write_bytes(data)
            add(name, d, ["gelsight", "calibrate", str(d), "--mm-per-px", MM_PER_PX, "--ball-radius-mm", "2",
                          "--method", "lut", "-o", str(work / "cal")])
    elif kind == "calibration":
        for i, (name, content) in enumerate(_calibration_cases(rng, nrng)):
            base = out / f"{i:03d}-{_slug(name)}"
            for suffix, data in (content or {}).items():
                _write(base.with_suffix(suffix), data)
            add(name, base, ["gelsight", "height", str(base), str(good_png), "-o", str(work / "h.npy")])
    elif kind == "gripper-calibration":
        items = _json_config_cases(rng)
        items += [(f"values-{i}", json.dumps(d).encode()) for i, d in enumerate([
            {"closed_ticks": "x"}, {"closed_ticks": 1e300, "open_ticks": 0, "max_opening_m": 0.1}, {},
            {"closed_ticks": 0, "open_ticks": 0, "max_opening_m": 0.1}, {"calibration": [1]},
            {"closed_ticks": None, "open_ticks": 1, "max_opening_m": -1}])]
        files(items, ".json", lambda p: ["gripper", "state", "--port", "rigsim://dynamixel?ids=1", "--calibration", str(p)])
    elif kind == "arguments":
        reg = ["gelsight", "register", str(good_npy), str(good_npy)]
        for v in ("1e300", "nan", "inf", "-inf", "-1", "0", "1e-300", "x", "", "1e9"):
            add(f"--mm-per-px {v}", good_npy, [*reg, "--mm-per-px", v])
        for v in ("1e9", "0", "-5", "1.5", "nan", "999999999999999999999", "x"):
            add(f"--ransac-iters {v}", good_npy, [*reg, "--mm-per-px", MM_PER_PX, "--ransac-iters", v])
        for v in ("0", "nan", "1e300", "-1"):
            add(f"--canvas-factor {v}", good_npy, ["gelsight", "map", str(good_npy), "--mm-per-px", MM_PER_PX,
                                                   "--canvas-factor", v, "-o", str(work / "m.npz")])
        for o in (work / "a" / "b" / "c" / "m.npz", work, out / "GOOD.png" / "x.npz", ""):
            add(f"-o {o}", good_npy, ["gelsight", "map", str(good_npy), "--mm-per-px", MM_PER_PX, "-o", str(o)])
        for v in ("0", "-1", "nan", "inf", "1e300"):
            add(f"--fps {v}", good_png, ["fingervision", "track", str(good_png), "--fps", v])
        for v in ("0", "-1", "1e12", "x"):
            add(f"--calib-frames {v}", good_png, ["fingervision", "track", str(good_png), "--calib-frames", v])
            add(f"--limit {v}", good_png, ["fingervision", "track", str(good_png), "--limit", v])
        for v in ("-1", "70000", "1e9"):
            add(f"--object-rect {v}", good_png, ["fingervision", "track", str(good_png), "--object-rect", v, "0", "1", "1"])
        for v in ("0", "-1", "1e300", "nan"):
            add(f"--ball-radius-mm {v}", good_png, ["gelsight", "calibrate", str(out), "--mm-per-px", MM_PER_PX,
                                                    "--ball-radius-mm", v, "-o", str(work / "cal")])
        for v in ("1", "0", "1e9"):
            add(f"--bins {v}", good_png, ["gelsight", "calibrate", str(out), "--mm-per-px", MM_PER_PX,
                                          "--ball-radius-mm", "2", "--bins", v, "-o", str(work / "cal")])
            add(f"--folds {v}", good_png, ["gelsight", "calibrate", str(out), "--mm-per-px", MM_PER_PX,
                                           "--ball-radius-mm", "2", "--folds", v, "-o", str(work / "cal")])
        for o in (work / "x" / "y" / "cal", str(work)):
            add(f"calibrate -o {o}", good_png, ["gelsight", "calibrate", str(out), "--mm-per-px", MM_PER_PX,
                                                "--ball-radius-mm", "2", "-o", str(o)])
        for o in (work / "x" / "y" / "h.npy", good_png):
            add(f"height -o {o}", good_png, ["gelsight", "height", str(out / "nocal"), str(good_png), "-o", str(o)])
    return cases


def good_case(kind: str, out_dir: str | Path, *, seed: int = 0) -> BadCase | None:
    """The baseline of ``kind``: the same command on a valid file, which it accepts (exit 0); None where
    the valid run is a long session (bench, press folder)."""
    out = Path(out_dir) / kind / "good"
    out.mkdir(parents=True, exist_ok=True)
    nrng = np.random.default_rng(seed)
    h = out / "h.npy"
    np.save(h, good_height_mm(np.random.default_rng(seed + 1)))
    png = out / "f.png"
    png.write_bytes(_png(good_image(np.random.default_rng(seed + 2))))
    if kind == "npy":
        return BadCase(kind, "valid", str(h), ("gelsight", "register", str(h), str(h), "--mm-per-px", MM_PER_PX), exit_code=0)
    if kind == "tactile-map":
        # a map made of the touch it is asked to localize: the command finds it (exit 0)
        tmap = TactileMap(float(MM_PER_PX))
        if not tmap.add_touch(np.load(h)).accepted:
            raise RuntimeError("the valid tactile map's root touch was refused")
        m = tmap.save(out / "map.npz")
        return BadCase(kind, "valid", str(m), ("gelsight", "localize", str(m), str(h)), exit_code=0)
    fv = out / "fv.png"
    fv.write_bytes(_png(FingerVisionRenderer(seed=seed).render()[0]))  # a rest frame with its markers
    if kind == "image":
        return BadCase(kind, "valid", str(fv), ("fingervision", "track", str(fv)), exit_code=0)
    if kind == "fv-config":
        c = out / "fv.json"
        c.write_text(json.dumps({"n_calib_frames": 1}))
        return BadCase(kind, "valid", str(c), ("fingervision", "track", str(fv), "--config", str(c)), exit_code=0)
    if kind == "mcap":
        m = out / "good.mcap"
        m.write_bytes(_good_mcap(nrng))
        return BadCase(kind, "valid", str(m), ("replay", str(m)), exit_code=0)
    if kind == "gripper-calibration":
        c = out / "gripper.json"
        c.write_text(json.dumps({"closed_ticks": 1024, "open_ticks": 3072, "max_opening_m": 0.1}))
        return BadCase(kind, "valid", str(c), ("gripper", "state", "--port", "rigsim://dynamixel?ids=1",
                                               "--calibration", str(c)), exit_code=0)
    if kind == "calibration":
        base = out / "cal"
        base.with_suffix(".json").write_text(json.dumps({
            "format": "tactile_rig.gelsight.calibration", "version": 1, "model": "lut", "mm_per_px_x": 0.0634,
            "mm_per_px_y": 0.0634, "ball_radius_mm": 2.0, "sensor": "gelsight"}))
        bg = good_image(np.random.default_rng(seed + 2))
        base.with_suffix(".npz").write_bytes(_write_npz({f"{k}.npy": _npy_bytes(v) for k, v in {
            "background": bg, "model_hyper": np.array([8.0, 128.0]), "model_table": np.zeros((8, 8, 8, 2), np.float32),
            "model_filled": np.ones((8, 8, 8), bool)}.items()}))
        return BadCase(kind, "valid", str(base), ("gelsight", "height", str(base), str(png), "-o", str(out / "h_out.npy")), exit_code=0)
    if kind == "arguments":
        return BadCase(kind, "valid", str(h), ("gelsight", "register", str(h), str(h), "--mm-per-px", MM_PER_PX,
                                               "--ransac-iters", "256"), exit_code=0)
    return None


def generate_all(out_dir: str | Path, *, seed: int = 0, kinds: list[str] | None = None) -> list[BadCase]:
    """Every kind's cases (or those of ``kinds``)."""
    return [c for k in (kinds or list(KINDS)) for c in generate(k, out_dir, seed=seed)]


def _slug(name: str) -> str:
    return "".join(ch if ch.isalnum() or ch in "-_=." else "_" for ch in name)[:60]
