"""Pure pieces of the controllers: eq. 3.3, the insertion transform chain and velocity law, the
following law's frame rotations, the perception-result adapter."""

from __future__ import annotations

import cmath
import math
from types import SimpleNamespace

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from tactile_rig.control.common import as_touch
from tactile_rig.control.following import Following, FollowingParams, rotate_xy
from tactile_rig.control.grasp import LeakyIntegrator
from tactile_rig.control.inhand import InHandRotation, InHandRotationParams
from tactile_rig.control.insertion import gripper_goal, velocity_command
from tactile_rig.core.geometry import invert_rigid as invert
from tactile_rig.core.geometry import matrix_from_pose as pose_to_matrix
from tactile_rig.core.geometry import pose_from_matrix as matrix_to_pose
from tactile_rig.core.geometry import rotation_2d
from tactile_rig.control.protocols import GripperOutcome, Pose, TouchReading

mm = st.floats(-500.0, 500.0)
deg = st.floats(-180.0, 180.0)
poses = st.builds(Pose, mm, mm, mm, deg)


@given(gain=st.floats(0.0, 1.0), leak=st.floats(0.0, 50.0), g_max=st.floats(0.0, 0.1),
       drives=st.lists(st.tuples(st.sampled_from([-1.0, 0.0, 1.0]), st.floats(0.0, 0.5)), max_size=60))
def test_the_leaky_integrator_stays_in_its_bounds_and_only_grows_when_driven(gain, leak, g_max, drives) -> None:
    li = LeakyIntegrator(gain, leak, g_max_m=g_max)
    for u, dt in drives:
        before = li.g_m
        g = li.step(u, dt)
        assert 0.0 <= g <= g_max and math.isfinite(g)
        if u <= 0:
            assert g <= before + 1e-15  # no drive: it can only hold or leak
        if u > 0 and leak == 0:
            assert g >= before


def test_the_leak_decays_the_integrator_geometrically_and_bad_steps_are_refused() -> None:
    li = LeakyIntegrator(1.0, leak_per_s=2.0)
    li.step(1.0, 0.01)
    g0 = li.g_m
    for _ in range(100):
        li.step(0.0, 0.01)
    assert li.g_m == pytest.approx(g0 * 0.98 ** 100)
    with pytest.raises(ValueError, match="dt_s"):
        li.step(1.0, math.nan)
    with pytest.raises(ValueError, match="gain_mps"):
        LeakyIntegrator(-1.0)


@given(goal=poses, m_T_o=poses, g_T_m=poses)
def test_the_transform_chain_puts_the_object_on_the_goal(goal, m_T_o, g_T_m) -> None:
    b_T_g = gripper_goal(goal, m_T_o, g_T_m)
    b_T_o = pose_to_matrix(b_T_g) @ pose_to_matrix(g_T_m) @ pose_to_matrix(m_T_o)
    np.testing.assert_allclose(b_T_o, pose_to_matrix(goal), atol=1e-6)
    np.testing.assert_allclose(invert(invert(pose_to_matrix(goal))), pose_to_matrix(goal), atol=1e-9)
    back = matrix_to_pose(pose_to_matrix(goal))
    assert math.cos(math.radians(back.theta_deg - goal.theta_deg)) == pytest.approx(1.0)


@given(q=poses, goal=poses, speed=st.floats(0.1, 500.0))
def test_the_velocity_law_has_the_commanded_speed_toward_the_goal(q, goal, speed) -> None:
    v = velocity_command(q, goal, speed)
    e = np.array([goal.x_mm - q.x_mm, goal.y_mm - q.y_mm, goal.z_mm - q.z_mm, goal.theta_deg - q.theta_deg])
    if np.linalg.norm(e) < 1e-9:
        assert v == (0.0, 0.0, 0.0, 0.0)
        return
    assert np.linalg.norm(v) == pytest.approx(speed)
    assert float(np.dot(v, e)) == pytest.approx(speed * np.linalg.norm(e))
    assert velocity_command(goal, goal, speed) == (0.0, 0.0, 0.0, 0.0)


