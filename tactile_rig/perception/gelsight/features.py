"""Features of a height map for registration: keypoints with binary descriptors, and dense samples.

A height map (mm) is checked (2-D, real, within +-MAX_ABS_HEIGHT_MM; unknown pixels read 0 mm),
rendered to 8 bits with a band-pass that gives smooth contacts a ring FAST-style detectors fire on,
and ORB and/or BRISK keypoints are found on it at the touch's detection scale. The map that is the
reference A also gets its dense samples: the steep pixels the Gauss–Newton polish
(:mod:`~tactile_rig.perception.gelsight.dense_refinement`) aligns, on heights high-passed so that two
touches pressed differently compare. Matching is a cross-checked Hamming nearest neighbour.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from tactile_rig.core.errors import HeightOutOfRange
from tactile_rig.perception.gelsight.registration_params import RegistrationParams

# Heights a registration accepts: a gel shows about 1 mm and a tactile map is a few mm deep; a map
# beyond +-50 mm is not a gel surface (and would overflow the float32 statistics).
MAX_ABS_HEIGHT_MM = 50.0
# A's samples are taken this far (px) inside its border.
DENSE_MARGIN_PX = 2


_DETECTORS: dict[tuple, cv2.Feature2D] = {}


def _detector(name: str, params: RegistrationParams) -> cv2.Feature2D:
    # Building BRISK's sampling pattern costs tens of ms: build each configuration once.
    key = (name, params.brisk_threshold, params.brisk_octaves, params.orb_features, params.orb_levels,
           params.orb_scale, params.orb_fast_threshold)
    det = _DETECTORS.get(key)
    if det is None:
        if name == "brisk":
            make = cv2.BRISK_create if hasattr(cv2, "BRISK_create") else cv2.xfeatures2d.BRISK_create  # 4.x / 5.x
            det = make(params.brisk_threshold, params.brisk_octaves)
        else:
            det = cv2.ORB_create(params.orb_features, scaleFactor=params.orb_scale, nlevels=params.orb_levels,
                                 edgeThreshold=15, patchSize=15, fastThreshold=params.orb_fast_threshold)
        _DETECTORS[key] = det
    return det


def check_height(h: object, name: str) -> np.ndarray:
    """A height map as float32: 2-D, >= 16x16, real; non-finite pixels (unknown) read 0 mm; heights
    beyond +-MAX_ABS_HEIGHT_MM raise :class:`HeightOutOfRange`."""
    return check_height_ptp(h, name)[0]


def check_height_ptp(h: object, name: str) -> tuple[np.ndarray, np.ndarray | None, float]:
    """:func:`check_height`, the mask of known (finite) pixels (None when all are known) and the
    map's range (mm), from the one min/max pass the check makes anyway."""
    if not isinstance(h, np.ndarray):
        raise ValueError(f"{name}: expected a numpy array, got {type(h).__name__}")
    if h.ndim != 2 or min(h.shape) < 16:
        raise ValueError(f"{name}: expected a 2-D height map of at least 16x16 pixels, got shape {h.shape}")
    if not (np.issubdtype(h.dtype, np.floating) or np.issubdtype(h.dtype, np.integer)) or h.dtype == np.float16:
        raise ValueError(f"{name}: expected a real numeric dtype (float32/64 or integer), got {h.dtype}")
    valid = None
    if h.dtype == np.float32:
        z = h  # clean float32 input (the common case) is used as is: nan_to_num would copy every call
        if not np.isfinite(z).all():
            valid = np.isfinite(z)
            z = np.nan_to_num(z, nan=0.0, posinf=0.0, neginf=0.0)
    else:
        finite = np.isfinite(h)
        valid = None if finite.all() else finite
        z = np.nan_to_num(h.astype(np.float64), nan=0.0, posinf=0.0, neginf=0.0)
    lo, hi = cv2.minMaxLoc(z)[:2]
    peak = max(-lo, hi)
    if peak > MAX_ABS_HEIGHT_MM:
        raise HeightOutOfRange(f"{name}: a height of {peak:.3g} mm; a gel height map stays within "
                               f"+-{MAX_ABS_HEIGHT_MM:g} mm (is it in mm?)", device="gelsight.registration",
                               value=float(peak), limit=MAX_ABS_HEIGHT_MM)
    if z.dtype == np.float32:
        return z, valid, float(hi - lo)
    z = z.astype(np.float32)
    return z, valid, _ptp(z)  # the range of what is used, after the rounding to float32


