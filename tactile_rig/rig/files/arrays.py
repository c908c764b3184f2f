"""``.npy`` and ``.npz`` arrays from outside, every header checked before any data is read.

Sizes come from the file's own header and are bounded before anything is allocated or inflated;
pickles, object, complex and structured dtypes are refused, shapes and (where a value cannot mean
anything) NaN and infinity are checked. A stored (uncompressed) ``.npz`` member is read once into a
buffer, its CRC-32 checked, and viewed in place.
"""

from __future__ import annotations

import io
import math
import struct
import zipfile
import zlib
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np
import numpy.lib.format as npformat

from tactile_rig.core.errors import BadFile
from tactile_rig.rig.files.checks import MAX_FILE_BYTES, check_file, checked
from tactile_rig.rig.files.deflate import crc32

MAX_ARRAY_ELEMENTS = 1 << 26      # 67 M elements (an 8192 x 8192 map)
REAL_KINDS = "iuf"                # signed, unsigned, float: real numbers only (no bool, complex, object)


def _dtype_problem(dtype: np.dtype, kinds: str) -> str | None:
    if dtype.hasobject:
        return "holds Python objects (dtype object)"
    if dtype.fields is not None or dtype.subdtype is not None:
        return f"has a structured dtype {dtype}"
    if dtype.kind not in kinds:
        names = {"c": "complex", "b": "boolean", "U": "text", "S": "bytes", "V": "raw void", "M": "datetime",
                 "m": "timedelta", "O": "object"}
        return f"has dtype {dtype} ({names.get(dtype.kind, dtype.kind)})"
    return None


def _expected_kinds(kinds: str) -> str:
    names = {"i": "signed integer", "u": "unsigned integer", "f": "float", "b": "boolean", "U": "text"}
    return "a dtype of kind " + " / ".join(names.get(k, k) for k in kinds)


def _shape_problem(shape: tuple[int, ...], ndim: int | Sequence[int] | None,
                   shape_spec: Sequence[int | None] | None) -> str | None:
    if ndim is not None:
        allowed = (ndim,) if isinstance(ndim, int) else tuple(ndim)
        if len(shape) not in allowed:
            return f"has {len(shape)} dimensions (shape {shape})"
    if shape_spec is not None:
        if len(shape) != len(shape_spec) or any(s is not None and s != n for s, n in zip(shape_spec, shape)):
            return f"has shape {shape}"
    return None


def _describe_shape(ndim: int | Sequence[int] | None, shape_spec: Sequence[int | None] | None) -> str:
    if shape_spec is not None:
        return "shape (" + ", ".join("N" if s is None else str(s) for s in shape_spec) + ")"
    if ndim is not None:
        allowed = (ndim,) if isinstance(ndim, int) else tuple(ndim)
        return " or ".join(f"{n}-D" for n in allowed) + " array"
    return "an array"


def read_npy_header(fp: Any, what: str, path: Path) -> tuple[tuple[int, ...], bool, np.dtype]:
    """``(shape, fortran_order, dtype)`` from an open ``.npy`` stream positioned at its start."""
    try:
        version = npformat.read_magic(fp)
        if version == (1, 0):
            shape, fortran, dtype = npformat.read_array_header_1_0(fp)
        elif version in ((2, 0), (3, 0)):
            shape, fortran, dtype = npformat.read_array_header_2_0(fp)
        else:
            raise ValueError(f"unknown .npy format version {version}")
    except Exception as exc:  # noqa: BLE001 - NumPy parses the header text (tokenize, literal_eval): any failure
        msg = str(exc).splitlines()[0][:160] if str(exc) else type(exc).__name__
        raise BadFile(path, f"{what} has no valid .npy header ({msg})", "a NumPy .npy array") from None
    if any((not isinstance(n, int)) or n < 0 for n in shape):
        raise BadFile(path, f"{what} declares the shape {shape}", "non-negative dimensions")
    return tuple(int(n) for n in shape), bool(fortran), np.dtype(dtype)


