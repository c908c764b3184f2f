"""FingerVision force and torque from marker displacements."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from tactile_rig.perception.fingervision import ForceParams, estimate_force_torque
from tests._fingervision_synth import lattice

WH = (320, 240)
CENTRE = np.array([(WH[0] - 1) / 2, (WH[1] - 1) / 2])


def _ft(rest, pos, sizes0=None, sizes=None, valid=None, **kw):
    n = len(rest)
    sizes0 = np.full(n, 8.0) if sizes0 is None else sizes0
    sizes = sizes0 if sizes is None else sizes
    valid = np.ones(n, bool) if valid is None else valid
    return estimate_force_torque(rest, sizes0, pos, sizes, valid, WH, ForceParams(**kw))


@pytest.mark.parametrize("angle_deg", [0.0, 37.0, 90.0, 181.0, -120.0])
def test_uniform_shear_gives_the_force_direction(angle_deg: float) -> None:
    rest = lattice()
    d = 1.7 * np.array([math.cos(math.radians(angle_deg)), math.sin(math.radians(angle_deg))])
    ft = _ft(rest, rest + d)
    got = math.degrees(math.atan2(ft.force_px[1], ft.force_px[0]))
    assert abs((got - angle_deg + 180) % 360 - 180) < 1e-6
    assert ft.force_px[2] == 0.0
    assert ft.n_used == len(rest)


def test_rotation_about_the_centre_gives_z_torque_only() -> None:
    rest = lattice(jitter_seed=None)
    rest = rest - rest.mean(axis=0) + CENTRE  # symmetric about the centre: no net shear from a rotation
    th = math.radians(2.0)  # positive: x towards y (clockwise on screen)
    R = np.array([[math.cos(th), -math.sin(th)], [math.sin(th), math.cos(th)]])
    pos = (rest - CENTRE) @ R.T + CENTRE
    ft = _ft(rest, pos)
    assert ft.torque_px2[2] > 0
    assert abs(ft.torque_px2[0]) < 1e-9 and abs(ft.torque_px2[1]) < 1e-9
    assert np.linalg.norm(ft.force_px[:2]) < 1e-9  # a pure rotation has no net shear
    ft2 = _ft(rest, (rest - CENTRE) @ R + CENTRE)
    assert ft2.torque_px2[2] == pytest.approx(-ft.torque_px2[2])


def test_normal_force_from_size_growth_and_from_norm() -> None:
    rest = lattice()
    sizes = np.full(len(rest), 8.0)
    grown = sizes + np.linspace(0.0, 2.0, len(rest))
    ft = _ft(rest, rest, sizes, grown)
    assert ft.force_px[2] == pytest.approx(1.0)
    shrunk = _ft(rest, rest, sizes, sizes - 1.0)
    assert shrunk.force_px[2] == 0.0  # a smaller marker is not a pull
    ft_n = _ft(rest, rest + [3.0, 4.0], normal="norm")
    assert ft_n.force_px[2] == pytest.approx(5.0)


def test_median_and_quantile_reductions_resist_outliers() -> None:
    rest = lattice()
    pos = rest + [1.0, 0.0]
    pos[0] += [100.0, 0.0]  # one marker mistracked
    sizes0 = np.full(len(rest), 8.0)
    sizes = sizes0 + np.linspace(0, 1, len(rest))
    assert _ft(rest, pos, sizes0, sizes).force_px[0] > 4.0
    assert _ft(rest, pos, sizes0, sizes, reduction="median").force_px[0] == pytest.approx(1.0)
    q = _ft(rest, pos, sizes0, sizes, reduction="quantile", quantile=0.75).force_px[2]
    assert q == pytest.approx(np.quantile(np.linspace(0, 1, len(rest)), 0.75))


def test_invalid_markers_are_ignored_and_none_valid_is_zero() -> None:
    rest = lattice()
    pos = rest + [1.0, 0.0]
    valid = np.ones(len(rest), bool)
    valid[:5] = False
    pos[:5] = np.nan
    ft = _ft(rest, pos, valid=valid)
    assert ft.force_px[0] == pytest.approx(1.0) and ft.n_used == len(rest) - 5
    none = _ft(rest, pos, valid=np.zeros(len(rest), bool))
    assert none.n_used == 0 and np.all(none.force_px == 0) and np.all(none.torque_px2 == 0)
    empty = _ft(np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0), np.zeros(0), np.zeros(0, bool))
    assert np.all(empty.force_px == 0)


def test_perception_has_no_newton_scale() -> None:
    """Force stays in px here; newtons come from a force map fitted on the rig."""
    with pytest.raises(TypeError):
        ForceParams(newton_per_px=0.05)  # type: ignore[call-arg]


def test_bad_parameters_are_named() -> None:
    with pytest.raises(ValueError, match="reduction"):
        ForceParams(reduction="mode")
    with pytest.raises(ValueError, match="normal"):
        ForceParams(normal="pressure")
    with pytest.raises(ValueError, match="quantile"):
        ForceParams(quantile=1.5)
    with pytest.raises(ValueError, match="rest positions"):
        estimate_force_torque(np.zeros((3, 2)), np.zeros(3), np.zeros((2, 2)), np.zeros(2), np.ones(2, bool), WH)


@settings(deadline=None, max_examples=40)
@given(
    disp=arrays(np.float64, (12, 2), elements=st.floats(-1e6, 1e6)),
    ds=arrays(np.float64, 12, elements=st.floats(-1e3, 1e3)),
    valid=arrays(np.bool_, 12),
    reduction=st.sampled_from(["mean", "median", "quantile"]),
)
def test_force_is_always_finite(disp, ds, valid, reduction) -> None:
    rest = lattice()[:12]
    ft = _ft(rest, rest + disp, np.full(12, 8.0), 8.0 + ds, valid, reduction=reduction)
    assert np.all(np.isfinite(ft.force_px)) and np.all(np.isfinite(ft.torque_px2))
    if not valid.any():
        assert np.all(ft.force_px == 0)
