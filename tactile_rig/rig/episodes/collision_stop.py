"""Episode: a guarded approach of the simulated arm toward a table (Alg. 2).

Property: the arm stops with at most ``allowed_overtravel_mm`` of travel past first contact, at
any speed up to the derived cap (the scene draws the speed as a fraction of the cap unless the
CLI gives one); a speed above the cap is refused before anything moves.
"""

from __future__ import annotations

import math

import numpy as np

from tactile_rig.control.collision_stop import CollisionStop, CollisionStopParams
from tactile_rig.control.protocols import Pose
from tactile_rig.errors import RigError
from tactile_rig.mocks.world.arm import SimArm
from tactile_rig.mocks.world.table import Table
from tactile_rig.rig.episodes import outcome_matches, params_for
from tactile_rig.rig.scene_runner import EpisodeContext, EpisodeReport
from tactile_rig.mocks.sensors import touch


def build(ctx: EpisodeContext) -> tuple[CollisionStop, SimArm, list[Table]]:
    arm: SimArm = ctx.model("arm")
    tables = [m for n in ctx.world if isinstance(m := ctx.world.get(n), Table)]

    def probe(t_s: float):
        p = arm.position_at(t_s)
        f = sum((tb.force_n(p) for tb in tables), np.zeros(3))
        return touch(t_s, force_n=tuple(float(v) for v in f), contact=bool(np.linalg.norm(f) > 0))

    sensor = ctx.make_sensor(probe, name="tactile")
    c = ctx.controller
    known = {"stop_latency_s": arm.command_latency_s + 3 * arm.tracking_tau_s,
             "decel_mps2": arm.decel_mps2,
             "contact_stiffness_n_per_mm": min(tb.stiffness_n_per_mm for tb in tables) if tables else None}
    params = params_for(CollisionStopParams, {**known, **c})
    return CollisionStop(arm, sensor, ctx.clock, params), arm, tables


def run_episode(ctx: EpisodeContext) -> EpisodeReport:
    ctrl, arm, tables = build(ctx)
    c = ctx.controller
    target = Pose(*c.get("target_mm", [0.0, 0.0, -50.0, 0.0]))
    start = arm.position_at(ctx.clock.now_s()).copy()
    path = np.array([target.x_mm, target.y_mm, target.z_mm]) - start[:3]
    path_dir = path / max(1e-12, float(np.linalg.norm(path)))
    worst = {"pen": 0.0}

    def watch() -> None:
        # ground truth: deepest travel past any surface, measured along the path
        for t, (p, _v) in zip(arm.history._t, arm.history._v):  # noqa: SLF001 - read-only
            for tb in tables:
                pen = tb.penetration_mm(p)
                if pen > 0:
                    cos = abs(float(np.dot(path_dir, tb.normal))) or 1.0
                    worst["pen"] = max(worst["pen"], pen / cos)

    try:
        ctrl.calibrate()
        cap = ctrl.cap_mps()
    except RigError:  # e.g. a frozen camera: run() meets the fault again and reports it
        cap = math.nan
    speed = ctx.speed_mps
    if speed is None:
        frac = float(c.get("speed_frac_of_cap", 1.0))
        speed = (cap if math.isfinite(cap) else 0.01) * frac
    res = ctrl.run(target, speed)  # LimitError above the cap propagates: the CLI exits non-zero
    still = ctx.settle_and_check_still([arm])
    watch()
    allowed = ctrl.p.allowed_overtravel_mm
    figures = {"speed_mps": speed, "cap_mps": res.cap_mps, "overtravel_mm": worst["pen"],
               "allowed_overtravel_mm": allowed,
               "peak_force_n": max((abs(v) for v in res.trace.channels.get("fz_n", [0.0])
                                    if math.isfinite(v)), default=0.0),
               "sensing_rate_hz": ctrl.rate_hz or math.nan, "latency_s": ctrl.latency_s or 0.0,
               "still_after": float(still)}
    ok = outcome_matches(res, c) and still and worst["pen"] <= allowed + 1e-6
    return EpisodeReport("", 0, ctx.seed, ok, res.outcome.value, figures, res.message, res.fault_device,
                         result=res)
