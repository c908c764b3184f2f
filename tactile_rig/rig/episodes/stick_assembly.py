"""Episode: the stick assembly of thesis ch. 4 (centre, scan, find the table, press to a load).

Property (stick truth): the stick ends centred (within ``centre_tol_mm``), grasped within one scan
step of the best grasp, the descent stopped within the allowed overtravel, and the scale's true
load ends in ``[target, target + load_tol_n]``.
"""

from __future__ import annotations

import numpy as np

from tactile_rig.control.collision_stop import CollisionStopParams
from tactile_rig.control.protocols import TouchReading
from tactile_rig.control.stick_assembly import StickAssembly, StickAssemblyParams
from tactile_rig.rig.episodes import outcome_matches, params_for
from tactile_rig.rig.episodes._devices import Devices
from tactile_rig.rig.scene_runner import EpisodeContext, EpisodeReport
from tactile_rig.sim.fakes.sensors import ModelGauge


def run_episode(ctx: EpisodeContext) -> EpisodeReport:
    arm = ctx.model("arm")
    gripper = ctx.model("gripper")
    stick = ctx.model("stick")
    c = ctx.controller
    params = params_for(StickAssemblyParams, c)
    params.collision = params_for(CollisionStopParams, {
        "retreat_mm": 0.0, "stop_latency_s": arm.command_latency_s + 3 * arm.tracking_tau_s,
        "decel_mps2": arm.decel_mps2, "contact_stiffness_n_per_mm": stick.stiffness_n_per_mm,
        **c.get("collision", {})})

    def probe(t_s: float) -> TouchReading:
        p = arm.position_at(t_s)
        cy = params.image_centre_y_px + stick.lateral_error_mm(p) / params.mm_per_px
        return TouchReading(t_s, force_n=(0.0, 0.0, stick.load_n(p)), contact=True,
                            object_area_px=2500.0 * stick.quality(p), object_centroid_px=(80.0, cy))

    sensor = ctx.make_sensor(probe)
    devices = Devices(ctx)
    try:
        if c.get("scale_device") == "hx711":  # the scale driver on the HX711 mock under the fixture
            ctx.model("load_cell").set_force_source(lambda t: stick.load_n(arm.position_at(t)))
            scale = devices.scale()
        else:
            scale = ModelGauge(ctx.clock, lambda t: stick.load_n(arm.position_at(t)),
                               rng=np.random.default_rng([ctx.seed, 31]), **dict(c.get("scale", {})))
        ctrl = StickAssembly(arm, gripper, sensor, scale, ctx.clock, params)
        res = ctrl.run()
    finally:
        devices.close()
    still = ctx.settle_and_check_still([arm], [gripper])
    p_end = arm.position_at(ctx.clock.now_s())
    true_load = stick.load_n(p_end)
    centre_err = abs(stick.lateral_error_mm(p_end))
    grasp_err = abs(float(p_end[0]) - stick.best_grasp_mm)
    overtravel = stick.press_mm(p_end) if res.outcome.value != "success" else float("nan")
    figures = {"final_load_n": true_load, "centre_error_mm": centre_err, "grasp_error_mm": grasp_err,
               "target_load_n": params.target_load_n, "still_after": float(still),
               "press_mm": stick.press_mm(p_end), "overtravel_mm": overtravel}
    ok = outcome_matches(res, c) and still
    if c.get("expect", "success") == "success":
        ok = (ok and centre_err <= float(c.get("centre_tol_mm", 0.5))
              and grasp_err <= params.scan_step_mm
              and params.target_load_n <= true_load <= params.target_load_n + float(c.get("load_tol_n", 0.5)))
    return EpisodeReport("", 0, ctx.seed, ok, res.outcome.value, figures, res.message, res.fault_device,
                         result=res)
