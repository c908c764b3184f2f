"""Episode: a guarded approach toward a table (Alg. 2), by the simulated arm or the GRBL jig.

Property: the axis stops with at most ``allowed_overtravel_mm`` of travel past first contact, at
any speed up to the derived cap (the scene draws the speed as a fraction of the cap unless the
CLI gives one); a speed above the cap is refused before anything moves.
"""

from __future__ import annotations

import math
from typing import Any, Callable

import numpy as np

from tactile_rig.control.collision_stop import CollisionStop, CollisionStopParams
from tactile_rig.control.protocols import Pose
from tactile_rig.core.errors import RigError
from tactile_rig.rig.episodes import outcome_matches, params_for
from tactile_rig.rig.episodes._devices import Devices, with_devices
from tactile_rig.rig.scene_runner import EpisodeContext, EpisodeReport
from tactile_rig.sim.fakes.sensors import touch
from tactile_rig.sim.world.table import Table


def _motion(ctx: EpisodeContext, devices: Devices) -> tuple[Any, Callable[[float], np.ndarray], Callable[[], list[tuple[float, np.ndarray]]], dict[str, float]]:
    """(Motion, position(t) → xyz mm, history samples [(t, xyz)], known stop figures)."""
    c = ctx.controller
    if c.get("motion") == "jig":
        jig, hist = devices.jig()
        stage = ctx.model("stage")

        def pos_jig(t_s: float) -> np.ndarray:
            stage.advance_to(ctx.clock.now_s())
            x, y, _th = hist.at(t_s)
            return np.array([x, y, 0.0])

        accel = jig.read_settings().get(120, 500.0)  # $120: x acceleration, mm/s²
        known = {"decel_mps2": accel / 1000.0, "stop_latency_s": float(c.get("jig_stop_latency_s", 0.02))}
        samples = lambda: [(t, np.array([v[0], v[1], 0.0])) for t, v in hist.between(-math.inf, math.inf)]  # noqa: E731
        return jig, pos_jig, samples, known
    arm = ctx.model("arm")
    known = {"stop_latency_s": arm.command_latency_s + 3 * arm.tracking_tau_s, "decel_mps2": arm.decel_mps2}
    samples = lambda: [(t, v[0][:3]) for t, v in arm.history.between(-math.inf, math.inf)]  # noqa: E731
    return arm, (lambda t: arm.position_at(t)[:3]), samples, known


def _run(ctx: EpisodeContext, devices: Devices) -> EpisodeReport:
    c = ctx.controller
    motion, pos, samples, known = _motion(ctx, devices)
    tables = [m for n in ctx.world if isinstance(m := ctx.world.get(n), Table)]

    def probe(t_s: float):
        p = pos(t_s)
        f = sum((tb.force_n(p) for tb in tables), np.zeros(3))
        return touch(t_s, force_n=tuple(float(v) for v in f), contact=bool(np.linalg.norm(f) > 0))

    sensor = ctx.make_sensor(probe, name="tactile")
    if tables:
        known["contact_stiffness_n_per_mm"] = min(tb.stiffness_n_per_mm for tb in tables)
    ctrl = CollisionStop(motion, sensor, ctx.clock, params_for(CollisionStopParams, {**known, **c}))
    target = Pose(*c.get("target_mm", [0.0, 0.0, -50.0, 0.0]))
    start = pos(ctx.clock.now_s()).copy()
    path = np.array([target.x_mm, target.y_mm, target.z_mm]) - start
    path_dir = path / max(1e-12, float(np.linalg.norm(path)))
    try:
        ctrl.calibrate()
        cap = ctrl.cap_mps()
    except RigError:  # e.g. a frozen camera: run() meets the fault again and reports it
        cap = math.nan
    speed = ctx.speed_mps
    if speed is None:
        speed = (cap if math.isfinite(cap) else 0.01) * float(c.get("speed_frac_of_cap", 1.0))
    res = ctrl.run(target, speed)  # LimitError above the cap propagates: the CLI exits non-zero
    still = ctx.settle_and_check_still([motion])
    worst = 0.0  # ground truth: deepest travel past any surface, measured along the path
    for _t, p in samples():
        for tb in tables:
            pen = tb.penetration_mm(p)
            if pen > 0:
                worst = max(worst, pen / (abs(float(np.dot(path_dir, tb.normal))) or 1.0))
    allowed = ctrl.p.allowed_overtravel_mm
    fz = [abs(v) for v in res.trace.channels.get("fz_n", []) + res.trace.channels.get("fx_n", []) if math.isfinite(v)]
    figures = {"speed_mps": speed, "cap_mps": res.cap_mps, "overtravel_mm": worst,
               "allowed_overtravel_mm": allowed, "peak_force_n": max(fz, default=0.0),
               "sensing_rate_hz": ctrl.rate_hz or math.nan, "latency_s": ctrl.latency_s or 0.0,
               "still_after": float(still)}
    ok = outcome_matches(res, c) and still and worst <= allowed + 1e-6
    return EpisodeReport("", 0, ctx.seed, ok, res.outcome.value, figures, res.message, res.fault_device,
                         result=res)


run_episode = with_devices(_run)
