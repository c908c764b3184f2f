"""Files from outside, checked before use: ``.npy``, ``.npz``, JSON, TOML and image headers.

Every loader here reads sizes from the file's own header and bounds them *before* anything is
allocated or decoded, refuses pickles, object, complex and structured dtypes, checks shapes, and
(where a value cannot mean anything) NaN and infinity. A problem is one :class:`BadFile` (a
``ValueError``) or :class:`MissingFile` (a ``FileNotFoundError``) whose message names the file, the
problem and what was expected, so the CLI turns it into one line and exit code 2.

The limits are module constants (bytes, elements, pixels, nesting depth); callers may pass their
own. OpenCV is imported only by :func:`read_image` (an optional extra at this layer).
"""

from __future__ import annotations

import io
import json
import math
import re
import stat
import struct
import threading
import zipfile
import zlib
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Callable, Iterator, Mapping, Sequence

import numpy as np
import numpy.lib.format as npformat

from tactile_rig.core.errors import BadFile, MissingFile

__all__ = [
    "MAX_FILE_BYTES", "MAX_ARRAY_ELEMENTS", "MAX_IMAGE_SIDE_PX", "MAX_IMAGE_PIXELS", "MAX_JSON_DEPTH",
    "REAL_KINDS", "check_file", "check_array", "read_npy_header", "load_npy", "load_npz", "loads_json",
    "load_json", "load_toml", "image_size", "check_image_file", "png_problem", "jpeg_problem", "check_image_dims", "read_image", "decode_image_bytes", "checked", "guarded", "toml_depth", "quiet_opencv", "json_depth",
]

MAX_FILE_BYTES = 1 << 30          # 1 GiB: no file the CLI reads is legitimately larger
MAX_TEXT_BYTES = 64 << 20         # 64 MiB of JSON or TOML
MAX_ARRAY_ELEMENTS = 1 << 26      # 67 M elements (an 8192 x 8192 map)
MAX_IMAGE_SIDE_PX = 16384
MAX_IMAGE_PIXELS = 1 << 26        # 67 Mpx: a 65535 x 65535 header is refused before decoding
MAX_JSON_DEPTH = 64
REAL_KINDS = "iuf"                # signed, unsigned, float: real numbers only (no bool, complex, object)


# -- plain files ------------------------------------------------------------------------------
def check_file(path: str | Path, what: str = "file", *, suffixes: Sequence[str] | None = None,
               max_bytes: int = MAX_FILE_BYTES, allow_empty: bool = False) -> Path:
    """The path of an existing, non-empty regular file of at most ``max_bytes`` (and, with
    ``suffixes``, one of those suffixes); else :class:`MissingFile` or :class:`BadFile`."""
    p = path if isinstance(path, Path) else Path(path)
    if suffixes is not None and p.suffix.lower() not in tuple(s.lower() for s in suffixes):
        raise BadFile(p, f"{what} has the suffix {p.suffix or '(none)'!r}", "one of " + ", ".join(suffixes))
    try:
        st = p.stat()
    except FileNotFoundError:
        raise MissingFile(p, what) from None
    except OSError as exc:
        raise BadFile(p, f"{what} cannot be read ({exc.strerror or exc})", "a readable file") from None
    if stat.S_ISDIR(st.st_mode):  # the mode of the stat above: one system call per file checked
        raise BadFile(p, f"{what} is a directory", "a file")
    if not stat.S_ISREG(st.st_mode):
        raise BadFile(p, f"{what} is not a regular file", "a regular file")
    if st.st_size == 0 and not allow_empty:
        raise BadFile(p, f"{what} is empty (0 bytes)", "a file with content")
    if st.st_size > max_bytes:
        raise BadFile(p, f"{what} is {st.st_size} bytes", f"at most {max_bytes} bytes")
    return p


def _read_bytes(p: Path, what: str) -> bytes:
    try:
        return p.read_bytes()
    except OSError as exc:
        raise BadFile(p, f"{what} cannot be read ({exc.strerror or exc})", "a readable file") from None


