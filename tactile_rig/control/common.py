"""What every controller shares: the outcome type, the fault guard, sensor adaptation, waiting.

A controller ends in an :class:`Outcome`. Any :class:`~tactile_rig.core.errors.RigError` raised by a
device inside a run is caught by :func:`fault_result`'s callers, motion is stopped
(:func:`safe_stop`) and the result names the device; no controller leaves an axis moving.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass, field
from typing import Any, Callable

from tactile_rig.control.protocols import (
    Gripper,
    GripperOutcome,
    Motion,
    Pose,
    TouchReading,
    Trace,
)
from tactile_rig.core.clock import Clock
from tactile_rig.core.errors import DeviceFault, DeviceTimeout, RigError


class Outcome(str, enum.Enum):
    """How a controller run ended."""

    SUCCESS = "success"  # the controller's goal was met (stopped on contact, object held, inserted...)
    NO_CONTACT = "no_contact"  # a guarded move reached its target without touching anything
    FAILED = "failed"  # the goal was not met (object dropped, not localized, search exhausted)
    TIMEOUT = "timeout"  # the run's own time budget ran out (motion stopped)
    FAULT = "fault"  # a device raised a RigError: motion stopped, see ``fault_device``


@dataclass
class ControllerResult:
    """The typed outcome of a run plus its trace and key figures (units in the keys)."""

    outcome: Outcome
    trace: Trace = field(default_factory=Trace)
    figures: dict[str, float] = field(default_factory=dict)
    message: str = ""
    fault_device: str | None = None

    @property
    def ok(self) -> bool:
        return self.outcome in (Outcome.SUCCESS, Outcome.NO_CONTACT)


def safe_stop(motion: Motion | None = None, gripper: Gripper | None = None, *,
              gripper_action: str = "hold", open_position: float | None = None,
              effort: float = 0.3) -> list[str]:
    """Stop ``motion`` and put ``gripper`` in a safe state; never raises. Returns what failed.

    ``gripper_action``: ``"hold"`` keeps the current opening (an object stays held), ``"open"``
    goes to ``open_position``, ``"none"`` leaves it alone (e.g. the gripper itself faulted).
    """
    problems: list[str] = []
    if motion is not None:
        try:
            motion.stop()
        except Exception as exc:  # the stop of a faulted device may fail too: keep going
            problems.append(f"motion.stop: {exc}")
    if gripper is not None and gripper_action != "none":
        try:
            if gripper_action == "open" and open_position is not None:
                gripper.gripper_go(open_position, effort, blocking=False)
            else:
                gripper.gripper_go(gripper.state().opening_m, effort, blocking=False)
        except Exception as exc:
            problems.append(f"gripper {gripper_action}: {exc}")
    return problems


def go(gripper: Gripper, position: float, effort: float, **kw: Any) -> GripperOutcome:
    """``gripper.gripper_go`` that raises :class:`DeviceFault` when the move ends in FAULT
    (drivers report a latched servo error as an outcome; a controller must stop on it)."""
    out = gripper.gripper_go(position, effort, **kw)
    if out is GripperOutcome.FAULT:
        raise DeviceFault("gripper_go ended in FAULT: a hardware error is latched, torque is off",
                          device=getattr(gripper, "name", "gripper"))
    return out


def check_gripper(gripper: Gripper) -> Any:
    """Read the gripper's state and raise :class:`DeviceFault` if it reports a hardware error
    (a driver may return the error bits instead of raising)."""
    st = gripper.state()
    if getattr(st, "hardware_error", 0):
        raise DeviceFault(f"hardware error status 0x{st.hardware_error:02x}",
                          device=getattr(gripper, "name", "gripper"), code=st.hardware_error)
    return st


def device_of(exc: BaseException) -> str:
    """The device an error names (``"unknown"`` when none)."""
    return getattr(exc, "device", None) or "unknown"


def fault_result(exc: RigError, trace: Trace, *, motion: Motion | None = None,
                 gripper: Gripper | None = None, gripper_action: str = "hold",
                 open_position: float | None = None,
                 figures: dict[str, float] | None = None) -> ControllerResult:
    """Stop everything and build the FAULT result for ``exc``."""
    # A faulted gripper cannot be commanded; anything else keeps its grip (or opens) as asked.
    action = "none" if gripper is not None and _is_gripper_error(exc) else gripper_action
    problems = safe_stop(motion, gripper, gripper_action=action, open_position=open_position)
    msg = f"{type(exc).__name__}: {exc}"
    if problems:
        msg += " (while stopping: " + "; ".join(problems) + ")"
    return ControllerResult(Outcome.FAULT, trace, dict(figures or {}), msg, device_of(exc))


def _is_gripper_error(exc: RigError) -> bool:
    dev = (getattr(exc, "device", None) or "").lower()
    return "gripper" in dev or "dynamixel" in dev


def guarded(run: Callable[[], ControllerResult], trace: Trace, *, motion: Motion | None = None,
            gripper: Gripper | None = None, gripper_action: str = "hold",
            open_position: float | None = None) -> ControllerResult:
    """Run ``run()``; a RigError becomes a FAULT result, any other error stops motion and re-raises."""
    try:
        return run()
    except RigError as exc:
        return fault_result(exc, trace, motion=motion, gripper=gripper,
                            gripper_action=gripper_action, open_position=open_position)
    except BaseException:
        safe_stop(motion, gripper, gripper_action=gripper_action, open_position=open_position)
        raise


# -- sensing ----------------------------------------------------------------------------------


def as_touch(result: Any, *, now_s: float = math.nan) -> TouchReading:
    """Adapt a perception result to a :class:`TouchReading`.

    Accepts a TouchReading as is, or anything shaped like a FingerVision result (``force_px``,
    ``torque_px2``, ``slip``, ``object_*``): its force units carry through unchanged.
    """
    if isinstance(result, TouchReading):
        return result
    force = getattr(result, "force_n", None)
    if force is None:
        force = getattr(result, "force_px", None)
    torque = getattr(result, "torque_nmm", None)
    if torque is None:
        torque = getattr(result, "torque_px2", None)
    if force is None:
        raise TypeError(f"cannot read a force from a {type(result).__name__}; expected a TouchReading "
                        "or a FingerVision-like result with force_px")
    f = tuple(float(v) for v in list(force)[:3])
    tq = tuple(float(v) for v in list(torque)[:3]) if torque is not None else (0.0, 0.0, 0.0)
    t = getattr(result, "t_s", None)
    slip_px = float(getattr(result, "slip_magnitude_px", 0.0) or 0.0)
    return TouchReading(
        t_s=float(t) if t is not None else now_s,
        force_n=f,  # type: ignore[arg-type]
        torque_nmm=tq,  # type: ignore[arg-type]
        contact=bool(getattr(result, "contact", abs(f[2]) > 0)),
        slip=bool(getattr(result, "slip", False)),
        slip_mm=float(getattr(result, "slip_mm", slip_px)),
        object_area_px=float(getattr(result, "object_area_px", 0.0) or 0.0),
        object_centroid_px=getattr(result, "object_centroid_px", None),
        object_orientation_deg=getattr(result, "object_orientation_deg", None),
    )


def read_touch(sensor: Any, clock: Clock, timeout_s: float) -> TouchReading:
    """One reading from ``sensor`` as a TouchReading; a sensor that returns None times out."""
    r = sensor.read(timeout_s)
    if r is None:
        raise DeviceTimeout(f"no frame within {timeout_s} s", device=getattr(sensor, "name", "sensor"))
    return as_touch(r, now_s=clock.now_s())


def read_fresh(sensor: Any, clock: Clock, after_s: float, timeout_s: float) -> TouchReading:
    """The first reading captured at or after ``after_s`` (frames from before a move show the old scene)."""
    while True:
        r = read_touch(sensor, clock, timeout_s)
        if r.t_s >= after_s:
            return r


def vec_norm(v: tuple[float, ...] | list[float]) -> float:
    return math.sqrt(sum(float(x) * float(x) for x in v))


# -- motion helpers ---------------------------------------------------------------------------


def pose_vec(p: Pose) -> tuple[float, float, float, float]:
    """The pose as the 4-vector (mm, mm, mm, deg) in which a feed rate is measured."""
    return (p.x_mm, p.y_mm, p.z_mm, p.theta_deg)


def pose_distance_mm(a: Pose, b: Pose) -> float:
    """Euclidean distance in (x, y, z, θ) with 1° counted as 1 mm, as a GRBL feed rate does."""
    return vec_norm([x - y for x, y in zip(pose_vec(a), pose_vec(b))])


def move_and_wait(motion: Motion, clock: Clock, target: Pose, speed_mps: float, *,
                  tol_mm: float = 0.05, poll_s: float = 0.01, timeout_s: float = 30.0,
                  trace: Trace | None = None) -> Pose:
    """Move to ``target`` and wait until within ``tol_mm``; on timeout stop and raise DeviceTimeout."""
    motion.move_toward(target, speed_mps)
    t_end = clock.now_s() + timeout_s
    while True:
        p = motion.pose()
        if trace is not None:
            trace.append(clock.now_s(), x_mm=p.x_mm, y_mm=p.y_mm, z_mm=p.z_mm, theta_deg=p.theta_deg)
        if pose_distance_mm(p, target) <= tol_mm:
            return p
        if clock.now_s() >= t_end:
            motion.stop()
            raise DeviceTimeout(f"did not reach {target} within {timeout_s} s (at {p})",
                                device=getattr(motion, "name", "motion"))
        clock.sleep(poll_s)


def record_pose(trace: Trace, t_s: float, p: Pose, **extra: float) -> None:
    trace.append(t_s, x_mm=p.x_mm, y_mm=p.y_mm, z_mm=p.z_mm, theta_deg=p.theta_deg, **extra)
