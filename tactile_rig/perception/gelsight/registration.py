"""Height map vs height map -> 2-D isometry (Li et al. 2014), honest about when it does not know.

:func:`register` runs named steps, each in its own module:

1. check both maps and refuse a flat one (:mod:`~tactile_rig.perception.gelsight.features`);
2. features: band-passed 8-bit renderings, ORB/BRISK keypoints, cross-checked Hamming matches, A's
   dense samples (:mod:`~tactile_rig.perception.gelsight.features`);
3. the keypoint answer: two-pair RANSAC, Li's confidence c = max(1 - |1 - det R|, 0)
   (:mod:`~tactile_rig.perception.gelsight.rigid_fit`), then the Gauss–Newton polish and its dense
   checks (:mod:`~tactile_rig.perception.gelsight.dense_refinement`);
4. when keypoints fail, the dense search (:mod:`~tactile_rig.perception.gelsight.dense_search`:
   masked correlation of high-passed heights over every rotation and shift), its candidates polished
   and held to the evidence bars;
5. otherwise a refusal (``ok=False`` with a ``reason``) rather than a confident wrong answer.

This module is the registration's public face: the names of the step modules that users and the
tactile map need are importable from here too. Frames: a point of B in mm from B's centre (x right,
y down) maps into A's frame (mm from A's centre) by ``matrix_mm``; ``matrix_px`` does the same in
pixel (column, row) coordinates.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tactile_rig.core.errors import DegenerateTransform, NoContact, PerceptionError
from tactile_rig.perception.gelsight.dense_refinement import (
    B_MARGIN_PX,
    COARSE_SIGMA_PX,
    CONVERGED_STEP_PX,
    STOP_STEP_PX,
    WANDER_DEG,
    WANDER_PX,
    DenseFit,
    dense_refine,
    overlap_ncc,
    pose_pinned,
)
from tactile_rig.perception.gelsight.dense_search import agreeing_patches, rotation_search
from tactile_rig.perception.gelsight.features import (
    DENSE_MARGIN_PX,
    MAX_ABS_HEIGHT_MM,
    Features,
    check_height,
    check_height_ptp,
    detect_keypoints,
    detect_scale,
    extract_features,
    hamming_cross_matches,
    match_features,
    prepare_features,
    render_u8,
)
from tactile_rig.perception.gelsight.registration_params import RegistrationParams
from tactile_rig.perception.gelsight.rigid_fit import (
    CONFIDENCE_PX,
    SQUASH_ANISOTROPY_FACTOR,
    fit_confidence,
    homography_confidence,
    looks_squashed,
    ransac_rigid,
    rigid_fit,
)

__all__ = [
    "B_MARGIN_PX", "COARSE_SIGMA_PX", "CONFIDENCE_PX", "CONVERGED_STEP_PX", "DEGENERATE", "DENSE_MARGIN_PX",
    "INSUFFICIENT_TEXTURE", "LOW_CONFIDENCE", "MAX_ABS_HEIGHT_MM", "MISMATCH", "NO_CONSENSUS", "NO_CONTACT",
    "REASONS", "SAME_POSE_DEG", "SAME_POSE_PX", "SQUASH_ANISOTROPY_FACTOR", "STOP_STEP_PX", "WANDER_DEG",
    "WANDER_PX", "WEAK_CONSENSUS_INLIERS", "WEAK_CONSENSUS_NCC", "DenseFit", "Features", "RegistrationParams",
    "RegistrationResult", "check_height", "dense_refine", "detect_scale", "extract_features",
    "hamming_cross_matches", "homography_confidence", "overlap_ncc", "pose_pinned", "ransac_rigid", "register",
    "render_u8", "rigid_fit",
]

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
# A keypoint answer with fewer RANSAC inliers than this and a dense NCC below WEAK_CONSENSUS_NCC must
# also pass the patch agreement of the dense search (search_min_patches): a thin consensus can line
# up two unrelated domes (docs/gelsight.md, "Registration parameters").
WEAK_CONSENSUS_INLIERS = 20
WEAK_CONSENSUS_NCC = 0.98
# Two poses are the same answer when they differ by less than this (deg, px at B's centre).
SAME_POSE_DEG = 2.0
SAME_POSE_PX = 3.0


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


    @classmethod
    def placed(cls, matrix_px: np.ndarray, shape_a: tuple[int, ...], shape_b: tuple[int, ...],
               mm_per_px: tuple[float, float], *, confidence: float, inliers: int, method: str, matches: int,
               ncc: float) -> "RegistrationResult":
        """An accepted answer from its B->A ``matrix_px`` (2x3) between maps of ``shape_a`` and
        ``shape_b`` (rows, cols) at ``mm_per_px`` (x, y): ``matrix_mm`` about the maps' centres."""
        sx, sy = mm_per_px
        s = np.diag([sx, sy])
        s_inv = np.diag([1.0 / sx, 1.0 / sy])
        ca = np.array([(shape_a[1] - 1) / 2.0, (shape_a[0] - 1) / 2.0])
        cb = np.array([(shape_b[1] - 1) / 2.0, (shape_b[0] - 1) / 2.0])
        r = matrix_px[:, :2]
        t = matrix_px[:, 2]
        r_mm = s @ r @ s_inv
        t_mm = s @ (r @ cb + t - ca)
        mat = np.hstack([r_mm, t_mm[:, None]])
        rot = float(np.degrees(np.arctan2(r[1, 0], r[0, 0])))
        return cls(True, mat, rot, t_mm, float(confidence), int(inliers), method, None, matrix_px, matches, ncc)

    @classmethod
    def refused(cls, reason: str, method: str, *, confidence: float = 0.0, inliers: int = 0, matches: int = 0,
                ncc: float = float("nan")) -> "RegistrationResult":
        """A refusal: no matrix, ``reason`` (one of :data:`REASONS` for :func:`register`)."""
        return cls(False, None, float("nan"), np.full(2, np.nan), float(confidence), int(inliers), method, reason,
                   None, matches, ncc)


