"""The one pose type and transform algebra of tactile_rig.core.geometry, at the extremes too."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from tactile_rig.core.geometry import (
    Pose,
    compose,
    invert_rigid,
    matrix_from_pose,
    pose_from_matrix,
    rotation_2d,
    wrap_deg,
)

mm = st.floats(-1e4, 1e4, allow_nan=False)
deg = st.floats(-1e4, 1e4, allow_nan=False)
poses = st.builds(Pose, mm, mm, mm, deg)
shapes = st.sampled_from([(4, 4), (3, 3), (2, 3)])


@given(pose=poses, shape=shapes)
def test_pose_round_trips_through_every_matrix_shape(pose, shape) -> None:
    back = pose_from_matrix(matrix_from_pose(pose, shape))
    assert back.x_mm == pytest.approx(pose.x_mm, abs=1e-6)
    assert back.y_mm == pytest.approx(pose.y_mm, abs=1e-6)
    assert back.z_mm == pytest.approx(pose.z_mm if shape == (4, 4) else 0.0, abs=1e-6)
    assert -180.0 < back.theta_deg <= 180.0
    assert math.cos(math.radians(back.theta_deg - pose.theta_deg)) == pytest.approx(1.0, abs=1e-9)


@given(a=poses, b=poses, shape=st.sampled_from([(4, 4), (3, 3)]))
def test_inverse_and_composition_are_consistent(a, b, shape) -> None:
    ma, mb = matrix_from_pose(a, shape), matrix_from_pose(b, shape)
    np.testing.assert_allclose(compose(ma, invert_rigid(ma)), np.eye(shape[0]), atol=1e-9)
    np.testing.assert_allclose(invert_rigid(compose(ma, mb)), compose(invert_rigid(mb), invert_rigid(ma)),
                               atol=1e-6 * (1 + np.abs(ma).max() + np.abs(mb).max()))


@given(pose=poses)
def test_planar_shapes_agree_with_the_spatial_one(pose) -> None:
    m4, m3, m23 = (matrix_from_pose(pose, s) for s in ((4, 4), (3, 3), (2, 3)))
    np.testing.assert_allclose(m3[:2, :2], m4[:2, :2])
    np.testing.assert_allclose(m3[:2], m23)
    np.testing.assert_allclose(invert_rigid(m23), invert_rigid(m3)[:2])


@given(st.floats(-1e9, 1e9, allow_nan=False))
def test_wrap_deg_lands_in_the_half_open_interval(a) -> None:
    w = wrap_deg(a)
    assert -180.0 < w <= 180.0
    assert math.cos(math.radians(w - a)) == pytest.approx(1.0, abs=1e-6)


def test_wrap_deg_at_the_seam_and_on_arrays() -> None:
    assert wrap_deg(180.0) == 180.0 and wrap_deg(-180.0) == 180.0 and wrap_deg(540.0) == 180.0
    np.testing.assert_allclose(wrap_deg(np.array([0.0, 190.0, -190.0])), [0.0, -170.0, 170.0])
    np.testing.assert_allclose(rotation_2d(90.0) @ [1.0, 0.0], [0.0, 1.0], atol=1e-12)


def test_bad_matrices_are_refused_with_their_shape() -> None:
    with pytest.raises(ValueError, match=r"\(2, 2\)"):
        pose_from_matrix(np.eye(2))
    with pytest.raises(ValueError, match="finite"):
        pose_from_matrix(np.full((3, 3), np.nan))
    with pytest.raises(ValueError, match="shape"):
        matrix_from_pose(Pose(), (5, 5))
    with pytest.raises(ValueError, match="at least one"):
        compose()


def test_pose_dict_round_trip_accepts_planar_records() -> None:
    p = Pose(1.0, -2.0, 0.5, 30.0)
    assert Pose.from_dict(p.as_dict()) == p
    assert Pose.from_dict({"x_mm": 1, "y_mm": 2, "theta_deg": 3}) == Pose(1.0, 2.0, 0.0, 3.0)
    assert Pose.from_dict(None) is None
