"""Tactile map (Li et al. 2014): mosaic touches onto a root height map and localize new touches in it.

The map frame m has its origin at the root touch's centre (mm, x right, y down). Each accepted touch
records ``g_T_m``, the 2x3 transform taking a point of the map (mm from the map origin) into that
touch's gel frame g (mm from the touch centre); its inverse places the touch in the map.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from tactile_rig.core.envelope import FileFormat
from tactile_rig.core.errors import BadFile
from tactile_rig.core.geometry import invert_rigid
from tactile_rig.perception.gelsight.dense_refinement import dense_refine, pose_pinned
from tactile_rig.perception.gelsight.features import Features, check_height, detect_scale, extract_features
from tactile_rig.perception.gelsight.registration import RegistrationResult, register
from tactile_rig.perception.gelsight.registration_params import RegistrationParams

# The metadata (a JSON string) inside a saved map's .npz.
MAP_FILE = FileFormat("gelsight.tactile_map", 1, "tactile map")
MAP_FORMAT_VERSION = MAP_FILE.version
ACCEPT_CONFIDENCE = 0.98  # Li 2014: a touch joins the map only above this confidence


@dataclass
class TouchRecord:
    """One add_touch call: accepted or not, the registration, and g_T_m when accepted."""

    accepted: bool
    result: RegistrationResult
    g_T_m: np.ndarray | None = None


@dataclass
class TactileMap:
    """A growing height map (mm) on a fixed canvas ``canvas_factor`` times the touch size.

    mm_per_px: pixel pitch (isotropic) in mm. accept_confidence: the paper's c threshold.
    """

    mm_per_px: float
    canvas_factor: float = 3.0
    accept_confidence: float = ACCEPT_CONFIDENCE
    params: RegistrationParams = field(default_factory=RegistrationParams)
    total: np.ndarray | None = None
    count: np.ndarray | None = None
    poses: list[np.ndarray] = field(default_factory=list)
    _features: Features | None = None
    _height: np.ndarray | None = None
    _touch_shape: tuple[int, int] | None = None

    def __post_init__(self) -> None:
        if not (np.isfinite(self.mm_per_px) and self.mm_per_px > 0):
            raise ValueError(f"mm_per_px must be positive, got {self.mm_per_px!r}")
        if self.canvas_factor < 1.0:
            raise ValueError(f"canvas_factor must be >= 1, got {self.canvas_factor!r}")

    @property
    def empty(self) -> bool:
        return self.total is None

    @property
    def height_mm(self) -> np.ndarray:
        """The mosaic (mm, float32): average of the touches covering each pixel, 0 where none (a copy)."""
        return self._mosaic().copy()

    def _mosaic(self) -> np.ndarray:
        # Cached (read-only) until the next touch is placed: every localize() reads the whole canvas.
        if self.total is None or self.count is None:
            raise ValueError("the tactile map is empty: add a touch first")
        if self._height is None:
            out = np.zeros_like(self.total)
            np.divide(self.total, self.count, out=out, where=self.count > 0)
            out.flags.writeable = False
            self._height = out
        return self._height

    @property
    def coverage(self) -> np.ndarray:
        """Boolean map of the pixels covered by at least one touch."""
        if self.count is None:
            raise ValueError("the tactile map is empty: add a touch first")
        return self.count > 0

    def _centre_px(self) -> np.ndarray:
        assert self.total is not None
        h, w = self.total.shape
        return np.array([(w - 1) / 2.0, (h - 1) / 2.0])

    def _place(self, height: np.ndarray, m_px: np.ndarray) -> None:
        assert self.total is not None and self.count is not None
        h, w = self.total.shape
        warped = cv2.warpAffine(height, m_px, (w, h), flags=cv2.INTER_LINEAR, borderValue=0.0)
        # A shrunken validity mask keeps the zero padding of the warp out of the average.
        valid = cv2.warpAffine(np.ones_like(height), m_px, (w, h), flags=cv2.INTER_LINEAR) > 0.999
        self.total[valid] += warped[valid]
        self.count[valid] += 1.0
        self._features = None
        self._height = None

    def _touch_px_to_mm(self, m_px: np.ndarray, touch_shape: tuple[int, int]) -> np.ndarray:
        s = self.mm_per_px
        cb = np.array([(touch_shape[1] - 1) / 2.0, (touch_shape[0] - 1) / 2.0])
        r = m_px[:, :2]
        return np.hstack([r, ((r @ cb + m_px[:, 2] - self._centre_px()) * s)[:, None]])

    def _mm_to_px(self, m_mm: np.ndarray, touch_shape: tuple[int, int]) -> np.ndarray:
        s = self.mm_per_px
        cb = np.array([(touch_shape[1] - 1) / 2.0, (touch_shape[0] - 1) / 2.0])
        r = np.asarray(m_mm)[:, :2]
        t = np.asarray(m_mm)[:, 2] / s + self._centre_px() - r @ cb
        return np.hstack([r, t[:, None]])

    def add_touch(self, height_mm: np.ndarray, pose_hint: np.ndarray | None = None) -> TouchRecord:
        """Register a touch against the map and mosaic it in when c > accept_confidence.

        Valid input as :func:`register` (a 2-D map >= 16x16 in mm within +-50 mm; NaN = unknown); a
        refused touch is returned with ``accepted=False`` and the reason, and leaves the map unchanged.

        The first touch becomes the root (identity pose). pose_hint: optional 2x3 (mm) touch -> map
        transform (e.g. from the jig) used as the start of a dense alignment when keypoints refuse.
        """
        z = check_height(height_mm, "height_mm")
        if self.total is None:
            h, w = z.shape
            self._touch_shape = (h, w)
            ch, cw = int(round(h * self.canvas_factor)), int(round(w * self.canvas_factor))
            self.total = np.zeros((ch, cw), np.float32)
            self.count = np.zeros((ch, cw), np.float32)
            m_px = np.array([[1.0, 0, (cw - 1) / 2.0 - (w - 1) / 2.0], [0, 1.0, (ch - 1) / 2.0 - (h - 1) / 2.0]])
            self._place(z, m_px)
            pose = self._touch_px_to_mm(m_px, z.shape)
            self.poses.append(invert_rigid(pose))
            res = RegistrationResult.placed(m_px, self.total.shape, z.shape, (self.mm_per_px,) * 2,
                                            confidence=1.0, inliers=0, method="root", matches=0, ncc=1.0)
            res.matrix_mm = pose
            res.translation_mm = pose[:, 2].copy()
            return TouchRecord(True, res, self.poses[-1])
        res = self.localize(z)
        if not res.ok and pose_hint is not None:
            res = self._from_hint(z, np.asarray(pose_hint, np.float64))
        if res.ok and res.confidence > self.accept_confidence and res.matrix_px is not None:
            self._place(z, res.matrix_px)
            pose = invert_rigid(res.matrix_mm)  # type: ignore[arg-type]
            self.poses.append(pose)
            return TouchRecord(True, res, pose)
        return TouchRecord(False, res, None)

    def _from_hint(self, z: np.ndarray, hint_mm: np.ndarray) -> RegistrationResult:
        fa = self._map_features()
        fb = extract_features(z, self.params, dense=False)
        fit = dense_refine(fa, fb.smooth, self._mm_to_px(hint_mm, z.shape), self.params.refine_iters,  # type: ignore[arg-type]
                           gain_fit=self.params.dense_gain, valid_b=fb.valid,
                           bias_order=self.params.dense_bias_order)
        ok = fit.ncc >= self.params.min_ncc and fit.overlap >= self.params.min_overlap and pose_pinned(fit, self.params)
        assert self.total is not None
        if not ok:
            return RegistrationResult.refused("hint_not_confirmed", "hint", ncc=fit.ncc)
        return RegistrationResult.placed(fit.matrix_px, self.total.shape, z.shape, (self.mm_per_px,) * 2,
                                         confidence=1.0, inliers=0, method="hint", matches=0, ncc=fit.ncc)

    def _map_features(self) -> Features:
        if self._features is None:
            shape = self._touch_shape or self._mosaic().shape
            self._features = extract_features(self._mosaic(), self.params, scale=detect_scale(self.params, shape),
                                              valid=self.coverage)
        return self._features

    def localize(self, height_mm: np.ndarray) -> RegistrationResult:
        """Where a touch lies in the map: ``matrix_mm`` takes a point of the touch (mm from its
        centre) into the map frame (mm from the root touch's centre). Valid input, errors and
        refusals (``no_contact``, ``degenerate_transform``, ...) as :func:`register`."""
        if self.total is None:
            raise ValueError("the tactile map is empty: add a touch first")
        z = check_height(height_mm, "height_mm")
        res = register(self._mosaic(), z, self.mm_per_px, self.params, features_a=self._map_features())
        return res

    # -- persistence ---------------------------------------------------------------------------
    def save(self, path: str | Path) -> Path:
        """Write the map as one npz (arrays + JSON metadata string; no pickle)."""
        if self.total is None or self.count is None:
            raise ValueError("the tactile map is empty: nothing to save")
        p = Path(path)
        if p.suffix != ".npz":
            p = p.with_suffix(".npz")
        p.parent.mkdir(parents=True, exist_ok=True)
        meta = {**MAP_FILE.header(), "mm_per_px": self.mm_per_px, "canvas_factor": self.canvas_factor,
                "accept_confidence": self.accept_confidence, "touches": len(self.poses),
                "touch_shape": list(self._touch_shape) if self._touch_shape else None}
        np.savez_compressed(p, total=self.total, count=self.count,
                            g_T_m=np.array(self.poses, np.float64).reshape(-1, 2, 3),
                            meta=np.array(json.dumps(meta)))
        return p

    @classmethod
    def load(cls, path: str | Path, params: RegistrationParams | None = None) -> "TactileMap":
        """Read a map written by :meth:`save`; another file is a :class:`BadFile` (a ValueError)."""
        with np.load(Path(path), allow_pickle=False) as d:
            if "meta" not in d.files:
                raise BadFile(path, "it holds no 'meta' array", f"a {MAP_FILE.what} written by TactileMap.save")
            meta = MAP_FILE.check(json.loads(str(d["meta"])), path)
            m = cls(float(meta["mm_per_px"]), float(meta["canvas_factor"]), float(meta["accept_confidence"]),
                    params or RegistrationParams())
            m.total = d["total"].astype(np.float32)
            m.count = d["count"].astype(np.float32)
            m.poses = [p for p in d["g_T_m"]]
            m._touch_shape = tuple(meta["touch_shape"]) if meta.get("touch_shape") else None
        return m
