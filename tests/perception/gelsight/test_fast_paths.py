"""The speed paths of GelSight registration and integration give the answers of the plain formulations."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tactile_rig.perception.gelsight import HeightMapper, TactileMap, extract_features, register, render_u8
from tactile_rig.perception.gelsight.dense_refinement import _sample
from tactile_rig.perception.gelsight.features import _dense_samples, _even_picks, _upper_quartile
from tactile_rig.perception.gelsight.registration import RegistrationParams, hamming_cross_matches, ransac_rigid
from tactile_rig.perception.gelsight.rigid_fit import _grad, _ransac_samples
from tactile_rig.perception.gelsight.synthetic import jig_move

MM = 0.1245


def _bf_pairs(q: np.ndarray, t: np.ndarray) -> tuple[list[int], list[int]]:
    ms = cv2.BFMatcher(cv2.NORM_HAMMING, crossCheck=True).match(q, t)
    return [m.queryIdx for m in ms], [m.trainIdx for m in ms]


@settings(deadline=None, max_examples=40)
@given(st.integers(1, 120), st.integers(1, 120), st.integers(0, 2 ** 31 - 1), st.booleans())
def test_hamming_matches_are_opencvs_cross_checked_matches(nq: int, nt: int, seed: int, ties: bool) -> None:
    rng = np.random.default_rng(seed)
    pool = rng.integers(0, 256, (max(nq, nt), 32), dtype=np.uint8)
    q = pool[:nq].copy()
    t = pool[rng.permutation(len(pool))[:nt]].copy()
    q ^= (rng.random(q.shape) < 0.05).astype(np.uint8) * rng.integers(0, 256, q.shape, dtype=np.uint8)
    if ties:  # equal distances must resolve to the lowest index, as OpenCV does
        t[: max(1, nt // 2)] = t[0]
        q[: max(1, nq // 3)] = q[0]
    qi, ti = hamming_cross_matches(q, t)
    assert (qi.tolist(), ti.tolist()) == _bf_pairs(q, t)


def test_hamming_matches_of_nothing_are_empty() -> None:
    d = np.zeros((5, 32), np.uint8)
    for q, t in ((d[:0], d), (d, d[:0])):
        qi, ti = hamming_cross_matches(q, t)
        assert len(qi) == 0 and len(ti) == 0


@settings(deadline=None, max_examples=30)
@given(st.integers(12, 150), st.floats(0.0, 0.7), st.floats(-np.pi, np.pi), st.integers(0, 2 ** 31 - 1))
def test_ransac_with_early_stop_finds_the_transform(n: int, outliers: float, theta: float, seed: int) -> None:
    rng = np.random.default_rng(seed)
    src = rng.uniform(0, 200, (n, 2))
    r = np.array([[np.cos(theta), -np.sin(theta)], [np.sin(theta), np.cos(theta)]])
    dst = src @ r.T + np.array([30.0, -12.0]) + rng.normal(0, 0.2, (n, 2))
    bad = rng.random(n) < outliers
    dst[bad] = rng.uniform(0, 200, (int(bad.sum()), 2))
    m, mask = ransac_rigid(src, dst, 256, 2.0, seed)
    if (~bad).sum() >= 6:
        assert m is not None
        np.testing.assert_allclose(m[:, :2], r, atol=0.01)
        assert mask[~bad].mean() > 0.9
    assert mask.shape == (n,)


def test_ransac_without_any_consensus_refuses_quietly() -> None:
    src = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])  # every pair shorter than 2 x inlier_px
    with np.errstate(all="raise"):
        m, mask = ransac_rigid(src, src + 5.0, 64, 2.0, 0)
    assert m is None and not mask.any()


def _render_reference(z: np.ndarray, band: tuple[float, float], valid: np.ndarray | None) -> np.ndarray:
    # The documented formula, written plainly.
    k = max(1, int(round(band[1] * 1.7)))
    k += 1 - k % 2
    blur = cv2.blur(cv2.blur(z, (k, k)), (k, k))
    fine = cv2.GaussianBlur(z, (0, 0), band[0]) if band[0] > 0 else z
    bp = fine - blur
    sel = (lambda x: x) if valid is None else (lambda x: x[valid])
    base = z - sel(z).mean()
    img = 0.8 * bp / (4 * sel(bp).std() + 1e-12) + 0.2 * base / (4 * sel(base).std() + 1e-12)
    if valid is not None:
        img[~valid] = 0.0
    return np.clip(128.0 + 100.0 * img, 0, 255).astype(np.uint8)


@pytest.mark.parametrize("band", [(0.0, 4.0), (1.0, 2.7)])
@pytest.mark.parametrize("masked", [False, True])
def test_rendering_follows_the_documented_formula(band, masked) -> None:
    rng = np.random.default_rng(3)
    z = cv2.GaussianBlur(rng.normal(0, 0.1, (60, 80)).astype(np.float32), (0, 0), 2.0)
    valid = None
    if masked:
        valid = np.zeros(z.shape, bool)
        valid[10:50, 15:70] = True
    got = render_u8(z, band, valid)
    ref = _render_reference(z, band, valid)
    assert got.dtype == np.uint8 and got.shape == z.shape
    assert np.abs(got.astype(int) - ref).max() <= 1 and (got != ref).mean() < 0.01
    if valid is not None:
        assert (got[~valid] == 128).all()


def test_flat_reference_has_no_dense_samples() -> None:
    xy, zs, slope = _dense_samples(np.zeros((40, 50), np.float32), 100)
    assert xy.shape == (0, 2) and zs.shape == (0,) and slope.shape == (0, 2)


def test_dense_samples_carry_the_central_difference_slopes_there() -> None:
    rng = np.random.default_rng(3)
    z = cv2.GaussianBlur(rng.normal(0, 1, (90, 130)).astype(np.float32), (0, 0), 2.0)
    xy, zs, slope = _dense_samples(z, 400)
    assert len(xy) == 400
    gx, gy = _grad(z)
    c, r = xy[:, 0].astype(int), xy[:, 1].astype(int)
    np.testing.assert_allclose(zs, z[r, c])
    np.testing.assert_allclose(slope[:, 0], gx[r, c], rtol=1e-6, atol=1e-7)
    np.testing.assert_allclose(slope[:, 1], gy[r, c], rtol=1e-6, atol=1e-7)


@settings(max_examples=200, deadline=None)
@given(n=st.integers(1, 10**7), count=st.integers(0, 5000))
def test_even_picks_are_linspaces_indices(n, count) -> None:
    # The dense samples are thinned on linspace's indices; _even_picks computes them without its
    # overhead and must give the very same ones.
    np.testing.assert_array_equal(_even_picks(n, count), np.linspace(0, n - 1, count).astype(np.int64))


def test_ransac_samples_are_seeded_shared_and_read_only() -> None:
    i, j = _ransac_samples(0, 57, 256)
    rng = np.random.default_rng(0)
    np.testing.assert_array_equal(i, rng.integers(0, 57, 256))
    np.testing.assert_array_equal(j, rng.integers(0, 57, 256))
    assert _ransac_samples(0, 57, 256)[0] is i
    with pytest.raises(ValueError):
        i[0] = 1


@settings(max_examples=40, deadline=None)
@given(n=st.sampled_from([0, 1, 9, 2000, 8192, 8193, 20000]), channels=st.sampled_from([1, 2, 3]),
       seed=st.integers(0, 2**16))
def test_the_row_laid_sampler_reads_what_a_column_map_reads(n, channels, seed) -> None:
    # _sample lays the points out as rows of the remap map (3.5x faster than a one-pixel column each):
    # the samples must be the very numbers, padding dropped, anywhere in or beyond the image.
    rng = np.random.default_rng(seed)
    shape = (int(rng.integers(16, 200)), int(rng.integers(16, 200)))
    img = rng.normal(size=shape + ((channels,) if channels > 1 else ())).astype(np.float32)
    x, y = rng.uniform(-4, shape[1] + 4, n), rng.uniform(-4, shape[0] + 4, n)
    got = _sample(img, x, y)
    assert got.shape == (n, channels) and got.dtype == np.float64
    for start in range(0, n, 10_000):  # a column map must stay under remap's 32767 rows
        uv = np.stack([x[start:start + 10_000], y[start:start + 10_000]], 1).astype(np.float32)[:, None, :]
        ref = cv2.remap(img, uv, None, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE).reshape(len(uv), -1)
        np.testing.assert_array_equal(got[start:start + 10_000], ref.astype(np.float64))


@pytest.fixture(scope="module")
def surface() -> np.ndarray:
    rng = np.random.default_rng(7)
    z = cv2.GaussianBlur(rng.normal(0, 1, (120, 160)).astype(np.float32), (0, 0), 3.0)
    return z * np.float32(0.5 / float(np.abs(z).max()))


def test_cached_reference_features_give_the_same_answer(surface) -> None:
    b, truth = jig_move(surface, 25.0, (1.0, -0.5), MM)
    fa = extract_features(surface)
    plain = register(surface, b, MM)
    cached = register(surface, b, MM, features_a=fa)
    assert plain.ok and cached.ok
    np.testing.assert_allclose(cached.matrix_mm, plain.matrix_mm, atol=1e-9)
    np.testing.assert_allclose(cached.matrix_mm, truth, atol=0.03)
    assert fa.train_bits  # the reference's descriptor terms are kept for the next touch
    # Features of one array used with another (equal, even) array: the other is checked as usual.
    dirty = surface.copy()
    dirty[0, 0] = np.nan
    other = register(dirty, b, MM, features_a=fa)
    assert other.ok and np.isfinite(other.matrix_mm).all()


def test_flat_map_with_cached_features_is_refused() -> None:
    flat = np.zeros((60, 80), np.float32)
    res = register(flat, flat.copy(), MM, features_a=extract_features(flat))
    assert not res.ok and res.reason == "no_contact"


def test_map_height_is_a_fresh_copy_and_follows_new_touches(surface) -> None:
    tmap = TactileMap(MM, params=RegistrationParams())
    tmap.add_touch(surface)
    h1 = tmap.height_mm
    h1[:] = 99.0  # the caller's copy: the map must not change
    assert float(tmap.height_mm.max()) < 1.0
    covered = int(tmap.coverage.sum())
    b, _ = jig_move(surface, 0.0, (2.0, 1.0), MM)
    rec = tmap.add_touch(b)
    assert rec.accepted
    assert int(tmap.coverage.sum()) > covered
    assert int(np.count_nonzero(tmap.height_mm)) > int(np.count_nonzero(h1 != 99.0))


@pytest.mark.parametrize("solver", ["dct", "dst", "fc"])
@pytest.mark.parametrize("downsample", [1, 2])
def test_integration_leaves_inputs_alone_and_masks_like_where(solver: str, downsample: int) -> None:
    rng = np.random.default_rng(5)
    gx = rng.normal(0, 0.3, (40, 56)).astype(np.float32)
    gy = rng.normal(0, 0.3, (40, 56)).astype(np.float32)
    gx[3, 4], gy[7, 9] = np.inf, np.nan
    mask = rng.random(gx.shape) > 0.4
    keep = gx.copy(), gy.copy()
    hm = HeightMapper(gx.shape, 0.06, 0.07, solver=solver, downsample=downsample, border_px=2)
    z = hm.height_mm(gx, gy, mask=mask)
    np.testing.assert_array_equal(gx, keep[0])
    np.testing.assert_array_equal(gy, keep[1])
    clean = lambda g: np.where(mask & np.isfinite(g), g, np.float32(0)).astype(np.float32)  # noqa: E731
    z_ref = hm.height_mm(clean(gx), clean(gy))
    assert np.isfinite(z).all()
    np.testing.assert_allclose(z, z_ref, atol=1e-6 * max(1.0, float(np.abs(z_ref).max())))


@settings(deadline=None, max_examples=40)
@given(st.lists(st.floats(0.0, 1e6, allow_nan=False, width=32), min_size=1, max_size=60))
def test_upper_quartile_is_numpys(values: list[float]) -> None:
    x = np.array(values, np.float32)
    assert _upper_quartile(x) == pytest.approx(float(np.quantile(x, 0.75)), rel=1e-6, abs=1e-30)


@pytest.mark.parametrize("bad", [{"orb_levels": 0}, {"orb_scale": 1.0}, {"orb_fast_threshold": -1}])
def test_bad_orb_knobs_are_refused_by_name(bad: dict) -> None:
    with pytest.raises(ValueError, match=next(iter(bad))):
        RegistrationParams(**bad)


def test_orb_knobs_reach_the_detector(surface) -> None:
    few = extract_features(surface, RegistrationParams(orb_levels=1, orb_fast_threshold=40), dense=False)
    many = extract_features(surface, RegistrationParams(), dense=False)
    assert len(few.points["orb"]) < len(many.points["orb"])
