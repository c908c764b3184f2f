"""Episode: insert a grasped connector into a hole (Li 2014).

Property (truth from the part model): whenever one of the grasps the blind search visits is
localizable (its skin centre lies on the featured length), the insertion succeeds with the
connector within ±1 mm of the hole in x and y; otherwise the controller reports FAILED without
inserting.
"""

from __future__ import annotations

import math

import numpy as np

from tactile_rig.control.insertion import Insertion, InsertionParams
from tactile_rig.control.protocols import Localization, Pose
from tactile_rig.core.geometry import invert_rigid, matrix_from_pose, pose_from_matrix
from tactile_rig.rig.episodes import params_for
from tactile_rig.rig.scene_runner import EpisodeContext, EpisodeReport


def run_episode(ctx: EpisodeContext) -> EpisodeReport:
    part = ctx.model("part")
    arm = ctx.model("arm")
    gripper = ctx.model("gripper")
    c = ctx.controller
    mount = Pose(*c.get("sensor_mount", [0.0, 0.0, 0.0, 0.0]))
    m_T_g = invert_rigid(matrix_from_pose(mount))
    rng = np.random.default_rng([ctx.seed, 29])

    seen_featured = []

    def probe(t_s: float) -> Localization:
        m_T_o = m_T_g @ part.g_T_o_at(t_s)
        centre = part.skin_centre_in_part_mm()
        featured = part.attached and abs(centre) <= part.feature_half_length_mm
        seen_featured.append(featured)
        conf = float(rng.uniform(0.985, 1.0)) if featured else float(rng.uniform(0.3, 0.9))
        pose = pose_from_matrix(m_T_o)
        return Localization(t_s, pose.x_mm, pose.y_mm, pose.theta_deg, conf)

    sensor = ctx.make_sensor(probe, name="gelsight")
    hole = Pose(*c.get("hole_mm", [0.0, 0.0, 0.0, 0.0]))
    params = params_for(InsertionParams, {**c, "hole": hole, "sensor_mount": mount,
                                          "search_moves_mm": tuple(c.get("search_moves_mm", (7.5, -15.0)))})
    ctrl = Insertion(arm, gripper, sensor, ctx.clock, params)
    res = ctrl.run()
    # truth: did the search ever hold the part on its featured length (whatever the controller concluded)?
    localizable = any(seen_featured)
    still = ctx.settle_and_check_still([arm], [gripper])
    x, y, z, th = part.pose_mm_deg(ctx.clock.now_s())
    err_xy = math.hypot(x - hole.x_mm, y - hole.y_mm)
    figures = {"position_error_mm": err_xy, "height_error_mm": z - hole.z_mm,
               "angle_error_deg": th - hole.theta_deg, "regrasps": float(ctrl.regrasps),
               "localizable": float(localizable), "inserted": float(res.outcome.value == "success"),
               "still_after": float(still)}
    if c.get("expect") == "fault":
        ok = res.outcome.value == "fault" and still
    elif localizable:
        ok = res.outcome.value == "success" and abs(x - hole.x_mm) <= 1.0 and abs(y - hole.y_mm) <= 1.0 and still
    else:
        ok = res.outcome.value == "failed" and still
    return EpisodeReport("", 0, ctx.seed, ok, res.outcome.value, figures, res.message, res.fault_device,
                         result=res)