@dataclass
class _KeypointAnswer:
    """What the keypoint path concluded: the polished fit when it is the answer, else the reason it
    refused, with the confidence and inliers it reached on the way."""

    reason: str | None
    confidence: float = 0.0
    inliers: int = 0
    fit: DenseFit | None = None


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
    a, ptp_a, b, ptp_b = _checked_maps(height_a_mm, height_b_mm, features_a)
    pitch = _pitch_xy(mm_per_px)
    shapes = (a.shape, b.shape)
    if ptp_a < 1e-6 or ptp_b < 1e-6:  # a (near) flat map has nothing to register against
        return RegistrationResult.refused(NO_CONTACT, "none")
    fa, fb = _pair_features(a, ptp_a, b, ptp_b, params, features_a)
    pa, pb = match_features(fa, fb)
    kp = _keypoint_answer(fa, fb, pa, pb, params)
    if kp.fit is not None:
        return RegistrationResult.placed(kp.fit.matrix_px, *shapes, pitch, confidence=kp.confidence,
                                         inliers=kp.inliers, method=params.detector, matches=len(pa),
                                         ncc=kp.fit.ncc)
    method, reason, ncc = params.detector, kp.reason or INSUFFICIENT_TEXTURE, float("nan")
    if params.dense_fallback:
        fit_s, ncc = _dense_search(a, b, fa, fb, pa, pb, params)
        if fit_s is not None:
            return RegistrationResult.placed(fit_s.matrix_px, *shapes, pitch, confidence=1.0, inliers=0,
                                             method="dense_search", matches=len(pa), ncc=fit_s.ncc)
        method += "+dense"
        if reason == NO_CONSENSUS:
            reason = INSUFFICIENT_TEXTURE
    # Refused: name a squashing transform as such (only on this path, so it costs a success nothing).
    if looks_squashed(fa, fb, pa, pb, params):
        reason = DEGENERATE
    return RegistrationResult.refused(reason, method, confidence=kp.confidence, inliers=kp.inliers,
                                      matches=len(pa), ncc=ncc)


def _checked_maps(height_a_mm: np.ndarray, height_b_mm: np.ndarray, features_a: Features | None
                  ) -> tuple[np.ndarray, float, np.ndarray, float]:
    """Both maps checked (float32; non-finite pixels read 0 mm, without a known mask) with their
    ranges (mm); A is not checked again when ``features_a`` was made from that very array."""
    if features_a is not None and features_a.height is height_a_mm:
        a, ptp_a = height_a_mm, features_a.ptp_mm
    else:
        a, _, ptp_a = check_height_ptp(height_a_mm, "height_a_mm")
    b, _, ptp_b = check_height_ptp(height_b_mm, "height_b_mm")
    return a, ptp_a, b, ptp_b


def _pitch_xy(mm_per_px: float | tuple[float, float]) -> tuple[float, float]:
    """The pixel pitch (x, y) in mm, refusing a non-positive or non-finite one."""
    pitch = (float(mm_per_px), float(mm_per_px)) if np.isscalar(mm_per_px) else tuple(map(float, mm_per_px))  # type: ignore[arg-type]
    if not all(np.isfinite(v) and v > 0 for v in pitch):
        raise ValueError(f"mm_per_px must be positive, got {mm_per_px!r}")
    return pitch  # type: ignore[return-value]