xy = st.floats(-1e6, 1e6)
any_deg = st.one_of(deg, st.floats(-1e4, 1e4), st.sampled_from([-270.0, -180.0, -90.0, 0.0, 90.0, 180.0, 270.0, 360.0]))


def _close(a: tuple[float, float], b: tuple[float, float], scale: float) -> bool:
    return math.hypot(a[0] - b[0], a[1] - b[1]) <= 1e-9 * (1.0 + scale)


@given(x=xy, y=xy, angle=any_deg)
def test_rotate_xy_is_the_complex_product_the_polar_sum_and_the_geometry_rotation(x, y, angle) -> None:
    """Three other formulations of the same counter-clockwise rotation agree with it: multiplying by
    e^(i angle), adding the angle to the vector's polar angle, and ``core.geometry.rotation_2d``."""
    got = rotate_xy(x, y, angle)
    r = math.hypot(x, y)
    z = complex(x, y) * cmath.exp(1j * math.radians(angle))
    phi = math.atan2(y, x) + math.radians(angle)
    m = rotation_2d(angle) @ np.array([x, y])
    for other in ((z.real, z.imag), (r * math.cos(phi), r * math.sin(phi)), (float(m[0]), float(m[1]))):
        assert _close(got, other, r), (got, other)
    assert math.hypot(*got) == pytest.approx(r, rel=1e-12, abs=1e-300)


@given(x=xy, y=xy, a=any_deg, b=any_deg)
def test_rotate_xy_composes_inverts_and_repeats_every_turn(x, y, a, b) -> None:
    r = math.hypot(x, y)
    assert _close(rotate_xy(*rotate_xy(x, y, a), b), rotate_xy(x, y, a + b), r)
    assert _close(rotate_xy(*rotate_xy(x, y, a), -a), (x, y), r)
    assert _close(rotate_xy(x, y, a + 360.0), rotate_xy(x, y, a), r)


@given(x=xy, y=xy)
def test_rotate_xy_quarter_and_half_turns(x, y) -> None:
    """+90 deg takes +x to +y (counter-clockwise), -90 deg takes +x to -y, and +180 and -180 deg are the
    same half turn."""
    r = math.hypot(x, y)
    assert _close(rotate_xy(x, y, 90.0), (-y, x), r)
    assert _close(rotate_xy(x, y, -90.0), (y, -x), r)
    assert _close(rotate_xy(x, y, 180.0), (-x, -y), r)
    assert _close(rotate_xy(x, y, -180.0), (-x, -y), r)
    assert _close(rotate_xy(x, y, 270.0), rotate_xy(x, y, -90.0), r)
    assert rotate_xy(x, y, 0.0) == (x, y)


def test_rotate_xy_known_vectors_and_non_finite_angles() -> None:
    assert rotate_xy(1.0, 0.0, 90.0) == pytest.approx((0.0, 1.0), abs=1e-15)
    assert rotate_xy(0.0, 2.0, 90.0) == pytest.approx((-2.0, 0.0), abs=1e-15)
    assert rotate_xy(3.0, 4.0, -90.0) == pytest.approx((4.0, -3.0), abs=1e-15)
    assert rotate_xy(1.0, 1.0, 45.0) == pytest.approx((0.0, math.sqrt(2.0)), abs=1e-15)
    assert rotate_xy(2.0, 0.0, 30.0) == pytest.approx((math.sqrt(3.0), 1.0), abs=1e-15)
    for bad in (math.nan, math.inf, -math.inf):
        with pytest.raises(ValueError, match="angle_deg"):
            rotate_xy(1.0, 0.0, bad)


