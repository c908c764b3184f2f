"""The marker lattice of one frame: grid indices for the detections, missing nodes found, print dropped.

FingerVision markers are printed on a grid in the skin; a fish-eye lens bends the grid (rows and
columns curve, the pitch shrinks towards the rim) but every marker still has four neighbours at
about the local pitch along two directions. Dark print seen through the skin (text, QR modules,
pictures) has no such structure. :func:`fit_lattice` uses that on a single frame:

1. **Axes and pitch** from the nearest-neighbour vectors of the detections (a 4-fold circular mean
   of their angles gives the grid's orientation; medians of the aligned vectors give the two pitches).
2. **Growth** from the detection nearest the centre (least distorted): a node's position is predicted
   from the nodes already placed (parallelograms where three neighbours exist, second-order
   extrapolation along a row or column otherwise, so the shrinking pitch at the rim is followed),
   and the nearest detection within ``tolerance`` x the local step takes the node's index.
3. **Fill**: a predicted node inside the image with no detection is measured in the contrast map
   (thresholded-moment centroid in a window); it becomes a marker only if it is dark, round enough,
   sized like its neighbours and lands where the lattice expects it.

Detections that never receive an index (print, debris, a bubble between markers) are dropped.
:func:`extend_lattice` finds, on later frames, detections on empty nodes next to the lattice (markers
hidden on the first frame that came into view).
Positions in pixels (x = column, y = row); indices ``(col, row)`` relative to the seed node.
Valid input: a contrast map (float, 0..1, H x W >= 1 x 1) and detections inside it; any number of
detections (fewer than ``min_markers`` gives an empty lattice, never an error).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from tactile_rig.perception.fingervision.markers import Detections, refine_centroids

__all__ = ["LatticeParams", "Lattice", "fit_lattice", "extend_lattice"]


@dataclass(frozen=True)
class LatticeParams:
    """Knobs of the lattice fit (fractions of the local marker pitch unless a unit is named)."""

    tolerance: float = 0.3
    """A detection takes a node when it lies within this fraction of the local step of the prediction."""
    min_step_px: float = 6.0
    """Pitches below this are not a marker lattice (print modules, noise): the fit gives up."""
    min_markers: int = 4
    """Fewer detections than this: no lattice (an empty result)."""
    fill: bool = True
    """Look for missed markers at predicted nodes in the contrast map."""
    fill_min_peak: float = 0.45
    """Peak contrast (0..1) a filled marker needs."""
    fill_size_ratio: tuple[float, float] = (0.45, 1.8)
    """A filled marker's diameter, relative to the median diameter of the lattice's detections."""
    fill_half_px: int = 6
    """Half size of the fill measurement window (px)."""
    fill_max_ring_fraction: float = 0.45
    """A filled marker is an island: at most this fraction of the ring around it (1.5-2.5 radii) may
    have half its peak contrast (print around a dark spot fills the ring)."""
    fill_max_value: int = 120
    """A filled marker's centre pixel must be at most this dark (HSV value, 0..255): ink, not a shadow."""
    max_nodes: int = 400
    """Safety bound on the number of nodes (a lattice never has more markers than this)."""


@dataclass(frozen=True)
class Lattice:
    """Markers of a frame on the lattice: positions (N, 2) px, diameters (N,) px, indices (N, 2)
    ``(col, row)``, ``detected`` (N,) True when the blob detector found the marker (False: filled)."""

    positions_px: np.ndarray
    sizes_px: np.ndarray
    indices: np.ndarray
    detected: np.ndarray
    pitch_px: tuple[float, float]
    """Pitch along the two axes at the seed (px)."""
    axis_deg: float
    """Orientation of the first axis, degrees from +x towards +y."""

    def __len__(self) -> int:
        return int(self.positions_px.shape[0])


def _empty(pitch: tuple[float, float] = (0.0, 0.0), axis_deg: float = 0.0) -> Lattice:
    return Lattice(np.zeros((0, 2)), np.zeros(0), np.zeros((0, 2), np.int64), np.zeros(0, bool), pitch, axis_deg)


