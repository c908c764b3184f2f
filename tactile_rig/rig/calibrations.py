"""Versioned calibration files: every session writes ``name-vN.ext`` and moves a stable link to it.

A calibration is never overwritten silently. Asked to write ``calib/scale.json`` a session writes
``calib/scale-v1.json`` the first time, ``calib/scale-v2.json`` the next, and so on; the stable
name ``calib/scale.json`` is a relative symbolic link to the newest version, so a bench file that
names ``calib/scale.json`` always reads the latest calibration while every earlier one stays on
disk. A calibration made of several files (``.npz`` + ``.json``, the report, the recording) is one
version: all its files share the ``-vN`` stem and each stable name links to its own file.

Overwriting needs ``force=True`` (the CLI's ``--force``):

* asked for the stable name, ``force`` rewrites the newest version in place instead of adding one;
* asked for an explicit version (``calib/scale-v3.json``) that exists, the session raises
  :class:`~tactile_rig.core.errors.CalibrationExists` unless ``force``;
* a regular file at the stable name (written by hand, or by an older tactile-rig) is never replaced
  without ``force``: the error says so, and with ``force`` it is replaced by the link.

Where symbolic links are not available (some Windows setups) the stable name is a copy of the
newest version, written after it.
"""

from __future__ import annotations

import os
import re
import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import Iterable, Sequence

from tactile_rig.core.errors import CalibrationExists

__all__ = ["CalibrationVersion", "plan_version", "publish", "existing_versions", "latest_version",
           "split_version", "version_of", "KNOWN_SUFFIXES"]

# Suffixes a calibration's files may carry; the longest match is stripped from a requested path.
KNOWN_SUFFIXES: tuple[str, ...] = (".report.json", ".report.md", ".json", ".npz", ".mcap", ".md")
_VERSION = re.compile(r"^(?P<stem>.+)-v(?P<n>\d+)$")


def _strip_suffix(path: Path) -> Path:
    name = path.name
    for suf in sorted(KNOWN_SUFFIXES, key=len, reverse=True):
        if name.endswith(suf) and len(name) > len(suf):
            return path.with_name(name[: -len(suf)])
    return path


def split_version(path: str | Path) -> tuple[Path, int | None]:
    """(stable base without suffix, explicit version or None): ``calib/scale-v3.json`` → (calib/scale, 3)."""
    p = _strip_suffix(Path(path))
    m = _VERSION.match(p.name)
    if m:
        return p.with_name(m.group("stem")), int(m.group("n"))
    return p, None


def version_of(path: str | Path) -> int | None:
    """The version a calibration file is (following the stable link), or None if unversioned."""
    p = Path(path)
    if p.is_symlink():
        p = Path(os.path.realpath(p))
    return split_version(p)[1]


def existing_versions(base: str | Path) -> list[int]:
    """Versions of ``base`` on disk (any of its files), ascending."""
    b = Path(base)
    if not b.parent.is_dir():
        return []
    pat = re.compile(re.escape(b.name) + r"-v(\d+)(?:\.|_|$)")
    found = {int(m.group(1)) for f in b.parent.iterdir() if (m := pat.match(f.name))}
    return sorted(found)


def latest_version(base: str | Path) -> int | None:
    v = existing_versions(base)
    return v[-1] if v else None


@dataclass(frozen=True)
class CalibrationVersion:
    """One version of a calibration: ``base`` is the stable stem (``calib/scale``), ``version`` its N."""

    base: Path
    version: int

    @property
    def stem(self) -> Path:
        """The version's stem: ``calib/scale-v2`` (append a suffix for each file)."""
        return self.base.with_name(f"{self.base.name}-v{self.version}")

    def path(self, suffix: str) -> Path:
        """This version's file with ``suffix`` (``.json``, ``.npz``, ``.report.json``, ...)."""
        return self.stem.with_name(self.stem.name + suffix)

    def link(self, suffix: str) -> Path:
        """The stable name with ``suffix`` (``calib/scale.json``)."""
        return self.base.with_name(self.base.name + suffix)


def plan_version(path: str | Path, suffixes: Sequence[str], *, force: bool = False) -> CalibrationVersion:
    """Choose the version a session writes for the requested ``path`` (see the module doc).

    ``suffixes`` are the files the session will write (checked for clashes). Raises
    :class:`CalibrationExists` naming the file and the way out when a write would replace one.
    """
    base, explicit = split_version(path)
    base.parent.mkdir(parents=True, exist_ok=True)
    if explicit is not None:
        ver = CalibrationVersion(base, explicit)
        clash = [ver.path(s) for s in suffixes if ver.path(s).exists()]
        if clash and not force:
            raise CalibrationExists(f"{clash[0]} exists (version {explicit} of this calibration); pass --force "
                                    f"to overwrite it, or ask for {ver.link(suffixes[0])} to add version "
                                    f"{(latest_version(base) or 0) + 1}", device=str(base.name))
        return ver
    plain = [base.with_name(base.name + s) for s in suffixes]
    plain = [p for p in plain if p.exists() and not p.is_symlink()]
    if plain and not force:
        raise CalibrationExists(f"{plain[0]} is a file, not a link to a calibration version; move it away (or "
                                f"rename it {base.name}-v<N>{plain[0].name[len(base.name):]} to keep it as a "
                                "version) or pass --force to replace it", device=str(base.name))
    latest = latest_version(base)
    if force and latest is not None:
        return CalibrationVersion(base, latest)
    return CalibrationVersion(base, (latest or 0) + 1)


def publish(ver: CalibrationVersion, suffixes: Iterable[str]) -> list[Path]:
    """Point the stable names at ``ver``'s files (only when ``ver`` is the newest version); returns the links.

    A link is replaced atomically (a new link renamed over the old), so a reader never sees a
    missing file.
    """
    latest = latest_version(ver.base)
    if latest is not None and ver.version < latest:
        return []
    links = []
    for suf in suffixes:
        target = ver.path(suf)
        if not target.exists():
            continue
        link = ver.link(suf)
        tmp = link.with_name(f".{link.name}.tmp{os.getpid()}")
        try:
            if tmp.exists() or tmp.is_symlink():
                tmp.unlink()
            os.symlink(target.name, tmp)
        except (OSError, NotImplementedError):
            shutil.copyfile(target, tmp)  # no symbolic links here: a copy of the newest version
        if link.is_dir() and not link.is_symlink():
            tmp.unlink()
            raise CalibrationExists(f"{link} is a folder; it cannot become a link to {target.name}",
                                    device=ver.base.name)
        os.replace(tmp, link)
        links.append(link)
    return links
