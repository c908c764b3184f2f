"""The JSON calibration a session writes: one envelope, the values at the top level, and its report.

``<out>-vN.json`` holds the envelope (:data:`CALIBRATION_FILE`'s ``format`` and ``version``, then
``kind``, ``created``, ``device``), the values at the top level (so a driver's ``from_dict`` reads it as
it is) and the ``report``; ``<out>-vN.report.json`` and ``.report.md`` hold the report again for
people. Files are versioned (:mod:`tactile_rig.rig.calibrations`): the stable names link to the newest.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

from tactile_rig.core.clock import utc_now
from tactile_rig.core.envelope import FileFormat
from tactile_rig.core.errors import BadFile, CalibrationError
from tactile_rig.core.jsonable import to_jsonable
from tactile_rig.rig.calibrations import CalibrationVersion, plan_version, publish
from tactile_rig.rig.files import load_json

__all__ = ["CALIBRATION_FILE", "CALIBRATION_FORMAT", "CALIBRATION_VERSION", "JSON_SUFFIXES", "LINKED_SUFFIXES",
           "SessionOutcome", "read_calibration", "session_version", "write_calibration", "write_report_md"]

CALIBRATION_FILE = FileFormat("calibration", 1, "calibration")
CALIBRATION_FORMAT = CALIBRATION_FILE.format_id
CALIBRATION_VERSION = CALIBRATION_FILE.version
# Files of one calibration version that get a stable link (those that exist).
LINKED_SUFFIXES = (".json", ".npz", ".report.json", ".report.md", ".mcap", "_presses")
JSON_SUFFIXES = (".json", ".report.json", ".report.md")


def session_version(out: str | Path, suffixes: Sequence[str], force: bool) -> CalibrationVersion:
    """The version a session writes to (see :func:`~tactile_rig.rig.calibrations.plan_version`)."""
    return plan_version(out, suffixes, force=force)


@dataclass
class SessionOutcome:
    """What a session wrote: the calibration file, its report (file and values)."""

    kind: str
    calibration_path: Path
    report_path: Path
    report: dict[str, Any]
    files: dict[str, Any] = field(default_factory=dict)  # paths, plus the version and links

    def as_dict(self) -> dict[str, Any]:
        return {"kind": self.kind, "calibration": str(self.calibration_path), "report": str(self.report_path),
                "values": self.report, "files": dict(self.files)}


_ENVELOPE = ("format", "version", "kind", "created", "device", "report")


def write_calibration(path: str | Path, kind: str, values: dict[str, Any], report: dict[str, Any], *,
                      device: str | None = None, force: bool = False,
                      version: CalibrationVersion | None = None) -> tuple[Path, Path]:
    """Write a JSON calibration and its report (``.report.json`` and ``.md``) as a new version of ``path``.

    ``path`` ``calib/scale.json`` writes ``calib/scale-vN.json`` and links ``calib/scale.json`` to it
    (see :mod:`tactile_rig.rig.calibrations`; ``force`` rewrites the newest version; ``version`` is
    one already chosen by the session). The file is flat: the envelope keys (``format``,
    ``version``, ``kind``, ``created``, ``device``), the values at the top level (so a driver's
    ``from_dict`` reads it as it is, e.g. ``GripperCalibration.from_dict``) and the ``report``.
    Returns (calibration path, report path) of the version written.
    """

    clash = sorted(set(values) & set(_ENVELOPE))
    if clash:
        raise ValueError(f"calibration values may not be named {', '.join(clash)} (envelope keys)")
    ver = version if version is not None else plan_version(path, JSON_SUFFIXES, force=force)
    p = ver.path(".json")
    p.parent.mkdir(parents=True, exist_ok=True)
    doc = {**CALIBRATION_FILE.header(), "kind": kind, "created": utc_now(), "device": device,
           **to_jsonable(values), "report": to_jsonable(report)}
    p.write_text(json.dumps(doc, indent=2) + "\n", encoding="utf-8")
    rpath = p.with_name(p.stem + ".report.json")
    rpath.write_text(json.dumps(to_jsonable({"kind": kind, **report}), indent=2) + "\n", encoding="utf-8")
    write_report_md(p.with_name(p.stem + ".report.md"), kind, p, values, report)
    publish(ver, LINKED_SUFFIXES)
    return p, rpath


def read_calibration(path: str | Path, kind: str) -> dict[str, Any]:
    """The values of a JSON calibration of ``kind``; raises CalibrationError naming the problem."""
    p = Path(path)
    try:
        doc = load_json(p, f"{kind} calibration", expect=None)
    except FileNotFoundError:
        raise CalibrationError(f"calibration file {p} does not exist; make it with: tactile-rig calibrate {kind}",
                               device=kind) from None
    except (OSError, ValueError) as exc:
        raise CalibrationError(f"{p} is not a readable calibration ({exc})", device=kind) from None
    try:
        doc = CALIBRATION_FILE.check(doc, p)
    except BadFile as exc:
        raise CalibrationError(f"{exc} (a {kind} calibration was asked for)", device=kind) from None
    if doc.get("kind") != kind:
        raise CalibrationError(f"{p} is not a {kind} calibration (its 'kind' is {doc.get('kind')!r})", device=kind)
    return {k: v for k, v in doc.items() if k not in _ENVELOPE}


def write_report_md(path: Path, kind: str, cal_path: Path, values: dict[str, Any], report: dict[str, Any]) -> None:
    """The report of a calibration as a Markdown table of its values and report numbers."""
    lines = [f"# {kind} calibration", "", f"- file: `{cal_path.name}`", f"- created: {utc_now()}", ""]
    if values:
        lines += ["## Values", "", "| name | value |", "| --- | --- |"]
        lines += [f"| {k} | {_short(v)} |" for k, v in values.items()]
        lines.append("")
    lines += ["## Report", "", "| name | value |", "| --- | --- |"]
    lines += [f"| {k} | {_short(v)} |" for k, v in report.items() if not isinstance(v, list)]
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")


def _short(v: Any) -> str:
    if isinstance(v, float):
        return f"{v:.6g}"
    text = json.dumps(v) if isinstance(v, (dict, list)) else str(v)
    return text if len(text) <= 80 else text[:77] + "..."
