"""Devices as typed messages: the gripper as ``foxglove.JointStates``; device events as ``foxglove.Log``.

The gripper is one prismatic joint, ``gripper``: position = the opening between the fingertips (m),
velocity its rate (m/s), effort the motor current (A: the MX-64 measures current, not force).
"""

from __future__ import annotations

import math
from typing import Any, Mapping

from tactile_rig.rig.messages.base import SchemaDef, foxglove_messages, foxglove_schema, timestamp

__all__ = ["GRIPPER_JOINT", "gripper_joint_states", "log_message", "LEVELS"]

GRIPPER_JOINT = "gripper"
LEVELS = ("debug", "info", "warning", "error", "fatal")


def _finite(v: Any) -> float | None:
    try:
        f = float(v)
    except (TypeError, ValueError):
        return None
    return f if math.isfinite(f) else None


def gripper_joint_states(state: Mapping[str, Any], log_time_ns: int) -> tuple[SchemaDef, bytes] | None:
    """The gripper state (``opening_m``, ``velocity_mps``, ``current_a``) as JointStates; None when
    ``state`` has no opening (a state of another kind)."""
    opening = _finite(state.get("opening_m"))
    if opening is None:
        return None
    fm = foxglove_messages()
    joint = fm.JointState(name=GRIPPER_JOINT, position=opening, velocity=_finite(state.get("velocity_mps")),
                          effort=_finite(state.get("current_a")))
    return foxglove_schema("JointStates"), fm.JointStates(timestamp=timestamp(log_time_ns), joints=[joint]).encode()


def log_message(name: str, message: str, log_time_ns: int, *, level: str = "info") -> tuple[SchemaDef, bytes]:
    """A ``foxglove.Log`` from ``name`` (a device or ``session``) at ``level`` (debug .. fatal)."""
    if level not in LEVELS:
        raise ValueError(f"log level {level!r} must be one of {', '.join(LEVELS)}")
    fm = foxglove_messages()
    lv = getattr(fm.LogLevel, level.capitalize())
    msg = fm.Log(timestamp=timestamp(log_time_ns), level=lv, message=message, name=name)
    return foxglove_schema("Log"), msg.encode()
