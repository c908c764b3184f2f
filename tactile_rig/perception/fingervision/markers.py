"""FingerVision marker detection: preprocessing, the SimpleBlobDetector chain, sub-pixel centroids, baseline.

Markers are small black dots printed in the clear skin. Behind them the camera sees whatever the
finger holds: dark print, QR codes, debris, reflections. Two cues separate a marker from all that:

* it is *locally* darker than its surroundings by a large *ratio* (a morphological closing with a
  disc a little larger than a marker estimates the local background; the ratio
  ``(background - value) / background`` is invariant to a global light gain, which is what threw off
  the thesis's fixed HSV threshold), and
* it is *absolutely* dark (black ink), while print seen through the skin is grey-to-dark green.

The contrast map goes through OpenCV's SimpleBlobDetector with every filter exposed
(:class:`MarkerDetectorParams`), then a darkness filter, then a sub-pixel refinement by thresholded
moments of the contrast (:func:`refine_centroids`, shared with the tracker).

Units: pixels (x = column, y = row, pixel centres at integer coordinates); ``size_px`` is a diameter.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field

import cv2
import numpy as np

from tactile_rig.core.errors import InvalidFrame

__all__ = [
    "MarkerDetectorParams",
    "ReferenceBlobParams",
    "Detections",
    "MarkerBaseline",
    "contrast_map",
    "detect_markers",
    "detect_markers_reference",
    "refine_centroids",
    "build_baseline",
]


@dataclass(frozen=True)
class MarkerDetectorParams:
    """Every knob of the marker detector, with the defaults used on the real and the rendered frames.

    Contrast thresholds are in contrast units x 255 (the 8-bit contrast image fed to the detector).
    """

    background_kernel_px: int = 15
    """Diameter of the closing disc that estimates the local background; > largest marker diameter."""
    background_square: bool = False
    """Square closing element instead of a disc: ~5x faster closing (saves ~0.3 ms a frame) but a
    little worse on the real frames (at 0.5x light: 8 instead of 4 false positives)."""
    background_floor: float = 40.0
    """Background values below this count as this (keeps the ratio sane on near-black regions)."""
    min_threshold: float = 60.0
    """SimpleBlobDetector first threshold on the contrast image (0..255)."""
    max_threshold: float = 230.0
    """SimpleBlobDetector last threshold."""
    threshold_step: float = 20.0
    min_repeatability: int = 2
    """A blob must appear at this many thresholds (rejects faint speckle)."""
    min_dist_between_blobs_px: float = 6.0
    filter_by_area: bool = True
    min_area_px: float = 6.0
    max_area_px: float = 200.0
    filter_by_circularity: bool = True
    min_circularity: float = 0.6
    """4 pi area / perimeter^2; a QR module (square) scores ~0.79 but fails convexity/darkness/size."""
    filter_by_convexity: bool = True
    min_convexity: float = 0.85
    filter_by_inertia: bool = True
    min_inertia_ratio: float = 0.2
    """Minor/major axis ratio; fish-eye border markers are squashed and smeared down to ~0.3."""
    filter_by_darkness: bool = True
    max_value: float = 60.0
    """Darkness filter: the darkest pixel of the blob (HSV value, 0..255) must be at most this."""
    max_value_rel: float = 0.35
    """...and at most this fraction of the local background (so a global dimming keeps markers)."""
    refine_half_px: int = 6
    """Half size of the window used for the sub-pixel centroid."""
    refine_rel_threshold: float = 0.5
    """Pixels below this fraction of the window's peak contrast do not count in the centroid."""


@dataclass(frozen=True)
class ReferenceBlobParams:
    """The reference FingerVision setting (akihikoy/fingervision ``fv_2_r.yaml`` + BlobTracker2 defaults).

    Used only as a baseline: HSV ``inRange`` to V <= ``thresh_v`` then plain SimpleBlobDetector.
    """

    thresh_h: int = 180
    thresh_s: int = 255
    thresh_v: int = 42
    min_threshold: float = 5.0
    max_threshold: float = 200.0
    threshold_step: float = 10.0
    min_area_px: float = 10.0
    max_area_px: float = 150.0
    min_circularity: float = 0.10
    min_convexity: float = 0.87
    min_inertia_ratio: float = 0.01
    min_dist_between_blobs_px: float = 10.0