@given(fx=st.floats(-5, 5), fy=st.floats(-5, 5), mount=deg)
def test_force_following_undoes_the_sensor_rotation(fx, fy, mount) -> None:
    """A shear (fx, fy) in end-effector axes, seen by a sensor mounted at ``mount``, commands the
    same velocity as an unrotated sensor seeing (fx, fy)."""
    plain = Following(None, None, None, FollowingParams(mode="force", deadband_n=0.1))  # type: ignore[arg-type]
    rotated = Following(None, None, None, FollowingParams(mode="force", deadband_n=0.1,  # type: ignore[arg-type]
                                                          sensor_rotation_deg=mount))
    sx, sy = rotate_xy(fx, fy, -mount)
    v0 = plain.velocity_mmps(TouchReading(0.0, force_n=(fx, fy, 1.0)))
    v1 = rotated.velocity_mmps(TouchReading(0.0, force_n=(sx, sy, 1.0)))
    assert v1 == pytest.approx(v0, abs=1e-9)
    if math.hypot(fx, fy) <= 0.1:
        assert v0 == (0.0, 0.0)
    else:  # it moves along the force, never faster than the cap
        assert v0[0] * fx + v0[1] * fy > 0
        assert math.hypot(*v0) <= 50.0 + 1e-9


@given(cx=st.floats(0, 160), cy=st.floats(0, 120), rot=deg)
def test_proximity_following_moves_toward_the_object_seen_in_a_rotated_image(cx, cy, rot) -> None:
    f = Following(None, None, None, FollowingParams(mode="proximity", image_rotation_deg=rot))  # type: ignore[arg-type]
    vx, vy = f.velocity_mmps(TouchReading(0.0, object_centroid_px=(cx, cy)))
    dx, dy = cx - 80.0, cy - 60.0
    if math.hypot(dx, dy) <= 2.0:
        assert (vx, vy) == (0.0, 0.0)
    else:
        ex, ey = rotate_xy(dx, dy, rot)
        assert vx * ex + vy * ey > 0
    assert f.velocity_mmps(TouchReading(0.0)) == (0.0, 0.0)  # nothing in view: hold still


def test_a_fingervision_like_result_adapts_and_junk_is_a_type_error() -> None:
    fv = SimpleNamespace(t_s=1.5, force_px=np.array([0.1, -0.2, 0.3]), torque_px2=np.array([0, 0, 2.0]),
                         slip=True, slip_magnitude_px=1.25, object_area_px=100.0,
                         object_centroid_px=(3.0, 4.0), object_orientation_deg=12.0)
    r = as_touch(fv)
    assert r.force_n == pytest.approx((0.1, -0.2, 0.3)) and r.torque_nmm[2] == 2.0
    assert r.slip and r.slip_mm == 1.25 and r.contact and r.t_s == 1.5
    with pytest.raises(TypeError, match="TouchReading"):
        as_touch(object())


class _RecordingGripper:
    def __init__(self) -> None:
        self.calls: list[tuple[float, float]] = []

    def gripper_go(self, opening_m: float, effort_frac: float, **kw):
        self.calls.append((opening_m, effort_frac))
        return GripperOutcome.MOVING


@given(g=st.floats(-0.01, 0.01), effort=st.floats(0.0, 1.0), y=st.floats(0.0, 0.1))
def test_inhand_loosening_by_effort_scales_the_current_cap_and_keeps_the_fingers_pressed(g, effort, y) -> None:
    p = InHandRotationParams(squeeze_by="effort", effort=effort)
    grip = _RecordingGripper()
    ctrl = InHandRotation(grip, None, None, p)  # type: ignore[arg-type]
    ctrl._command(y, g)
    pos, eff = grip.calls[-1]
    assert pos == pytest.approx(max(0.0, y - p.regrip_m))  # the fingers stay pressed into the object
    assert 0.0 <= eff <= 1.0
    if g >= p.max_open_m:
        assert eff == 0.0
    elif 0.0 <= g:
        assert eff == pytest.approx(effort * (1.0 - g / p.max_open_m))  # loosening lowers the cap
    else:
        assert eff >= effort or eff == 1.0  # a re-grip squeezes harder
    ctrl.p.squeeze_by = "position"
    ctrl._command(y, g)
    assert grip.calls[-1] == (pytest.approx(max(0.0, y + g)), effort)


def test_inhand_refuses_an_unknown_way_to_loosen() -> None:
    with pytest.raises(ValueError, match="squeeze_by"):
        InHandRotation(_RecordingGripper(), None, None, InHandRotationParams(squeeze_by="pressure"))  # type: ignore[arg-type]
