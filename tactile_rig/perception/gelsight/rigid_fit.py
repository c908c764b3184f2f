"""Rigid fit of keypoint matches: two-pair RANSAC (Li et al. 2014) and how much to trust the fit.

:func:`ransac_rigid` finds the rotation and translation most matches agree on and refits it on them;
:func:`fit_confidence` is the paper's confidence c = max(1 - |1 - det R|, 0), R the 2x2 part of the
least-squares homography of the inliers (1 for a rigid move, lower when the matches describe a
squash or a shear). :func:`looks_squashed` names a refused pair that is a squashed copy rather than
unrelated content.
"""

from __future__ import annotations

from functools import lru_cache

import cv2
import numpy as np

from tactile_rig.perception.gelsight.features import Features
from tactile_rig.perception.gelsight.registration_params import RegistrationParams

# Li's confidence is computed on the inliers within this residual (px) of the rigid fit: a looser
# consensus tolerance (independent touches move keypoints by a few px) must not dilute the
# homography test.
CONFIDENCE_PX = 2.0
# B's gradient structure differs from A's by more than this factor in its eigenvalue ratio: a rigid
# move keeps that ratio (up to the content that enters or leaves the overlap), a squash by s in one
# direction scales it by up to s^2 (docs/gelsight.md, "Registration parameters").
SQUASH_ANISOTROPY_FACTOR = 4.0
_RANSAC_BLOCK = 64


