"""Episode: rotate a held stick in the fingers by letting it slip (by orientation or by torque).

Property (from the friction model's truth): the final angle lies within ``tolerance_deg``
(default 5°) of the target and the object was never dropped.
"""

from __future__ import annotations

from tactile_rig.control.inhand import InHandRotation, InHandRotationParams
from tactile_rig.rig.episodes import outcome_matches, params_for
from tactile_rig.rig.episodes._devices import Devices, with_devices
from tactile_rig.rig.episodes._grasp_probe import frame_period_s, grasp_probe
from tactile_rig.rig.scene_runner import EpisodeContext, EpisodeReport


def _run(ctx: EpisodeContext, devices: Devices) -> EpisodeReport:
    obj = ctx.model("object")
    gripper = devices.pick_gripper()
    c = ctx.controller
    probe = grasp_probe(obj, frame_period_s(ctx.sensor))
    sensor = ctx.make_sensor(probe)
    start_angle = obj.state_at(ctx.clock.now_s()).angle_deg
    params = params_for(InHandRotationParams, {"start_angle_deg": start_angle, **c})
    ctrl = InHandRotation(gripper, sensor, ctx.clock, params)
    res = ctrl.run()
    still = ctx.settle_and_check_still(grippers=[gripper], settle_s=1.0)
    true_final = obj.state_at(ctx.clock.now_s()).angle_deg - start_angle
    err = true_final - params.target_deg
    tol = float(c.get("property_tolerance_deg", 5.0))
    figures = {"final_angle_deg": true_final, "target_deg": params.target_deg, "angle_error_deg": err,
               "measured_angle_deg": res.figures.get("final_angle_deg", float("nan")),
               "dropped": float(obj.dropped), "slid_mm": obj.state_at(ctx.clock.now_s()).slip_mm,
               "still_after": float(still)}
    ok = outcome_matches(res, c) and not obj.dropped and still
    if c.get("expect", "success") == "success":
        ok = ok and abs(err) <= tol
    return EpisodeReport("", 0, ctx.seed, ok, res.outcome.value, figures, res.message, res.fault_device,
                         result=res)


run_episode = with_devices(_run)
