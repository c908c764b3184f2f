"""The knobs of a height-map registration (:func:`~tactile_rig.perception.gelsight.registration.register`).

One frozen dataclass shared by the features, the rigid fit, the dense polish and the dense search.
Each field says what it sets, its unit and why its default; the measurements behind the defaults
(with the commands that regenerate them) are in docs/gelsight.md, "Registration parameters".
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class RegistrationParams:
    """Speed and refusal knobs of a registration; the defaults are the measured ones."""

    detector: str = "orb"
    """Keypoint detector: ``"orb"``, ``"brisk"`` or ``"both"`` (keypoints of both pooled); ORB places
    as many re-touches as BRISK at several times its speed."""
    brisk_threshold: int = 20
    """BRISK's FAST score threshold (grey levels of the 8-bit rendering); lower finds more keypoints."""
    brisk_octaves: int = 3
    """BRISK's scale-space octaves."""
    orb_features: int = 300
    """ORB keypoints per touch-sized area (a larger map gets proportionally more); with fewer the
    plate's keypoint path fails more often and the slower dense search takes over."""
    orb_levels: int = 6
    """ORB pyramid levels (the detector's scale-space depth); fewer detect faster."""
    orb_scale: float = 1.2
    """Scale step between ORB pyramid levels (> 1)."""
    orb_fast_threshold: int = 5
    """ORB's FAST threshold (grey levels of the rendering); higher finds fewer keypoints, faster."""
    detect_scale: float | None = None
    """Resize factor of the maps for detection (0.1-4); None picks the factor that makes the touch's
    short side ``detect_short_px`` (the dense polish restores full-resolution accuracy)."""
    detect_short_px: int = 120
    """Short side (px) of a touch resized for detection when ``detect_scale`` is None: 96 halves the
    detail of a 120x160 touch, more costs time and places nothing more."""
    band_px: tuple[float, float] = (0.0, 4.0)
    """(fine, coarse) Gaussian sigmas (px) of the band-pass rendering the keypoints are found on:
    it turns a smooth dome into a ring that FAST-style detectors fire on."""
    ransac_iters: int = 256
    """Most two-pair RANSAC samples (scoring stops early once the consensus is clear)."""
    inlier_px: float = 4.0
    """RANSAC residual (px) of an inlier: keypoints of an independent re-touch move by a few px, so at
    2 px the keypoint path fails more often and the slower dense search takes over."""
    min_inliers: int = 8
    """Fewest RANSAC inliers (>= 2) of a keypoint answer; fewer is a refusal of that answer."""
    min_confidence: float = 0.9
    """Li's confidence c (det of the inliers' homography) below this is refused (the tactile map
    accepts a touch at 0.98, the paper's value)."""
    min_ncc: float = 0.6
    """Dense check: normalised correlation of the two touches' high-passed heights on A's samples
    after the polish; a wrong pose reads about 0 there, a right one 0.7-0.99."""
    min_overlap: float = 0.2
    """Smallest share of A's dense samples that B covers at the answer."""
    dense_fallback: bool = True
    """Run the dense search when keypoints fail (False: refuse instead); it places the plate's
    re-touches that share too few keypoints with the map."""
    refine: bool = True
    """Gauss–Newton polish of the pose on A's steep pixels (sub-pixel); without it a keypoint pose
    is several tenths of a pixel off and many answers are confidently wrong."""
    dense_samples: int = 2000
    """Steep pixels of A the polish compares (the steepest quarter, thinned to this many)."""
    refine_iters: int = 5
    """Gauss–Newton steps per call of the polish (it is called again while it has not settled)."""
    max_sigma_rot_deg: float = 0.25
    """Refuse when the polish's 1-sigma rotation (deg, from its information and residual) is larger:
    the content does not pin the rotation."""
    max_sigma_px: float = 0.25
    """Refuse a keypoint answer whose polish's 1-sigma translation (px) is larger."""
    min_rotation_pinning: float = 0.05
    """Refuse rotation-symmetric content: rotation over translation information x radius² (a lone
    smooth dome reads 0.01-0.02, one real press with gel texture 0.14-0.2, texture about 1)."""
    dense_highpass_px: float = 6.0
    """Sigma (px) of the low-pass the polish removes from both maps (0: plain heights): it removes
    the press-depth and integration differences of independent re-touches, which bias plain heights
    by pixels."""
    dense_gain: bool = True
    """The polish also fits a height gain (0.5-2) between the touches: a deeper press shows its
    relief a little higher."""
    dense_bias_order: int = 2
    """Height difference the polish allows between the touches: 0 a constant, 1 a plane, 2 a
    quadratic surface (the bowl of a deeper press)."""
    search_highpass_px: float = 8.0
    """Sigma (px) of the low-pass removed from both maps for the dense search and its polish: the
    press bowl and the depth's gain go, the relief stays."""
    search_coarse_px: int = 8
    """The dense search runs on the maps area-reduced by this factor (full px per coarse px)."""
    search_step_deg: float = 6.0
    """Rotation step (deg) of the dense search's sweep over the full circle."""
    search_candidates: int = 5
    """Best poses of the dense search (local maxima over rotation) polished and checked."""
    search_min_explained: float = 0.3
    """Share of A's high-passed relief a search pose explains (NCC² x overlap) below which it is
    refused: a floor under the right re-touches' 0.45-0.9."""
    search_min_ratio: float = 1.5
    """A search pose must agree on this many times more patches than any distinct candidate, else
    the content is ambiguous (blobs and domes fit several poses)."""
    search_min_support: int = 0
    """Keypoint matches that must lie within ``inlier_px`` of a search pose (0: not asked; a re-touch
    that keypoints failed on keeps too few true matches for the count to separate right from wrong)."""
    search_patch_px: int = 24
    """Side (px) of the square patches whose agreement counts as evidence for a pose."""
    search_min_patches: int = 23
    """Patches of the overlap that carry relief and agree at the pose
    (:func:`~tactile_rig.perception.gelsight.dense_search.agreeing_patches`), asked of every search
    answer and of a keypoint answer with a thin consensus; right re-touches agree on 24 or more,
    wrong poses on at most 20 (0 turns the count off)."""
    search_max_sigma_px: float = 0.375
    """The translation 1-sigma bar (px) of a dense-search pose, in place of ``max_sigma_px``: such a
    pose has also won the patch count and the uniqueness ratio, so this bar only keeps out content
    that cannot pin and a turned twin whose right pose is not among the candidates."""
    seed: int = 0
    """Seed of the RANSAC samples: the same inputs give the same answer."""

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
