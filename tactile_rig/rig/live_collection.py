"""Guided live collection for the learned calibrations: the force map and the substance classifier.

**Force map** (:func:`collect_force_map`). The scale stands between the gripper's fingers with its
platform facing the FingerVision fingertip. The session

1. opens the fingers to ``release_opening_m`` and tares the scale (nothing touching);
2. starts the marker tracker from the camera's stored baseline (``calibrate fingervision``), or
   builds one from the first frames at rest;
3. **probes**: raises the effort slowly until the scale reads ``max(peaks_n)`` (or the effort
   reaches ``max_effort``: a CalibrationError says which limit to change), which gives the effort
   per newton of this gripper on this scale;
4. **presses** once per peak force, rising: the effort ramps up over ``ramp_s``, holds ``hold_s``
   and ramps down (the profile of the mock stick-press scene), the fingers open between presses.

Every camera frame (JPEG), its marker force/torque (``/perception/<camera>``, with the trial),
every scale reading (``/scale/force``), every gripper command and the trial starts go to one MCAP
file, which :func:`tactile_rig.rig.learning.force_trials_from_recording` pairs and fits; so the
fit of a live session is the fit of a recording. On the mock bench the scene
``force_map_press`` (:mod:`tactile_rig.sim.world.scale_press`) closes the loop: the Dynamixel mock
drives the fingers, their squeeze loads the simulated cell and deforms the rendered skin.

**Substance** (:func:`collect_stirring`). The gripper holds the stirring stick (``grip_effort``);
for each trial the operator is asked to put it in the named substance and stir; the camera's marker
forces are recorded for ``trial_s`` with a labelled trial start.

Both take a connected :class:`~tactile_rig.rig.bench.Rig` (real, rehearsal or mock: the same code)
and a :class:`~tactile_rig.rig.calibration_sessions.Guide` (prompts on a terminal, logs otherwise).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from tactile_rig.core.errors import CalibrationError, check_range
from tactile_rig.perception.fingervision import FingerVision, FingerVisionParams
from tactile_rig.rig.calibration_sessions import Guide
from tactile_rig.rig.camera_calibrations import CameraCalibrations, FingerVisionCalibration
from tactile_rig.rig.recording import Recorder

__all__ = ["PressPlan", "collect_force_map", "collect_stirring", "press_profile"]


@dataclass(frozen=True)
class PressPlan:
    """How the gripper presses on the scale (forces in N, times in s, openings in m, effort 0-1).

    ``peaks_n``: one press per peak force (the fit holds one trial out, so at least 2).
    ``max_effort`` caps the effort (fraction of the current limit) anywhere in the session.
    ``press_opening_m`` is the goal while pressing (past the platform, so the servo stalls on it at
    the effort cap); ``release_opening_m`` where the fingers wait between presses.
    ``probe_s`` is the duration of the probe's effort ramp; ``rest_frames`` the frames at rest
    before the first press (baseline, or a check of the stored one).
    """

    peaks_n: tuple[float, ...] = tuple(float(v) for v in np.linspace(2.0, 20.0, 10))
    max_effort: float = 0.5
    ramp_s: float = 1.0
    hold_s: float = 0.5
    gap_s: float = 0.5
    press_opening_m: float = 0.0
    release_opening_m: float = 0.06
    probe_s: float = 3.0
    rest_frames: int = 10
    frame_timeout_s: float = 2.0

    def __post_init__(self) -> None:
        if len(self.peaks_n) < 2:
            raise ValueError(f"peaks_n={self.peaks_n!r}: the force map needs >= 2 presses (one is held out)")
        for p in self.peaks_n:
            check_range("peaks_n", float(p), 1e-3, 1e4, "N")
        check_range("max_effort", float(self.max_effort), 1e-3, 1.0)
        check_range("ramp_s", float(self.ramp_s), 0.05, 60.0, "s")
        check_range("hold_s", float(self.hold_s), 0.0, 60.0, "s")
        check_range("probe_s", float(self.probe_s), 0.1, 120.0, "s")
        check_range("release_opening_m", float(self.release_opening_m), 0.0, 1.0, "m")


def press_profile(t_s: float, ramp_s: float, hold_s: float) -> float:
    """Fraction of the peak at ``t_s`` into a press: up over ``ramp_s``, hold, down over ``ramp_s``."""
    up = min(max(t_s / ramp_s, 0.0), 1.0)
    down = min(max((2 * ramp_s + hold_s - t_s) / ramp_s, 0.0), 1.0)
    return min(up, down)


def _frame(camera: Any, timeout_s: float) -> tuple[np.ndarray, float]:
    fr = camera.read(timeout_s=timeout_s)
    return np.ascontiguousarray(getattr(fr, "image", fr)), float(getattr(fr, "t_host_s", 0.0))


def _tracker(calibrations: CameraCalibrations | None, params: FingerVisionParams | None) -> FingerVision:
    fv = FingerVision(params or FingerVisionParams())
    cal = None if calibrations is None else calibrations.calibration
    if isinstance(cal, FingerVisionCalibration):
        cal.apply(fv)
    return fv


class _Session:
    """One recording of frames, marker forces, scale readings and commands, on the rig's clock."""

    def __init__(self, rig: Any, path: str | Path, camera: str, kind: str, fv: FingerVision,
                 record_frames: bool, **meta: Any) -> None:
        self.rig, self.camera_name, self.fv = rig, camera, fv
        self.camera = rig.devices[camera]
        self.rec = Recorder(path, clock=rig.clock)
        self.path = Path(path)
        self.record_frames = record_frames
        self.rec.add_bench(rig.bench)
        self.rec.add_metadata("session", {"kind": kind, "camera": camera, "live": True, **meta})
        self.stored: FingerVisionCalibration | None = None
        self.trial: int | None = None
        self.phase = "rest"  # rest | probe | press | release: only "press" samples train the map
        self.last_force_n = 0.0

    def sample(self, timeout_s: float) -> Any:
        """One frame through the tracker (recorded), and every scale reading that came meanwhile."""
        image, t = _frame(self.camera, timeout_s)
        if self.stored is not None:
            self.stored.check_frame(image)
            self.stored = None  # one check: the camera keeps its format
        r = self.fv.process(image, t)
        if self.record_frames:
            self.rec.write_frame(self.camera_name, image, t_s=t, compress="jpeg")
        d: dict[str, Any] = {"force_px": [float(v) for v in r.force_px],
                             "torque_px2": [float(v) for v in r.torque_px2], "calibrating": r.calibrating,
                             "marker_count": r.n_markers, "phase": self.phase}
        if self.trial is not None:
            d["trial"] = self.trial
        if not r.calibrating:
            self.rec.write_perception(self.camera_name, d, t_s=t)
        self.drain_scale()
        return r

    def drain_scale(self) -> None:
        scale = self.rig.devices.get("scale")
        if scale is None:
            return
        for reading in scale.poll():
            self.last_force_n = float(reading.newtons)
            extra = {} if self.trial is None else {"trial": self.trial}
            self.rec.write_scale(self.last_force_n, t_s=float(reading.t_host_s), **extra)

    def close(self) -> None:
        self.rec.close()


