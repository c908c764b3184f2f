"""GelSight colour -> gradient calibration from ball presses; versioned save/load without pickle.

:class:`GelSightCalibration` holds a fitted colour(+position) -> slope model
(:mod:`~tactile_rig.perception.gelsight.models`), its background frame and scale, evaluated through a
baked table; :func:`calibrate_from_presses` fits one from labelled presses
(:mod:`~tactile_rig.perception.gelsight.presses`, whose names are importable from here too).
Slopes are dimensionless dz/dx, dz/dy with x right, y down and z the indentation height in mm.
"""

from __future__ import annotations

import datetime as _dt
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping

import cv2
import numpy as np

from tactile_rig.core.envelope import FileFormat
from tactile_rig.core.errors import BadFile, CalibrationError, GradientOutOfRange, SaturatedFrame
from tactile_rig.core.geometry import pitch_xy_mm
from tactile_rig.perception.gelsight.models import COLOUR_SCALE, MODELS, LutModel
from tactile_rig.perception.gelsight.presses import (
    DEFAULT_MAX_RADIUS_FRACTION,
    FitOptions,
    PressSet,
    clamp_radius_px,
    load_presses,
    marker_mask,
    pixel_features,
    sphere_cap,
    training_samples,
)

__all__ = ["CALIBRATION_FILE", "DEFAULT_MAX_RADIUS_FRACTION", "FORMAT_VERSION", "MAX_OUT_OF_RANGE_FRACTION",
           "MAX_SATURATED_FRACTION", "FitOptions", "GelSightCalibration", "PackedTable", "PressSet",
           "calibrate_from_presses", "clamp_radius_px", "load_presses", "make_model", "marker_mask", "pixel_features",
           "sphere_cap", "training_samples"]

# The .json of a saved calibration (its .npz holds the arrays).
CALIBRATION_FILE = FileFormat("gelsight.calibration", 1, "GelSight calibration")
FORMAT_VERSION = CALIBRATION_FILE.version
# A frame is refused when more than this fraction of its pixels is newly clipped (0 or 255 in a
# channel where the background was not) or differs from the background by more than the
# calibration's colour range: a covered lens, lights off or over-exposure, whose "slopes" would be
# invented by the table's edge bins (unchecked, an all-black frame reads -7..+7 mm).
MAX_SATURATED_FRACTION = 0.2
MAX_OUT_OF_RANGE_FRACTION = 0.2


@dataclass(frozen=True)
class PackedTable:
    """A baked table laid out for one gather per pixel (see :meth:`GelSightCalibration.packed_table`).

    A pixel's key is ``(qb << 2 bits) | (qg << bits) | qr`` with ``q = s >> shift`` of the saturated
    difference byte ``s = clip(frame - background + 128, 0, 255)`` of each channel, and
    ``table[cell_offset + key]`` is its ``gx + 1j * gy``. ``zero_key`` is a zero difference (slope 0,
    the background's own). ``peak_slope`` is the largest |slope| in the table (``inf`` if any entry is
    not finite).
    """

    shift: int
    bits: int
    zero_key: int
    table: np.ndarray
    cell_offset: np.ndarray
    peak_slope: float