def _axes_and_pitch(pos: np.ndarray) -> tuple[np.ndarray, np.ndarray, float, float] | None:
    """Grid axes (unit vectors u, v) and pitches from the 4 nearest neighbours of every point."""
    n = len(pos)
    d = np.hypot(pos[:, None, 0] - pos[None, :, 0], pos[:, None, 1] - pos[None, :, 1])
    np.fill_diagonal(d, np.inf)
    k = min(4, n - 1)
    nn = np.argsort(d, axis=1)[:, :k]
    vec = (pos[nn] - pos[:, None, :]).reshape(-1, 2)
    length = np.hypot(vec[:, 0], vec[:, 1])
    # the nearest-neighbour distance of each point bounds its lattice step: longer vectors are diagonals
    near = np.repeat(d[np.arange(n), nn[:, 0]], k)
    keep = (length <= 1.35 * near) & (length > 0)
    if np.count_nonzero(keep) < 2:
        return None
    vec, length = vec[keep], length[keep]
    ang = np.arctan2(vec[:, 1], vec[:, 0])
    theta = float(np.angle(np.sum(length * np.exp(4j * ang)))) / 4.0
    u = np.array([math.cos(theta), math.sin(theta)])
    v = np.array([-u[1], u[0]])
    pu = np.abs(vec @ u)
    pv = np.abs(vec @ v)
    along_u = pu >= 2.0 * pv
    along_v = pv >= 2.0 * pu
    if not along_u.any() and not along_v.any():
        return None
    su = float(np.median(pu[along_u])) if along_u.any() else float(np.median(pv[along_v]))
    sv = float(np.median(pv[along_v])) if along_v.any() else su
    return u, v, su, sv


def _predict(nodes: dict[tuple[int, int], int], pos: np.ndarray, ij: tuple[int, int],
             default_steps: tuple[np.ndarray, np.ndarray]) -> tuple[np.ndarray, float, int] | None:
    """Predicted position of node ``ij``, the local step length (px) and a support score (higher: surer)."""
    i, j = ij
    preds: list[np.ndarray] = []
    steps: list[float] = []
    support = 0

    def at(a: int, b: int) -> np.ndarray | None:
        k = nodes.get((a, b))
        return None if k is None else pos[k]

    # parallelograms: two neighbours and the diagonal node between them
    for di in (-1, 1):
        for dj in (-1, 1):
            a, b, c = at(i + di, j), at(i, j + dj), at(i + di, j + dj)
            if a is not None and b is not None and c is not None:
                preds.append(a + b - c)
                steps.append(0.5 * (float(np.hypot(*(a - c))) + float(np.hypot(*(b - c)))))
                support += 3
    # along a row or a column: second-order extrapolation (follows the pitch shrinking at the rim)
    for di, dj in ((1, 0), (-1, 0), (0, 1), (0, -1)):
        p1, p2, p3 = at(i - di, j - dj), at(i - 2 * di, j - 2 * dj), at(i - 3 * di, j - 3 * dj)
        if p1 is None:
            continue
        if p2 is not None:
            s1 = p1 - p2
            if p3 is not None:
                s2 = p2 - p3
                n1, n2 = float(np.hypot(*s1)), float(np.hypot(*s2))
                ratio = min(max(n1 / n2, 0.5), 1.25) if n2 > 0 else 1.0
                # the step keeps turning and shrinking as it did between the last two steps
                step = s1 + (s1 - s2) if ratio < 1.0 else s1
                step = step if np.hypot(*step) >= 0.4 * n1 else s1 * 0.4
                preds.append(p1 + step)
                support += 2
            else:
                step = s1
                preds.append(p1 + step)
                support += 1
            steps.append(float(np.hypot(*step)))
        elif not preds:
            # a single neighbour: the default step of that axis (the seed's pitch)
            step = default_steps[0] * di + default_steps[1] * dj
            preds.append(p1 + step)
            steps.append(float(np.hypot(*step)))
    if not preds:
        return None
    steps.sort()
    m = len(steps) // 2
    step_px = steps[m] if len(steps) % 2 else 0.5 * (steps[m - 1] + steps[m])
    mean = preds[0] if len(preds) == 1 else np.add.reduce(preds) / len(preds)
    return mean, step_px, support