def rigid_fit(src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    """Least-squares 2-D rotation + translation mapping src (N,2) onto dst (N,2); 2x3 matrix."""
    cs, cd = src.mean(0), dst.mean(0)
    s, d = src - cs, dst - cd
    num = np.sum(s[:, 0] * d[:, 1] - s[:, 1] * d[:, 0])
    den = np.sum(s[:, 0] * d[:, 0] + s[:, 1] * d[:, 1])
    th = np.arctan2(num, den)
    c, si = np.cos(th), np.sin(th)
    r = np.array([[c, -si], [si, c]])
    return np.hstack([r, (cd - r @ cs)[:, None]])


@lru_cache(maxsize=512)
def _ransac_samples(seed: int, n: int, iters: int) -> tuple[np.ndarray, np.ndarray]:
    """The two match indices of every RANSAC sample (seeded: the same for the same n), read-only;
    kept because seeding a generator costs as much as scoring a block of samples."""
    rng = np.random.default_rng(seed)
    i = rng.integers(0, n, iters)
    j = rng.integers(0, n, iters)
    i.flags.writeable = False
    j.flags.writeable = False
    return i, j


def ransac_rigid(src: np.ndarray, dst: np.ndarray, iters: int = 256, inlier_px: float = 2.0,
                 seed: int = 0) -> tuple[np.ndarray | None, np.ndarray]:
    """Two-pair sampling RANSAC (Li 2014): each sample of two matches fixes a rotation and a
    translation; pairs whose lengths disagree are skipped. Samples are scored in blocks of
    ``_RANSAC_BLOCK``, stopping early once the best consensus makes a better one unlikely
    (probability 1e-3 of never drawing two inliers); at most ``iters`` samples. Returns (2x3 or
    None, inlier mask)."""
    n = len(src)
    if n < 2:
        return None, np.zeros(n, bool)
    i, j = _ransac_samples(seed, n, iters)
    # Points as complex numbers: a rotation is a unit complex factor, so every hypothesis and its
    # residuals are a few complex array operations (no trigonometry).
    zs = src[:, 0] + 1j * src[:, 1]
    zd = dst[:, 0] + 1j * dst[:, 1]
    vs = zs[j] - zs[i]
    vd = zd[j] - zd[i]
    ls, ld = np.abs(vs), np.abs(vd)
    good = (i != j) & (ls > 2 * inlier_px) & (np.abs(ls - ld) < 2 * inlier_px)
    if not good.any():
        return None, np.zeros(n, bool)
    rot = vd[good] * vs[good].conj()
    rot /= np.abs(rot)
    tr = zd[i[good]] - rot * zs[i[good]]
    best_n, mask = -1, np.zeros(n, bool)
    for start in range(0, len(rot), _RANSAC_BLOCK):
        stop = start + _RANSAC_BLOCK
        # Residuals of every match under every hypothesis of the block: (hypotheses, matches).
        res = rot[start:stop, None] * zs[None, :] + (tr[start:stop, None] - zd[None, :])
        inl = (res.real * res.real + res.imag * res.imag) < inlier_px * inlier_px
        counts = inl.sum(1)
        k = int(np.argmax(counts))
        if counts[k] > best_n:  # strict: ties go to the earliest sample, as one argmax over all
            best_n, mask = int(counts[k]), inl[k]
        w2 = (best_n / n) ** 2
        if w2 >= 1.0 or (w2 > 0.0 and min(stop, len(rot)) >= np.log(1e-3) / np.log1p(-w2)):
            break
    if mask.sum() < 2:
        return None, mask
    m = rigid_fit(src[mask], dst[mask])
    for _ in range(2):  # re-select inliers under the refit, then refit
        res = src @ m[:, :2].T + m[:, 2] - dst
        new = np.einsum("ij,ij->i", res, res) < inlier_px * inlier_px
        if new.sum() < 2:
            break
        mask = new
        m = rigid_fit(src[mask], dst[mask])
    return m, mask


def homography_confidence(src: np.ndarray, dst: np.ndarray) -> float:
    """Li 2014 confidence c = max(1 - |1 - det R|, 0), R the 2x2 part of the least-squares
    homography of the inlier matches (normalised so H[2,2] = 1); 0 when it is degenerate."""
    if len(src) < 4:
        return 0.0
    # Centring each point set is a translation conjugation (an exact isometry still gives c = 1) and
    # keeps the projective terms from trading off against the linear part far from the origin.
    src = src - src.mean(0)
    dst = dst - dst.mean(0)
    h, _ = cv2.findHomography(src.astype(np.float32), dst.astype(np.float32), 0)
    if h is None or not np.all(np.isfinite(h)) or abs(h[2, 2]) < 1e-12:
        return 0.0
    h = h / h[2, 2]
    det = float(np.linalg.det(h[:2, :2]))
    if not np.isfinite(det):
        return 0.0
    return max(1.0 - abs(1.0 - det), 0.0)


def fit_confidence(src: np.ndarray, dst: np.ndarray, matrix: np.ndarray, inliers: np.ndarray, inlier_px: float,
                   min_inliers: int) -> float:
    """Li's c of the rigid fit ``matrix`` (2x3, src -> dst) on its inliers (mask) that lie within
    ``min(inlier_px, CONFIDENCE_PX)`` of it; on all its inliers when fewer than ``min_inliers`` do."""
    res = src[inliers] @ matrix[:, :2].T + matrix[:, 2] - dst[inliers]
    tight = np.einsum("ij,ij->i", res, res) < min(inlier_px, CONFIDENCE_PX) ** 2
    sub = np.flatnonzero(inliers)[tight] if tight.sum() >= min_inliers else np.flatnonzero(inliers)
    return homography_confidence(src[sub], dst[sub])


def _grad(z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Central-difference slopes per pixel (x, y) as float32."""
    gx = cv2.Sobel(z, cv2.CV_32F, 1, 0, ksize=1, scale=0.5, borderType=cv2.BORDER_REPLICATE)
    gy = cv2.Sobel(z, cv2.CV_32F, 0, 1, ksize=1, scale=0.5, borderType=cv2.BORDER_REPLICATE)
    return gx, gy


def _anisotropy(smooth: np.ndarray) -> float:
    """Smaller / larger eigenvalue of the gradient structure tensor summed over the map (1 =
    isotropic, 0 = all gradients along one direction); rotation invariant."""
    gx, gy = _grad(smooth)
    sxx, syy, sxy = float((gx * gx).sum()), float((gy * gy).sum()), float((gx * gy).sum())
    tr = sxx + syy
    if tr <= 1e-30:
        return 1.0
    d = np.sqrt(max((sxx - syy) ** 2 + 4.0 * sxy * sxy, 0.0))
    return max((tr - d) / (tr + d), 0.0)


def looks_squashed(fa: Features, fb: Features, pa: np.ndarray, pb: np.ndarray, params: RegistrationParams) -> bool:
    """True when B looks like A under a squashing (far from det 1) transform: either the matches
    agree on an affine map whose determinant is outside 1 +- (1 - min_confidence), or the gradient
    anisotropy of the two maps differs by more than SQUASH_ANISOTROPY_FACTOR."""
    if len(pa) >= 3 * params.min_inliers:
        m, inl = cv2.estimateAffine2D(pb.astype(np.float32), pa.astype(np.float32), method=cv2.RANSAC,
                                      ransacReprojThreshold=params.inlier_px, maxIters=500, refineIters=10)
        if m is not None and inl is not None:
            n = int(inl.sum())
            det = float(np.linalg.det(m[:, :2]))
            if n >= max(2 * params.min_inliers, 0.3 * len(pa)) and abs(1.0 - det) > 1.0 - params.min_confidence:
                return True
    if fa.smooth is None or fb.smooth is None:
        return False
    ra, rb = _anisotropy(fa.smooth), _anisotropy(fb.smooth)
    lo, hi = min(ra, rb), max(ra, rb)
    return hi > 1e-6 and lo * SQUASH_ANISOTROPY_FACTOR < hi
