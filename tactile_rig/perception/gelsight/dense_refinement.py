"""Dense refinement: the Gauss–Newton polish of a B->A rigid pose on A's steep pixels.

Given a start (a keypoint consensus, a dense-search candidate or a jig's hint), the polish aligns
B's heights to A's dense samples (:class:`~tactile_rig.perception.gelsight.features.Features`),
fitting rotation, translation and the height difference an independent re-touch shows (a surface
and a gain). It reports what the answer is worth: the normalised correlation and overlap on A's
samples, the 1-sigma rotation and translation from the Gauss–Newton information, how much the
content pins rotation, and whether the polish converged or wandered out of its basin;
:func:`pose_pinned` judges that against the bars of
:class:`~tactile_rig.perception.gelsight.registration_params.RegistrationParams`.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from tactile_rig.perception.gelsight.features import Features
from tactile_rig.perception.gelsight.registration_params import RegistrationParams

# A polish that moves further than this from its starting pose has wandered (flat content, or a
# start outside the fine basin): the coarse-to-fine retry starts over, and a wandered fit is never
# accepted.
WANDER_DEG = 4.0
WANDER_PX = 5.0
# Gaussian sigma (px) of the coarse stage of the retry: widens the basin of the polish to several px.
COARSE_SIGMA_PX = 3.0
# The polish has converged when its last step moves the samples by less than this (px; rotation
# counted at a 100 px lever).
CONVERGED_STEP_PX = 0.05
# The Gauss–Newton steps stop once a step moves the samples by less than this (px): smaller steps
# change no answer and cost time.
STOP_STEP_PX = CONVERGED_STEP_PX
# Samples that land within this many px of B's border are left out of the polish: a high-pass (and
# the Poisson integration) distorts heights next to a border, and a re-touch shifted by a few mm puts
# B's border over A's interior, where that distortion pulls the fit by pixels.
B_MARGIN_PX = 8.0
# Points per row of the map handed to cv2.remap (which refuses a side of 32767 or more).
_REMAP_ROW = 8192


def overlap_ncc(height_a: np.ndarray, height_b: np.ndarray, matrix_px: np.ndarray) -> tuple[float, float]:
    """(normalised cross-correlation of A and B warped into A, overlap fraction of A's area)."""
    h, w = height_a.shape
    warped = cv2.warpAffine(height_b, matrix_px, (w, h), flags=cv2.INTER_LINEAR, borderValue=np.nan)
    valid = np.isfinite(warped)
    frac = float(valid.mean())
    if valid.sum() < 16:
        return 0.0, frac
    a = height_a[valid].astype(np.float64)
    b = warped[valid].astype(np.float64)
    a -= a.mean()
    b -= b.mean()
    den = np.sqrt((a * a).sum() * (b * b).sum())
    if den < 1e-18:
        return 0.0, frac
    return float((a * b).sum() / den), frac


def _sample(img: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Bilinear samples of a C-channel float32 image at (x, y) px: (N, C) float64."""
    uv = _point_buffer(len(x))
    uv[:len(x), 0], uv[:len(x), 1] = x, y
    return _remap_points(img, uv, len(x))


def _point_buffer(n: int) -> np.ndarray:
    """A zeroed (M, 2) float32 buffer for n points, M padded to whole rows of _REMAP_ROW."""
    cols = max(1, min(n, _REMAP_ROW))
    return np.zeros((-(-n // cols) * cols, 2), np.float32)  # the padding reads pixel (0, 0) and is dropped


def _remap_points(img: np.ndarray, uv: np.ndarray, n: int) -> np.ndarray:
    """Bilinear samples (n, C) float64 of a float32 image at the first n points of a
    :func:`_point_buffer`."""
    if n == 0:
        return np.zeros((0, 1 if img.ndim == 2 else img.shape[2]))
    # The points laid out as rows of a map, not as a column: remap's cost is per map row, and a
    # column of 10,000 one-pixel rows cost 3.5x the same points in one row (the same samples).
    cols = min(n, _REMAP_ROW)
    out = cv2.remap(img, uv.reshape(-1, cols, 2), None, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    return out.reshape(len(uv), -1)[:n].astype(np.float64)


def _inside(u: np.ndarray, v: np.ndarray, w: int, h: int, margin: float = 0.0) -> tuple[np.ndarray, int]:
    ok = (u >= margin) & (u <= w - 1 - margin) & (v >= margin) & (v <= h - 1 - margin)
    return ok, int(np.count_nonzero(ok))


@dataclass
class DenseFit:
    """Result of :func:`dense_refine`: B->A matrix (px), NCC and overlap on A's samples, and the
    1-sigma uncertainty of rotation (deg) and translation (px) from the Gauss–Newton information
    (residual variance floored at ``noise_mm``): large when the content is rotation-symmetric/flat;
    ``wandered``: the polish left its basin and the matrix is the unpolished start (never accept it);
    ``converged``: its last step was below CONVERGED_STEP_PX."""

    matrix_px: np.ndarray
    ncc: float = 0.0
    overlap: float = 0.0
    sigma_rot_deg: float = float("inf")
    sigma_px: float = float("inf")
    rotation_pinning: float = 0.0
    wandered: bool = False
    converged: bool = False


def _bias_basis(x: np.ndarray, y: np.ndarray, order: int) -> np.ndarray:
    """Columns 1 (order 0), + x, y (1), + x^2, xy, y^2 (2) on coordinates centred and scaled to ~1."""
    xn = (x - x.mean()) / max(float(x.std()), 1.0)
    yn = (y - y.mean()) / max(float(y.std()), 1.0)
    cols = [np.ones_like(xn)]
    if order >= 1:
        cols += [xn, yn]
    if order >= 2:
        cols += [xn * xn, xn * yn, yn * yn]
    return np.stack(cols, 1)


def _b_image(smooth_b: np.ndarray, valid_b: np.ndarray | None) -> np.ndarray:
    """B's heights (and its known mask as a second channel): what the polish samples per step."""
    if valid_b is None:
        return smooth_b
    return cv2.merge([smooth_b, valid_b.astype(np.float32)])


@dataclass
class _GNState:
    th: float
    t: np.ndarray
    gain: float
    coef: np.ndarray
    last_step_px: float = float("inf")


def _gauss_newton(zb_img: np.ndarray, x: np.ndarray, y: np.ndarray, za: np.ndarray, basis: np.ndarray,
                  st: _GNState, iters: int, gain_fit: bool, slope_a: np.ndarray | None = None) -> _GNState:
    """Gauss–Newton iterations of the B->A pose (A px -> B px as rotation ``th`` and translation
    ``t``), height gain and bias surface, on A's samples (x, y) and heights ``za`` against B's heights
    ``zb_img`` (B's slopes from bilinear samples 1 px either side: no slope images of B).

    slope_a: A's slopes (N, 2) at its samples. Given, the pose columns use the mean of B's slopes
    (times the gain) and A's turned into B's frame, as efficient second-order minimisation does: on
    an independent re-touch (another depth, blur and gain) a Jacobian of B's slopes alone overshoots
    and its steps alternate in sign, so a right pose can stop short of the convergence bar."""
    h, w = zb_img.shape[:2]
    nb = basis.shape[1]
    th, t, gain, coef = st.th, st.t.copy(), st.gain, st.coef.copy()
    last = float("inf")
    frozen = None
    picked: tuple = ()  # (selection, A's heights, basis rows, A's slopes) of the frozen selection
    for k in range(iters):
        # After two steps the samples in play are frozen: samples crossing B's margin or coverage
        # edge at every step would otherwise keep the fit cycling by a fraction of a pixel.
        got = _gather(zb_img, x, y, th, t, w, h, frozen if k >= 2 else None)
        if got is None:
            break
        frozen = got[0]
        sel, u, v, zb, bx, by, _n = got
        if picked and picked[0] is sel:
            zo, bas, ax, ay = picked[1:]
        else:
            zo, bas = za[sel], basis[sel]
            ax, ay = (slope_a[sel, 0], slope_a[sel, 1]) if slope_a is not None else (None, None)
            picked = (sel, zo, bas, ax, ay)
        gbx, gby = gain * bx, gain * by
        if slope_a is not None:
            # A's slope in A's frame, turned by the current rotation into B's frame.
            c_th, s_th = np.cos(th), np.sin(th)
            gbx = 0.5 * (gbx + c_th * ax - s_th * ay)
            gby = 0.5 * (gby + s_th * ax + c_th * ay)
        npar = 3 + nb + (1 if gain_fit else 0)
        j = np.empty((len(zb), npar))
        # d(u, v)/d(theta) = (-(v - t_y), u - t_x): no second rotation of the samples.
        j[:, 0] = gby * (u - t[0]) - gbx * (v - t[1])
        j[:, 1], j[:, 2] = gbx, gby
        j[:, 3:3 + nb] = bas
        if gain_fit:
            j[:, -1] = zb
        r = gain * zb + bas @ coef - zo
        hess = j.T @ j
        hess[np.diag_indices(npar)] *= 1.0 + 1e-6
        try:
            d = -np.linalg.solve(hess, j.T @ r)
        except np.linalg.LinAlgError:
            break
        th += d[0]
        t += d[1:3]
        coef += d[3:3 + nb]
        last = float(abs(d[0]) * 100.0 + np.hypot(d[1], d[2]))
        if gain_fit:
            # A re-touch pressed deeper shows its relief a little higher: a bounded height gain.
            gain = float(np.clip(gain + d[-1], 0.5, 2.0))
        if last < STOP_STEP_PX:
            break
    return _GNState(float(th), t, gain, coef, last)


def _gather(zb_img: np.ndarray, x: np.ndarray, y: np.ndarray, th: float, t: np.ndarray, w: int, h: int,
            only: np.ndarray | slice | None = None):
    """A's samples moved into B by (th, t), B's heights and slopes there (slopes: half the difference
    of bilinear samples 1 px either side, the same numbers as sampling a central-difference image;
    all five samples per point in one remap), dropping samples within B_MARGIN_PX of B's border or on
    its unknown pixels: (selection, u, v, zb, bx, by, n inside) or None below 8 samples.
    only: a previous selection to keep as it is (no inside or known test)."""
    c, s_ = np.cos(th), np.sin(th)
    if only is not None:
        xs, ys = x[only], y[only]
        u = c * xs - s_ * ys + t[0]
        v = s_ * xs + c * ys + t[1]
        zb, bx, by, _known = _sample5(zb_img, u, v)
        return only, u, v, zb, bx, by, len(u)
    u = c * x - s_ * y + t[0]
    v = s_ * x + c * y + t[1]
    ok, n_ok = _inside(u, v, w, h, B_MARGIN_PX)
    if n_ok < 8:
        return None
    idx = np.flatnonzero(ok) if n_ok < len(x) else None
    if idx is not None:
        u, v = u[idx], v[idx]
    zb, bx, by, known = _sample5(zb_img, u, v)
    if known is not None:
        keep = known > 0.999
        if keep.sum() < 8:
            return None
        idx = np.flatnonzero(keep) if idx is None else idx[keep]
        zb, bx, by, u, v = zb[keep], bx[keep], by[keep], u[keep], v[keep]
    sel = slice(None) if idx is None else idx
    return sel, u, v, zb, bx, by, n_ok


def _sample5(zb_img: np.ndarray, u: np.ndarray, v: np.ndarray
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]:
    """B's height, x and y slopes at (u, v) and, for a two-channel image, its known mask there."""
    n = len(u)
    uv = _point_buffer(5 * n)
    # The five points of each sample: itself, 1 px right, left, down, up (offsets added in float64,
    # then rounded to the map's float32, as a concatenation of the offset coordinates would be).
    for i, (du, dv) in enumerate(((0.0, 0.0), (1.0, 0.0), (-1.0, 0.0), (0.0, 1.0), (0.0, -1.0))):
        uv[i * n:(i + 1) * n, 0] = u + du if du else u
        uv[i * n:(i + 1) * n, 1] = v + dv if dv else v
    smp = _remap_points(zb_img, uv, 5 * n)
    z5 = smp[:, 0]
    known = smp[:n, 1] if smp.shape[1] > 1 else None
    return z5[:n], 0.5 * (z5[n:2 * n] - z5[2 * n:3 * n]), 0.5 * (z5[3 * n:4 * n] - z5[4 * n:]), known


def _wandered(st: _GNState, start: tuple[float, np.ndarray], cx: float, cy: float) -> bool:
    """The polish moved A's sample centroid (cx, cy) by more than WANDER_PX, or turned by more than
    WANDER_DEG, from the start (the centroid, not the pixel origin: a small turn about a far origin
    is a large translation there)."""
    if not np.isfinite(st.th) or not np.all(np.isfinite(st.t)):
        return True
    if abs(st.th - start[0]) > np.radians(WANDER_DEG):
        return True
    moved = [np.cos(th) * cx - np.sin(th) * cy + t[0] for th, t in ((st.th, st.t), start)], \
        [np.sin(th) * cx + np.cos(th) * cy + t[1] for th, t in ((st.th, st.t), start)]
    return float(np.hypot(moved[0][0] - moved[0][1], moved[1][0] - moved[1][1])) > WANDER_PX


def dense_refine(fa: Features, smooth_b: np.ndarray, matrix_px: np.ndarray, iters: int = 5,
                 noise_mm: float = 2e-3, gain_fit: bool = False, valid_b: np.ndarray | None = None,
                 bias_order: int = 0, coarse_retry: bool = True) -> DenseFit:
    """Gauss–Newton polish of a B->A rigid transform on A's steep pixels: rotation, translation,
    a height offset between the touches (with ``bias_order`` 1 or 2 a plane or quadratic surface in
    A's frame: the tilt or bowl by which an independent re-touch differs) and, with ``gain_fit``, a
    height gain in [0.5, 2]. Samples landing outside B or on its unknown pixels are left out.

    A polish that wanders (moves more than WANDER_DEG / WANDER_PX from the start: the start was
    outside the basin of the fine heights) is retried coarse to fine with ``coarse_retry`` (heights
    blurred by COARSE_SIGMA_PX first); a fit that still wanders is returned at the start pose with
    ``wandered=True`` and must not be accepted. ``converged`` says the last step moved the samples
    by less than CONVERGED_STEP_PX (with ``iters=0``, no polish asked for, the start pose is judged
    as it is)."""
    xy, za = fa.sample_xy, fa.sample_z
    if xy is None or za is None or len(xy) < 8:
        return DenseFit(matrix_px)
    h, w = smooth_b.shape
    zb_img = _b_image(smooth_b, valid_b)
    inv = cv2.invertAffineTransform(matrix_px)  # A px -> B px
    x, y = xy[:, 0].astype(np.float64), xy[:, 1].astype(np.float64)
    basis = _bias_basis(x, y, int(bias_order))
    st0 = _GNState(float(np.arctan2(inv[1, 0], inv[0, 0])), inv[:, 2].astype(np.float64).copy(), 1.0,
                   np.zeros(basis.shape[1]))
    start = (st0.th, st0.t.copy())
    cx, cy = float(x.mean()), float(y.mean())
    slope_a = fa.sample_slope if fa.sample_slope is not None and len(fa.sample_slope) == len(x) else None
    st = _gauss_newton(zb_img, x, y, za, basis, st0, iters, gain_fit, slope_a)
    for _ in range(2):  # a start a few degrees off needs more than ``iters`` steps to settle
        if st.last_step_px < CONVERGED_STEP_PX or _wandered(st, start, cx, cy):
            break
        st = _gauss_newton(zb_img, x, y, za, basis, st, iters, gain_fit, slope_a)
    wandered = _wandered(st, start, cx, cy)
    if wandered and coarse_retry and iters > 0 and fa.smooth is not None:
        # Coarse to fine: blurred heights have a basin of several px; A's samples keep their places
        # and read A's blurred heights there.
        ia, ja = xy[:, 1].astype(np.intp), xy[:, 0].astype(np.intp)
        blur_a = cv2.GaussianBlur(fa.smooth, (0, 0), COARSE_SIGMA_PX)
        coarse_a = blur_a[ia, ja].astype(np.float64)
        # Samples lie >= 2 px inside A (features.DENSE_MARGIN_PX): their neighbours exist.
        coarse_slope = np.stack([0.5 * (blur_a[ia, ja + 1] - blur_a[ia, ja - 1]),
                                 0.5 * (blur_a[ia + 1, ja] - blur_a[ia - 1, ja])], 1).astype(np.float64)
        coarse_b = _b_image(cv2.GaussianBlur(smooth_b, (0, 0), COARSE_SIGMA_PX), valid_b)
        st = _gauss_newton(coarse_b, x, y, coarse_a, basis, st0, 2 * iters, gain_fit,
                           None if slope_a is None else coarse_slope)
        if not _wandered(st, start, cx, cy):
            st = _gauss_newton(zb_img, x, y, za, basis, st, iters, gain_fit, slope_a)
        wandered = _wandered(st, start, cx, cy)
    if wandered:
        st = _GNState(start[0], start[1].copy(), 1.0, np.zeros(basis.shape[1]))
    th, t, gain, coef = st.th, st.t, st.gain, st.coef
    c, s_ = np.cos(th), np.sin(th)
    fwd = np.array([[c, -s_, t[0]], [s_, c, t[1]]])
    u_all = c * x - s_ * y + t[0]
    v_all = s_ * x + c * y + t[1]
    fit = DenseFit(cv2.invertAffineTransform(fwd).astype(np.float64),
                   overlap=_inside(u_all, v_all, w, h)[1] / len(x), wandered=bool(wandered),
                   converged=bool(not wandered and (iters == 0 or st.last_step_px < CONVERGED_STEP_PX)))
    got = _gather(zb_img, x, y, th, t, w, h)
    if got is None:
        return fit
    sel, _u, _v, zb, bx, by, _n = got
    gbx, gby = gain * bx, gain * by
    xo, yo, bas = x[sel], y[sel], basis[sel]
    zo = za[sel] - bas @ coef  # A's heights with the fitted surface between the touches removed
    a_ = zo - zo.mean()
    b_ = zb - zb.mean()
    den = np.sqrt((a_ * a_).sum() * (b_ * b_).sum())
    fit.ncc = float((a_ * b_).sum() / den) if den > 1e-18 else 0.0
    # Rotate about the samples' centroid so the angle's information is not mixed with translation.
    xo, yo = xo - xo.mean(), yo - yo.mean()
    j = np.column_stack([gbx * (-s_ * xo - c * yo) + gby * (c * xo - s_ * yo), gbx, gby, bas])
    resid = gain * b_ - a_
    var = max(float(resid @ resid) / max(len(resid) - j.shape[1], 1), noise_mm ** 2)
    try:
        inv_info = np.linalg.inv(j.T @ j)
        cov = var * inv_info
        fit.sigma_rot_deg = float(np.degrees(np.sqrt(max(cov[0, 0], 0.0))))
        fit.sigma_px = float(np.sqrt(max(cov[1, 1], 0.0) + max(cov[2, 2], 0.0)))
        # How much the content pins rotation compared with translation, whatever the noise: the
        # rotation information (after translation and offset are solved) over the translation
        # information times the samples' squared radius. ~0 for a rotation-symmetric dome, O(0.1-1)
        # for texture. Unlike sigma it does not shrink on a noise-free (resampled) map.
        r2 = float(np.mean(xo * xo + yo * yo))
        info_rot = 1.0 / max(inv_info[0, 0], 1e-300)
        info_t = 0.5 * (1.0 / max(inv_info[1, 1], 1e-300) + 1.0 / max(inv_info[2, 2], 1e-300))
        fit.rotation_pinning = float(np.sqrt(info_rot / max(info_t * r2, 1e-300)))
    except np.linalg.LinAlgError:
        pass
    return fit



def pose_pinned(fit: DenseFit, params: RegistrationParams, max_sigma_px: float | None = None) -> bool:
    """The dense fit pins the pose: it converged (did not wander, last step small), its 1-sigma
    errors are within ``params.max_sigma_rot_deg`` and ``max_sigma_px`` (default
    ``params.max_sigma_px``) and its content is not rotation-symmetric (``min_rotation_pinning``)."""
    bar_px = params.max_sigma_px if max_sigma_px is None else max_sigma_px
    return (fit.converged and fit.sigma_rot_deg <= params.max_sigma_rot_deg and fit.sigma_px <= bar_px
            and fit.rotation_pinning >= params.min_rotation_pinning)