def collect_force_map(rig: Any, path: str | Path, *, camera: str, plan: PressPlan | None = None,
                      calibrations: CameraCalibrations | None = None, guide: Guide | None = None,
                      params: FingerVisionParams | None = None, record_frames: bool = True) -> Path:
    """Run the guided press session on ``rig`` (needs ``gripper``, ``scale`` and ``camera``) into ``path``.

    See the module doc. Returns ``path``; raises CalibrationError when the scale never sees the
    top force within the effort cap, or when the camera's markers are not found.
    """
    plan = plan or PressPlan()
    guide = guide or Guide(False, quiet=True)
    for dev in ("gripper", "scale"):
        if rig.devices.get(dev) is None:
            raise ValueError(f"force-map collection needs a [{dev}] on the bench")
    if camera not in rig.devices:
        raise ValueError(f"force-map collection: the bench has no camera [{camera}]")
    gripper, scale, clock = rig.gripper, rig.scale, rig.clock
    peaks = sorted(float(p) for p in plan.peaks_n)
    s = _Session(rig, path, camera, "force-map", _tracker(calibrations, params), record_frames,
                 peaks_n=peaks, max_effort=plan.max_effort)
    _attach_baseline(s, calibrations)
    try:
        guide.step("stand the scale between the fingers, its platform facing the FingerVision fingertip, "
                   "nothing touching it")
        gripper.activate(min(plan.max_effort, 0.1))
        s.rec.write_command("gripper", "go", opening_m=plan.release_opening_m, effort=0.1)
        gripper.gripper_go(plan.release_opening_m, min(plan.max_effort, 0.1), blocking=True, timeout_s=5.0)
        s.rec.write_command("scale", "tare")
        scale.tare()
        scale.poll()
        guide.say(f"{plan.rest_frames} frames at rest" + ("" if s.fv.tracker is not None else
                                                          " (no stored baseline: building one)"))
        # Frames at rest: the baseline's own (when none is stored), then rest_frames tracked against it.
        for _ in range(int(plan.rest_frames) + (s.fv.params.n_calib_frames if s.fv.tracker is None else 0)):
            s.sample(plan.frame_timeout_s)
        if s.fv.tracker is None:
            raise CalibrationError(f"camera [{camera}]: no marker baseline after {plan.rest_frames} frames",
                                   device="force-map")
        newton_per_effort = _probe(s, plan, peaks[-1], guide)
        guide.say(f"probe: {newton_per_effort:.1f} N per unit effort; pressing {len(peaks)} times up to "
                  f"{peaks[-1]:g} N")
        for k, peak in enumerate(peaks):
            effort_peak = min(plan.max_effort, peak / newton_per_effort)
            s.trial, s.phase = k, "press"
            s.rec.write_command("session", "trial_start", trial=k, peak_force_n=peak, peak_effort=effort_peak)
            t0 = clock.now_s()
            while (dt := clock.now_s() - t0) < 2 * plan.ramp_s + plan.hold_s:
                e = effort_peak * press_profile(dt, plan.ramp_s, plan.hold_s)
                gripper.gripper_go(plan.press_opening_m, e, blocking=False)
                s.rec.write_command("gripper", "go", opening_m=plan.press_opening_m, effort=e, trial=k)
                s.sample(plan.frame_timeout_s)
            s.trial = None
            _release(s, plan)
        guide.say(f"force map: {len(peaks)} presses recorded -> {s.path}")
    finally:
        try:
            gripper.gripper_go(plan.release_opening_m, min(plan.max_effort, 0.1), blocking=False)
        except Exception:  # noqa: BLE001 - the session's own error (if any) is the one to report
            pass
        s.close()
    return Path(path)


