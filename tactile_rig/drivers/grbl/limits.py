"""The jig's firmware travel window in work coordinates, checked before a move is sent.

GRBL's soft limits (``$20=1``) refuse a target outside machine ``[−$13x, 0]`` with ``ALARM:2``,
which locks the jig until ``$X``. The same window in work coordinates is ``[−$13x − WCO, −WCO]``.
A lab sets its work zero on whole motor steps, so that window's edges sit a fraction of a step
off the round numbers: the project's jig homes θ to a WCO of −179.998° (6400 steps of 1/35.556°),
so ``θ = 180`` lies 0.002° past the edge; and positions are printed and sent with 3 decimals, so
the window is narrowed by 0.001 on each side. A target within half a motor step plus 0.001 of an
edge is moved onto the narrowed edge (at most 1.3 µm in x/y, 0.015° in θ: GRBL rounds targets to
steps anyway); a target further out is a :class:`~tactile_rig.core.errors.LimitError` naming the
axis, the value and the firmware's window, raised before anything moves.

The window is the homed machine's: after a power-up without homing (``$X`` only) GRBL itself does
not know where the stage is, and neither does this check.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from tactile_rig.core.errors import LimitError

__all__ = ["FirmwareWindow", "read_window"]

_AXES = {"x_mm": 0, "y_mm": 1}
# GRBL prints positions with 3 decimals ($13=0): the WCO read back may be 0.0005 off the one GRBL
# holds, and the move is sent with 3 decimals too; the window is narrowed by one printed digit.
_PRINT_RESOLUTION = 0.001


@dataclass(frozen=True)
class FirmwareWindow:
    """Work-coordinate limits per axis name (``x_mm``, ``y_mm``, ``theta_deg``) and half a step there."""

    limits: dict[str, tuple[float, float]]
    half_step: dict[str, float]
    device: str = "jig"

    def fit(self, **target: float | None) -> dict[str, float | None]:
        """The target moved onto the window when within half a step of it; LimitError further out."""
        out: dict[str, float | None] = {}
        for name, value in target.items():
            if value is None or name not in self.limits:
                out[name] = value
                continue
            lo, hi = self.limits[name]
            tol = self.half_step.get(name, 0.0) + _PRINT_RESOLUTION
            unit = "deg" if name == "theta_deg" else "mm"
            if not lo - tol <= value <= hi + tol:
                raise LimitError(f"{name} = {value:g} {unit} is outside the firmware's soft limits "
                                 f"[{lo:.3f}, {hi:.3f}] {unit} (GRBL travel from the homed position); "
                                 "nothing was moved", device=self.device)
            out[name] = min(hi, max(lo, value))
        return out


def read_window(jig: Any) -> FirmwareWindow | None:
    """The window of a connected :class:`~tactile_rig.drivers.grbl.jig.Jig` (``$$`` and one status), or
    None when soft limits are off (``$20=0``) or the status reports no WCO to place it by."""
    settings = jig.read_settings()
    if not int(settings.get(20, 0)):
        return None
    st = jig.status()
    if st.mpos is None or st.wpos is None:
        return None
    wco = [m - w for m, w in zip(st.mpos, st.wpos)]
    axes = dict(_AXES)
    axes["theta_deg"] = "XYZA".index(jig.theta_axis)
    limits, half = {}, {}
    for name, i in axes.items():
        travel = settings.get(130 + i)
        steps = settings.get(100 + i)
        if travel is None or i >= len(wco):
            continue
        limits[name] = (-float(travel) - wco[i] + _PRINT_RESOLUTION, -wco[i] - _PRINT_RESOLUTION)
        half[name] = 0.5 / float(steps) if steps else 0.0
    return FirmwareWindow(limits, half, device=getattr(jig, "device", "jig"))