class GelSightCalibration:
    """A fitted colour(+position) -> slope model with its background frame and scale.

    gradients(frame) returns (gx, gy) float32 slopes; the model's answer on the background itself is
    subtracted so that a no-contact frame reads flat. With ``bake_bins`` the model is tabulated
    once over colour bins x position cells and evaluated by integer indexing (fast path).
    """

    def __init__(self, model: object, background_bgr: np.ndarray, mm_per_px_x: float,
                 mm_per_px_y: float | None = None, ball_radius_mm: float = float("nan"),
                 sensor: str = "gelsight", date: str | None = None, bake_bins: int | None = 32,
                 bake_cells: tuple[int, int] = (6, 8), colour_range: float = 128.0,
                 extra: dict | None = None, *, baked_table: np.ndarray | None = None) -> None:
        _check_frame(background_bgr, None, "background_bgr")
        self._preloaded_table = baked_table  # a saved bake, used (and dropped) by _bake when it fits
        self.model = model
        self.background = np.ascontiguousarray(background_bgr)
        # Pixels already clipped with nothing touching (hot LEDs) do not count against a frame.
        self._bg_clipped = self.background.shape[0] * self.background.shape[1] - cv2.countNonZero(
            cv2.inRange(self.background, (1, 1, 1), (254, 254, 254)))
        self.mm_per_px_x = float(mm_per_px_x)
        self.mm_per_px_y = float(mm_per_px_x if mm_per_px_y is None else mm_per_px_y)
        for name, v in (("mm_per_px_x", self.mm_per_px_x), ("mm_per_px_y", self.mm_per_px_y)):
            if not (np.isfinite(v) and v > 0):
                raise ValueError(f"{name} must be a positive finite number of mm per pixel, got {v!r}")
        self.ball_radius_mm = float(ball_radius_mm)
        self.sensor = sensor
        self.date = date or _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds")
        self.colour_range = float(colour_range)
        self.extra = dict(extra or {})
        self.bake_bins = None if isinstance(model, LutModel) else bake_bins
        self.bake_cells = (int(bake_cells[0]), int(bake_cells[1]))
        self._prepare()

    @property
    def shape(self) -> tuple[int, int]:
        return self.background.shape[0], self.background.shape[1]

    # -- evaluation ---------------------------------------------------------------------------
    def _prepare(self) -> None:
        h, w = self.shape
        self._g0: np.ndarray | None = None
        self._raw_table: np.ndarray | None = None
        self._table: np.ndarray | None = None
        self._packed_shift: int | None = None
        self._packed: PackedTable | None = None
        if isinstance(self.model, LutModel):
            self._setup_table(self.model.table.reshape(-1, 2), self.model.bins, self.model.colour_range,
                              np.zeros(h * w, np.int64))
        elif self.bake_bins:
            self._bake(self.bake_bins)
        else:
            self._table = None
            # Background's own slope (non-zero for position-aware models), subtracted from every frame.
            gx0, gy0 = self._evaluate(np.zeros((h, w, 3), np.int16))
            self._g0 = np.stack([gx0, gy0], -1)

    def _setup_table(self, table: np.ndarray, bins: int, colour_range: float, cell_offset: np.ndarray) -> None:
        d = np.arange(-255, 256, dtype=np.float64)
        idx = np.clip(np.floor((d + colour_range) * bins / (2 * colour_range)), 0, bins - 1).astype(np.int32)
        zero_bin = int(idx[255])
        # The background's own slope is the table entry of a zero difference in each position cell:
        # subtracting it inside the table costs nothing per frame.
        # As complex64 (gx + 1j gy) so that the subtraction runs along the cell, not over pairs.
        table = np.ascontiguousarray(table, np.float32).reshape(-1, bins ** 3, 2).view(np.complex64)[..., 0]
        table = table - table[:, (zero_bin * bins + zero_bin) * bins + zero_bin][:, None]
        table = table.view(np.float32).reshape(-1, 2)
        self._table = table
        self._tab_xy: tuple[np.ndarray, np.ndarray] | None = None  # gx, gy columns: made on first use
        self._bins = bins
        # Per-channel contributions to the flat table index, looked up by the colour difference + 255.
        self._lut_b = (idx * bins * bins).astype(np.int32)
        self._lut_g = (idx * bins).astype(np.int32)
        self._lut_r = idx.astype(np.int32)
        self._cell_offset = cell_offset.reshape(self.shape).astype(np.int32)
        # The bin of a difference d is a shift of the saturated byte d + 128 when the bins are a power
        # of two over +-128 (the default 32 bins): the fast path's precondition, checked on all 511 d.
        self._packed_shift = None
        self._packed = None
        if 2 <= bins <= 256 and bins & (bins - 1) == 0:
            shift = 9 - bins.bit_length()
            if np.array_equal(idx, np.clip(d + 128, 0, 255).astype(np.int32) >> shift):
                self._packed_shift = shift

    def packed_table(self) -> PackedTable | None:
        """The table as one complex64 entry per key (``gx + 1j * gy``, a view: no copy) for a gather
        per pixel, or None when the bins do not allow the shifted-byte key (see :class:`PackedTable`)."""
        if self._packed_shift is None or self._table is None:
            return None
        if self._packed is None:
            t = self._table
            # All entries finite and their largest magnitude, once per load.
            finite = bool(np.isfinite(t).all())
            lo, hi = cv2.minMaxLoc(t)[:2] if t.size else (0.0, 0.0)
            bins = self._bins
            self._packed = PackedTable(shift=self._packed_shift, bits=bins.bit_length() - 1,
                                       zero_key=(bins // 2) * (bins * bins + bins + 1),
                                       table=t.view(np.complex64).ravel(), cell_offset=self._cell_offset,
                                       peak_slope=max(-lo, hi) if finite else float("inf"))
        return self._packed

    def _bake(self, bins: int) -> None:
        h, w = self.shape
        cy, cx = self.bake_cells
        baked, self._preloaded_table = self._preloaded_table, None
        if baked is not None and baked.shape == (cy * cx * bins ** 3, 2):
            # The table saved with the calibration: baking an MLP costs about a second per load,
            # which a folder of frames through the CLI would pay every run.
            self._raw_table = baked
            yy, xx = np.mgrid[0:h, 0:w]
            cell = np.minimum(yy * cy // h, cy - 1) * cx + np.minimum(xx * cx // w, cx - 1)
            self._setup_table(baked, bins, self.colour_range, cell * bins ** 3)
            return
        centres = (np.arange(bins) + 0.5) * (2 * self.colour_range / bins) - self.colour_range
        cb, cg, cr = np.meshgrid(centres, centres, centres, indexing="ij")
        colours = np.stack([cb.ravel(), cg.ravel(), cr.ravel()], axis=1) / COLOUR_SCALE
        blocks = []
        for iy in range(cy):
            for ix in range(cx):
                u = -1.0 + (2 * ix + 1) / cx
                v = -1.0 + (2 * iy + 1) / cy
                f = np.concatenate([colours, np.full((len(colours), 1), u), np.full((len(colours), 1), v)], 1)
                blocks.append(self.model.predict(f.astype(np.float32)))  # type: ignore[attr-defined]
        table = np.concatenate(blocks).astype(np.float32)
        self._raw_table = table
        yy, xx = np.mgrid[0:h, 0:w]
        cell = np.minimum(yy * cy // h, cy - 1) * cx + np.minimum(xx * cx // w, cx - 1)
        self._setup_table(table, bins, self.colour_range, cell * bins ** 3)

    def _evaluate(self, diff16: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        if self._table is not None:
            b, g, r = cv2.split(diff16)
            flat = np.take(self._lut_b, b + 255)
            flat += np.take(self._lut_g, g + 255)
            flat += np.take(self._lut_r, r + 255)
            flat += self._cell_offset
            if self._tab_xy is None:
                self._tab_xy = (np.ascontiguousarray(self._table[:, 0]), np.ascontiguousarray(self._table[:, 1]))
            return np.take(self._tab_xy[0], flat), np.take(self._tab_xy[1], flat)
        cr = self.colour_range
        feats = pixel_features(np.clip(diff16.astype(np.float32), -cr, cr))
        g = self.model.predict(feats).reshape(diff16.shape[0], diff16.shape[1], 2)  # type: ignore[attr-defined]
        if self._g0 is not None:
            g = g - self._g0
        return np.ascontiguousarray(g[..., 0]), np.ascontiguousarray(g[..., 1])

    def diff(self, frame_bgr: np.ndarray) -> np.ndarray:
        """Frame minus background as int16 (HxWx3), after checking the frame's type and size."""
        _check_frame(frame_bgr, self.shape, "frame_bgr")
        return cv2.subtract(frame_bgr, self.background, dtype=cv2.CV_16S)

    def check_range(self, frame_bgr: np.ndarray, max_diff_u8: np.ndarray | None = None,
                    max_saturated_fraction: float = MAX_SATURATED_FRACTION,
                    max_out_of_range_fraction: float = MAX_OUT_OF_RANGE_FRACTION) -> None:
        """Refuse a frame the calibration cannot read (type and size checked first).

        Raises :class:`SaturatedFrame` when more than ``max_saturated_fraction`` of the pixels are
        clipped (a channel at 0 or 255) beyond those clipped in the background, and
        :class:`GradientOutOfRange` when more than ``max_out_of_range_fraction`` differ from the
        background by more than ``colour_range`` in some channel (the fitted range). max_diff_u8:
        the per-pixel max-channel ``|frame - background|`` if the caller has it already.
        """
        _check_frame(frame_bgr, self.shape, "frame_bgr")
        n = frame_bgr.shape[0] * frame_bgr.shape[1]
        clipped = n - cv2.countNonZero(cv2.inRange(frame_bgr, (1, 1, 1), (254, 254, 254)))
        sat = max(clipped - self._bg_clipped, 0) / n
        if sat > max_saturated_fraction:
            raise SaturatedFrame(f"{sat:.1%} of the frame's pixels are clipped at 0 or 255 (the background "
                                 f"has {self._bg_clipped / n:.1%}); expected at most {max_saturated_fraction:.0%} "
                                 "more: check the lights, exposure and lens", device="gelsight.calibration",
                                 value=sat, limit=max_saturated_fraction)
        if max_diff_u8 is None:
            b, g, r = cv2.split(cv2.absdiff(frame_bgr, self.background))
            max_diff_u8 = cv2.max(cv2.max(b, g), r)
        limit = min(int(self.colour_range), 255)
        out = cv2.countNonZero(cv2.compare(max_diff_u8, limit, cv2.CMP_GT)) / n
        if out > max_out_of_range_fraction:
            raise GradientOutOfRange(f"{out:.1%} of the pixels differ from the background by more than the "
                                     f"calibration's colour range ({limit} grey levels); expected at most "
                                     f"{max_out_of_range_fraction:.0%}: another sensor, lighting or a stale "
                                     "background", device="gelsight.calibration", value=out,
                                     limit=max_out_of_range_fraction)

    def gradients(self, frame_bgr: np.ndarray, check: bool = True) -> tuple[np.ndarray, np.ndarray]:
        """Slopes (gx, gy) float32 HxW of a BGR uint8 frame of the calibration's size.

        Valid input: uint8 HxWx3 of the calibration's size whose colours lie within the fitted range
        (see :meth:`check_range`, skipped with ``check=False``); slopes are then bounded by the
        model's range (|slope| <= tan 1.5 rad ~ 14 for the MLP, the training slopes for a table).
        """
        if check:
            self.check_range(frame_bgr)
        return self._evaluate(self.diff(frame_bgr))

    # -- persistence ---------------------------------------------------------------------------
    def metadata(self) -> dict:
        return {**CALIBRATION_FILE.header(), "sensor": self.sensor, "mm_per_px_x": self.mm_per_px_x, "mm_per_px_y": self.mm_per_px_y,
                "ball_radius_mm": self.ball_radius_mm, "date": self.date,
                "model": self.model.kind, "bake_bins": self.bake_bins,  # type: ignore[attr-defined]
                "bake_cells": list(self.bake_cells), "colour_range": self.colour_range,
                "shape": list(self.shape), **({"extra": self.extra} if self.extra else {})}

    def reduced(self, factor: int) -> "GelSightCalibration":
        """This calibration for frames area-reduced by ``factor`` (rows // factor x cols // factor):
        the background reduced the same way, the pitch scaled to match, the baked table shared (a
        colour's slope does not depend on the resolution; no re-bake)."""
        if int(factor) != factor or factor < 1:
            raise ValueError(f"factor must be an integer >= 1, got {factor!r}")
        h, w = self.shape
        hs, ws = max(3, h // int(factor)), max(3, w // int(factor))
        bg = cv2.resize(self.background, (ws, hs), interpolation=cv2.INTER_AREA)
        return GelSightCalibration(self.model, bg, self.mm_per_px_x * w / ws, self.mm_per_px_y * h / hs,
                                   self.ball_radius_mm, self.sensor, self.date, self.bake_bins, self.bake_cells,
                                   self.colour_range, self.extra, baked_table=self._raw_table)

    def save(self, path: str | Path) -> Path:
        """Write ``<path>.npz`` (arrays) and ``<path>.json`` (metadata); returns the npz path."""
        base = Path(path)
        if base.suffix in (".npz", ".json"):
            base = base.with_suffix("")
        base.parent.mkdir(parents=True, exist_ok=True)
        arrays = {f"model_{k}": v for k, v in self.model.to_arrays().items()}  # type: ignore[attr-defined]
        arrays["background"] = self.background
        if getattr(self, "_raw_table", None) is not None:
            arrays["baked_table"] = self._raw_table
        # Uncompressed: the baked table (float32, ~12 MB for 32 bins x 48 cells) hardly compresses, and
        # inflating it took ~0.4 s of every CLI call.
        np.savez(base.with_suffix(".npz"), **arrays)
        base.with_suffix(".json").write_text(json.dumps(self.metadata(), indent=2) + "\n")
        return base.with_suffix(".npz")

    @classmethod
    def load(cls, path: str | Path) -> "GelSightCalibration":
        """Load a calibration written by :meth:`save` (npz + JSON); raises CalibrationError."""
        base = Path(path)
        if base.suffix in (".npz", ".json"):
            base = base.with_suffix("")
        jpath, npath = base.with_suffix(".json"), base.with_suffix(".npz")
        if not jpath.exists() or not npath.exists():
            raise CalibrationError(f"calibration {base} needs both {jpath.name} and {npath.name}",
                                   device="gelsight.calibration")
        meta = json.loads(jpath.read_text())
        with np.load(npath, allow_pickle=False) as data:
            arrays = {k: data[k] for k in data.files}
        return cls.from_saved(meta, arrays, str(jpath), str(npath))

    @classmethod
    def from_saved(cls, meta: Mapping[str, Any], arrays: Mapping[str, np.ndarray],
                   source: str = "calibration", arrays_source: str | None = None) -> "GelSightCalibration":
        """A calibration from what :meth:`save` wrote, already read by the caller: the JSON metadata
        and the npz's arrays by name (``background``, ``model_*``, ``baked_table``). ``source`` names
        the metadata file in messages, ``arrays_source`` the arrays' (default ``source``). Raises
        CalibrationError: another format or version, an unknown model, a model array missing, of
        another shape than the model declares, or not finite (a checked loader reads the files once)."""
        arrays_source = source if arrays_source is None else arrays_source
        try:
            CALIBRATION_FILE.check(meta, source)
        except BadFile as exc:
            raise CalibrationError(str(exc), device="gelsight.calibration") from None
        kind = meta.get("model")
        if kind not in MODELS:
            raise CalibrationError(f"{source}: unknown model {kind!r}", device="gelsight.calibration")
        if "background" not in arrays:
            raise CalibrationError(f"{arrays_source}: the array 'background' is missing", device="gelsight.calibration")
        model_arrays = {k[len("model_"):]: v for k, v in arrays.items() if k.startswith("model_")}
        background = arrays["background"]
        baked = arrays["baked_table"].astype(np.float32, copy=False) if "baked_table" in arrays else None
        try:
            model = MODELS[kind].from_arrays(model_arrays)
        except CalibrationError as exc:
            raise CalibrationError(f"{arrays_source}: {exc.args[0]} ({kind} model)",
                                   device="gelsight.calibration") from None
        cells = tuple(meta.get("bake_cells", (6, 8)))
        cal = cls(model, background, meta["mm_per_px_x"], meta["mm_per_px_y"], meta["ball_radius_mm"],
                  meta.get("sensor", "gelsight"), meta.get("date"), meta.get("bake_bins"),
                  (int(cells[0]), int(cells[1])), meta.get("colour_range", 128.0), meta.get("extra"),
                  baked_table=baked)
        return cal


def _check_frame(frame: object, shape: tuple[int, int] | None, name: str) -> None:
    if not isinstance(frame, np.ndarray):
        raise ValueError(f"{name}: expected a numpy array, got {type(frame).__name__}")
    if frame.dtype != np.uint8:
        raise ValueError(f"{name}: expected dtype uint8 (BGR 0..255), got {frame.dtype}")
    if frame.ndim != 3 or frame.shape[2] != 3:
        raise ValueError(f"{name}: expected an HxWx3 BGR image, got shape {frame.shape}")
    if shape is not None and frame.shape[:2] != tuple(shape):
        raise ValueError(f"{name}: expected {shape[0]}x{shape[1]} pixels (the calibration's size), "
                         f"got {frame.shape[0]}x{frame.shape[1]}")


def make_model(method: str, **hyper: object) -> object:
    """A fresh, unfitted model: "lut", "poly" or "mlp" with its hyper-parameters."""
    if method not in MODELS:
        raise ValueError(f"method must be one of {sorted(MODELS)}, got {method!r}")
    return MODELS[method](**hyper)


def calibrate_from_presses(press_dir: str | Path | PressSet, mm_per_px: float | tuple[float, float],
                           ball_radius_mm: float, method: str = "mlp", *, sensor: str = "gelsight",
                           fit: FitOptions = FitOptions(), bake_bins: int | None = 32,
                           bake_cells: tuple[int, int] = (6, 8), **hyper: Any) -> GelSightCalibration:
    """Fit a calibration from ball presses (folder or :class:`PressSet`).

    mm_per_px: scalar or (x, y) in mm per pixel; ball_radius_mm: the ball's radius. method: "lut"
    (Li 2014), "poly" (colour + position polynomial) or "mlp" (tiny numpy MLP on colour + position).
    bake_bins / bake_cells: tabulate a non-LUT model over colour bins x position cells for fast
    evaluation (None: evaluate the model per pixel).
    """
    presses = press_dir if isinstance(press_dir, PressSet) else load_presses(press_dir)
    sx, sy = pitch_xy_mm(mm_per_px)
    if not (float(ball_radius_mm) > 0):
        raise ValueError(f"ball_radius_mm must be > 0, got {ball_radius_mm!r}")
    if not (float(sx) > 0 and float(sy) > 0):
        raise ValueError(f"mm_per_px must be > 0, got {mm_per_px!r}")
    feats, slopes = training_samples(presses, float(np.sqrt(float(sx) * float(sy))), float(ball_radius_mm), fit)
    model = make_model(method, **hyper)
    model.fit(feats, slopes)  # type: ignore[attr-defined]
    return GelSightCalibration(model, presses.background, float(sx), float(sy), float(ball_radius_mm),
                               sensor=sensor, bake_bins=bake_bins, bake_cells=bake_cells,
                               extra={"presses": len(presses.frames),
                                      "max_radius_fraction": fit.max_radius_fraction})
