"""Episode: follow an object a person moves, by its shear force (eq. 3.1) or by proximity vision
(eq. 3.2), with a randomised sensor/image rotation.

Property (truth from the hand's path and the arm): once started, the fingertip stays within
``max_lag_mm`` of the object and ends within ``final_error_mm`` of it, at rest.
"""

from __future__ import annotations

import math

import numpy as np

from tactile_rig.control.following import Following, FollowingParams, rotate_xy
from tactile_rig.control.protocols import TouchReading
from tactile_rig.perception.fingervision.processor import (
    FingerVision,
    FingerVisionParams,
)
from tactile_rig.rig.episodes import outcome_matches, params_for
from tactile_rig.rig.episodes._devices import Devices, with_devices
from tactile_rig.rig.scene_runner import EpisodeContext, EpisodeReport
from tactile_rig.sim.render.fingervision import FingerVisionRenderer, FvObject


def _run(ctx: EpisodeContext, devices: Devices) -> EpisodeReport:
    arm, position_at = devices.pick_motion()
    hand = ctx.model("hand")
    c = ctx.controller
    params = params_for(FollowingParams, c)
    k_shear = float(c.get("shear_stiffness_n_per_mm", 0.5))
    mu_n = float(c.get("friction_limit_n", 3.0))
    p0 = position_at(ctx.clock.now_s())[:2].copy()

    def offset(t_s: float) -> np.ndarray:
        return hand.position_mm(t_s)[:2] - (position_at(t_s)[:2] - p0)

    def probe(t_s: float) -> TouchReading:
        ox, oy = offset(t_s)
        if params.mode == "force":
            fx, fy = k_shear * ox, k_shear * oy
            n = math.hypot(fx, fy)
            if n > mu_n:  # the skin slips on the object: friction caps the shear
                fx, fy = fx * mu_n / n, fy * mu_n / n
            sx, sy = rotate_xy(fx, fy, -params.sensor_rotation_deg)  # as the rotated sensor sees it
            return TouchReading(t_s, force_n=(sx, sy, 1.0), contact=True)
        ix, iy = rotate_xy(ox / params.mm_per_px, oy / params.mm_per_px, -params.image_rotation_deg)
        cx, cy = params.image_centre_px
        return TouchReading(t_s, contact=False, object_area_px=800.0, object_centroid_px=(cx + ix, cy + iy))

    render = process = None
    if ctx.sensor.get("kind") == "rendered":
        render, process = _rendered_proximity(ctx, params, offset)
    sensor = ctx.make_sensor(probe, render=render, process=process)
    ctrl = Following(arm, sensor, ctx.clock, params)
    res = ctrl.run()
    still = ctx.settle_and_check_still([arm])
    settle = float(c.get("start_s", 0.5))
    # from the poses the controller read (the arm's own history is kept for a few seconds only)
    xs, ys = res.trace.channels.get("x_mm", []), res.trace.channels.get("y_mm", [])
    lags = [float(np.linalg.norm(hand.position_mm(t)[:2] - (np.array([x, y]) - p0)))
            for t, x, y in zip(res.trace.t_s, xs, ys) if t >= settle]
    final = float(np.linalg.norm(offset(ctx.clock.now_s())))
    figures = {"max_lag_mm": max(lags, default=math.nan), "final_error_mm": final, "still_after": float(still)}
    ok = (outcome_matches(res, c) and still and figures["max_lag_mm"] <= float(c.get("max_lag_mm", 5.0))
          and final <= float(c.get("final_error_mm", 1.0)))
    return EpisodeReport("", 0, ctx.seed, ok, res.outcome.value, figures, res.message, res.fault_device,
                         result=res)


def _rendered_proximity(ctx: EpisodeContext, params: FollowingParams, offset):  # noqa: ANN001, ANN202
    """The FingerVision renderer drawing the object where it is, and the real FingerVision
    processor (calibrated on empty frames, object colours taught from one frame) reading it."""

    renderer = FingerVisionRenderer(seed=ctx.seed)
    fv = FingerVision(FingerVisionParams())
    fv.calibrate([renderer.render()[0] for _ in range(FingerVisionParams().n_calib_frames)])
    cx, cy = params.image_centre_px

    def obj_at(ox: float, oy: float) -> FvObject:
        ix, iy = rotate_xy(ox / params.mm_per_px, oy / params.mm_per_px, -params.image_rotation_deg)
        return FvObject((cx + ix, cy + iy), (30.0, 20.0), 10.0)

    teach = renderer.render(object=obj_at(0.0, 0.0))[0]
    fv.learn_object(teach, rects=[(int(cx) - 30, int(cy) - 20, 60, 40)])

    def render(t_s: float):  # noqa: ANN202
        ox, oy = offset(t_s)
        return renderer.render(object=obj_at(float(ox), float(oy)))[0]

    return render, fv.process


run_episode = with_devices(_run)