def fit_lattice(
    detections: Detections,
    contrast: np.ndarray,
    value: np.ndarray | None = None,
    params: LatticeParams = LatticeParams(),
) -> Lattice:
    """Fit the marker lattice to one frame's detections; see the module docstring.

    ``contrast`` is the contrast map the detections came from (0..1, H x W) and ``value`` the HSV
    value channel (optional; used to check a filled marker is dark). Never raises on degenerate
    input: too few detections, a pitch below ``min_step_px`` or non-finite positions give an empty
    lattice.
    """
    pos_all = np.asarray(detections.positions_px, dtype=np.float64).reshape(-1, 2)
    size_all = np.asarray(detections.sizes_px, dtype=np.float64).reshape(-1)
    finite = np.isfinite(pos_all).all(axis=1) & np.isfinite(size_all)
    pos_all, size_all = pos_all[finite], size_all[finite]
    if len(pos_all) < max(2, params.min_markers):
        return _empty()
    axes = _axes_and_pitch(pos_all)
    if axes is None:
        return _empty()
    u, v, su, sv = axes
    axis_deg = math.degrees(math.atan2(u[1], u[0]))
    if min(su, sv) < params.min_step_px:
        return _empty((su, sv), axis_deg)
    h, w = contrast.shape[:2]

    pos = [p for p in pos_all]
    sizes = [float(s) for s in size_all]
    detected = [True] * len(pos)
    # seed: the detection nearest the middle of all detections (the least distorted region)
    mid = np.median(pos_all, axis=0)
    seed = int(np.argmin(np.hypot(*(pos_all - mid).T)))
    nodes: dict[tuple[int, int], int] = {(0, 0): seed}
    taken = {seed}
    default_steps = (u * su, v * sv)
    median_size = float(np.median(size_all))
    tried_fill: set[tuple[int, int]] = set()

    pos_arr = np.array(pos)
    cache: dict[tuple[int, int], tuple[np.ndarray, float, int] | None] = {}

    def added(ij: tuple[int, int]) -> None:
        # a prediction leans on nodes up to 3 steps away: forget the ones the new node may change
        for key in [k for k in cache if abs(k[0] - ij[0]) <= 3 and abs(k[1] - ij[1]) <= 3]:
            del cache[key]

    changed = True
    while changed and len(nodes) < params.max_nodes:
        changed = False
        frontier = {(i + di, j + dj) for (i, j) in nodes for di, dj in ((1, 0), (-1, 0), (0, 1), (0, -1))}
        frontier -= set(nodes)
        scored = []
        for ij in frontier:
            if ij not in cache:
                cache[ij] = _predict(nodes, pos_arr, ij, default_steps)
            pr = cache[ij]
            if pr is not None:
                scored.append((-pr[2], ij, pr))
        scored.sort(key=lambda t: (t[0], t[1]))
        for _neg, ij, (p, step, _support) in scored:
            if ij in nodes:
                continue
            if step < params.min_step_px:
                continue
            free = [k for k in range(len(pos_all)) if k not in taken]
            if free:
                d = np.hypot(*(pos_all[free] - p).T)
                k = int(np.argmin(d))
                if d[k] <= params.tolerance * step:
                    nodes[ij] = free[k]
                    taken.add(free[k])
                    added(ij)
                    changed = True
                    break  # re-predict with the new node: later predictions lean on it
        if changed:
            continue
        if not params.fill:
            break
        # no detection takes any frontier node: look for a missed marker at the best prediction
        for _neg, ij, (p, step, _support) in scored:
            if ij in tried_fill or step < params.min_step_px:
                continue
            tried_fill.add(ij)
            if not (-0.5 <= p[0] <= w - 0.5 and -0.5 <= p[1] <= h - 0.5):
                continue
            got = _measure(contrast, value, p, step, median_size, params)
            if got is None:
                continue
            q, s = got
            if any(np.hypot(*(q - pos[k])) < 0.3 * step for k in nodes.values()):
                continue
            pos.append(q)
            sizes.append(s)
            detected.append(False)
            pos_arr = np.array(pos)
            nodes[ij] = len(pos) - 1
            added(ij)
            changed = True
            break
    if len(nodes) < params.min_markers:
        return _empty((su, sv), axis_deg)
    keys = sorted(nodes, key=lambda ij: (ij[1], ij[0]))
    idx = np.array([nodes[k] for k in keys], dtype=np.int64)
    out_pos = np.array(pos)[idx]
    order = np.lexsort((out_pos[:, 0], out_pos[:, 1]))
    return Lattice(
        out_pos[order],
        np.array(sizes)[idx][order],
        np.array(keys, dtype=np.int64).reshape(-1, 2)[order],
        np.array(detected)[idx][order],
        (su, sv),
        axis_deg,
    )