@dataclass(frozen=True)
class Detections:
    """Markers found in one frame: ``positions_px`` (N, 2) as (x, y), ``sizes_px`` (N,) diameters."""

    positions_px: np.ndarray
    sizes_px: np.ndarray
    peak_contrast: np.ndarray = field(default_factory=lambda: np.zeros(0))

    def __len__(self) -> int:
        return int(self.positions_px.shape[0])


@dataclass(frozen=True)
class MarkerBaseline:
    """Rest positions and sizes of the markers (no contact), with a per-marker valid flag."""

    positions_px: np.ndarray
    sizes_px: np.ndarray
    valid: np.ndarray

    def __len__(self) -> int:
        return int(self.positions_px.shape[0])


def check_frame_bgr(frame_bgr: np.ndarray) -> np.ndarray:
    """Validate a frame (HxW or HxWx{1,3}, any size >= 1x1); returns it as uint8.

    Floats are clipped to 0..255 with NaN read as 0 and +-inf as 255/0; integers are clipped; bool,
    complex and object arrays are refused. Raises :class:`InvalidFrame` (a ``ValueError``).
    """
    if not isinstance(frame_bgr, np.ndarray) or frame_bgr.ndim not in (2, 3) or frame_bgr.size == 0:
        raise InvalidFrame(
            f"frame_bgr: expected a non-empty HxW or HxWx3 uint8 array, got "
            f"{getattr(frame_bgr, 'shape', type(frame_bgr).__name__)}", device="fingervision"
        )
    if frame_bgr.ndim == 3 and frame_bgr.shape[2] not in (1, 3):
        raise InvalidFrame(f"frame_bgr: expected 1 or 3 channels, got shape {frame_bgr.shape}", device="fingervision")
    if frame_bgr.dtype != np.uint8:
        if not (np.issubdtype(frame_bgr.dtype, np.floating) or np.issubdtype(frame_bgr.dtype, np.integer)) \
                or frame_bgr.dtype == np.bool_:
            raise InvalidFrame(f"frame_bgr: expected uint8 (or a real number type), got {frame_bgr.dtype}",
                               device="fingervision")
        if np.issubdtype(frame_bgr.dtype, np.floating):
            frame_bgr = np.clip(np.nan_to_num(frame_bgr), 0, 255).astype(np.uint8)
        else:
            frame_bgr = np.clip(frame_bgr, 0, 255).astype(np.uint8)
    return frame_bgr


def value_channel(frame_bgr: np.ndarray) -> np.ndarray:
    """HSV value (max over B, G, R) as uint8: black ink is dark in every channel, coloured print is not."""
    frame_bgr = check_frame_bgr(frame_bgr)
    if frame_bgr.ndim == 2:
        return frame_bgr
    if frame_bgr.shape[2] == 1:
        return frame_bgr[:, :, 0]
    return cv2.max(cv2.max(frame_bgr[:, :, 0], frame_bgr[:, :, 1]), frame_bgr[:, :, 2])


_KERNELS: dict[tuple[int, bool], np.ndarray] = {}


def _element(diameter_px: int, square: bool) -> np.ndarray:
    d = max(3, int(diameter_px) | 1)
    if (d, square) not in _KERNELS:
        _KERNELS[(d, square)] = cv2.getStructuringElement(cv2.MORPH_RECT if square else cv2.MORPH_ELLIPSE, (d, d))
    return _KERNELS[(d, square)]