def _ptp(z: np.ndarray) -> float:
    lo, hi = cv2.minMaxLoc(z)[:2]
    return float(hi - lo)


def _blur(z: np.ndarray, sigma: float) -> np.ndarray:
    # Two box passes approximate a Gaussian at O(1) cost per pixel whatever the sigma.
    if sigma <= 0:
        return z
    k = max(1, int(round(sigma * 1.7)))
    k += 1 - k % 2
    return cv2.blur(cv2.blur(z, (k, k)), (k, k))


def _lowpass_coarse(z: np.ndarray, sigma_px: float, valid: np.ndarray | None) -> np.ndarray:
    """Gaussian low-pass of sigma ``sigma_px``, over ``valid`` only when given (normalised
    convolution: the zeros outside a tactile map's coverage do not leak into its edge), computed on the
    map area-reduced by up to 4 (to a sigma of >= 1.5 px there) and brought back by bilinear resize:
    a wide low-pass at a fraction of the full-size cost."""
    f = int(np.clip(sigma_px // 1.5, 1, 4))
    if f == 1 or min(z.shape) < 8 * f:
        w = None if valid is None else valid.astype(np.float32)
        num = cv2.GaussianBlur(z if w is None else z * w, (0, 0), sigma_px, borderType=cv2.BORDER_REPLICATE)
        if w is None:
            return num
        return num / np.maximum(cv2.GaussianBlur(w, (0, 0), sigma_px, borderType=cv2.BORDER_REPLICATE), 1e-3)
    size = (max(1, z.shape[1] // f), max(1, z.shape[0] // f))
    small = cv2.resize(z, size, interpolation=cv2.INTER_AREA)
    v_small = None if valid is None else cv2.resize(valid.astype(np.float32), size, interpolation=cv2.INTER_AREA)
    # A true Gaussian (isotropic): a box blur's square kernel gives a lone dome's high-pass a
    # four-fold pattern that pins rotation where nothing does.
    sig = sigma_px / f
    if v_small is None:
        low = cv2.GaussianBlur(small, (0, 0), sig, borderType=cv2.BORDER_REPLICATE)
    else:
        low = (cv2.GaussianBlur(small * v_small, (0, 0), sig, borderType=cv2.BORDER_REPLICATE)
               / np.maximum(cv2.GaussianBlur(v_small, (0, 0), sig, borderType=cv2.BORDER_REPLICATE), 1e-3))
    return cv2.resize(low, (z.shape[1], z.shape[0]), interpolation=cv2.INTER_LINEAR)


def render_u8(height_mm: np.ndarray, band_px: tuple[float, float] = (0.0, 4.0),
              valid: np.ndarray | None = None) -> np.ndarray:
    """8-bit image for keypoints: band-passed height (difference of blurs) plus a little of the
    height itself, contrast-normalised per image (statistics over ``valid`` pixels when given, e.g.
    the covered part of a tactile map). Rotation-invariant (no directional shading), and a smooth
    dome gets a ring/blob structure that FAST-style detectors fire on."""
    z = np.asarray(height_mm, np.float32)
    fine = cv2.GaussianBlur(z, (0, 0), band_px[0]) if band_px[0] > 0 else z
    band = cv2.subtract(fine, _blur(z, band_px[1]))
    m8 = None if valid is None else valid.astype(np.uint8)
    z_mean, z_std = (float(v[0, 0]) for v in cv2.meanStdDev(z, mask=m8))
    _, b_std = (float(v[0, 0]) for v in cv2.meanStdDev(band, mask=m8))
    ka = 100.0 * 0.8 / (4.0 * b_std + 1e-12)
    kz = 100.0 * 0.2 / (4.0 * z_std + 1e-12)
    # 128 + 100 * (0.8 band / s_band + 0.2 (z - mean) / s_z), saturated to 8 bits, in two OpenCV passes.
    img = cv2.addWeighted(band, ka, z, kz, 128.0 - kz * z_mean)
    np.clip(img, 0, 255, out=img)
    out = img.astype(np.uint8)  # truncation toward zero: the keypoints depend on these exact bytes
    if valid is not None:
        out[~valid] = 128
    return out


@dataclass
class Features:
    """Keypoint positions (N, 2) px and binary descriptors per detector, of one height map, with
    the checked float32 map itself (``height``) and its range (``ptp_mm``):
    :func:`~tactile_rig.perception.gelsight.registration.register` given
    these features and that very array skips re-checking it (treat the array as frozen)."""

    points: dict[str, np.ndarray] = field(default_factory=dict)
    descriptors: dict[str, np.ndarray] = field(default_factory=dict)
    image: np.ndarray | None = None
    scale: float = 1.0
    smooth: np.ndarray | None = None
    sample_xy: np.ndarray | None = None
    sample_z: np.ndarray | None = None
    sample_slope: np.ndarray | None = None
    height: np.ndarray | None = None
    ptp_mm: float = float("nan")
    valid: np.ndarray | None = None
    train_bits: dict[str, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)


def detect_scale(params: RegistrationParams, touch_shape: tuple[int, int]) -> float:
    """Resize factor for keypoint detection; both maps of a pair must use the same (the touch's)."""
    if params.detect_scale:
        return float(params.detect_scale)
    return float(np.clip(params.detect_short_px / min(touch_shape), 0.25, 2.0))


def extract_features(height_mm: np.ndarray, params: RegistrationParams = RegistrationParams(),
                     dense: bool = True, scale: float | None = None, valid: np.ndarray | None = None) -> Features:
    """Keypoints and descriptors of a height map (reuse for a map matched many times); with
    ``dense`` also the steep-pixel samples used when this map is the reference A. scale: detection
    resize factor (default from this map's own shape; pass the touch's for a large map)."""
    z, known, ptp_mm = check_height_ptp(height_mm, "height_mm")
    if known is not None:
        valid = known if valid is None else (valid & known)
    return _features(z, ptp_mm, params, dense, scale, valid)


def _features(z: np.ndarray, ptp_mm: float, params: RegistrationParams, dense: bool, scale: float | None,
              valid: np.ndarray | None) -> Features:
    """:func:`extract_features` of a map already checked (float32, finite) whose range is ``ptp_mm``."""
    feats = prepare_features(z, ptp_mm, params, dense, scale, valid)
    detect_keypoints(feats, params)
    return feats


def prepare_features(z: np.ndarray, ptp_mm: float, params: RegistrationParams, dense: bool, scale: float | None,
                     valid: np.ndarray | None) -> Features:
    """A checked map (float32, finite, range ``ptp_mm``) up to its keypoints: the polish's heights,
    with ``dense`` A's samples, and the 8-bit image at detection ``scale`` (None: from its shape)."""
    smooth = cv2.GaussianBlur(z, (0, 0), 1.0)
    if params.dense_highpass_px > 0:
        # The dense polish compares high-passed heights: an independent re-touch pressed deeper or
        # through a softer gel differs from the map mostly at low spatial frequencies (the bowl of
        # the press, the integrator's offsets), which would bias the alignment by pixels.
        smooth = cv2.subtract(smooth, _lowpass_coarse(z, params.dense_highpass_px, valid))
    # The checked map and its range ride along, so register() need not re-check a cached reference.
    feats = Features(smooth=smooth, height=z, ptp_mm=ptp_mm, valid=valid)
    if dense:
        # A high-pass bends the heights within about two sigmas of a coverage edge (a tactile map's):
        # samples keep that far inside it.
        edge = max(3, int(round(2.0 * params.dense_highpass_px)))
        feats.sample_xy, feats.sample_z, feats.sample_slope = _dense_samples(smooth, params.dense_samples, valid, edge)
    k = detect_scale(params, z.shape) if scale is None else float(scale)
    small = z if k == 1.0 else cv2.resize(z, None, fx=k, fy=k, interpolation=cv2.INTER_AREA)
    if valid is not None and k != 1.0:
        valid = cv2.resize(valid.astype(np.uint8), (small.shape[1], small.shape[0]),
                           interpolation=cv2.INTER_NEAREST).astype(bool)
    feats.image = render_u8(small, tuple(b * k for b in params.band_px), valid)  # type: ignore[arg-type]
    feats.scale = k
    return feats


def detect_keypoints(feats: Features, params: RegistrationParams) -> None:
    """Keypoints and descriptors of a prepared map's 8-bit image, into ``feats``."""
    img, k = feats.image, feats.scale
    if img is None:  # an assert would vanish under python -O
        raise ValueError("gelsight.registration: features without their 8-bit image; prepare_features them first")
    names = ("brisk", "orb") if params.detector == "both" else (params.detector,)
    # Keep the keypoint density of a touch-sized image on a larger map.
    per_area = params.orb_features / (params.detect_short_px ** 2 * 4.0 / 3.0)
    n_orb = max(params.orb_features, int(per_area * img.shape[0] * img.shape[1]))
    for name in names:
        det = _detector(name, params)
        if name == "orb":
            det.setMaxFeatures(n_orb)
        kps, desc = det.detectAndCompute(img, None)
        # Keypoints back to full-resolution pixel centres.
        pts = (np.asarray(cv2.KeyPoint_convert(kps), np.float64).reshape(-1, 2) + 0.5) / k - 0.5
        feats.points[name] = pts
        feats.descriptors[name] = desc if desc is not None else np.zeros((0, 32), np.uint8)


def _train_bits(desc: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Train-side terms of the Hamming product: the unpacked bits (N, bits) float32 and popcounts (N,)."""
    t = np.unpackbits(desc, axis=1).astype(np.float32)
    return t, t.sum(1)


def hamming_cross_matches(desc_q: np.ndarray, desc_t: np.ndarray,
                          train_bits: tuple[np.ndarray, np.ndarray] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Cross-checked nearest neighbours of binary descriptors (N, bytes) uint8 under the Hamming
    distance: (query indices, train indices), query order, ties to the lowest index — the same pairs
    as ``cv2.BFMatcher(NORM_HAMMING, crossCheck=True).match(desc_q, desc_t)``. train_bits: the
    cached ``_train_bits(desc_t)`` of a reference matched many times."""
    if len(desc_q) == 0 or len(desc_t) == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    # d(q, t) = |q| + |t| - 2 q.t on the unpacked bits: one float32 matrix product (exact: counts
    # <= 8 * bytes) is about twice as fast as OpenCV's brute-force matcher on a few hundred points.
    # The product takes the train bits transposed as a view (BLAS reads them so): no copy.
    q = np.unpackbits(desc_q, axis=1).astype(np.float32)
    t_bits, t_count = train_bits if train_bits is not None else _train_bits(desc_t)
    d = q @ t_bits.T
    d *= -2.0
    d += q.sum(1)[:, None]
    d += t_count[None, :]
    best_t = d.argmin(1)
    best_q = d.argmin(0)
    qi = np.flatnonzero(best_q[best_t] == np.arange(len(q)))
    return qi, best_t[qi]


def match_features(fa: Features, fb: Features) -> tuple[np.ndarray, np.ndarray]:
    """Cross-checked matches of B's keypoints to A's, per detector pooled: (points in A, points in B)
    (N, 2) px float64. A's descriptor bits are kept with ``fa`` (a stored map is matched many times)."""
    pa, pb = [], []
    for name, da in fa.descriptors.items():
        db = fb.descriptors.get(name)
        if db is None or len(da) < 2 or len(db) < 2:
            continue
        bits = fa.train_bits.get(name)
        if bits is None:  # kept with A's features: a stored map is matched many times
            bits = fa.train_bits[name] = _train_bits(da)
        qi, ti = hamming_cross_matches(db, da, bits)
        pb.append(fb.points[name][qi])
        pa.append(fa.points[name][ti])
    if not pa:
        return np.zeros((0, 2)), np.zeros((0, 2))
    return np.concatenate(pa).astype(np.float64), np.concatenate(pb).astype(np.float64)


def _upper_quartile(x: np.ndarray) -> float:
    """``np.quantile(x, 0.75)`` (linear interpolation) by a partial sort, without its overhead."""
    v = x.ravel()
    pos = 0.75 * (v.size - 1)
    lo = int(pos)
    hi = min(lo + 1, v.size - 1)
    part = np.partition(v, (lo, hi))
    return float(part[lo] + (part[hi] - part[lo]) * (pos - lo))


def _dense_samples(smooth: np.ndarray, count: int, valid: np.ndarray | None = None, edge_px: int = 3
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pixels of A that constrain alignment: the steepest quarter of every other pixel of every other
    row (DENSE_MARGIN_PX from the edge and inside ``valid`` shrunk by ``edge_px``), thinned to at most
    ``count`` on a regular stride (deterministic). The half-density grid finds the same structure at
    a quarter of the cost; the polish samples B bilinearly wherever A's samples land. Returns the
    samples (N, 2) px, A's heights there (N,) and A's central-difference slopes there (N, 2) (x, y)."""
    h, w = smooth.shape
    ys0, xs0 = 2 * np.arange(1, (h - 1) // 2), 2 * np.arange(1, (w - 1) // 2)  # even rows/columns, not the edge
    if len(ys0) < 2 or len(xs0) < 2:
        return np.zeros((0, 2), np.float32), np.zeros(0), np.zeros((0, 2))
    r0, r1, c0, c1 = ys0[0], ys0[-1] + 1, xs0[0], xs0[-1] + 1
    # Central differences on the even grid: half the difference of the two neighbours.
    gx = 0.5 * (smooth[r0:r1:2, c0 + 1:c1 + 1:2] - smooth[r0:r1:2, c0 - 1:c1 - 1:2])
    gy = 0.5 * (smooth[r0 + 1:r1 + 1:2, c0:c1:2] - smooth[r0 - 1:r1 - 1:2, c0:c1:2])
    mag = cv2.magnitude(gx, gy)  # the slope's size: its quartile selects the same pixels as its square's
    m = max(2, min(DENSE_MARGIN_PX, min(h, w) // 4))
    mag[(ys0 < m) | (ys0 >= h - m), :] = 0
    mag[:, (xs0 < m) | (xs0 >= w - m)] = 0
    if valid is not None:
        k = 2 * edge_px + 1
        inner = cv2.erode(valid.astype(np.uint8), np.ones((k, k), np.uint8))
        mag[inner[r0:r1:2, c0:c1:2] == 0] = 0
    thr = _upper_quartile(mag[::2, ::2])  # a sparse grid estimates the quartile well enough
    pts = cv2.findNonZero((mag > max(float(thr), 1e-10)).view(np.uint8))  # row-major, as np.nonzero
    if pts is None:
        return np.zeros((0, 2), np.float32), np.zeros(0), np.zeros((0, 2))
    pts = pts.reshape(-1, 2)  # (N, 1, 2) on OpenCV 4, (N, 2) on 5
    if len(pts) > count:
        pts = pts[_even_picks(len(pts), count)]
    xs, ys = xs0[pts[:, 0]], ys0[pts[:, 1]]
    on_grid = pts[:, 1] * gx.shape[1] + pts[:, 0]  # gx and gy are fresh C-ordered arrays
    slope = np.stack([gx.ravel().take(on_grid), gy.ravel().take(on_grid)], 1).astype(np.float64)
    heights = np.take(smooth, ys * smooth.shape[1] + xs) if smooth.flags.c_contiguous else smooth[ys, xs]
    return np.stack([xs, ys], 1).astype(np.float32), heights.astype(np.float64), slope


def _even_picks(n: int, count: int) -> np.ndarray:
    """``np.linspace(0, n - 1, count).astype(np.int64)`` (the same numbers: index i times the step,
    the last index exact) without linspace's overhead; count >= 0."""
    if count < 2:
        return np.linspace(0, n - 1, count).astype(np.int64)
    picks = (np.arange(count, dtype=np.float64) * ((n - 1) / (count - 1))).astype(np.int64)
    picks[-1] = n - 1
    return picks