def _check_header(path: Path, what: str, shape: tuple[int, ...], dtype: np.dtype, *, kinds: str,
                  ndim: int | Sequence[int] | None, shape_spec: Sequence[int | None] | None,
                  max_elements: int) -> int:
    prob = _dtype_problem(dtype, kinds)
    if prob:
        raise BadFile(path, f"{what} {prob}", _expected_kinds(kinds))
    prob = _shape_problem(shape, ndim, shape_spec)
    if prob:
        raise BadFile(path, f"{what} {prob}", _describe_shape(ndim, shape_spec))
    n = math.prod(shape)
    if n > max_elements:
        raise BadFile(path, f"{what} declares {n} elements (shape {shape})", f"at most {max_elements} elements")
    return n * dtype.itemsize


def check_array(arr: Any, path: str | Path, what: str, *, kinds: str = REAL_KINDS,
                ndim: int | Sequence[int] | None = None, shape: Sequence[int | None] | None = None,
                finite: bool = True, min_size: int = 1) -> np.ndarray:
    """Validate an array already in memory (dtype kind, shape, at least ``min_size`` elements, and
    with ``finite`` no NaN or infinity); returns it."""
    p = Path(path)
    if not isinstance(arr, np.ndarray):
        raise BadFile(p, f"{what} is a {type(arr).__name__}", "an array")
    prob = _dtype_problem(arr.dtype, kinds) or _shape_problem(arr.shape, ndim, shape)
    if prob:
        raise BadFile(p, f"{what} {prob}", _expected_kinds(kinds) if _dtype_problem(arr.dtype, kinds)
                      else _describe_shape(ndim, shape))
    if arr.size < min_size:
        raise BadFile(p, f"{what} is empty (shape {arr.shape})", f"at least {min_size} element(s)")
    if finite and arr.dtype.kind == "f" and not np.isfinite(arr).all():
        bad = int(np.count_nonzero(~np.isfinite(arr)))
        raise BadFile(p, f"{what} holds {bad} NaN/infinite value(s)", "finite numbers only")
    return arr


def load_npy(path: str | Path, what: str = "array", *, kinds: str = REAL_KINDS,
             ndim: int | Sequence[int] | None = None, shape: Sequence[int | None] | None = None,
             finite: bool = True, max_elements: int = MAX_ARRAY_ELEMENTS, min_size: int = 1) -> np.ndarray:
    """A ``.npy`` array, its header checked (dtype, shape, element count against the file size)
    before the data are read; never a pickle."""
    p = check_file(path, what)
    size = p.stat().st_size
    with open(p, "rb") as fh:
        shp, _fortran, dtype = read_npy_header(fh, what, p)
        nbytes = _check_header(p, what, shp, dtype, kinds=kinds, ndim=ndim, shape_spec=shape,
                               max_elements=max_elements)
        have = size - fh.tell()
        if have < nbytes:
            raise BadFile(p, f"{what} is truncated: the header declares {shp} {dtype} ({nbytes} bytes of data) "
                          f"but {have} bytes follow", "a complete .npy file")
        fh.seek(0)
        with checked(p, what, "a NumPy .npy array"):
            arr = np.load(fh, allow_pickle=False)
    return check_array(arr, p, what, kinds=kinds, ndim=ndim, shape=shape, finite=finite, min_size=min_size)