def _attach_baseline(s: _Session, calibrations: CameraCalibrations | None) -> None:
    """Record the stored baseline the session starts from, and check the camera's frames against it."""
    if calibrations is not None and isinstance(calibrations.calibration, FingerVisionCalibration):
        s.stored = calibrations.calibration
        s.rec.add_calibration(calibrations.sensor, path=calibrations.files["calibration"])


def _release(s: _Session, plan: PressPlan) -> None:
    """Open the fingers and keep recording (phase ``release``) for ``gap_s``."""
    s.phase = "release"
    s.rig.gripper.gripper_go(plan.release_opening_m, min(plan.max_effort, 0.1), blocking=False)
    t0 = s.rig.clock.now_s()
    while s.rig.clock.now_s() - t0 < plan.gap_s:
        s.sample(plan.frame_timeout_s)


def _probe(s: _Session, plan: PressPlan, target_n: float, guide: Guide) -> float:
    """Raise the effort until the scale reads ``target_n``; return newtons per unit effort."""
    gripper, clock = s.rig.gripper, s.rig.clock
    guide.say(f"probe: raising the effort until the scale reads {target_n:g} N (at most {plan.max_effort:g})")
    t0 = clock.now_s()
    e = 0.0
    s.phase = "probe"
    while True:
        e = min(plan.max_effort, plan.max_effort * (clock.now_s() - t0) / plan.probe_s)
        gripper.gripper_go(plan.press_opening_m, e, blocking=False)
        s.rec.write_command("gripper", "go", opening_m=plan.press_opening_m, effort=e, purpose="probe")
        s.sample(plan.frame_timeout_s)
        if s.last_force_n >= target_n:
            break
        if e >= plan.max_effort:
            _release(s, plan)
            raise CalibrationError(f"the scale read {s.last_force_n:.2f} N at the effort cap {plan.max_effort:g}, "
                                   f"short of the top press {target_n:g} N: raise --max-effort or lower "
                                   "--max-force (is the platform between the fingers?)", device="force-map")
    # The scale lags the command by its filter and the frame time: read the force the effort made.
    hold_until = clock.now_s() + 0.3
    while clock.now_s() < hold_until:
        s.sample(plan.frame_timeout_s)
    force = s.last_force_n
    _release(s, plan)
    if not (force > 0 and math.isfinite(force)):
        raise CalibrationError(f"the probe read {force} N on the scale", device="force-map")
    return force / max(e, 1e-6)