def _pair_features(a: np.ndarray, ptp_a: float, b: np.ndarray, ptp_b: float, params: RegistrationParams,
                   features_a: Features | None) -> tuple[Features, Features]:
    """A's features (``features_a`` when made at B's detection scale) and B's, at B's scale."""
    k = detect_scale(params, b.shape)
    if features_a is not None and features_a.scale == k:
        fb = prepare_features(b, ptp_b, params, False, k, None)
        detect_keypoints(fb, params)
        return features_a, fb
    # Both maps prepared, then both detected: the detector's two calls back to back find its code
    # and buffers warm (~0.09 ms a fresh pair).
    fa, fb = prepare_features(a, ptp_a, params, True, k, None), prepare_features(b, ptp_b, params, False, k, None)
    detect_keypoints(fa, params)
    detect_keypoints(fb, params)
    return fa, fb


def _keypoint_answer(fa: Features, fb: Features, pa: np.ndarray, pb: np.ndarray,
                     params: RegistrationParams) -> _KeypointAnswer:
    """The keypoint path: RANSAC consensus, Li's confidence, the polish and its dense checks."""
    if len(pa) < params.min_inliers:
        return _KeypointAnswer(INSUFFICIENT_TEXTURE)
    m, mask = ransac_rigid(pb, pa, params.ransac_iters, params.inlier_px, params.seed)
    n_inl = int(mask.sum())
    if m is None or n_inl < params.min_inliers:
        return _KeypointAnswer(NO_CONSENSUS, inliers=n_inl)
    conf = fit_confidence(pb, pa, m, mask, params.inlier_px, params.min_inliers)
    if not conf >= params.min_confidence:
        return _KeypointAnswer(LOW_CONFIDENCE, conf, n_inl)
    fit = dense_refine(fa, fb.smooth, m, params.refine_iters if params.refine else 0,  # type: ignore[arg-type]
                       gain_fit=params.dense_gain, valid_b=fb.valid, bias_order=params.dense_bias_order)
    if not (fit.ncc >= params.min_ncc and fit.overlap >= params.min_overlap):
        return _KeypointAnswer(MISMATCH, conf, n_inl)
    if not pose_pinned(fit, params):
        return _KeypointAnswer(INSUFFICIENT_TEXTURE, conf, n_inl)
    if not _consensus_backed(fa, fb, fit, n_inl, params):
        return _KeypointAnswer(MISMATCH, conf, n_inl)
    return _KeypointAnswer(None, conf, n_inl, fit)


def _consensus_backed(fa: Features, fb: Features, fit: DenseFit, inliers: int, params: RegistrationParams) -> bool:
    """A thin consensus (a handful of inliers, a dense NCC under WEAK_CONSENSUS_NCC) can line up two
    unrelated domes: it must also agree patch by patch, as a dense-search pose must."""
    return bool(inliers >= WEAK_CONSENSUS_INLIERS or fit.ncc >= WEAK_CONSENSUS_NCC
                or params.search_min_patches <= 0
                or agreeing_patches(fa.smooth, fb.smooth, fit.matrix_px, params.search_patch_px,  # type: ignore[arg-type]
                                    fa.valid, fb.valid) >= params.search_min_patches)


def _same_pose(m: np.ndarray, n: np.ndarray, centre: np.ndarray) -> bool:
    """Two B->A poses (2x3 px) are one answer: within SAME_POSE_DEG and SAME_POSE_PX at ``centre``."""
    d_rot = abs(float(np.degrees(np.arctan2(m[1, 0], m[0, 0]) - np.arctan2(n[1, 0], n[0, 0])))) % 360.0
    d_px = float(np.linalg.norm((m[:, :2] - n[:, :2]) @ centre + m[:, 2] - n[:, 2]))
    return min(d_rot, 360.0 - d_rot) <= SAME_POSE_DEG and d_px <= SAME_POSE_PX


def _search_bars(fit: DenseFit, params: RegistrationParams) -> bool:
    """A search pose, polished: it explains search_min_explained of A's relief (NCC^2 x overlap),
    passes min_overlap and pins the pose."""
    explained = fit.ncc * fit.ncc * fit.overlap if fit.ncc > 0.0 else 0.0
    return bool(explained >= params.search_min_explained and fit.overlap >= params.min_overlap
                and pose_pinned(fit, params, params.search_max_sigma_px))


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

