"""Episode: a person hands an object over (Alg. 3).

Properties, from the world's truth: the gripper closes only at frames where the object was
slipping while touching the skin; the object is never dropped; a person who keeps holding (or an
object passing by without touching) never makes the gripper close.
"""

from __future__ import annotations

import math

from tactile_rig.control.grasp import Handover, HandoverParams
from tactile_rig.rig.episodes import outcome_matches, params_for
from tactile_rig.rig.episodes._devices import Devices, with_devices
from tactile_rig.rig.episodes._grasp_probe import frame_period_s, grasp_probe
from tactile_rig.rig.scene_runner import EpisodeContext, EpisodeReport


def _run(ctx: EpisodeContext, devices: Devices) -> EpisodeReport:
    obj = ctx.model("object")
    if ctx.controller.get("gripper") == "dynamixel":
        gripper = devices.gripper(effort=float(ctx.controller.get("effort", 0.5)))
    else:
        gripper = ctx.model("gripper")
    period = frame_period_s(ctx.sensor)
    probe = grasp_probe(obj, period, slip_threshold_mm=float(ctx.controller.get("slip_threshold_mm", 0.05)))
    sensor = ctx.make_sensor(probe)
    params = params_for(HandoverParams, {"open_m": gripper.state().opening_m, **ctx.controller})
    ctrl = Handover(gripper, sensor, ctx.clock, params)
    res = ctrl.run()
    still = ctx.settle_and_check_still(grippers=[gripper])
    # every closing command must follow a frame whose truth was slip ∧ touch
    bad_closes = 0
    tr = res.trace
    cmds = tr.channels.get("command_m", [])
    frames = tr.channels.get("frame_t_s", [])
    for i in range(1, len(cmds)):
        if cmds[i] < cmds[i - 1] - 1e-9:
            truth = probe(frames[i])
            if not (truth.slip and truth.contact):
                bad_closes += 1
    max_slip = max((obj.history.at(t).slip_mm for t in tr.t_s), default=0.0)
    figures = {"dropped": float(obj.dropped), "closings": float(ctrl.closings), "bad_closings": float(bad_closes),
               "max_slip_mm": max_slip, "peak_force_n": max((s for s in tr.channels.get("fz_n", [0.0])
                                                             if math.isfinite(s)), default=0.0),
               "still_after": float(still)}
    ok = outcome_matches(res, ctx.controller) and not obj.dropped and bad_closes == 0 and still
    if ctx.controller.get("expect_no_close") and ctrl.closings:
        ok = False
    return EpisodeReport("", 0, ctx.seed, ok, res.outcome.value, figures, res.message, res.fault_device,
                         result=res)


run_episode = with_devices(_run)
