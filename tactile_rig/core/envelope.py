"""The envelope of every versioned file tactile-rig writes: a format id and a version, checked on read.

A writer puts ``{"format": FORMAT.format_id, "version": FORMAT.version}`` first (:meth:`FileFormat.header`);
a reader hands the parsed metadata to :meth:`FileFormat.check`, which refuses anything else with one
:class:`~tactile_rig.core.errors.BadFile` naming the file, the field and what was expected. Ids are
written one way, ``tactile_rig.<name>`` (``tactile_rig.gelsight.calibration``); the spelling the force
map and substance model files carry, ``tactile-rig/<name>`` with hyphens (``tactile-rig/force-map``),
reads as the same id. The envelope is needed by perception's save files too, so it lives in ``core``;
reading the bytes is the caller's job."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping

from tactile_rig.core.errors import BadFile

__all__ = ["FORMAT_PREFIX", "FileFormat", "canonical_format_id"]

FORMAT_PREFIX = "tactile_rig."
_OTHER_PREFIX = "tactile-rig/"


def canonical_format_id(value: object) -> object:
    """A format id in the spelling files are written with: ``tactile-rig/force-map`` reads as
    ``tactile_rig.force_map``; anything that is not such a string is returned as it is."""
    if isinstance(value, str) and value.startswith(_OTHER_PREFIX):
        rest = value[len(_OTHER_PREFIX):]
        return FORMAT_PREFIX + rest.replace("/", ".").replace("-", "_")
    return value


@dataclass(frozen=True)
class FileFormat:
    """A versioned file format: ``name`` (``gelsight.calibration``), the ``version`` this code writes
    and reads, and ``what`` the file is, for messages (``"GelSight calibration"``)."""

    name: str
    version: int
    what: str

    def __post_init__(self) -> None:
        if not self.name or self.name != self.name.strip() or any(c in self.name for c in "-/ "):
            raise ValueError(f"format name {self.name!r} must be dotted words with underscores (no '-', '/', ' ')")
        if isinstance(self.version, bool) or not isinstance(self.version, int) or self.version < 1:
            raise ValueError(f"format version must be an integer >= 1, got {self.version!r}")

    @property
    def format_id(self) -> str:
        """The id written into every file of this format: ``tactile_rig.<name>``."""
        return FORMAT_PREFIX + self.name

    def header(self) -> dict[str, Any]:
        """The envelope fields a writer puts first in its metadata."""
        return {"format": self.format_id, "version": self.version}

    def matches(self, meta: object) -> bool:
        """Whether ``meta`` is a mapping in this format and version (either spelling of the id)."""
        return (isinstance(meta, Mapping) and canonical_format_id(meta.get("format")) == self.format_id
                and _same_version(meta.get("version"), self.version))

    def check(self, meta: object, path: str | Path) -> dict[str, Any]:
        """``meta`` (the file's parsed metadata) as a dict once its envelope is this format's: a JSON
        object whose ``format`` is this id (either spelling) and whose ``version`` is this code's.
        Otherwise :class:`BadFile` naming ``path``, the field and what was expected."""
        expected_id = f"{self.format_id!r} ({self.what})"
        if not isinstance(meta, Mapping):
            raise BadFile(path, f"its metadata is a {type(meta).__name__}, not an object",
                          f"a JSON object with 'format' {expected_id}")
        if "format" not in meta:
            raise BadFile(path, "the field 'format' is missing", f"'format' {expected_id}")
        fmt = meta["format"]
        if canonical_format_id(fmt) != self.format_id:
            raise BadFile(path, f"the field 'format' is {fmt!r}: not a {self.what}", f"'format' {expected_id}")
        if not _same_version(meta.get("version"), self.version):
            got = "missing" if "version" not in meta else f"{meta['version']!r}"
            raise BadFile(path, f"the field 'version' is {got}: {self.what} format version {got} is not "
                          f"one this tactile-rig reads", f"'version' {self.version}")
        return dict(meta)


def _same_version(value: object, version: int) -> bool:
    # JSON has one number type: 1 and 1.0 are the same version, True is not.
    return not isinstance(value, bool) and isinstance(value, (int, float)) and value == version
