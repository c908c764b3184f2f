"""Episode: find the least grip effort that lifts the object (Alg. 4).

Property (friction model truth): the effort found lies between the least effort that can hold the
object's weight at all and 10 % above the least effort that lifts it at the arm's acceleration:
``e_hold ≤ effort ≤ 1.10 · e_lift`` with ``e = m (g + a) / (2 μs F_stall)``.
"""

from __future__ import annotations

from tactile_rig.control.lift_effort import LiftEffortParams, MinimalLiftEffort
from tactile_rig.devices.dynamixel import control_table as ct
from tactile_rig.rig.episodes import outcome_matches, params_for
from tactile_rig.rig.episodes._devices import Devices, with_devices
from tactile_rig.rig.episodes._grasp_probe import frame_period_s, grasp_probe
from tactile_rig.rig.scene_runner import EpisodeContext, EpisodeReport


def _run(ctx: EpisodeContext, devices: Devices) -> EpisodeReport:
    obj = ctx.model("object")
    gripper = devices.pick_gripper()
    arm = ctx.model("arm")
    sensor = ctx.make_sensor(grasp_probe(obj, frame_period_s(ctx.sensor)))
    params = params_for(LiftEffortParams, ctx.controller)
    ctrl = MinimalLiftEffort(gripper, arm, sensor, ctx.clock, params)
    res = ctrl.run()
    still = ctx.settle_and_check_still([arm], [gripper])
    # the squeeze at effort 1: the sim gripper's stall force, or the MX-64's current limit × N/A
    stall = getattr(gripper, "stall_force_n", None) or gripper.current_limit_a * ctx.model("fingers").force_per_a_n
    e_hold = obj.min_squeeze_n(0.0) / stall
    e_lift = obj.min_squeeze_n(arm.accel_mmps2 / 1000.0) / stall
    effort = res.figures.get("effort", float("nan"))
    if hasattr(gripper, "current_limit_a") and effort == effort:
        # the MX-64 applies a whole number of 3.36 mA current units: judge the effort it applied

        unit = ct.P2_CURRENT_A_PER_UNIT
        effort = round(effort * gripper.current_limit_a / unit) * unit / gripper.current_limit_a
    ratio = effort / e_lift
    figures = {"effort": effort, "true_min_effort": e_lift, "hold_min_effort": e_hold,
               "effort_over_min": ratio, "lifts": res.figures.get("lifts", 0.0), "still_after": float(still)}
    ok = outcome_matches(res, ctx.controller) and still
    if ctx.controller.get("expect", "success") == "success":
        ok = ok and e_hold * (1 - 1e-9) <= effort <= 1.10 * e_lift
    return EpisodeReport("", 0, ctx.seed, ok, res.outcome.value, figures, res.message, res.fault_device,
                         result=res)


run_episode = with_devices(_run)
