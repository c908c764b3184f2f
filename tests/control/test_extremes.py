"""Controllers at the extremes: arbitrary poses and speeds, ±180° and beyond, zero and huge inputs,
NaN/inf readings. Properties: no NaN in a command, every command bounded by its cap, bad input a
typed error naming the argument, and closed loops that end (no hang) on a VirtualClock."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import assume, given
from hypothesis import strategies as st

from tactile_rig.control.collision_stop import CollisionStop, CollisionStopParams
from tactile_rig.control.common import Outcome
from tactile_rig.control.following import Following, FollowingParams, rotate_xy
from tactile_rig.control.grasp import LeakyIntegrator
from tactile_rig.control.inhand import InHandRotation, InHandRotationParams
from tactile_rig.control.insertion import gripper_goal, velocity_command
from tactile_rig.control.protocols import Pose, TouchReading
from tactile_rig.control.safety import check_speed, collision_speed_cap_mps, worst_case_overtravel_mm
from tactile_rig.core.clock import VirtualClock
from tactile_rig.core.errors import LimitError
from tactile_rig.sim.fakes.arm import SimArm
from tactile_rig.sim.fakes.sensors import ModelSensor
from tactile_rig.sim.world.table import Table

any_float = st.floats(allow_nan=True, allow_infinity=True)
finite = st.floats(allow_nan=False, allow_infinity=False)
wide_deg = st.one_of(st.floats(-180.0, 180.0), st.sampled_from([-180.0, 180.0, -179.999, 179.999, 0.0]),
                     st.floats(-1e6, 1e6))
gain = st.one_of(st.just(0.0), st.floats(1e-6, 1e6))
max_speed = st.floats(1e-4, 10.0)


def _norm(v) -> float:
    return math.hypot(*v)


# -- the following law ------------------------------------------------------------------------
@given(fx=any_float, fy=any_float, rot=wide_deg, k=gain, dead=st.floats(0.0, 1e3), vmax=max_speed)
def test_force_following_command_is_finite_and_capped_for_any_reading(fx, fy, rot, k, dead, vmax):
    f = Following(None, None, None, FollowingParams(mode="force", gain_mmps_per_n=k, deadband_n=dead,
                                                    sensor_rotation_deg=rot, max_speed_mps=vmax))
    vx, vy = f.velocity_mmps(TouchReading(0.0, force_n=(fx, fy, 1.0)))
    assert math.isfinite(vx) and math.isfinite(vy)
    assert _norm((vx, vy)) <= 1000.0 * vmax * (1 + 1e-9)
    if not (math.isfinite(fx) and math.isfinite(fy)):
        assert (vx, vy) == (0.0, 0.0)  # a glitch holds still
    elif k > 0 and _norm((vx, vy)) > 1e-9 and max(abs(fx), abs(fy)) < 1e150:
        # the command points along the force turned by the sensor mount, whatever its size
        ex, ey = rotate_xy(fx, fy, rot)
        cos = (vx * ex + vy * ey) / (_norm((vx, vy)) * _norm((ex, ey)))
        assert cos > 1 - 1e-6


@given(cx=any_float, cy=any_float, rot=wide_deg, k=gain, scale=st.floats(0.0, 1e3), vmax=max_speed)
def test_proximity_following_command_is_finite_and_capped_for_any_centroid(cx, cy, rot, k, scale, vmax):
    f = Following(None, None, None, FollowingParams(mode="proximity", gain_per_s=k, mm_per_px=scale,
                                                    image_rotation_deg=rot, max_speed_mps=vmax))
    vx, vy = f.velocity_mmps(TouchReading(0.0, object_centroid_px=(cx, cy)))
    assert math.isfinite(vx) and math.isfinite(vy)
    assert _norm((vx, vy)) <= 1000.0 * vmax * (1 + 1e-9)


def test_huge_readings_keep_their_direction_and_saturate_at_the_cap():
    f = Following(None, None, None, FollowingParams(mode="force", max_speed_mps=0.05))
    vx, vy = f.velocity_mmps(TouchReading(0.0, force_n=(1e308, 1e308, 0.0)))  # hypot overflows
    assert vx == pytest.approx(50.0 / math.sqrt(2)) and vy == pytest.approx(vx)
    p = Following(None, None, None, FollowingParams(mode="proximity", max_speed_mps=0.05, image_rotation_deg=180.0))
    vx, vy = p.velocity_mmps(TouchReading(0.0, object_centroid_px=(1e308, 60.0)))
    assert vx == pytest.approx(-50.0) and abs(vy) < 1e-9


@pytest.mark.parametrize("name, value", [("sensor_rotation_deg", math.inf), ("image_rotation_deg", math.nan),
                                          ("gain_per_s", -1.0), ("max_speed_mps", math.nan)])
def test_following_refuses_non_finite_or_negative_settings(name, value):
    with pytest.raises(ValueError, match=name):
        Following(None, None, None, FollowingParams(**{name: value}))
    with pytest.raises(ValueError, match="angle_deg"):
        rotate_xy(1.0, 0.0, math.inf)


# -- insertion: the velocity law and the transform chain --------------------------------------
poses_any = st.builds(Pose, finite, finite, finite, finite)


@given(q=poses_any, goal=poses_any, speed=st.floats(0.0, 1e6))
def test_insertion_velocity_has_exactly_the_commanded_speed_for_any_finite_poses(q, goal, speed):
    v = velocity_command(q, goal, speed)
    assert all(math.isfinite(x) for x in v)
    n = math.sqrt(sum(x * x for x in v))
    assert n == 0.0 or n == pytest.approx(speed, rel=1e-9)
    if n > 0 and speed > 0:  # it points at the goal
        a = np.array([q.x_mm, q.y_mm, q.z_mm, q.theta_deg]) / 1e300
        b = np.array([goal.x_mm, goal.y_mm, goal.z_mm, goal.theta_deg]) / 1e300
        d = b - a
        if np.linalg.norm(d) > 0:
            assert float(np.dot(d / np.linalg.norm(d), np.array(v) / n)) > 1 - 1e-6


@given(bad=st.sampled_from([math.nan, math.inf, -math.inf]), where=st.integers(0, 4))
def test_insertion_velocity_refuses_non_finite_input(bad, where):
    q, goal, speed = [0.0] * 4, [1.0, 2.0, 3.0, 4.0], 10.0
    if where < 4:
        q[where] = bad
    else:
        speed = bad
    with pytest.raises(ValueError, match="finite"):
        velocity_command(Pose(*q), Pose(*goal), speed)


mm_big = st.floats(-1e6, 1e6)
poses_deg = st.builds(Pose, mm_big, mm_big, mm_big, wide_deg)


@given(goal=poses_deg, m_T_o=poses_deg, g_T_m=poses_deg)
def test_gripper_goal_is_finite_with_an_angle_in_range_for_any_mount(goal, m_T_o, g_T_m):
    g = gripper_goal(goal, m_T_o, g_T_m)
    assert all(math.isfinite(v) for v in (g.x_mm, g.y_mm, g.z_mm, g.theta_deg))
    assert -180.0 - 1e-9 <= g.theta_deg <= 180.0 + 1e-9


# -- the grasp integrator (eq. 3.3) -------------------------------------------------------------
@given(k=st.floats(0.0, 1e6), leak=st.floats(0.0, 1e6), g_max=st.floats(0.0, 1.0),
       drives=st.lists(st.tuples(finite, st.floats(0.0, 1e6)), max_size=40))
def test_integrator_stays_bounded_under_any_finite_drive(k, leak, g_max, drives):
    li = LeakyIntegrator(k, leak, g_max_m=g_max)
    for u, dt in drives:
        g = li.step(u, dt)
        assert math.isfinite(g) and 0.0 <= g <= g_max


@pytest.mark.parametrize("u", [math.nan, math.inf, -math.inf])
def test_integrator_refuses_a_non_finite_drive_instead_of_resetting(u):
    li = LeakyIntegrator(1.0, g_max_m=0.01)
    li.step(1.0, 0.005)
    with pytest.raises(ValueError, match="finite drive"):
        li.step(u, 0.01)
    assert li.g_m == pytest.approx(0.005)  # untouched by the refused step


# -- the speed cap ----------------------------------------------------------------------------
@given(allowed=st.floats(0.0, 1e4), rate=st.floats(1e-3, 1e6), lat=st.floats(0.0, 60.0),
       stop=st.floats(0.0, 60.0), decel=st.one_of(st.just(math.inf), st.floats(1e-300, 1e300)),
       det=st.floats(0.0, 1e4))
def test_cap_is_finite_and_its_worst_case_stays_within_the_allowance(allowed, rate, lat, stop, decel, det):
    cap = collision_speed_cap_mps(allowed, rate, lat, stop_latency_s=stop, decel_mps2=decel,
                                  detection_travel_mm=det)
    assert math.isfinite(cap) and cap >= 0.0
    if cap > 0:
        worst = worst_case_overtravel_mm(cap, rate, lat, stop_latency_s=stop, decel_mps2=decel,
                                         detection_travel_mm=det)
        assert worst <= allowed * (1 + 1e-9) + 1e-12


@given(value=st.sampled_from([math.nan, math.inf, -1.0, 1e7]),
       which=st.sampled_from(["allowed", "rate", "latency"]))
def test_cap_refuses_out_of_range_input_by_name(value, which):
    kw = {"allowed": 1.0, "rate": 16.0, "latency": 0.0}
    kw[which] = value
    with pytest.raises(ValueError, match={"allowed": "allowed_overtravel_mm", "rate": "sensing_rate_hz",
                                          "latency": "latency_s"}[which]):
        collision_speed_cap_mps(kw["allowed"], kw["rate"], kw["latency"])


@given(speed=any_float, cap=st.floats(0.0, 10.0))
def test_check_speed_passes_only_positive_finite_speeds_up_to_the_cap(speed, cap):
    try:
        v = check_speed(speed, cap)
    except LimitError as exc:
        assert exc.device == "collision_stop"
        assert not (0 < speed <= cap * (1 + 1e-9))
    else:
        assert v == speed and 0 < v <= cap * (1 + 1e-9)


# -- in-hand rotation's angle estimate ----------------------------------------------------------
@given(tau0=st.one_of(finite, st.just(0.0)), tau=any_float, start=st.floats(-180.0, 180.0))
def test_torque_angle_is_bounded_or_nan_never_a_silent_zero(tau0, tau, start):
    rot = InHandRotation(None, None, None, InHandRotationParams(mode="torque", start_angle_deg=start))
    rot._tau0 = tau0
    ang = rot.angle_deg(TouchReading(0.0, torque_nmm=(0.0, 0.0, tau)))
    if math.isnan(ang):
        assert tau0 != 0.0 and not math.isfinite(tau / tau0)
    else:
        assert -start <= ang <= 180.0 - start


# -- closed loops end, at any start, target and speed ---------------------------------------------
@given(table_z=st.one_of(st.none(), st.floats(-15.0, 5.0)), stiff=st.floats(1.0, 1e4),
       target=st.builds(Pose, st.floats(-10.0, 10.0), st.floats(-10.0, 10.0), st.floats(-15.0, 5.0),
                        st.floats(-180.0, 180.0)),
       frac=st.floats(0.2, 1.0), rate=st.floats(4.0, 500.0))
def test_collision_stop_ends_within_its_budget_and_never_exceeds_the_cap(table_z, stiff, target, frac, rate):
    assume(math.hypot(target.x_mm, target.y_mm, target.z_mm - 10.0) > 1.0)
    clock = VirtualClock()
    arm = SimArm(clock, start=(0.0, 0.0, 10.0, 0.0), command_latency_s=0.0, tracking_tau_s=0.002, decel_mps2=5.0)
    table = None if table_z is None else Table(point_mm=[0.0, 0.0, table_z], normal=[0.0, 0.0, 1.0],
                                               stiffness_n_per_mm=stiff)

    def probe(t):
        p = arm.position_at(t)[:3]
        f = table.force_n(p) if table is not None else np.zeros(3)
        return TouchReading(t, force_n=tuple(float(v) for v in f), contact=bool(np.linalg.norm(f) > 0))

    sensor = ModelSensor(clock, probe, rate_hz=rate, force_noise_n=0.01, rng=np.random.default_rng(0))
    ctrl = CollisionStop(arm, sensor, clock, CollisionStopParams(force_eps_n=0.3, timeout_s=10.0,
                                                                 stop_latency_s=0.008, decel_mps2=5.0))
    ctrl.calibrate()
    cap = ctrl.cap_mps()
    res = ctrl.run(target, frac * cap)
    # a slow approach to a far (or much turned) target runs out of its budget: that is an end too
    assert res.outcome in (Outcome.SUCCESS, Outcome.NO_CONTACT, Outcome.TIMEOUT)
    assert clock.now_s() < 10.0 + 15.0  # ended inside its budget (plus calibration, settle and retreat)
    speeds = [math.hypot(*v[:3]) / 1000.0 for _t, (_p, v) in arm.history.between(-math.inf, math.inf)]
    assert max(speeds) <= cap * (1 + 1e-6) + 1e-12
    for name in ("x_mm", "y_mm", "z_mm", "theta_deg"):  # other channels are NaN where a row lacks them
        assert all(math.isfinite(v) for v in res.trace.channels[name]), name


@given(speed=st.sampled_from([math.nan, math.inf, 0.0, -0.01, 10.0]))
def test_collision_stop_refuses_bad_speeds_before_moving(speed):
    clock = VirtualClock()
    arm = SimArm(clock)
    sensor = ModelSensor(clock, lambda t: TouchReading(t), rate_hz=16.0)
    ctrl = CollisionStop(arm, sensor, clock)
    with pytest.raises(LimitError):
        ctrl.run(Pose(0.0, 0.0, -10.0, 0.0), speed)
    assert arm.commands == 0


@given(rot=wide_deg, hand=st.tuples(st.floats(-1e4, 1e4), st.floats(-1e4, 1e4)), vmax=st.floats(0.001, 0.2))
def test_following_ends_on_time_and_the_arm_never_exceeds_max_speed(rot, hand, vmax):
    clock = VirtualClock()
    arm = SimArm(clock, command_latency_s=0.0, tracking_tau_s=0.005, max_speed_mps=1.0)
    params = FollowingParams(mode="proximity", image_rotation_deg=rot, gain_per_s=9.0, mm_per_px=0.2,
                             max_speed_mps=vmax, duration_s=1.0)

    def probe(t):  # an object far away in the image, at an arbitrary bearing
        p = arm.position_at(t)
        ex, ey = rotate_xy(hand[0] - p[0], hand[1] - p[1], -rot)
        return TouchReading(t, object_area_px=800.0, object_centroid_px=(80.0 + ex / 0.2, 60.0 + ey / 0.2))

    f = Following(arm, ModelSensor(clock, probe, rate_hz=30.0), clock, params)
    res = f.run()
    assert res.outcome is not Outcome.FAULT, res.message
    assert clock.now_s() <= params.duration_s + 0.5
    speeds = [math.hypot(*v[:2]) / 1000.0 for _t, (_p, v) in arm.history.between(-math.inf, math.inf)]
    assert max(speeds) <= vmax * (1 + 1e-6) + 1e-9
