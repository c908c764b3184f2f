"""Height map vs height map -> 2-D isometry (Li et al. 2014), honest about when it does not know.

Pipeline: height maps rendered to 8-bit with a band-pass that puts keypoints on smooth contacts ->
BRISK or ORB keypoints -> cross-checked Hamming matches -> two-pair sampling RANSAC for a rigid
transform -> least-squares refit on the inliers -> the paper's confidence
c = max(1 - |1 - det R|, 0), R the 2x2 part of the least-squares homography of the inliers -> a dense
check (normalised correlation of the overlapping heights). When keypoints fail, a global dense search
(:mod:`~tactile_rig.perception.gelsight.dense_search`: masked correlation of high-passed heights over
every rotation and shift, its best poses polished and checked) is tried; when neither is trustworthy
the result is a refusal (``ok=False`` with a ``reason``) rather than a confident wrong answer.

Frames: a point of B in mm from B's centre (x right, y down) maps into A's frame (mm from A's centre)
by ``matrix_mm``; ``matrix_px`` does the same in pixel (column, row) coordinates.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import lru_cache

import cv2
import numpy as np

from tactile_rig.core.errors import DegenerateTransform, HeightOutOfRange, NoContact, PerceptionError
from tactile_rig.perception.gelsight.dense_search import agreeing_patches, rotation_search

INSUFFICIENT_TEXTURE = "insufficient_texture"
NO_CONSENSUS = "no_consensus"
LOW_CONFIDENCE = "low_confidence"
MISMATCH = "dense_check_failed"
NO_CONTACT = "no_contact"
DEGENERATE = "degenerate_transform"
REASONS: dict[str, str] = {
    NO_CONTACT: "a map is flat: nothing touched the gel",
    INSUFFICIENT_TEXTURE: "too little texture to pin rotation and translation (e.g. a lone smooth dome)",
    NO_CONSENSUS: "keypoint matches agree on no rigid move",
    LOW_CONFIDENCE: "the inliers' homography is not a rigid move (Li's c below min_confidence)",
    MISMATCH: "the aligned heights do not correlate (NCC or overlap below the bar)",
    DEGENERATE: "the maps are related by a squashing transform (det R far from 1), not a rigid move",
}
# Heights a registration accepts: a gel shows about 1 mm and a tactile map is a few mm deep; a map
# beyond +-50 mm is not a gel surface (and would overflow the float32 statistics).
MAX_ABS_HEIGHT_MM = 50.0
# Li's confidence is computed on the inliers within this residual (px) of the rigid fit.
CONFIDENCE_PX = 2.0
# A keypoint answer with fewer RANSAC inliers than this and a dense NCC below WEAK_CONSENSUS_NCC must
# also pass the patch agreement of the dense search (search_min_patches): 8-15 inliers lined up
# unrelated ball-press tiles (6 of 960 pairs, NCC 0.84-0.98), while the USB re-touches the fast path
# localizes carry 25-120 and a small touch on a tactile map (too few patches to count) reads 0.999.
WEAK_CONSENSUS_INLIERS = 20
WEAK_CONSENSUS_NCC = 0.98


@dataclass
class RegistrationResult:
    """Outcome of a registration; ``ok=False`` means refused (``matrix_mm`` None, ``reason`` set)."""

    ok: bool
    matrix_mm: np.ndarray | None
    rotation_deg: float
    translation_mm: np.ndarray
    confidence: float
    inliers: int
    method: str
    reason: str | None = None
    matrix_px: np.ndarray | None = None
    matches: int = 0
    ncc: float = float("nan")

    def error(self) -> PerceptionError | None:
        """The typed error of a refusal (None when ok): :class:`~tactile_rig.core.errors.NoContact`
        for a flat map, :class:`DegenerateTransform` for a squashed one, else a
        :class:`PerceptionError` naming the reason."""
        if self.ok:
            return None
        text = REASONS.get(self.reason or "", self.reason or "refused")
        msg = f"registration refused ({self.reason}): {text}; confidence {self.confidence:.3f}, inliers {self.inliers}"
        cls = {NO_CONTACT: NoContact, DEGENERATE: DegenerateTransform}.get(self.reason or "", PerceptionError)
        return cls(msg, device="gelsight.registration", value=self.confidence)

    def as_dict(self) -> dict:
        """JSON-friendly summary (lists, floats, None)."""
        return {"ok": self.ok,
                "matrix_mm": None if self.matrix_mm is None else np.asarray(self.matrix_mm).tolist(),
                "rotation_deg": self.rotation_deg, "translation_mm": np.asarray(self.translation_mm).tolist(),
                "confidence": self.confidence, "inliers": self.inliers, "method": self.method,
                "reason": self.reason, "matches": self.matches, "ncc": self.ncc}


@dataclass(frozen=True)
class RegistrationParams:
    """Knobs (measured in docs/gelsight.md).

    detector: "brisk", "orb" or "both" (keypoints of both pooled); brisk_threshold / orb_features:
    detector sensitivity; orb_levels / orb_scale / orb_fast_threshold: ORB pyramid levels, scale step
    between them and FAST threshold (fewer levels or a higher threshold detect faster but refuse more
    independent touches, see docs/gelsight.md); detect_scale: keypoints are found on the map resized by this factor (the
    dense polish restores full-resolution accuracy); None picks the factor that makes the short side
    ``detect_short_px``; band_px: (fine, coarse) Gaussian sigmas of the band-pass rendering;
    ransac_iters: two-pair samples; inlier_px: RANSAC residual threshold; min_inliers: fewer is a
    refusal of the keypoint answer; min_confidence: the paper's c below this is refused (the tactile
    map accepts at 0.98); min_ncc: the dense check, normalised correlation of the two touches' heights
    on A's samples after the polish (of the high-passed heights when dense_highpass_px > 0: a wrong
    pose reads ~0 there, a right one 0.7-0.99); dense_fallback: try the dense search
    when keypoints fail; refine: Gauss–Newton polish on dense_samples steep pixels (sub-pixel);
    max_sigma_rot_deg / max_sigma_px: refuse when the dense fit cannot pin rotation/translation
    (1-sigma from the Gauss-Newton information and the residual); min_rotation_pinning: refuse
    rotation-symmetric content (rotation information over translation information x radius^2: a
    lone smooth dome reads 0.01-0.02, one real press with gel texture 0.14-0.2, texture ~1);
    dense_highpass_px: the polish compares heights minus their low-pass of this sigma (0: plain
    heights), which removes the press-depth and integration differences of independent re-touches
    (on plain heights they biased the plate's re-touches by up to 2.3 px, with 6 px at most 1.4);
    dense_gain: the polish also fits a height gain between the touches (a deeper press);
    dense_bias_order: the height difference between the touches the polish allows: 0 a constant, 1 a
    plane, 2 a quadratic surface (the bowl of a deeper press).

    When keypoints fail and ``dense_fallback`` is on, a global dense search
    (:mod:`~tactile_rig.perception.gelsight.dense_search`) runs on high-passed heights:
    search_highpass_px: sigma (px) of the low-pass removed from both maps for the search and its
    polish (the press bowl and the depth's gain go, the relief stays); search_coarse_px: the search
    runs on maps reduced by this factor (full px per coarse px); search_step_deg: rotation step of
    the sweep over the full circle; search_candidates: best poses (local maxima over rotation)
    polished and checked; search_min_explained: the share of A's high-passed relief the polished
    pose explains (NCC^2 x overlap) below this is refused (a floor: right plate re-touches explain
    0.45-0.9); search_patch_px / search_min_patches: the evidence a pose needs, the overlap's square
    patches of this side that carry relief and agree at the pose
    (:func:`~tactile_rig.perception.gelsight.dense_search.agreeing_patches`: local evidence spread over
    the overlap, which a rigid move cannot line up by chance: right re-touches agree on 24 or more,
    the best wrong pose of 1,720 pairs that must be refused on at most 20; the usb panel's turned twin
    agrees on up to 35 but fails the pinning bars, its translation 1-sigma >= 0.39 px); asked of every
    search answer and of a keypoint answer with a thin consensus (fewer than WEAK_CONSENSUS_INLIERS
    inliers and a dense NCC under WEAK_CONSENSUS_NCC: such answers on plate and usb re-touches agree on
    26 or more, on unrelated tiled ball presses on at most 19); 0 turns the count off;
    search_min_ratio: the pose must agree on this many times more patches than any distinct
    candidate pose, else the content is ambiguous (blobs and domes fit several poses; the usb's
    right poses agree on >= 1.53x their turned twin);
    search_min_support: at least this many of the keypoint matches must agree with the pose within
    inlier_px (0 by default: a right re-touch that keypoints failed on keeps 1-3 of them, a wrong
    pose of tiled domes up to 15). A search answer must also pass min_overlap and the pinning bars,
    with search_max_sigma_px (0.375 px) in place of max_sigma_px: a search pose has also won the patch count
    and the uniqueness ratio, so its translation bar only has to keep out content that cannot pin
    and a turned twin whose right pose is not among the candidates. Its 1-sigma comes from the
    residual, which grows with how differently two touches were pressed: right plate re-touches
    read up to 0.355 px (a 0.66 mm deep press at the widest gel blur), the usb's turned twin (the
    only wrong pose agreeing on search_min_patches) 0.393 px or more (re-touch seeds 0-5).
    """

    detector: str = "orb"
    brisk_threshold: int = 20
    brisk_octaves: int = 3
    orb_features: int = 300
    orb_levels: int = 6
    orb_scale: float = 1.2
    orb_fast_threshold: int = 5
    detect_scale: float | None = None
    detect_short_px: int = 120
    band_px: tuple[float, float] = (0.0, 4.0)
    ransac_iters: int = 256
    inlier_px: float = 4.0
    min_inliers: int = 8
    min_confidence: float = 0.9
    min_ncc: float = 0.6
    min_overlap: float = 0.2
    dense_fallback: bool = True
    refine: bool = True
    dense_samples: int = 2000
    refine_iters: int = 5
    max_sigma_rot_deg: float = 0.25
    max_sigma_px: float = 0.25
    min_rotation_pinning: float = 0.05
    dense_highpass_px: float = 6.0
    dense_gain: bool = True
    dense_bias_order: int = 2
    search_highpass_px: float = 8.0
    search_coarse_px: int = 8
    search_step_deg: float = 6.0
    search_candidates: int = 5
    search_min_explained: float = 0.3
    search_min_ratio: float = 1.5
    search_min_support: int = 0
    search_patch_px: int = 24
    search_min_patches: int = 23
    search_max_sigma_px: float = 0.375
    seed: int = 0

    def __post_init__(self) -> None:
        if self.detector not in ("brisk", "orb", "both"):
            raise ValueError(f"detector must be 'brisk', 'orb' or 'both', got {self.detector!r}")
        if self.detect_scale is not None and not 0.1 <= self.detect_scale <= 4.0:
            raise ValueError(f"detect_scale must be None (auto) or in [0.1, 4], got {self.detect_scale!r}")
        if self.ransac_iters < 1 or self.min_inliers < 2:
            raise ValueError(
                f"ransac_iters={self.ransac_iters!r} must be >= 1 and min_inliers={self.min_inliers!r} must be >= 2"
            )
        search_ranges = {"search_highpass_px": (0.5, 256.0), "search_coarse_px": (1, 64), "search_step_deg": (0.1, 45.0),
                         "search_candidates": (1, 32), "search_min_explained": (0.0, 1.0),
                         "search_min_ratio": (1.0, 1e6), "search_min_support": (0, 1_000_000),
                         "search_patch_px": (4, 4096), "search_min_patches": (0, 1_000_000),
                         "search_max_sigma_px": (0.0, 1e4)}
        for name, (lo, hi) in search_ranges.items():
            value = getattr(self, name)
            if not lo <= value <= hi:  # also refuses NaN
                raise ValueError(f"{name} must be in [{lo:g}, {hi:g}], got {value!r}")
        if self.orb_levels < 1 or not self.orb_scale > 1.0 or self.orb_fast_threshold < 0:
            raise ValueError(f"orb_levels must be >= 1, orb_scale > 1 and orb_fast_threshold >= 0, got "
                             f"{self.orb_levels!r}, {self.orb_scale!r}, {self.orb_fast_threshold!r}")


_DETECTORS: dict[tuple, cv2.Feature2D] = {}


def _detector(name: str, params: "RegistrationParams") -> cv2.Feature2D:
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


def _check_height(h: object, name: str) -> np.ndarray:
    """A height map as float32: 2-D, >= 16x16, real; non-finite pixels (unknown) read 0 mm; heights
    beyond +-MAX_ABS_HEIGHT_MM raise :class:`HeightOutOfRange`."""
    return _check_height_valid(h, name)[0]


def _check_height_valid(h: object, name: str) -> tuple[np.ndarray, np.ndarray | None]:
    """:func:`_check_height` and the mask of known (finite) pixels, None when all are known."""
    z, valid, _ = _check_height_ptp(h, name)
    return z, valid


def _check_height_ptp(h: object, name: str) -> tuple[np.ndarray, np.ndarray | None, float]:
    """:func:`_check_height_valid` and the map's range (mm), from the one min/max pass the check
    makes anyway."""
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
    out = img.astype(np.uint8)  # truncation, as the 8-bit rendering always was
    if valid is not None:
        out[~valid] = 128
    return out


@dataclass
class Features:
    """Keypoint positions (N, 2) px and binary descriptors per detector, of one height map, with
    the checked float32 map itself (``height``) and its range (``ptp_mm``): :func:`register` given
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


def detect_scale(params: "RegistrationParams", touch_shape: tuple[int, int]) -> float:
    """Resize factor for keypoint detection; both maps of a pair must use the same (the touch's)."""
    if params.detect_scale:
        return float(params.detect_scale)
    return float(np.clip(params.detect_short_px / min(touch_shape), 0.25, 2.0))


def extract_features(height_mm: np.ndarray, params: RegistrationParams = RegistrationParams(),
                     dense: bool = True, scale: float | None = None, valid: np.ndarray | None = None) -> Features:
    """Keypoints and descriptors of a height map (reuse for a map matched many times); with
    ``dense`` also the steep-pixel samples used when this map is the reference A. scale: detection
    resize factor (default from this map's own shape; pass the touch's for a large map)."""
    z, known, ptp_mm = _check_height_ptp(height_mm, "height_mm")
    if known is not None:
        valid = known if valid is None else (valid & known)
    return _features(z, ptp_mm, params, dense, scale, valid)


def _features(z: np.ndarray, ptp_mm: float, params: RegistrationParams, dense: bool, scale: float | None,
              valid: np.ndarray | None) -> Features:
    """:func:`extract_features` of a map already checked (float32, finite) whose range is ``ptp_mm``."""
    feats = _prepare(z, ptp_mm, params, dense, scale, valid)
    _detect(feats, params)
    return feats


def _prepare(z: np.ndarray, ptp_mm: float, params: RegistrationParams, dense: bool, scale: float | None,
             valid: np.ndarray | None) -> Features:
    """:func:`_features` up to the keypoints: the polish's heights, A's samples and the 8-bit image."""
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


def _detect(feats: Features, params: RegistrationParams) -> None:
    """Keypoints and descriptors of a prepared map's 8-bit image, into ``feats``."""
    img, k = feats.image, feats.scale
    if img is None:  # an assert would vanish under python -O
        raise ValueError("gelsight.registration: features without their 8-bit image; _prepare them first")
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


def _match(fa: Features, fb: Features) -> tuple[np.ndarray, np.ndarray]:
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


_RANSAC_BLOCK = 64


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
    # Central differences on the even grid (as _grad, whose slopes are half the neighbour difference).
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


def _grad(z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Central-difference slopes per pixel (x, y) as float32."""
    gx = cv2.Sobel(z, cv2.CV_32F, 1, 0, ksize=1, scale=0.5, borderType=cv2.BORDER_REPLICATE)
    gy = cv2.Sobel(z, cv2.CV_32F, 0, 1, ksize=1, scale=0.5, borderType=cv2.BORDER_REPLICATE)
    return gx, gy


# Points per row of the map handed to cv2.remap (which refuses a side of 32767 or more).
_REMAP_ROW = 8192


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
# The Gauss–Newton steps stop once a step moves the samples by less than this (px). Going on to a
# hundredth of a pixel (the earlier setting) cost ~3 % of a fresh pair's time and changed no answer
# (re-touch seeds 0-2 and every pair that must be refused; seed 0's mean errors moved by < 0.001 deg).
STOP_STEP_PX = CONVERGED_STEP_PX
# A's samples are taken this far (px) inside its border.
DENSE_MARGIN_PX = 2
# Samples that land within this many px of B's border are left out of the polish: a high-pass (and
# the Poisson integration) distorts heights next to a border, and a re-touch shifted by a few mm puts
# B's border over A's interior, where that distortion pulled the fit by 2-4 px.
B_MARGIN_PX = 8.0


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
    an independent re-touch (another depth, blur and gain) the B-only Jacobian overshot and the steps
    alternated in sign, shrinking by ~0.8 a step, so a right pose could stop short of the
    convergence bar; with the mean the same pose settles in one call."""
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


def dense_refine(fa: "Features", smooth_b: np.ndarray, matrix_px: np.ndarray, iters: int = 5,
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
        # Samples lie >= 2 px inside A (DENSE_MARGIN_PX): their neighbours exist.
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


# Two poses are the same answer when they differ by less than this (deg, px at B's centre).
SAME_POSE_DEG = 2.0
SAME_POSE_PX = 3.0


def _same_pose(m: np.ndarray, n: np.ndarray, centre: np.ndarray) -> bool:
    d_rot = abs(float(np.degrees(np.arctan2(m[1, 0], m[0, 0]) - np.arctan2(n[1, 0], n[0, 0])))) % 360.0
    d_px = float(np.linalg.norm((m[:, :2] - n[:, :2]) @ centre + m[:, 2] - n[:, 2]))
    return min(d_rot, 360.0 - d_rot) <= SAME_POSE_DEG and d_px <= SAME_POSE_PX


def _search_bars(fit: DenseFit, params: RegistrationParams) -> bool:
    """A search pose, polished: it explains search_min_explained of A's relief (NCC^2 x overlap),
    passes min_overlap and pins the pose."""
    explained = fit.ncc * fit.ncc * fit.overlap if fit.ncc > 0.0 else 0.0
    return bool(explained >= params.search_min_explained and fit.overlap >= params.min_overlap
                and _pinned(fit, params, params.search_max_sigma_px))


def _dense_search(a: np.ndarray, b: np.ndarray, fa: Features, fb: Features, pa: np.ndarray, pb: np.ndarray,
                  params: RegistrationParams) -> tuple[DenseFit | None, float]:
    """The answer when keypoints fail: :func:`~tactile_rig.perception.gelsight.dense_search.rotation_search`
    on high-passed heights, each candidate polished by :func:`dense_refine` (fa's samples, fb's
    heights, as the keypoint answer's). A polished pose is acceptable when it passes
    search_min_explained, min_overlap and the pinning bars and agrees on search_min_patches patches
    (:func:`~tactile_rig.perception.gelsight.dense_search.agreeing_patches`); the one agreeing on
    most is accepted only when it agrees on search_min_ratio times more patches than any distinct
    candidate (content that fits several poses is ambiguous: blobs, domes) and at least
    search_min_support of the keypoint matches (pa in A, pb in B) lie within inlier_px of it.
    Returns (accepted fit or None, the best polished NCC)."""
    found = rotation_search(
        a, b, highpass_px=params.search_highpass_px, coarse_px=params.search_coarse_px,
        step_deg=params.search_step_deg, max_candidates=params.search_candidates,
        valid_a=fa.valid, valid_b=fb.valid)
    fits = [dense_refine(fa, fb.smooth, c.matrix_px, params.refine_iters if params.refine else 0,  # type: ignore[arg-type]
                         gain_fit=params.dense_gain, valid_b=fb.valid, bias_order=params.dense_bias_order)
            for c in found.candidates]
    fits = [f for f in fits if np.isfinite(f.ncc) and not f.wandered]
    if not fits:
        return None, float("nan")
    best_ncc = max(f.ncc for f in fits)
    # Evidence per pose: the patches of the overlap that carry relief and agree (0 for a pose
    # overlapping too little to count).
    agree = [agreeing_patches(fa.smooth, fb.smooth, f.matrix_px, params.search_patch_px, fa.valid, fb.valid)  # type: ignore[arg-type]
             if f.overlap >= params.min_overlap else 0 for f in fits]
    passed = [i for i, f in enumerate(fits) if agree[i] >= params.search_min_patches and _search_bars(f, params)]
    if not passed:
        return None, best_ncc
    i_top = max(passed, key=lambda i: (agree[i], fits[i].ncc))
    top = fits[i_top]
    centre_b = np.array([(b.shape[1] - 1) / 2.0, (b.shape[0] - 1) / 2.0])
    for j, other in enumerate(fits):
        if j == i_top or _same_pose(other.matrix_px, top.matrix_px, centre_b):
            continue
        if agree[i_top] < params.search_min_ratio * agree[j]:
            return None, best_ncc  # another pose is backed by nearly as much evidence: ambiguous content
    if params.search_min_support > 0:
        if len(pa):
            res = pb @ top.matrix_px[:, :2].T + top.matrix_px[:, 2] - pa
            support = int(np.count_nonzero(np.einsum("ij,ij->i", res, res) < params.inlier_px ** 2))
        else:
            support = 0
        if support < params.search_min_support:
            return None, best_ncc
    return top, top.ncc


def _pinned(fit: DenseFit, params: RegistrationParams, max_sigma_px: float | None = None) -> bool:
    """The dense fit pins the pose: it converged (did not wander, last step small), small 1-sigma
    errors and content that is not rotation-symmetric."""
    bar_px = params.max_sigma_px if max_sigma_px is None else max_sigma_px
    return (fit.converged and fit.sigma_rot_deg <= params.max_sigma_rot_deg and fit.sigma_px <= bar_px
            and fit.rotation_pinning >= params.min_rotation_pinning)


def _result(ok: bool, m_px: np.ndarray | None, shape_a: tuple[int, int], shape_b: tuple[int, int],
            mm_per_px: tuple[float, float], conf: float, inliers: int, method: str, reason: str | None,
            matches: int, ncc: float) -> RegistrationResult:
    if not ok or m_px is None:
        return RegistrationResult(False, None, float("nan"), np.full(2, np.nan), float(conf), int(inliers),
                                  method, reason, None, matches, ncc)
    sx, sy = mm_per_px
    s = np.diag([sx, sy])
    s_inv = np.diag([1.0 / sx, 1.0 / sy])
    ca = np.array([(shape_a[1] - 1) / 2.0, (shape_a[0] - 1) / 2.0])
    cb = np.array([(shape_b[1] - 1) / 2.0, (shape_b[0] - 1) / 2.0])
    r = m_px[:, :2]
    t = m_px[:, 2]
    r_mm = s @ r @ s_inv
    t_mm = s @ (r @ cb + t - ca)
    mat = np.hstack([r_mm, t_mm[:, None]])
    rot = float(np.degrees(np.arctan2(r[1, 0], r[0, 0])))
    return RegistrationResult(True, mat, rot, t_mm, float(conf), int(inliers), method, None, m_px, matches, ncc)


def register(height_a_mm: np.ndarray, height_b_mm: np.ndarray, mm_per_px: float | tuple[float, float],
             params: RegistrationParams | None = None, features_a: Features | None = None,
             **knobs: object) -> RegistrationResult:
    """Register height map B (mm) onto height map A (mm): the rigid transform taking B into A.

    mm_per_px: scalar or (x, y) pixel pitch. features_a: precomputed :func:`extract_features` of A
    (a map matched many times). Knobs override :class:`RegistrationParams` fields.

    Valid input: 2-D real maps of at least 16x16 pixels with heights within +-50 mm (non-finite
    pixels read 0 mm); any rotation (+-180 deg) and any overlap. Otherwise ``ValueError`` (shape,
    dtype, pitch) or :class:`~tactile_rig.core.errors.HeightOutOfRange`. The answer is either a rigid
    transform (``ok``; det R = 1, rotation in (-180, 180] deg) or a refusal with a ``reason`` from
    :data:`REASONS` (``no_contact`` for a flat map, ``degenerate_transform`` for a squashed one, ...);
    ``result.error()`` gives the matching typed exception.
    """
    if params is None:
        params = RegistrationParams(**knobs)  # type: ignore[arg-type]
    elif knobs:
        raise ValueError("pass either params or individual knobs, not both")
    cached = features_a is not None and features_a.height is height_a_mm
    # Non-finite pixels read 0 mm here (as documented): the checked maps go on without a known mask.
    if cached:
        a, ptp_a = height_a_mm, features_a.ptp_mm  # type: ignore[union-attr]
    else:
        a, _, ptp_a = _check_height_ptp(height_a_mm, "height_a_mm")
    b, _, ptp_b = _check_height_ptp(height_b_mm, "height_b_mm")
    scale = (float(mm_per_px), float(mm_per_px)) if np.isscalar(mm_per_px) else tuple(map(float, mm_per_px))  # type: ignore[arg-type]
    if not all(np.isfinite(v) and v > 0 for v in scale):
        raise ValueError(f"mm_per_px must be positive, got {mm_per_px!r}")
    shapes = (a.shape, b.shape)

    def refuse(reason: str, method: str, conf: float = 0.0, inl: int = 0, matches: int = 0,
               ncc: float = float("nan")) -> RegistrationResult:
        return _result(False, None, *shapes, scale, conf, inl, method, reason, matches, ncc)  # type: ignore[arg-type]

    # A (near) flat map has nothing to register against.
    if ptp_a < 1e-6 or ptp_b < 1e-6:
        return refuse(NO_CONTACT, "none")
    k = detect_scale(params, b.shape)
    if features_a is not None and features_a.scale == k:
        fa = features_a
        fb = _features(b, ptp_b, params, False, k, None)
    else:
        # Both maps prepared, then both detected: the detector's two calls back to back find its code
        # and buffers warm (~0.09 ms a fresh pair).
        fa, fb = _prepare(a, ptp_a, params, True, k, None), _prepare(b, ptp_b, params, False, k, None)
        _detect(fa, params)
        _detect(fb, params)
    pa, pb = _match(fa, fb)
    method = params.detector
    keypoint_reason = INSUFFICIENT_TEXTURE
    conf, n_inl = 0.0, 0
    if len(pa) >= params.min_inliers:
        m, mask = ransac_rigid(pb, pa, params.ransac_iters, params.inlier_px, params.seed)
        n_inl = int(mask.sum())
        if m is not None and n_inl >= params.min_inliers:
            # Li's c on the inliers the rigid fit explains within 2 px: a looser consensus tolerance
            # (independent touches move keypoints by a few px) must not dilute the homography test.
            res = pb[mask] @ m[:, :2].T + m[:, 2] - pa[mask]
            tight = np.einsum("ij,ij->i", res, res) < min(params.inlier_px, CONFIDENCE_PX) ** 2
            sub = np.flatnonzero(mask)[tight] if tight.sum() >= params.min_inliers else np.flatnonzero(mask)
            conf = homography_confidence(pb[sub], pa[sub])
            if conf >= params.min_confidence:
                fit = dense_refine(fa, fb.smooth, m, params.refine_iters if params.refine else 0,  # type: ignore[arg-type]
                               gain_fit=params.dense_gain, valid_b=fb.valid,
                                   bias_order=params.dense_bias_order)
                if fit.ncc >= params.min_ncc and fit.overlap >= params.min_overlap:
                    if _pinned(fit, params):
                        # A thin consensus (a handful of inliers) can line up two unrelated domes: it
                        # must also agree patch by patch, as a dense-search pose must.
                        if (n_inl >= WEAK_CONSENSUS_INLIERS or fit.ncc >= WEAK_CONSENSUS_NCC
                                or params.search_min_patches <= 0
                                or agreeing_patches(fa.smooth, fb.smooth, fit.matrix_px, params.search_patch_px,  # type: ignore[arg-type]
                                                    fa.valid, fb.valid) >= params.search_min_patches):
                            return _result(True, fit.matrix_px, *shapes, scale, conf, n_inl, method, None,  # type: ignore[arg-type]
                                           len(pa), fit.ncc)
                        keypoint_reason = MISMATCH
                    else:
                        keypoint_reason = INSUFFICIENT_TEXTURE
                else:
                    keypoint_reason = MISMATCH
            else:
                keypoint_reason = LOW_CONFIDENCE
        else:
            keypoint_reason = NO_CONSENSUS
    ncc = float("nan")
    if params.dense_fallback:
        fit_s, ncc = _dense_search(a, b, fa, fb, pa, pb, params)
        if fit_s is not None:
            return _result(True, fit_s.matrix_px, *shapes, scale, 1.0, 0, "dense_search", None,  # type: ignore[arg-type]
                           len(pa), fit_s.ncc)
        method += "+dense"
        if keypoint_reason == NO_CONSENSUS:
            keypoint_reason = INSUFFICIENT_TEXTURE
    # Refused: name a squashing transform as such (only on this path, so it costs a success nothing).
    if _squashed(fa, fb, pa, pb, params):
        keypoint_reason = DEGENERATE
    return refuse(keypoint_reason, method, conf, n_inl, len(pa), ncc)


# B's gradient structure differs from A's by more than this factor in its eigenvalue ratio: a rigid
# move keeps that ratio (up to the content that enters or leaves the overlap), a squash by s in one
# direction scales it by up to s^2 (4 flags s < ~0.45 on the tiled real presses, whose rigid moves
# keep it within 0.76-0.84).
SQUASH_ANISOTROPY_FACTOR = 4.0


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


def _squashed(fa: Features, fb: Features, pa: np.ndarray, pb: np.ndarray, params: RegistrationParams) -> bool:
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
