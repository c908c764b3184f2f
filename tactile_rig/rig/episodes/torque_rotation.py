"""Episode: turn the held object until the skin torque says it met its stop.

Property: the turn past the stop never exceeds ``allowed_overturn_deg`` at any rate up to the
derived cap; a faster rate is refused.
"""

from __future__ import annotations

import math

from tactile_rig.control.protocols import TouchReading
from tactile_rig.control.rotation import TorqueRotation, TorqueRotationParams
from tactile_rig.rig.episodes import outcome_matches, params_for
from tactile_rig.rig.episodes._devices import Devices, with_devices
from tactile_rig.rig.scene_runner import EpisodeContext, EpisodeReport


def _run(ctx: EpisodeContext, devices: Devices) -> EpisodeReport:
    arm, position_at = devices.pick_motion()
    stop = ctx.model("stop")
    c = ctx.controller

    def probe(t_s: float) -> TouchReading:
        return TouchReading(t_s, torque_nmm=(0.0, 0.0, stop.torque_nmm(float(position_at(t_s)[3]))),
                            contact=True)

    sensor = ctx.make_sensor(probe)
    known = {"sensing_rate_hz": float(ctx.sensor.get("rate_hz", 30.0)),
             "latency_s": float(ctx.sensor.get("latency_s", 0.0)),
             "stop_latency_s": (arm.command_latency_s + 3 * arm.tracking_tau_s if hasattr(arm, "command_latency_s")
                                else float(c.get("jig_stop_latency_s", 0.02))),
             "torsion_stiffness_nmm_per_deg": stop.stiffness_nmm_per_deg}
    if c.get("motion") == "jig":  # θ rides on GRBL's Z channel: $122 is its acceleration (°/s²)
        known["decel_dps2"] = float(arm.read_settings().get(122, math.inf))
    ctrl = TorqueRotation(arm, sensor, ctx.clock, params_for(TorqueRotationParams, {**known, **c}))
    cap = ctrl.cap_dps()
    rate = 1000.0 * ctx.speed_mps if ctx.speed_mps is not None else cap * float(c.get("rate_frac_of_cap", 1.0))
    res = ctrl.run(float(c.get("target_deg", 180.0)), rate)
    still = ctx.settle_and_check_still([arm])
    over = max((stop.overturn_deg(float(position_at(t)[3])) for t in res.trace.t_s), default=0.0)
    over = max(over, stop.overturn_deg(float(position_at(ctx.clock.now_s())[3])))
    figures = {"rate_dps": rate, "cap_dps": cap, "overturn_deg": over,
               "allowed_overturn_deg": ctrl.p.allowed_overturn_deg, "still_after": float(still)}
    ok = outcome_matches(res, c) and still and over <= ctrl.p.allowed_overturn_deg + 1e-6
    return EpisodeReport("", 0, ctx.seed, ok, res.outcome.value, figures, res.message, res.fault_device,
                         result=res)


run_episode = with_devices(_run)