def load_npz(path: str | Path, what: str = "archive", *,
             arrays: Mapping[str, Mapping[str, Any]] | None = None, required: Sequence[str] = (),
             default: Mapping[str, Any] | None = None, max_elements: int = MAX_ARRAY_ELEMENTS,
             max_total_bytes: int = 4 * MAX_FILE_BYTES) -> dict[str, np.ndarray]:
    """Every array of a ``.npz`` archive, each header checked before its data are inflated.

    ``arrays`` maps a member name to the keyword arguments of :func:`check_array` for it (``kinds``,
    ``ndim``, ``shape``, ``finite``, ``min_size``); ``default`` applies to the other members (text
    members such as JSON metadata need ``{"kinds": "U"}``). ``required`` names members that must be
    there. The sum of the declared sizes is bounded (no zip bombs)."""
    p = check_file(path, what)
    specs = dict(arrays or {})
    dflt = dict(default or {})
    out: dict[str, np.ndarray] = {}
    try:
        zf = zipfile.ZipFile(p)
    except (zipfile.BadZipFile, EOFError, OSError, ValueError) as exc:
        raise BadFile(p, f"{what} is not a readable .npz archive ({str(exc)[:120] or type(exc).__name__}; "
                      "truncated?)", "a NumPy .npz archive") from None
    with zf, open(p, "rb") as raw:  # raw: the stored members' bytes, read by _stored_member
        names = [i for i in zf.infolist() if i.filename.endswith(".npy")]
        if len(names) != len(zf.infolist()):
            extra = [i.filename for i in zf.infolist() if not i.filename.endswith(".npy")][:3]
            raise BadFile(p, f"{what} holds members that are not arrays ({', '.join(extra)})", "only .npy members")
        missing = [k for k in required if f"{k}.npy" not in {i.filename for i in names}]
        if missing:
            raise BadFile(p, f"{what} lacks the array(s) {', '.join(missing)}", "the arrays "
                          + ", ".join(required))
        total = sum(i.file_size for i in names)
        if total > max_total_bytes:
            raise BadFile(p, f"{what} inflates to {total} bytes", f"at most {max_total_bytes} bytes")
        for info in names:
            key = info.filename[:-4]
            spec = {**dflt, **specs.get(key, {})}
            kinds = spec.get("kinds", REAL_KINDS)
            member = f"{what} member {key!r}"
            try:
                with zf.open(info) as fh:
                    head = fh.read(min(info.file_size, 65536 + 12))
                    hb = io.BytesIO(head)
                    shp, fortran, dtype = read_npy_header(hb, member, p)
                    nbytes = _check_header(p, member, shp, dtype, kinds=kinds, ndim=spec.get("ndim"),
                                           shape_spec=spec.get("shape"), max_elements=max_elements)
                    if info.file_size - hb.tell() < nbytes:
                        raise BadFile(p, f"{member} is truncated ({info.file_size - hb.tell()} of {nbytes} "
                                      "bytes)", "a complete array")
                stored = _stored_member(raw, p, info, member) if info.compress_type == zipfile.ZIP_STORED else None
                if stored is not None:
                    # np.savez's uncompressed members (a calibration's 12.6 MB table) are read once into
                    # a writable buffer, their CRC checked, and viewed in place: no copies.
                    arr = np.frombuffer(stored, dtype, count=math.prod(shp), offset=hb.tell())
                    arr = arr.reshape(shp[::-1]).T if fortran else arr.reshape(shp)
                else:
                    with zf.open(info) as fh:
                        arr = np.load(io.BytesIO(fh.read(info.file_size)), allow_pickle=False)
            except BadFile:
                raise
            except (zipfile.BadZipFile, EOFError, OSError, ValueError, zlib.error, NotImplementedError) as exc:
                raise BadFile(p, f"{member} cannot be read ({str(exc)[:120] or type(exc).__name__}; "
                              "corrupt or truncated)", "a NumPy .npz archive") from None
            out[key] = check_array(arr, p, member, kinds=kinds, ndim=spec.get("ndim"), shape=spec.get("shape"),
                                   finite=spec.get("finite", True), min_size=spec.get("min_size", 1))
    return out


_ZIP_LOCAL_HEADER = struct.Struct("<4s22xHH")  # signature ... file name length, extra field length


def _stored_member(fh: Any, path: Path, info: zipfile.ZipInfo, what: str) -> bytearray | None:
    """The bytes of an uncompressed zip member of the archive open as ``fh`` (binary, seekable),
    read into a writable buffer and checked against its CRC-32 (ISA-L's with the ``fast`` extra);
    None when its local header is not where the directory says or its sizes disagree (zipfile then
    reads it and names the damage)."""
    if info.compress_size != info.file_size:  # a stored member's two sizes are one: the bounded one counts
        return None
    fh.seek(info.header_offset)
    head = fh.read(_ZIP_LOCAL_HEADER.size)
    if len(head) != _ZIP_LOCAL_HEADER.size:
        return None
    sig, name_len, extra_len = _ZIP_LOCAL_HEADER.unpack(head)
    if sig != b"PK\x03\x04":
        return None
    fh.seek(name_len + extra_len, io.SEEK_CUR)
    data = bytearray(info.compress_size)
    if fh.readinto(data) != len(data):
        raise BadFile(path, f"{what} is truncated", "a complete .npz archive")
    if crc32()(data) != info.CRC:
        raise BadFile(path, f"{what} fails its CRC-32", "an intact .npz archive")
    return data