@contextmanager
def checked(path: str | Path, what: str, expected: str) -> Iterator[None]:
    """Turn any decoding failure of a third-party or format reader inside the block into a
    :class:`BadFile` naming ``path`` (the reader's own exception types say nothing about the file)."""
    try:
        yield
    except (BadFile, MissingFile):
        raise
    except (ValueError, KeyError, IndexError, TypeError, AttributeError, EOFError, OSError, zipfile.BadZipFile,
            RecursionError, MemoryError, struct.error, UnicodeError, OverflowError) as exc:
        detail = str(exc).splitlines()[0] if str(exc) else ""
        raise BadFile(Path(path), f"{what} is malformed ({type(exc).__name__}{': ' + detail[:160] if detail else ''})",
                      expected) from exc


# -- arrays -----------------------------------------------------------------------------------
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
    if _crc32()(data) != info.CRC:
        raise BadFile(path, f"{what} fails its CRC-32", "an intact .npz archive")
    return data


# -- text -------------------------------------------------------------------------------------
_JSON_STRING = re.compile(rb'"(?:[^"\\]|\\.)*"', re.S)
_TOML_STRING = re.compile(rb'"""(?:.|\n)*?"""|\'\'\'(?:.|\n)*?\'\'\'|"(?:[^"\\\n]|\\.)*"|\'[^\'\n]*\'|#[^\n]*')


def _nesting(data: bytes, strings: re.Pattern[bytes]) -> int:
    """Deepest bracket nesting of a JSON/TOML text, strings (and comments) stripped: found without
    parsing, so a hostile depth never reaches a recursive parser."""
    bare = np.frombuffer(strings.sub(b"", data), np.uint8)
    if bare.size == 0:
        return 0
    step = np.zeros(bare.shape, np.int64)
    step[(bare == ord("[")) | (bare == ord("{"))] = 1
    step[(bare == ord("]")) | (bare == ord("}"))] = -1
    return int(np.cumsum(step).max(initial=0))


def json_depth(data: bytes | str) -> int:
    """The bracket nesting depth of a JSON text (0 for a scalar)."""
    return _nesting(data.encode() if isinstance(data, str) else bytes(data), _JSON_STRING)


def toml_depth(text: bytes | str) -> int:
    """The bracket nesting depth of a TOML text (strings and comments stripped)."""
    return _nesting(text.encode() if isinstance(text, str) else bytes(text), _TOML_STRING)


def _refuse_constant(name: str) -> Any:
    raise ValueError(f"the non-finite constant {name}")


def loads_json(data: bytes | str, source: str | Path, what: str = "JSON", *, max_depth: int = MAX_JSON_DEPTH,
               allow_nan: bool = False, max_bytes: int = MAX_TEXT_BYTES) -> Any:
    """Parse JSON text whose depth is bounded first (``RecursionError`` never happens); ``NaN`` and
    ``Infinity`` are refused unless ``allow_nan``. ``source`` names where the text came from."""
    raw = data.encode("utf-8") if isinstance(data, str) else bytes(data)
    p = Path(str(source))
    if len(raw) > max_bytes:
        raise BadFile(p, f"{what} is {len(raw)} bytes", f"at most {max_bytes} bytes")
    text = _text(raw, json_depth(raw), p, what, max_depth, "UTF-8 JSON")
    try:
        return json.loads(text, parse_constant=None if allow_nan else _refuse_constant)
    except (ValueError, RecursionError) as exc:
        raise BadFile(p, f"{what} is not valid JSON ({str(exc)[:160]})", "a JSON document") from None


def _text(raw: bytes, depth: int, p: Path, what: str, max_depth: int, expected: str) -> str:
    """The bytes of a nested text format as text, once its nesting ``depth`` is within ``max_depth``."""
    if depth > max_depth:
        raise BadFile(p, f"{what} nests {depth} levels deep", f"at most {max_depth} levels")
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise BadFile(p, f"{what} is not UTF-8 text (byte {exc.start})", expected) from None


def load_json(path: str | Path, what: str = "JSON file", *, max_depth: int = MAX_JSON_DEPTH,
              allow_nan: bool = False, max_bytes: int = MAX_TEXT_BYTES, expect: type | None = dict) -> Any:
    """A JSON file (bounded size and depth, no NaN/Infinity); with ``expect`` its top level must be
    of that type (default an object)."""
    p = check_file(path, what, max_bytes=max_bytes)
    value = loads_json(_read_bytes(p, what), p, what, max_depth=max_depth, allow_nan=allow_nan, max_bytes=max_bytes)
    if expect is not None and not isinstance(value, expect):
        raise BadFile(p, f"{what} holds a JSON {type(value).__name__}", f"a JSON {_json_name(expect)}")
    return value


