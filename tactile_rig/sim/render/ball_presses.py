"""Ball-press data sets in the ``presses/`` format (``background.png``, ``press_NN.png``, ``labels.csv``):
the lighting fitted on real ones, and rendered ones with their exact labels.

A ball of radius R pressed into the gel leaves a sphere cap; :func:`ball_press_height_mm` is that cap
for a labelled contact circle, :func:`fit_lighting` fits the renderer's lighting matrix on real presses
through the renderer's own geometry, :func:`render_ball_press_dataset` writes presses the renderer makes.
"""

from __future__ import annotations

import csv
import math
from pathlib import Path
from typing import Any, Sequence

import cv2
import numpy as np

from tactile_rig.sim.render.gel_surface import surface_gradients
from tactile_rig.sim.render.gelsight_renderer import GelSightRenderer, LightingModel

__all__ = ["ball_press_height_mm", "fit_lighting", "read_labels", "render_ball_press_dataset"]


def ball_press_height_mm(shape_px: tuple[int, int], mm_per_px: float, center_xy_px: tuple[float, float],
                         ball_radius_mm: float, contact_radius_px: float) -> np.ndarray:
    """Indentation of a ball whose contact circle has ``contact_radius_px`` (clamped below R)."""
    rows, cols = shape_px
    r_px = ball_radius_mm / mm_per_px
    a_px = min(float(contact_radius_px), 0.999 * r_px)
    yy, xx = np.mgrid[0:rows, 0:cols].astype(np.float32)
    r2 = (xx - center_xy_px[0]) ** 2 + (yy - center_xy_px[1]) ** 2
    z_px = np.sqrt(np.maximum(r_px * r_px - r2, 0.0)) - math.sqrt(r_px * r_px - a_px * a_px)
    return (np.maximum(z_px, 0.0) * mm_per_px).astype(np.float32)


def fit_lighting(presses_dir: str | Path, *, mm_per_px: float = 0.1245, ball_radius_mm: float = 2.0,
                 files: Sequence[str] | None = None, smoothing_mm: float = 0.6,
                 max_protrusion_mm: float = 1.0, margin_px: int = 4) -> LightingModel:
    """Least-squares fit of the lighting matrix on real ball presses (a ``presses/`` folder).

    Uses the renderer's own geometry (clip, smoothing) on the labelled circles, over the contact
    disc dilated by ``margin_px``.
    """
    presses_dir = Path(presses_dir)
    bg = cv2.imread(str(presses_dir / "background.png"), cv2.IMREAD_COLOR)
    if bg is None:
        raise FileNotFoundError(f"{presses_dir}/background.png is missing")
    r = GelSightRenderer(bg, mm_per_px, smoothing_mm=smoothing_mm, max_protrusion_mm=max_protrusion_mm,
                         noise_sigma=0.0)
    xs, ys = [], []
    for row in read_labels(presses_dir):
        if files is not None and row["file"] not in files:
            continue
        img = cv2.imread(str(presses_dir / row["file"]), cv2.IMREAD_COLOR)
        h = ball_press_height_mm(r.shape_px, mm_per_px, (row["center_x_px"], row["center_y_px"]),
                                 ball_radius_mm, row["contact_radius_px"])
        gx, gy = surface_gradients(r.gel_surface_mm(h), mm_per_px)
        m = cv2.dilate((h > 0).astype(np.uint8), np.ones((2 * margin_px + 1,) * 2, np.uint8)) > 0
        nz1 = 1.0 / np.sqrt(1 + gx * gx + gy * gy) - 1.0
        xs.append(np.stack([gx[m], gy[m], nz1[m]], -1))
        ys.append((img.astype(np.float32) - bg.astype(np.float32))[m])
    if not xs:
        raise ValueError(f"fit_lighting: no presses selected in {presses_dir}")
    mat = np.linalg.lstsq(np.concatenate(xs), np.concatenate(ys), rcond=None)[0]
    return LightingModel(mat)


def read_labels(presses_dir: str | Path) -> list[dict[str, Any]]:
    """Rows of ``labels.csv``: file, center_x_px, center_y_px, contact_radius_px (floats)."""
    with open(Path(presses_dir) / "labels.csv", newline="", encoding="utf-8") as fh:
        return [{"file": r["file"], "center_x_px": float(r["center_x_px"]), "center_y_px": float(r["center_y_px"]),
                 "contact_radius_px": float(r["contact_radius_px"])} for r in csv.DictReader(fh)]


def render_ball_press_dataset(
    out_dir: str | Path,
    *,
    n_presses: int = 20,
    shape_px: tuple[int, int] = (120, 160),
    mm_per_px: float = 0.1245,
    ball_radius_mm: float = 2.0,
    press_depth_mm: tuple[float, float] = (0.4, 0.9),
    background: str | np.ndarray = "taxim",
    border_px: int | None = None,
    seed: int = 0,
    renderer: GelSightRenderer | None = None,
) -> list[dict[str, Any]]:
    """Write a ``presses/``-format data set: background.png, press_NN.png and labels.csv.

    Each press is a ball of ``ball_radius_mm`` pressed a depth drawn from ``press_depth_mm`` (kept
    within the gel's range so the labelled sphere cap is the true shape) at a random centre at
    least ``border_px`` (default: the contact radius) from the edge. ``contact_radius_px`` is the
    geometric contact radius ``sqrt(R² − (R − d)²) / mm_per_px``. Returns the label rows (with
    ``press_depth_mm`` added).
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)
    r = renderer or GelSightRenderer(background, mm_per_px, shape_px=shape_px, seed=rng)
    if r.mm_per_px != mm_per_px or r.shape_px != tuple(shape_px):
        raise ValueError("render_ball_press_dataset: renderer's mm_per_px/shape_px differ from the arguments")
    lo, hi = float(press_depth_mm[0]), float(press_depth_mm[1])
    if not (0 < lo <= hi <= min(ball_radius_mm, r.max_protrusion_mm)):
        raise ValueError(f"press_depth_mm={press_depth_mm!r} must satisfy 0 < lo <= hi <= "
                         f"min(ball radius, gel range) = {min(ball_radius_mm, r.max_protrusion_mm)} mm")
    rows_px, cols_px = r.shape_px
    cv2.imwrite(str(out / "background.png"), r.render(None))
    labels: list[dict[str, Any]] = []
    for i in range(int(n_presses)):
        d = float(rng.uniform(lo, hi))
        a_px = math.sqrt(ball_radius_mm**2 - (ball_radius_mm - d) ** 2) / mm_per_px
        b = a_px if border_px is None else float(border_px)
        if 2 * b >= min(rows_px, cols_px):
            raise ValueError(f"border_px={b:.1f} leaves no room on a {rows_px}x{cols_px} sensor")
        cx = round(float(rng.uniform(b, cols_px - 1 - b)), 1)
        cy = round(float(rng.uniform(b, rows_px - 1 - b)), 1)
        h = ball_press_height_mm(r.shape_px, mm_per_px, (cx, cy), ball_radius_mm, a_px)
        name = f"press_{i:02d}.png"
        cv2.imwrite(str(out / name), r.render(h))
        labels.append({"file": name, "center_x_px": cx, "center_y_px": cy,
                       "contact_radius_px": round(a_px, 2), "press_depth_mm": round(d, 4)})
    with open(out / "labels.csv", "w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh)
        w.writerow(["file", "center_x_px", "center_y_px", "contact_radius_px"])
        for lab in labels:
            w.writerow([lab["file"], lab["center_x_px"], lab["center_y_px"], lab["contact_radius_px"]])
    return labels