def _measure(contrast: np.ndarray, value: np.ndarray | None, p: np.ndarray, step: float, median_size: float,
             params: LatticeParams) -> tuple[np.ndarray, float] | None:
    """A marker measured at predicted position ``p`` in the contrast map, or None when none is there."""
    half = int(params.fill_half_px)
    qs, sizes, peaks = refine_centroids(contrast, p[None, :], half, 0.5, iterations=3)
    q, s, peak = qs[0], float(sizes[0]), float(peaks[0])
    if not (np.isfinite(q).all() and peak >= params.fill_min_peak):
        return None
    if np.hypot(*(q - p)) > params.tolerance * step:
        return None
    lo, hi = float(params.fill_size_ratio[0]), float(params.fill_size_ratio[1])
    if not lo * median_size <= s <= hi * median_size:
        return None
    h, w = contrast.shape[:2]
    x, y = int(round(q[0])), int(round(q[1]))
    if not (0 <= x < w and 0 <= y < h):
        return None
    # a marker is an island: the ring around it (1.5..2.5 radii) is background, print is not
    r = max(2.0, s / 2.0)
    y0, y1 = max(0, int(y - 2.5 * r) - 1), min(h, int(y + 2.5 * r) + 2)
    x0, x1 = max(0, int(x - 2.5 * r) - 1), min(w, int(x + 2.5 * r) + 2)
    yy, xx = np.mgrid[y0:y1, x0:x1]
    rr = np.hypot(xx - q[0], yy - q[1])
    ring = (rr >= 1.5 * r) & (rr <= 2.5 * r)
    if np.any(ring) and float(np.mean(contrast[y0:y1, x0:x1][ring] > 0.5 * peak)) > params.fill_max_ring_fraction:
        return None
    if value is not None and int(value[y, x]) > params.fill_max_value:
        return None
    return q, s


def extend_lattice(
    indices: np.ndarray,
    positions_px: np.ndarray,
    detections: Detections,
    pitch_px: tuple[float, float],
    axis_deg: float,
    params: LatticeParams = LatticeParams(),
) -> list[tuple[tuple[int, int], np.ndarray, float]]:
    """Detections that sit on empty nodes next to a known lattice: ``[(index, position_px, size_px)]``.

    ``indices`` (N, 2) and ``positions_px`` (N, 2) are the lattice's markers now (e.g. tracked);
    a detection is returned when it lies within ``tolerance`` x the local step of the prediction of a
    node that has no marker yet and touches the lattice (a marker hidden on the first frame that has
    come into view). The caller decides when to believe it (e.g. the same place in two frames).
    """
    idx = np.asarray(indices, dtype=np.int64).reshape(-1, 2)
    pos = np.asarray(positions_px, dtype=np.float64).reshape(-1, 2)
    det = np.asarray(detections.positions_px, dtype=np.float64).reshape(-1, 2)
    if len(idx) < params.min_markers or len(det) == 0 or not np.isfinite(pos).all():
        return []
    nodes = {(int(i), int(j)): k for k, (i, j) in enumerate(idx)}
    t = math.radians(axis_deg)
    u = np.array([math.cos(t), math.sin(t)])
    v = np.array([-u[1], u[0]])
    default_steps = (u * pitch_px[0], v * pitch_px[1])
    frontier = {(i + di, j + dj) for (i, j) in nodes for di, dj in ((1, 0), (-1, 0), (0, 1), (0, -1))} - set(nodes)
    out: list[tuple[tuple[int, int], np.ndarray, float]] = []
    used: set[int] = set()
    for ij in sorted(frontier):
        pr = _predict(nodes, pos, ij, default_steps)
        if pr is None or pr[1] < params.min_step_px:
            continue
        p, step, _support = pr
        d = np.hypot(*(det - p).T)
        k = int(np.argmin(d))
        # not already a marker (a tracked marker that drifted is not a new one)
        if d[k] <= params.tolerance * step and k not in used and np.hypot(*(pos - det[k]).T).min() > 0.3 * step:
            used.add(k)
            out.append((ij, det[k].copy(), float(detections.sizes_px[k])))
    return out