def _json_name(t: type) -> str:
    return {dict: "object", list: "array", str: "string", float: "number", int: "integer"}.get(t, t.__name__)


def load_toml(path: str | Path, what: str = "TOML file", *, max_depth: int = MAX_JSON_DEPTH,
              max_bytes: int = MAX_TEXT_BYTES) -> tuple[dict[str, Any], str]:
    """A TOML file as ``(data, text)``: bounded size and nesting, UTF-8, parsed by ``tomllib``."""
    import tomllib

    p = check_file(path, what, max_bytes=max_bytes, allow_empty=True)
    raw = _read_bytes(p, what)
    text = _text(raw, _nesting(raw, _TOML_STRING), p, what, max_depth, "a UTF-8 TOML file")
    try:
        return tomllib.loads(text), text
    except (tomllib.TOMLDecodeError, RecursionError) as exc:
        raise BadFile(p, f"{what} is not valid TOML ({str(exc)[:160]})", "a TOML file") from None


# -- images -----------------------------------------------------------------------------------
def _png_chunks(data: bytes | memoryview) -> tuple[str | None, list[tuple[bytes, memoryview]]]:
    """Walk a PNG's chunks once, checking every CRC: ``(problem or None, [(tag, body), ...])`` (the
    bodies are views into ``data``, no copies)."""
    mv = memoryview(data)
    n_bytes = len(mv)
    unpack = struct.unpack_from
    crc32 = _crc32()
    chunks: list[tuple[bytes, memoryview]] = []
    pos = 8
    n = 0
    while pos + 12 <= n_bytes:
        length = unpack(">I", mv, pos)[0]
        tag = bytes(mv[pos + 4:pos + 8])
        end = pos + 12 + length
        if length > n_bytes or end > n_bytes:
            return f"chunk {n} ({tag!r}) runs past the end of the file (truncated)", chunks
        if crc32(mv[pos + 4:end - 4]) != unpack(">I", mv, end - 4)[0]:
            return f"chunk {n} ({tag!r}) at byte {pos} fails its CRC", chunks
        chunks.append((tag, mv[pos + 8:end - 4]))
        if tag == b"IEND":
            return None, chunks
        pos = end
        n += 1
    return "no IEND chunk (truncated)", chunks


def png_problem(data: bytes) -> str | None:
    """What is wrong with a PNG's chunk structure (a chunk CRC, a cut-off end), or None. PNG stores a
    CRC-32 per chunk: checking them all costs a pass over the bytes and catches any flipped bit, so
    the decoder (and its own messages on stderr) never sees a damaged file."""
    return _png_chunks(data)[0]


# Chunks that change nothing in OpenCV's BGR decode of an 8-bit RGB PNG; any other (gamma, colour
# profile, transparency, palette ...) sends the file to OpenCV's own decoder.
_PNG_PLAIN_CHUNKS = frozenset({b"IHDR", b"IDAT", b"IEND", b"tEXt", b"zTXt", b"iTXt", b"tIME", b"pHYs"})
_PNG_MAX_INTEGRAL_PX = (2**31 - 1) // 255  # the int32 running sums of every pixel stay exact
_png_work = threading.local()
_decompressobj: Callable[[], Any] | None = None
_crc: Callable[..., int] | None = None


def _crc32() -> Callable[..., int]:
    """zlib's CRC-32, or ISA-L's if the ``fast`` extra is installed (the same value, ~6x faster)."""
    global _crc
    if _crc is None:
        try:
            from isal import isal_zlib  # optional extra

            _crc = isal_zlib.crc32
        except ImportError:
            _crc = zlib.crc32
    return _crc


def _inflater() -> Any:
    """A fresh inflater: zlib's, or ISA-L's if the ``fast`` extra is installed (the same bytes out,
    about three times faster)."""
    global _decompressobj
    if _decompressobj is None:
        try:
            from isal import isal_zlib  # optional extra: ISA-L inflate

            _decompressobj = isal_zlib.decompressobj
        except ImportError:
            _decompressobj = zlib.decompressobj
    return _decompressobj()


