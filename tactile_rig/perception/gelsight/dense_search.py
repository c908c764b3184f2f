"""Global dense search for a rigid move between two height maps, for when keypoints fail.

Independent re-touches of a part with sparse relief (raised dots and bars on a smooth plate) share
too few keypoints with the map touch, and a Fourier–Mellin estimate on raw heights follows the press
bowl, not the relief. This search works on what the touches do share:

1. each map is high-passed (its low-pass of ``highpass_px`` over known pixels subtracted: the bowl of
   the press and the integrator's offsets go), normalised to unit standard deviation (press depth
   changes the relief's height) and reduced by an integer factor (``coarse_px`` full pixels per
   coarse pixel, area averaging);
2. B is rotated at every ``step_deg`` over the full circle and, per angle, the masked normalised
   cross-correlation (Padfield 2012: NCC over the overlap only, for every shift at once by FFT)
   against A is computed; shifts whose overlap is below ``min_overlap`` of the smaller map are left
   out, since a few pixels correlate by chance;
3. the angles whose best score is a local maximum over the circle become candidates, best first,
   each with a sub-pixel shift and a sub-step angle from parabolas through the neighbouring scores.

The candidates are estimates to be polished and checked by the caller
(:func:`~tactile_rig.perception.gelsight.registration.register` runs its Gauss–Newton polish and its
acceptance bars on each, and refuses when two distinct candidates fit about as well).

Frames as in :mod:`~tactile_rig.perception.gelsight.registration`: ``matrix_px`` maps B's pixel
(column, row) into A's.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
import scipy.fft as sfft


@dataclass(frozen=True)
class SearchCandidate:
    """One pose of the search: B->A ``matrix_px`` (2x3, full-resolution px), its coarse masked NCC
    ``score`` and ``overlap`` (fraction of the smaller map's coarse pixels)."""

    matrix_px: np.ndarray
    score: float
    overlap: float
    rotation_deg: float


@dataclass(frozen=True)
class SearchResult:
    """Candidates best first (possibly none) and the full pixels per coarse pixel used."""

    candidates: tuple[SearchCandidate, ...]
    coarse_px: int = 0


# Heights beyond this (mm) are not a gel surface: treated as unknown.
MAX_ABS_HEIGHT_MM = 1e3
# Longest side of a map in coarse pixels; beyond it the reduction factor grows.
MAX_COARSE_SIDE = 160
# Rotations correlated per batch of FFTs (bounds the working memory).
ANGLE_BATCH = 16


@dataclass
class _Coarse:
    z: np.ndarray  # high-passed, unit-std, masked (0 outside), float32
    m: np.ndarray  # known pixels, float32 0/1
    f: int  # full pixels per coarse pixel


def _lowpass(z: np.ndarray, w: np.ndarray, sigma_px: float) -> np.ndarray:
    """Gaussian low-pass over the known pixels only (normalised convolution)."""
    num = cv2.GaussianBlur(z * w, (0, 0), sigma_px, borderType=cv2.BORDER_REPLICATE)
    den = cv2.GaussianBlur(w, (0, 0), sigma_px, borderType=cv2.BORDER_REPLICATE)
    return num / np.maximum(den, 1e-3)


def prepare(height_mm: np.ndarray, highpass_px: float, coarse_px: int,
            valid: np.ndarray | None = None) -> _Coarse | None:
    """High-passed, normalised, reduced map (None when it has no relief, under 8x8 coarse pixels or
    under 64 known pixels)."""
    z = np.asarray(height_mm, np.float64)
    # Non-finite and absurd heights (beyond MAX_ABS_HEIGHT_MM: no gel shows them) count as unknown.
    known = np.abs(np.nan_to_num(z, nan=np.inf)) <= MAX_ABS_HEIGHT_MM
    if valid is not None:
        known &= np.asarray(valid, bool)
    z = np.where(known, z, 0.0).astype(np.float32)
    f = int(coarse_px)
    hc, wc = z.shape[0] // f, z.shape[1] // f
    if hc < 8 or wc < 8 or known.sum() < 64:
        return None
    w = known.astype(np.float32)
    # Area reduction first (heights and mask), then the high-pass at coarse resolution: the same
    # band at a fraction of the cost. A coarse pixel counts as known when all of it is.
    zs = cv2.resize((z * w)[:hc * f, :wc * f], (wc, hc), interpolation=cv2.INTER_AREA)
    wm = cv2.resize(w[:hc * f, :wc * f], (wc, hc), interpolation=cv2.INTER_AREA)
    m = (wm > 0.999).astype(np.float32)
    if m.sum() < 16:
        return None
    zc = np.where(m > 0, zs / np.maximum(wm, 1e-3), 0.0).astype(np.float32)
    zc = (zc - _lowpass(zc, m, max(highpass_px / f, 0.5))) * m
    sel = m > 0
    vals = zc[sel].astype(np.float64)
    mu = float(vals.mean())
    sd = float(vals.std())
    if not np.isfinite(sd) or sd < 1e-9:
        return None
    zc = np.where(sel, (zc - mu) / sd, 0.0).astype(np.float32)
    return _Coarse(zc, m, f)


def _to_full(m_c: np.ndarray, f: int) -> np.ndarray:
    """A coarse-pixel affine (2x3) as full-resolution pixels: p_c = (p + 0.5) / f - 0.5."""
    s = np.array([[1.0 / f, 0, 0.5 / f - 0.5], [0, 1.0 / f, 0.5 / f - 0.5], [0, 0, 1]])
    s_inv = np.linalg.inv(s)
    m3 = np.vstack([m_c, [0, 0, 1]])
    return (s_inv @ m3 @ s)[:2]


def _parabola(ym: float, y0: float, yp: float) -> float:
    """Offset in (-0.5, 0.5) of a parabola's vertex through three equally spaced samples."""
    den = ym - 2.0 * y0 + yp
    if not np.isfinite(den) or den >= 0:
        return 0.0
    return float(np.clip(0.5 * (ym - yp) / den, -0.5, 0.5))


def rotation_search(height_a_mm: np.ndarray, height_b_mm: np.ndarray, *, highpass_px: float = 16.0,
                    coarse_px: int = 8, step_deg: float = 6.0, min_overlap: float = 0.3,
                    max_candidates: int = 3, valid_a: np.ndarray | None = None,
                    valid_b: np.ndarray | None = None) -> SearchResult:
    """Masked-NCC search of B's rotation (full circle) and shift onto A; see the module docstring.

    highpass_px: sigma (full px) of the low-pass removed; coarse_px: full pixels per coarse pixel;
    step_deg: rotation step; min_overlap: smallest overlap scored (fraction of the smaller map's
    known coarse pixels); max_candidates: how many local maxima over angle are returned. A map
    larger than ``MAX_COARSE_SIDE`` coarse pixels is reduced further (bounded memory and time).
    Non-finite heights and heights beyond +-``MAX_ABS_HEIGHT_MM`` count as unknown. Maps without
    relief or under 8x8 coarse pixels give no candidates. Raises ``ValueError`` for non-2-D maps or
    parameters out of range.
    """
    for name, h in (("height_a_mm", height_a_mm), ("height_b_mm", height_b_mm)):
        if not isinstance(h, np.ndarray) or h.ndim != 2:
            raise ValueError(f"{name}: expected a 2-D numpy array, got {getattr(h, 'shape', type(h).__name__)}")
        if not (np.issubdtype(h.dtype, np.floating) or np.issubdtype(h.dtype, np.integer)):
            raise ValueError(f"{name}: expected real heights (float or integer), got dtype {h.dtype}")
    if not (highpass_px > 0 and np.isfinite(highpass_px)):
        raise ValueError(f"highpass_px must be a positive number of pixels, got {highpass_px!r}")
    if not 1 <= int(coarse_px) <= 64:
        raise ValueError(f"coarse_px must be in [1, 64], got {coarse_px!r}")
    if not 0.1 <= step_deg <= 45.0:
        raise ValueError(f"step_deg must be in [0.1, 45] deg, got {step_deg!r}")
    if not 0.0 < min_overlap <= 1.0:
        raise ValueError(f"min_overlap must be in (0, 1], got {min_overlap!r}")
    if max_candidates < 1:
        raise ValueError(f"max_candidates must be >= 1, got {max_candidates!r}")
    # A large map (a tactile map's canvas) is searched coarser: the FFTs' size stays bounded.
    longest = max(*height_a_mm.shape, *height_b_mm.shape)
    f = max(int(coarse_px), int(np.ceil(longest / MAX_COARSE_SIDE)))
    ca = prepare(height_a_mm, highpass_px, f, valid_a)
    cb = prepare(height_b_mm, highpass_px, f, valid_b)
    if ca is None or cb is None:
        return SearchResult((), f)
    ha, wa = ca.z.shape
    hb, wb = cb.z.shape
    # B rotated into a square canvas that holds it at any angle.
    side = int(np.ceil(np.hypot(hb, wb))) + 2
    p0 = sfft.next_fast_len(ha + side - 1, real=True)
    p1 = sfft.next_fast_len(wa + side - 1, real=True)
    n_ang = int(np.ceil(360.0 / step_deg))
    angles = -180.0 + np.arange(n_ang) * (360.0 / n_ang)
    cb_xy = ((wb - 1) / 2.0, (hb - 1) / 2.0)
    cc = (side - 1) / 2.0
    shape = (p0, p1)
    fa_z = sfft.rfft2(ca.z, shape)
    fa_z2 = sfft.rfft2(ca.z * ca.z, shape)
    fa_m = sfft.rfft2(ca.m, shape)
    small = min(float(ca.m.sum()), float(cb.m.sum()))
    n_min = max(min_overlap * small, 16.0)
    # Per angle: the best shift's flat index, its rank score, NCC and overlap, and the rank scores
    # of its four neighbours (rows -1, +1, columns -1, +1) for the sub-pixel peak.
    best_idx = np.zeros(n_ang, np.int64)
    best = np.full(n_ang, -1.0)
    best_ncc = np.full(n_ang, -1.0)
    best_n = np.zeros(n_ang)
    nbr = np.full((n_ang, 4), -1.0)

    def corr(fx: np.ndarray, fy: np.ndarray) -> np.ndarray:
        # C[s] = sum_x X(x + s) Y(x): A's pixel x + s under B's canvas pixel x.
        return sfft.irfft2(fx[None] * fy, shape, axes=(1, 2))

    for start in range(0, n_ang, ANGLE_BATCH):
        batch = angles[start:start + ANGLE_BATCH]
        g = np.zeros((len(batch), side, side), np.float32)
        gm = np.zeros((len(batch), side, side), np.float32)
        for j, ang in enumerate(batch):
            # getRotationMatrix2D turns counter-clockwise on screen (y down): -ang is +ang in (x, y).
            r = cv2.getRotationMatrix2D(cb_xy, -float(ang), 1.0)
            r[:, 2] += (cc - cb_xy[0], cc - cb_xy[1])
            g[j] = cv2.warpAffine(cb.z, r, (side, side), flags=cv2.INTER_LINEAR)
            gm[j] = cv2.warpAffine(cb.m, r, (side, side), flags=cv2.INTER_LINEAR)
        # Rotated masks: only pixels fully inside B count; heights outside are zero.
        gm = (gm > 0.999).astype(np.float32)
        g *= gm
        fg = np.conj(sfft.rfft2(g, shape, axes=(1, 2)))
        fg2 = np.conj(sfft.rfft2(g * g, shape, axes=(1, 2)))
        fgm = np.conj(sfft.rfft2(gm, shape, axes=(1, 2)))
        # Both maps are high-passed (zero mean on any window wider than the low-pass), so the
        # overlap's means are left out: four inverse transforms per angle instead of six.
        n = np.rint(corr(fa_m, fgm))
        va = corr(fa_z2, fgm)
        vb = corr(fa_m, fg2)
        sab = corr(fa_z, fg)
        nn = np.maximum(n, 1.0)
        # Too small an overlap, or one where either side is (nearly) constant, carries no evidence.
        ok = (n >= n_min) & (va > 1e-3 * nn) & (vb > 1e-3 * nn)
        ncc = np.where(ok, sab / np.sqrt(np.maximum(va * vb, 1e-12)), -1.0)
        # Ranked by NCC times the square root of the overlap: a small overlap correlates by chance
        # more easily (the chance NCC of n independent pixels falls as 1 / sqrt(n)).
        rank = np.where(ok, ncc * np.sqrt(np.minimum(n / small, 1.0)), -1.0)
        flat = rank.reshape(len(batch), -1)
        k = flat.argmax(1)
        rows_i, cols_i = np.unravel_index(k, shape)
        sl = slice(start, start + len(batch))
        jj = np.arange(len(batch))
        best_idx[sl] = k
        best[sl] = flat[jj, k]
        best_ncc[sl] = ncc.reshape(len(batch), -1)[jj, k]
        best_n[sl] = n.reshape(len(batch), -1)[jj, k]
        nbr[sl, 0] = rank[jj, (rows_i - 1) % p0, cols_i]
        nbr[sl, 1] = rank[jj, (rows_i + 1) % p0, cols_i]
        nbr[sl, 2] = rank[jj, rows_i, (cols_i - 1) % p1]
        nbr[sl, 3] = rank[jj, rows_i, (cols_i + 1) % p1]
    # Local maxima over the circle of angles, best first.
    prev, nxt = np.roll(best, 1), np.roll(best, -1)
    peaks = np.flatnonzero((best >= prev) & (best >= nxt) & (best > -1.0))
    peaks = peaks[np.argsort(-best[peaks], kind="stable")]
    cands: list[SearchCandidate] = []
    for i in peaks[:max_candidates]:
        r_i, c_i = np.unravel_index(int(best_idx[i]), shape)
        dy = _parabola(nbr[i, 0], best[i], nbr[i, 1])
        dx = _parabola(nbr[i, 2], best[i], nbr[i, 3])
        sy = (r_i if r_i < p0 - side + 1 else r_i - p0) + dy
        sx = (c_i if c_i < p1 - side + 1 else c_i - p1) + dx
        da = _parabola(best[(i - 1) % n_ang], best[i], best[(i + 1) % n_ang])
        ang = float(angles[i] + da * (360.0 / n_ang))
        r = cv2.getRotationMatrix2D(cb_xy, -ang, 1.0)
        # Coarse B px -> canvas px -> A px (shift), then full resolution.
        r[:, 2] += (cc - cb_xy[0] + sx, cc - cb_xy[1] + sy)
        m_full = _to_full(r, f)
        cands.append(SearchCandidate(m_full, float(best_ncc[i]), float(best_n[i] / small),
                                     float((ang + 180.0) % 360.0 - 180.0)))
    return SearchResult(tuple(cands), f)


# The spread agreement of a pose (agreeing_patches): a patch carries relief when its height variance
# is at least SPREAD_ENERGY_SHARE of the SPREAD_REF_QUANTILE quantile of the overlap's patches (a
# robust reference: one deep hole or tall ridge does not silence the rest, as a share of the single
# strongest patch did), and agrees when the two touches' heights correlate there at least
# SPREAD_AGREE_NCC.
SPREAD_REF_QUANTILE = 0.9
SPREAD_ENERGY_SHARE = 0.1
SPREAD_AGREE_NCC = 0.6
# A patch takes part when at least this share of it lies inside both maps' known pixels.
SPREAD_FULL_SHARE = 0.9


def _sane(z: np.ndarray, valid: np.ndarray | None) -> tuple[np.ndarray | None, np.ndarray]:
    """(known mask or None for all known, heights with the unknown ones zeroed): non-finite and
    absurd heights (beyond MAX_ABS_HEIGHT_MM) count as unknown, as in the search. Two reductions
    when every height is sane (the polish's maps), no masks built."""
    lo, hi = float(z.min()), float(z.max())  # NaN propagates: then the masked path
    if valid is None and np.isfinite(lo) and np.isfinite(hi) and max(hi, -lo) <= MAX_ABS_HEIGHT_MM:
        return None, z
    known = np.abs(np.nan_to_num(z, nan=np.inf)) <= MAX_ABS_HEIGHT_MM
    if valid is not None:
        known &= np.asarray(valid, bool)
    return known, np.where(known, z, 0.0).astype(np.float32)


def agreeing_patches(height_a: np.ndarray, height_b: np.ndarray, matrix_px: np.ndarray, patch_px: int = 24,
                     valid_a: np.ndarray | None = None, valid_b: np.ndarray | None = None) -> int:
    """How many square patches (side ``patch_px``, on A's grid) of the overlap both carry relief and
    agree when B is moved into A by ``matrix_px`` (B->A, px): independent local evidence for the pose.

    height_a / height_b: the two maps' high-passed heights (mm; any unit, only correlations count);
    valid_*: known pixels (None: all). Measured on 240x320 maps with 24 px patches (docs/gelsight.md):
    the right pose of a plate or usb re-touch agrees on 24-68 patches; the best wrong pose of pairs
    with nothing to register (tiled real ball presses, the other part, other plates) on at most 20;
    a part's turned twin (the usb panel at 180 deg) on up to 35, which this count alone does not
    refuse (the polish's pinning bars and the uniqueness ratio do). Patch moments are area means
    (one OpenCV reduction per moment image).
    """
    za = np.asarray(height_a, np.float32)
    zb = np.asarray(height_b, np.float32)
    h, w = za.shape
    p = int(patch_px)
    rows, cols = h // p, w // p
    if p < 1 or rows < 1 or cols < 1:
        return 0
    known_a, za = _sane(za, valid_a)
    known_b, zb = _sane(zb, valid_b)
    wb = cv2.warpAffine(zb, matrix_px, (w, h), flags=cv2.INTER_LINEAR)
    cover = np.ones(zb.shape, np.float32) if known_b is None else known_b.astype(np.float32)
    kb = cv2.warpAffine(cover, matrix_px, (w, h), flags=cv2.INTER_LINEAR) > 0.999
    if known_a is not None:
        kb &= known_a
    hh, ww = rows * p, cols * p
    m = kb[:hh, :ww].astype(np.float32)
    x = za[:hh, :ww] * m
    y = wb[:hh, :ww] * m

    def mean(v: np.ndarray) -> np.ndarray:  # per patch, over all its pixels
        return cv2.resize(v, (cols, rows), interpolation=cv2.INTER_AREA).astype(np.float64)

    n = mean(m)
    full = n >= SPREAD_FULL_SHARE
    if not full.any():
        return 0
    nn = np.maximum(n, 1.0 / (p * p))
    xm, ym = mean(x) / nn, mean(y) / nn
    sxx = mean(x * x) / nn - xm * xm
    syy = mean(y * y) / nn - ym * ym
    sxy = mean(x * y) / nn - xm * ym
    energy = np.maximum(sxx, syy)
    # The reference quantile (linear interpolation, as np.quantile) by one sort of a few hundred values.
    e = np.sort(energy[full])
    pos = SPREAD_REF_QUANTILE * (e.size - 1)
    lo = int(pos)
    ref = float(e[lo] + (e[min(lo + 1, e.size - 1)] - e[lo]) * (pos - lo))
    if not np.isfinite(ref) or ref <= 0.0:
        return 0
    strong = full & (energy >= SPREAD_ENERGY_SHARE * ref)
    ncc = sxy / np.sqrt(np.maximum(sxx * syy, 1e-30))
    return int(np.count_nonzero(strong & (ncc >= SPREAD_AGREE_NCC)))
