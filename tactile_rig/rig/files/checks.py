"""Plain files from outside: an existing, readable regular file of bounded size, and one error type.

Every reader of :mod:`tactile_rig.rig.files` starts here: :func:`check_file` refuses a missing path,
a directory, an empty or oversized file with a :class:`~tactile_rig.core.errors.BadFile` (a
``ValueError``) or :class:`~tactile_rig.core.errors.MissingFile` naming the file, the problem and
what was expected; :func:`checked` turns whatever a third-party reader raises into the same.
"""

from __future__ import annotations

import stat
import struct
import zipfile
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Callable, Iterator, Sequence

from tactile_rig.core.errors import BadFile, MissingFile

MAX_FILE_BYTES = 1 << 30          # 1 GiB: no file the CLI reads is legitimately larger


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


def read_bytes(p: Path, what: str) -> bytes:
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



def guarded(loader: Callable[..., Any], path: str | Path, what: str, expected: str, *args: Any, **kw: Any) -> Any:
    """``loader(path, *args, **kw)`` with any decoding failure turned into a :class:`BadFile`."""
    with checked(path, what, expected):
        return loader(path, *args, **kw)
