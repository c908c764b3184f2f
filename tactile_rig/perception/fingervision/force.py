"""Marker displacement -> mean force and mean torque about the image centre.

Per marker: ``f = (dx, dy, fz)`` with ``(dx, dy)`` the displacement from the rest position and ``fz``
either the diameter growth ``max(0, ds)`` (a pressed marker looks bigger: ``normal="size"``) or
``|d|`` (``normal="norm"``). Torque per marker is ``r x f`` with ``r = (rx, ry, 0)`` the rest position
relative to the image centre. Units: ``force_px`` is in pixels and ``torque_px2`` in pixels squared,
always: converting to newtons is a force map's job (:mod:`.force_map`, fitted on the rig).
Image axes: x right, y down, z into the skin, so a positive z torque turns x towards y (clockwise on
screen).

Valid input: any positions (non-finite ones and markers not flagged valid are left out); the outputs
are always finite, zeros when no marker is usable.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["ForceParams", "ForceTorque", "estimate_force_torque"]

_REDUCTIONS = ("mean", "median", "quantile")
_NORMALS = ("size", "norm")


@dataclass(frozen=True)
class ForceParams:
    """How per-marker forces are reduced to one force and one torque."""

    reduction: str = "mean"
    """``mean``, ``median`` or ``quantile`` (median for x/y and the upper ``quantile`` for z)."""
    quantile: float = 0.75
    normal: str = "size"
    """``size``: fz = max(0, diameter growth); ``norm``: fz = |displacement|."""

    def __post_init__(self) -> None:
        if self.reduction not in _REDUCTIONS:
            raise ValueError(f"ForceParams.reduction: expected one of {_REDUCTIONS}, got {self.reduction!r}")
        if self.normal not in _NORMALS:
            raise ValueError(f"ForceParams.normal: expected one of {_NORMALS}, got {self.normal!r}")
        if not 0.0 <= self.quantile <= 1.0:
            raise ValueError(f"ForceParams.quantile: expected 0..1, got {self.quantile}")


@dataclass(frozen=True)
class ForceTorque:
    """Reduced force (3,) px and torque (3,) px^2, per-marker forces (N, 3) px, markers used."""

    force_px: np.ndarray
    torque_px2: np.ndarray
    per_marker_px: np.ndarray
    n_used: int


def estimate_force_torque(
    rest_positions_px: np.ndarray,
    rest_sizes_px: np.ndarray,
    positions_px: np.ndarray,
    sizes_px: np.ndarray,
    valid: np.ndarray,
    image_size_wh: tuple[int, int],
    params: ForceParams = ForceParams(),
) -> ForceTorque:
    """Force and torque from the markers flagged ``valid``; zeros (never NaN) when none is valid."""
    rest = np.asarray(rest_positions_px, dtype=np.float64).reshape(-1, 2)
    pos = np.asarray(positions_px, dtype=np.float64).reshape(-1, 2)
    n = rest.shape[0]
    if pos.shape[0] != n:
        raise ValueError(f"estimate_force_torque: {n} rest positions but {pos.shape[0]} positions")
    use = np.asarray(valid, dtype=bool).reshape(n) & np.isfinite(pos).all(axis=1) & np.isfinite(rest).all(axis=1)
    d = pos - rest
    ds = np.asarray(sizes_px, dtype=np.float64).reshape(n) - np.asarray(rest_sizes_px, dtype=np.float64).reshape(n)
    ds = np.nan_to_num(ds)
    fz = np.maximum(0.0, ds) if params.normal == "size" else np.hypot(d[:, 0], d[:, 1])
    f = np.column_stack([d, fz])
    w, h = image_size_wh
    r = rest - np.array([(w - 1) / 2.0, (h - 1) / 2.0])
    # r x f with r = (rx, ry, 0)
    tau = np.column_stack([r[:, 1] * f[:, 2], -r[:, 0] * f[:, 2], r[:, 0] * f[:, 1] - r[:, 1] * f[:, 0]])
    per = np.where(use[:, None], f, 0.0)
    if not np.any(use):
        return ForceTorque(np.zeros(3), np.zeros(3), per, 0)
    fu, tu = f[use], tau[use]
    if params.reduction == "mean":
        force, torque = fu.mean(axis=0), tu.mean(axis=0)
    else:
        force, torque = np.median(fu, axis=0), np.median(tu, axis=0)
        if params.reduction == "quantile":
            force[2] = np.quantile(fu[:, 2], params.quantile)
    return ForceTorque(force, torque, per, int(use.sum()))