def _png_rgb8_bgr(chunks: list[tuple[bytes, memoryview]]) -> np.ndarray | None:
    """OpenCV's BGR decode of an intact (CRC-checked) 8-bit RGB, non-interlaced PNG whose rows are
    all filtered None or Sub (what OpenCV's own writer emits), or None for any other PNG (left to
    OpenCV). The same pixels, about twice as fast with the ``fast`` extra's inflate."""
    import cv2

    if not chunks or chunks[0][0] != b"IHDR" or len(chunks[0][1]) != 13:
        return None
    w, h, depth, ctype, comp, filt, interlace = struct.unpack(">IIBBBBB", chunks[0][1])
    if (depth, ctype, comp, filt, interlace) != (8, 2, 0, 0, 0) or w < 1 or h < 1:
        return None
    if any(tag not in _PNG_PLAIN_CHUNKS for tag, _ in chunks):
        return None
    stride = 3 * w + 1
    if h * w > _PNG_MAX_INTEGRAL_PX:
        return None
    try:
        # Bounded: a stream that inflates beyond the rows its header declares is not read past them.
        inflater = _inflater()
        raw = inflater.decompress(b"".join(body for tag, body in chunks if tag == b"IDAT"), h * stride + 1)
        complete = inflater.eof and not inflater.unused_data  # the stream's Adler-32 checked at its end
    except Exception:  # noqa: BLE001 - a broken stream is OpenCV's to report, as before
        return None
    if len(raw) != h * stride or not complete:
        return None
    rows = np.frombuffer(raw, np.uint8).reshape(h, stride)
    kinds = rows[:, 0]
    if kinds.max() > 1:
        return None  # Up, Average or Paeth rows depend on the row above: OpenCV decodes those
    x = rows[:, 1:].reshape(h, w, 3)
    if kinds.any():
        # Sub rows: the running sum of each channel along the row, mod 256. OpenCV's integral image
        # gives the sums (int32) and a row minus the one above leaves that row's running sums; the
        # low byte is the pixel, so the sums are cut to their low bytes first and subtracted as
        # bytes (mod 256 either way; a quarter of the memory traffic). The int32 buffer is kept per
        # thread: a fresh one of ~1 MB a frame costs more in page faults than the arithmetic.
        sums = getattr(_png_work, "sums", None)
        if sums is None or sums.shape != (h + 1, w + 1, 3):
            sums = np.empty((h + 1, w + 1, 3), np.int32)
            _png_work.sums = sums
        cv2.integral(x, sum=sums, sdepth=cv2.CV_32S)
        low = sums.astype(np.uint8)
        plain = x
        x = np.subtract(low[1:, 1:], low[:-1, 1:])
        if not kinds.all():
            x[kinds == 0] = plain[kinds == 0]  # None rows are stored as they are
    return cv2.cvtColor(x, cv2.COLOR_RGB2BGR)


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
            if head.startswith(b"\x89PNG\r\n\x1a\n"):
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
            if head.startswith(b"\x89PNG\r\n\x1a\n"):
                dims = _png_size(head)
                if dims is None:
                    raise BadFile(p, f"{what} has a truncated or malformed PNG header", "a complete PNG image")
                check_image_dims(p, what, dims[0], dims[1], max_side_px, max_pixels)
                raw = head + fh.read()
    except OSError as exc:
        raise BadFile(p, f"{what} cannot be read ({exc.strerror or exc})", "a readable file") from None
    if dims is not None:
        w, h, fmt = dims[0], dims[1], "PNG"
        problem, chunks = _png_chunks(raw)
        if png is not None:
            png[:] = chunks
    else:
        w, h, fmt = image_size(p, what)
        check_image_dims(p, what, w, h, max_side_px, max_pixels)
        raw = _read_bytes(p, what)
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
    import cv2

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
    import cv2

    p = Path(path)
    chunks: list = []
    w, h, fmt, raw = _checked_image(p, what, max_side_px, max_pixels, chunks)
    img = _png_rgb8_bgr(chunks) if color and fmt == "PNG" else None
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
    import cv2

    p = Path(str(source))
    bio = io.BytesIO(data)
    head = data[:32]
    if head.startswith(b"\x89PNG\r\n\x1a\n"):
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


def guarded(loader: Callable[..., Any], path: str | Path, what: str, expected: str, *args: Any, **kw: Any) -> Any:
    """``loader(path, *args, **kw)`` with any decoding failure turned into a :class:`BadFile`."""
    with checked(path, what, expected):
        return loader(path, *args, **kw)
