"""The bench path: the controllers on the real drivers over the device mocks served on ptys, with a
RealClock (as on the bench), and the same drivers in process on a VirtualClock."""

from __future__ import annotations

import pytest

from tactile_rig.core.clock import RealClock
from tactile_rig.rig.scene_runner import run_episode

pytestmark = pytest.mark.pty


def test_collision_stop_on_the_jig_driver_over_a_pty_in_real_time() -> None:
    r = run_episode("collision_stop_jig", 3, clock=RealClock(),
                    overrides={"controller": {"transport": "pty"}, "wall": {"point_mm": [3.0, 0.0, 0.0]}})
    assert r.outcome == "success", r.message
    assert r.figures["overtravel_mm"] <= r.figures["allowed_overtravel_mm"]
    assert r.figures["latency_s"] > 0  # measured on the wall clock, not assumed
    assert r.ok


def test_handover_on_the_dynamixel_driver_over_a_pty_in_real_time() -> None:
    r = run_episode("handover_dynamixel", 1, clock=RealClock(),
                    overrides={"controller": {"transport": "pty", "duration_s": 1.5},
                               "hand": {"arrive_s": 0.1, "release_s": 0.4, "release_duration_s": 0.3}})
    assert r.outcome == "success", r.message
    assert r.figures["dropped"] == 0 and r.figures["bad_closings"] == 0 and r.ok


@pytest.mark.parametrize("scene", ["collision_stop_jig", "handover_dynamixel"])
def test_the_same_drivers_in_process_in_virtual_time(scene) -> None:
    r = run_episode(scene, 5)
    assert r.ok, r.message


SHORT = {
    "following_jig": {"controller": {"transport": "pty", "duration_s": 2.0},
                      "hand": {"path_mm": [[0.0, 0.0, 0.0, 0.0], [0.2, 0.0, 0.0, 0.0], [1.2, 4.0, 3.0, 0.0]]}},
    "torque_rotation_jig": {"controller": {"transport": "pty", "rate_frac_of_cap": 0.8},
                            "stop": {"free_play_deg": 4.0, "stiffness_nmm_per_deg": 50.0}},
    "inhand_rotation_dynamixel": {"controller": {"transport": "pty", "target_deg": 20.0, "open_rate_mps": 0.002},
                                  "object": {"mass_kg": 0.1, "com_offset_mm": 60.0}},
    "lift_effort_dynamixel": {"controller": {"transport": "pty", "lift_mm": 1.0, "lift_speed_mps": 0.01,
                                             "ratio_tol": 1.05, "effort_start": 0.02},
                              "object": {"mass_kg": 0.5, "mu_static": 0.6}},
    "stick_assembly_hx711": {"controller": {"transport": "pty", "scan_range_mm": 4.0, "scan_step_mm": 4.0,
                                            "target_load_n": 1.0, "load_tol_n": 0.7, "press_speed_mps": 0.0002},
                             "stick": {"lateral_offset_mm": 1.0, "best_grasp_mm": 0.0, "table_z_mm": -61.0,
                                       "stiffness_n_per_mm": 10.0}},
}


@pytest.mark.slow
@pytest.mark.parametrize("scene", sorted(SHORT))
def test_every_controller_on_real_drivers_over_ptys_in_real_time(scene) -> None:
    r = run_episode(scene, 2, clock=RealClock(), overrides=SHORT[scene])
    assert r.ok, (r.outcome, r.message, r.figures)


def test_insertion_runs_on_a_real_clock_with_its_simulated_arm() -> None:
    r = run_episode("insertion", 4, clock=RealClock(),
                    overrides={"controller": {"speed_mps": 0.1, "insert_speed_mps": 0.05, "approach_height_mm": 2.0},
                               "arm": {"start_mm": [95.0, 40.0, 8.0, 30.0], "accel_mps2": 5.0, "decel_mps2": 5.0},
                               "part": {"grasp_offset_mm": 0.0, "grasp_theta_deg": 0.0, "grasp_y_mm": 0.0}})
    assert r.outcome == "success" and r.ok, r.message


def test_proximity_following_closes_the_loop_through_the_renderer_and_the_real_processor() -> None:
    r = run_episode("following_proximity_rendered", 1, overrides={"controller": {"duration_s": 4.0},
                    "hand": {"path_mm": [[0.0, 0.0, 0.0, 0.0], [0.3, 0.0, 0.0, 0.0], [2.0, 8.0, -6.0, 0.0]]}})
    assert r.figures["final_error_mm"] <= 1.0 and r.figures["max_lag_mm"] <= 5.0
    assert r.ok, r.message
