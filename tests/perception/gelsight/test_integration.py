"""Gradients -> height: solvers against an analytic sphere cap, knobs, and extreme inputs."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from tactile_rig.core.errors import GradientOutOfRange
from tactile_rig.perception.gelsight import HeightMapper, IntegrationParams, height_map_mm, sphere_cap
from tactile_rig.perception.gelsight.integration import auto_downsample

MM_PER_PX = 0.1245


def _cap(shape=(120, 160), center=(80.0, 60.0), radius_px=14.0):
    z, gx, gy, inside = sphere_cap(shape, center, radius_px, 2.0, MM_PER_PX)
    return z, gx, gy, inside


@pytest.mark.parametrize("solver", ["dst", "dct", "fc"])
@pytest.mark.parametrize("downsample,rms_mm", [(1, 0.02), (2, 0.03)])
def test_solvers_recover_a_sphere_cap(solver: str, downsample: int, rms_mm: float) -> None:
    # Full resolution within 0.02 mm RMS; the default (slopes halved before the solve: 0.6 of the
    # time, and on real presses more accurate) rounds the cap's rim a little more.
    z, gx, gy, inside = _cap()
    est = height_map_mm(gx, gy, MM_PER_PX, method=solver, downsample=downsample)
    assert est.dtype == np.float32 and est.shape == z.shape
    d = est[inside] - z[inside]
    assert np.sqrt(np.mean((d - d.mean()) ** 2)) < rms_mm
    assert abs(float(est.max() - est[5, 5]) - float(z.max())) < 0.05


def test_anisotropic_pitch_scales_each_axis() -> None:
    gx = np.full((40, 50), 0.1)
    gy = np.zeros((40, 50))
    # A slope of 0.1 over 10 px at 0.2 mm/px rises 0.2 mm: twice what 0.1 mm/px gives.
    m1 = HeightMapper(gx.shape, 0.1, 0.3, solver="dct").height_mm(gx, gy)
    m2 = HeightMapper(gx.shape, 0.2, 0.3, solver="dct").height_mm(gx, gy)
    r1 = m1[20, 30] - m1[20, 20]
    r2 = m2[20, 30] - m2[20, 20]
    assert r1 == pytest.approx(0.1, rel=0.05)
    assert r2 == pytest.approx(2 * r1, rel=1e-3)


@pytest.mark.parametrize("downsample", [2, 3])
def test_downsampling_keeps_the_shape_and_roughly_the_height(downsample: int) -> None:
    z, gx, gy, inside = _cap()
    est = HeightMapper(z.shape, MM_PER_PX, solver="dst", downsample=downsample).height_mm(gx, gy)
    assert est.shape == z.shape
    d = est[inside] - z[inside]
    assert np.sqrt(np.mean((d - d.mean()) ** 2)) < 0.1


def test_mask_and_border_remove_slopes_outside() -> None:
    gx = np.zeros((60, 80))
    gy = np.zeros((60, 80))
    gx[:, :5] = 5.0  # a bogus slope stripe at the border
    plain = HeightMapper(gx.shape, MM_PER_PX, solver="dst").height_mm(gx, gy)
    cropped = HeightMapper(gx.shape, MM_PER_PX, solver="dst", border_px=6).height_mm(gx, gy)
    mask = np.ones(gx.shape, bool)
    mask[:, :5] = False
    masked = HeightMapper(gx.shape, MM_PER_PX, solver="dst").height_mm(gx, gy, mask=mask)
    assert np.abs(plain).max() > 0.1
    assert np.abs(cropped).max() < 1e-6
    assert np.abs(masked).max() < 1e-6


def test_flat_gradients_give_a_flat_map() -> None:
    for solver in ("dst", "dct", "fc"):
        z = height_map_mm(np.zeros((30, 40)), np.zeros((30, 40)), (0.1, 0.1), method=solver)
        assert np.all(np.isfinite(z)) and np.abs(z).max() < 1e-9


@settings(deadline=None, max_examples=20)
@given(
    arrays(np.float64, (12, 17), elements=st.floats(allow_nan=True, allow_infinity=True, width=64)),
    st.sampled_from(["dst", "dct", "fc"]),
)
def test_any_gradients_give_a_finite_bounded_map_or_gradient_out_of_range(g: np.ndarray, solver: str) -> None:
    finite = g[np.isfinite(g)]
    if finite.size and np.abs(finite).max() > 20.0:
        with pytest.raises(GradientOutOfRange) as err:
            height_map_mm(g, g.T.copy().T[::-1], MM_PER_PX, method=solver)
        assert err.value.limit == 20.0 and err.value.value > 20.0
        return
    z = height_map_mm(g, g.T.copy().T[::-1], MM_PER_PX, method=solver)
    assert np.all(np.isfinite(z))
    # Slopes are at most max_slope, so the height cannot exceed what that slope spans.
    assert np.abs(z).max() <= 20.0 * MM_PER_PX * (12 + 17) * 2


@pytest.mark.parametrize(
    "gx, gy, msg",
    [
        (np.zeros((10, 10)), np.zeros((10, 11)), "same shape"),
        (np.zeros(10), np.zeros(10), "2-D"),
        (np.zeros((2, 10)), np.zeros((2, 10)), "at least 3x3"),
        (np.zeros((5, 5), dtype=complex), np.zeros((5, 5), dtype=complex), "dtype"),
    ],
)
def test_bad_gradients_raise_value_error(gx, gy, msg) -> None:
    with pytest.raises(ValueError, match=msg):
        height_map_mm(gx, gy, MM_PER_PX)


def test_bad_knobs_raise_value_error() -> None:
    with pytest.raises(ValueError, match="solver"):
        IntegrationParams(solver="multigrid")
    with pytest.raises(ValueError, match="downsample"):
        IntegrationParams(downsample=0)
    with pytest.raises(ValueError, match="mm_per_px_x"):
        HeightMapper((10, 10), -1.0)
    with pytest.raises(ValueError, match="does not match"):
        HeightMapper((10, 10), 0.1).height_mm(np.zeros((11, 10)), np.zeros((11, 10)))


@pytest.mark.parametrize("pitch_mm,factor", [(0.0634, 2), (0.1245, 1), (0.04, 3), (0.0325, 4), (0.13, 1), (0.5, 1)])
def test_automatic_downsample_keeps_the_reduced_pixel_within_0_13_mm(pitch_mm: float, factor: int) -> None:
    assert auto_downsample(pitch_mm) == factor
    assert HeightMapper((60, 80), pitch_mm)._k == factor
    assert HeightMapper((60, 80), pitch_mm, downsample=1)._k == 1