def collect_stirring(rig: Any, path: str | Path, *, camera: str, substances: Sequence[str], per_substance: int = 3,
                     trial_s: float = 10.0, grip_effort: float = 0.3, calibrations: CameraCalibrations | None = None,
                     guide: Guide | None = None, params: FingerVisionParams | None = None,
                     record_frames: bool = True) -> Path:
    """Record ``per_substance`` labelled stirring trials of each substance (interleaved) into ``path``."""
    guide = guide or Guide(False, quiet=True)
    names = [str(x).strip() for x in substances if str(x).strip()]
    if len(set(names)) < 2:
        raise ValueError(f"substances={list(substances)!r}: the classifier needs at least two different substances")
    check_range("per_substance", float(per_substance), 2, 1000)
    check_range("trial_s", float(trial_s), 0.5, 3600.0, "s")
    if camera not in rig.devices:
        raise ValueError(f"substance collection: the bench has no camera [{camera}]")
    s = _Session(rig, path, camera, "substance", _tracker(calibrations, params), record_frames,
                 substances=names, per_substance=int(per_substance))
    _attach_baseline(s, calibrations)
    clock, gripper = rig.clock, rig.devices.get("gripper")
    try:
        guide.step("put the stirring stick between the fingers")
        if gripper is not None:
            gripper.activate(grip_effort)
            s.rec.write_command("gripper", "go", opening_m=0.0, effort=grip_effort)
            gripper.gripper_go(0.0, grip_effort, blocking=True, timeout_s=5.0)
        for _ in range(s.fv.params.n_calib_frames if s.fv.tracker is None else 1):
            s.sample(2.0)
        k = 0
        for rep in range(int(per_substance)):
            for name in names:
                guide.step(f"trial {k + 1}/{len(names) * int(per_substance)}: put the stick in {name} and stir")
                s.trial, s.phase = k, "stir"
                s.rec.write_command("session", "trial_start", trial=k, label=name)
                t0 = clock.now_s()
                while clock.now_s() - t0 < trial_s:
                    s.sample(2.0)
                s.trial, s.phase = None, "rest"
                k += 1
        guide.say(f"substance: {k} trials recorded -> {s.path}")
    finally:
        s.close()
    return Path(path)
