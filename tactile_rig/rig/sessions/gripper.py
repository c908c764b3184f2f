"""The gripper calibration session: find the closed and open stops at a low effort."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from tactile_rig.core.jsonable import to_jsonable
from tactile_rig.rig.sessions.calibration_file import JSON_SUFFIXES, SessionOutcome, session_version, write_calibration
from tactile_rig.rig.sessions.guide import Guide
from tactile_rig.rig.sessions.session_recording import SessionRecording

__all__ = ["gripper_session"]


def gripper_session(gripper: Any, out: str | Path, *, effort: float = 0.2, max_opening_m: float | None = None,
                    closing_sign: int = -1, guide: Guide | None = None, force: bool = False,
                    bench: Any = None, live: Any = None) -> SessionOutcome:
    """Find the gripper's closed and open stops at a low effort and write them (``GripperCalibration``
    fields at the top level, so ``tactile-rig gripper --calibration`` reads the file as it is); the
    recording holds the commands and the servo's state before and after."""
    guide = guide or Guide(False, quiet=True)
    ver = session_version(out, JSON_SUFFIXES, force)
    guide.step("clear the fingers: the gripper will close and open fully")
    rec = SessionRecording(ver.path(".mcap"), getattr(gripper, "clock", None), kind="gripper", bench=bench, live=live)
    try:
        rec.state("gripper", _state_or_none(gripper))
        rec.command("gripper", "calibrate", effort=float(effort), closing_sign=int(closing_sign))
        cal = gripper.calibrate(effort=effort, max_opening_m=max_opening_m, closing_sign=closing_sign)
        rec.state("gripper", _state_or_none(gripper))
    except BaseException:
        rec.close()
        raise
    values = dict(cal.to_dict())
    span = int(values["open_ticks"]) - int(values["closed_ticks"])
    report: dict[str, Any] = {"span_ticks": span, "effort": float(effort), "closing_sign": int(closing_sign),
              "m_per_tick": float(values["max_opening_m"]) / abs(span) if span else None}
    report["recording"] = None if rec.path is None else str(rec.path)
    path, rpath = write_calibration(out, "gripper", values, report, device=str(getattr(gripper, "device", "gripper")),
                                    version=ver)
    rec.attach("gripper", path, values=values)
    rec.close()
    guide.say(f"gripper: closed {values['closed_ticks']} ticks, open {values['open_ticks']} ticks -> {path}")
    return SessionOutcome("gripper", path, rpath, {**values, **report},
                          {"json": str(path), "recording": report["recording"], "version": ver.version,
                           "latest": str(ver.link(".json"))})


def _state_or_none(device: Any) -> dict[str, Any]:
    """A device's state for the recording ({} when it cannot report one)."""
    try:
        return to_jsonable(device.state())
    except Exception:  # noqa: BLE001 - a state that cannot be read is simply not recorded
        return {}