def contrast_map(
    frame_bgr: np.ndarray, params: MarkerDetectorParams = MarkerDetectorParams()
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Return ``(value, background, contrast)``: uint8 value, float32 local background, float32 0..1.

    ``contrast = (background - value) / max(background, floor)``: 0 where nothing is darker than its
    surroundings, close to 1 for a black dot on a bright background, whatever the global light gain.
    """
    value = value_channel(frame_bgr)
    background = cv2.morphologyEx(
        value, cv2.MORPH_CLOSE, _element(params.background_kernel_px, params.background_square),
        borderType=cv2.BORDER_REPLICATE,
    )
    bg = background.astype(np.float32)
    diff = cv2.subtract(background, value).astype(np.float32)
    contrast = diff / np.maximum(bg, np.float32(params.background_floor))
    return value, bg, contrast


def _gather_windows(
    image: np.ndarray, centres_xy: np.ndarray, half: int, padded: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Windows (N, 2h+1, 2h+1) of ``image`` around rounded centres; outside the image reads as 0."""
    h, w = image.shape[:2]
    if padded is None:
        padded = cv2.copyMakeBorder(image, half, half, half, half, cv2.BORDER_CONSTANT, value=0)
    c = np.rint(np.nan_to_num(centres_xy)).astype(np.int64)
    np.clip(c[:, 0], 0, w - 1, out=c[:, 0])
    np.clip(c[:, 1], 0, h - 1, out=c[:, 1])
    offs = np.arange(2 * half + 1)
    rows = c[:, 1, None] + offs  # padded coords: window starts at centre - half + half
    cols = c[:, 0, None] + offs
    return padded[rows[:, :, None], cols[:, None, :]], c


def refine_centroids(
    contrast: np.ndarray,
    centres_xy: np.ndarray,
    half_px: int = 6,
    rel_threshold: float = 0.5,
    iterations: int = 2,
    disc_margin_px: float | None = 1.0,
    max_radius_px: np.ndarray | float | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Sub-pixel centroids by thresholded moments of the contrast in a window around each centre.

    Vectorised over markers. Returns ``(positions_px (N,2), sizes_px (N,), peak (N,))``. Weights are
    ``max(0, c - t * peak)``: subtracting the threshold keeps the centroid of a symmetric dot unbiased
    and silences the texture around it. The size is the diameter of the disc whose area equals the
    peak-normalised contrast mass above a quarter of the peak. After the first pass only a disc of
    the half-maximum radius + ``disc_margin_px`` around the last centroid counts (None: the whole
    window), at most ``max_radius_px`` (per centre or one value: the tracker passes the marker's known
    radius plus a margin, so print next to a marker cannot widen the disc). A window with no contrast
    keeps its centre and reports peak 0.

    Valid input: a float contrast map (H x W, >= 1 x 1) and any centres (non-finite ones are read
    as 0 and clipped into the frame); outputs are finite, positions inside the window around each centre.
    """
    centres = np.asarray(centres_xy, dtype=np.float64).reshape(-1, 2)
    n = centres.shape[0]
    if n == 0:
        return np.zeros((0, 2)), np.zeros(0), np.zeros(0)
    offs = np.arange(-half_px, half_px + 1, dtype=np.float64)
    padded = cv2.copyMakeBorder(contrast, half_px, half_px, half_px, half_px, cv2.BORDER_CONSTANT, value=0)
    pos = centres.copy()
    peak = np.zeros(n)
    size = np.zeros(n)
    radius = np.full(n, np.inf)
    for it in range(max(1, iterations)):
        win, c = _gather_windows(contrast, pos, half_px, padded)
        win = win.astype(np.float64)
        if it > 0 and disc_margin_px is not None:
            # keep only a disc around the last centroid: print touching a marker stops pulling it
            rx = c[:, 0, None] + offs[None, :] - pos[:, 0, None]
            ry = c[:, 1, None] + offs[None, :] - pos[:, 1, None]
            inside = (rx[:, None, :] ** 2 + ry[:, :, None] ** 2) <= (radius ** 2)[:, None, None]
            win = np.where(inside, win, 0.0)
        peak = win.reshape(n, -1).max(axis=1)
        wt = np.maximum(win - rel_threshold * peak[:, None, None], 0.0)
        mass = wt.sum(axis=(1, 2))
        ok = mass > 1e-9
        safe = np.where(ok, mass, 1.0)
        dx = (wt.sum(axis=1) * offs).sum(axis=1) / safe
        dy = (wt.sum(axis=2) * offs).sum(axis=1) / safe
        new = np.stack([c[:, 0] + dx, c[:, 1] + dy], axis=1)
        pos = np.where(ok[:, None], new, pos)
        norm = np.clip(win / np.where(peak > 0, peak, 1.0)[:, None, None], 0.0, 1.0)
        area = np.where(norm > 0.25, norm, 0.0).sum(axis=(1, 2))
        size = 2.0 * np.sqrt(area / np.pi)
        if disc_margin_px is not None:
            half_max_r = np.sqrt(np.count_nonzero(wt > 0, axis=(1, 2)) / np.pi)
            radius = half_max_r + disc_margin_px
            if max_radius_px is not None:
                radius = np.minimum(radius, max_radius_px)
    return pos, np.where(peak > 0, size, 0.0), peak


@functools.lru_cache(maxsize=8)
def _blob_detector(p: MarkerDetectorParams) -> cv2.SimpleBlobDetector:
    sp = cv2.SimpleBlobDetector_Params()
    sp.minThreshold = float(p.min_threshold)
    sp.maxThreshold = float(p.max_threshold)
    sp.thresholdStep = float(p.threshold_step)
    sp.minRepeatability = int(p.min_repeatability)
    sp.minDistBetweenBlobs = float(p.min_dist_between_blobs_px)
    sp.filterByColor = True
    sp.blobColor = 255  # markers are bright in the contrast image
    sp.filterByArea = bool(p.filter_by_area)
    sp.minArea = float(p.min_area_px)
    sp.maxArea = float(p.max_area_px)
    sp.filterByCircularity = bool(p.filter_by_circularity)
    sp.minCircularity = float(p.min_circularity)
    sp.filterByConvexity = bool(p.filter_by_convexity)
    sp.minConvexity = float(p.min_convexity)
    sp.filterByInertia = bool(p.filter_by_inertia)
    sp.minInertiaRatio = float(p.min_inertia_ratio)
    return cv2.SimpleBlobDetector_create(sp)


def detect_markers(
    frame_bgr: np.ndarray, params: MarkerDetectorParams = MarkerDetectorParams()
) -> Detections:
    """Find markers in one frame (full-frame SimpleBlobDetector chain + darkness filter + sub-pixel).

    Valid input: see :func:`check_frame_bgr` (any size from 1 x 1); flat, black or saturated frames give
    no detections. Raises :class:`InvalidFrame` outside it."""
    value, bg, contrast = contrast_map(frame_bgr, params)
    return detect_in_contrast(value, bg, contrast, params)


def detect_in_contrast(
    value: np.ndarray, bg: np.ndarray, contrast: np.ndarray, params: MarkerDetectorParams
) -> Detections:
    """The detection chain on an already computed :func:`contrast_map` (the processor reuses it)."""
    img8 = np.clip(contrast * 255.0, 0, 255).astype(np.uint8)
    kps = _blob_detector(params).detect(img8)
    if not kps:
        return Detections(np.zeros((0, 2)), np.zeros(0), np.zeros(0))
    pts = np.array([kp.pt for kp in kps], dtype=np.float64)
    pos, size, peak = refine_centroids(
        contrast, pts, params.refine_half_px, params.refine_rel_threshold
    )
    keep = peak > 0
    if params.filter_by_darkness:
        # darkest pixel near the centre, compared with the absolute and the relative limits
        r = 1
        vwin, _ = _gather_windows(value.astype(np.float32) + 1.0, pos, r)
        vmin = np.where(vwin > 0, vwin, 1e9).reshape(len(pos), -1).min(axis=1) - 1.0
        bwin, _ = _gather_windows(bg, pos, 0)
        bmax = bwin.reshape(len(pos))
        keep &= (vmin <= params.max_value) & (vmin <= params.max_value_rel * np.maximum(bmax, 1.0))
    # two refined centroids may converge on one dot: keep the stronger
    order = np.argsort(-peak)
    chosen: list[int] = []
    for i in order:
        if not keep[i]:
            continue
        if all(np.hypot(*(pos[i] - pos[j])) >= params.min_dist_between_blobs_px for j in chosen):
            chosen.append(int(i))
    chosen.sort(key=lambda i: (pos[i, 1], pos[i, 0]))
    idx = np.array(chosen, dtype=np.int64)
    return Detections(pos[idx].reshape(-1, 2), size[idx], peak[idx])


def detect_markers_reference(
    frame_bgr: np.ndarray, params: ReferenceBlobParams = ReferenceBlobParams()
) -> Detections:
    """Baseline: the reference setting (HSV ``inRange`` V <= 42, plain SimpleBlobDetector), no refinement."""
    frame_bgr = check_frame_bgr(frame_bgr)
    if frame_bgr.ndim == 2 or frame_bgr.shape[2] == 1:
        frame_bgr = cv2.cvtColor(frame_bgr.reshape(frame_bgr.shape[:2]), cv2.COLOR_GRAY2BGR)
    hsv = cv2.cvtColor(frame_bgr, cv2.COLOR_BGR2HSV)
    dark = cv2.inRange(hsv, (0, 0, 0), (params.thresh_h, params.thresh_s, params.thresh_v))
    img = cv2.bitwise_not(dark)  # dark markers on white, as SimpleBlobDetector expects by default
    sp = cv2.SimpleBlobDetector_Params()
    sp.minThreshold = params.min_threshold
    sp.maxThreshold = params.max_threshold
    sp.thresholdStep = params.threshold_step
    sp.filterByColor = True
    sp.blobColor = 0
    sp.filterByArea = True
    sp.minArea = params.min_area_px
    sp.maxArea = params.max_area_px
    sp.filterByCircularity = True
    sp.minCircularity = params.min_circularity
    sp.filterByConvexity = True
    sp.minConvexity = params.min_convexity
    sp.filterByInertia = True
    sp.minInertiaRatio = params.min_inertia_ratio
    sp.minDistBetweenBlobs = params.min_dist_between_blobs_px
    kps = cv2.SimpleBlobDetector_create(sp).detect(img)
    if not kps:
        return Detections(np.zeros((0, 2)), np.zeros(0), np.zeros(0))
    return Detections(
        np.array([kp.pt for kp in kps], dtype=np.float64),
        np.array([kp.size for kp in kps], dtype=np.float64),
        np.ones(len(kps)),
    )


def build_baseline(
    detections: list[Detections],
    match_dist_px: float = 3.0,
    dist_max_px: float = 0.8,
    size_max_px: float = 1.5,
    min_fraction: float = 1.0,
) -> MarkerBaseline:
    """Marker rest positions and sizes from N no-contact frames, with a per-marker valid flag.

    Markers are seeded from every frame (a marker missed in frame 0 still gets an entry) and matched by
    nearest neighbour within ``match_dist_px``. Per marker, the detections within ``dist_max_px`` of
    the median position and ``size_max_px`` of the median size are inliers (the reference's
    DistMaxCalib / DSMaxCalib, made robust to one bad frame); the rest position and size are the
    inlier means, and the marker is valid when inliers make up at least ``min_fraction`` of the frames.
    Valid input: at least one frame's detections (a frame may have none; no detections at all give an
    empty baseline).
    """
    if not detections:
        raise ValueError("build_baseline: expected at least one frame of detections, got none")
    tracks: list[list[tuple[np.ndarray, float]]] = []
    centres: list[np.ndarray] = []
    for det in detections:
        used: set[int] = set()
        for p, s in zip(det.positions_px, det.sizes_px):
            best, best_d = -1, match_dist_px
            for k, c in enumerate(centres):
                d = float(np.hypot(*(p - c)))
                if d <= best_d and k not in used:
                    best, best_d = k, d
            if best < 0:
                tracks.append([(p, float(s))])
                centres.append(p.copy())
                used.add(len(centres) - 1)
            else:
                tracks[best].append((p, float(s)))
                centres[best] = np.median([q for q, _ in tracks[best]], axis=0)
                used.add(best)
    n_frames = len(detections)
    pos = np.zeros((len(tracks), 2))
    size = np.zeros(len(tracks))
    valid = np.zeros(len(tracks), dtype=bool)
    for k, tr in enumerate(tracks):
        ps = np.array([q for q, _ in tr])
        ss = np.array([s for _, s in tr])
        inl = (np.hypot(*(ps - np.median(ps, axis=0)).T) <= dist_max_px) & (np.abs(ss - np.median(ss)) <= size_max_px)
        valid[k] = inl.sum() >= min_fraction * n_frames - 1e-9
        if not inl.any():  # no consensus: keep the median as the rest position, flagged invalid
            inl[:] = True
        pos[k] = ps[inl].mean(axis=0)
        size[k] = ss[inl].mean()
    order = np.lexsort((pos[:, 0], pos[:, 1])) if len(tracks) else np.zeros(0, dtype=np.int64)
    return MarkerBaseline(pos[order].reshape(-1, 2), size[order], valid[order])
