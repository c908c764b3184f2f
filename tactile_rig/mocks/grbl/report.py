"""GRBL 1.1h's printed text, as pure functions: status reports, ``$$``, ``$#``, ``$G``, ``$I``, messages.

Every number goes through :func:`fmt_float`, GRBL's own ``printFloat`` (print.c): add 0.5 at the
last decimal and truncate, a minus sign for any negative input (so ``-0.0001`` prints ``-0.000``
and ``-0.0`` prints ``0.000``). Positions and rates follow ``$13`` (inches: 4 and 1 decimals).
The layout of each line is report.c's; the firmware passes in the values.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping, Sequence

import numpy as np

import tactile_rig.mocks.grbl.gcode as gcode
from tactile_rig.devices import grbl as gp

MM_PER_INCH = 25.4
SETTING_DECIMALS = 3
INTEGER_SETTINGS = frozenset({0, 1, 2, 3, 4, 5, 6, 10, 13, 20, 21, 22, 23, 26, 32})
RPM_SETTINGS = frozenset({30, 31})
# Refresh counts of the WCO and Ov fields (config.h REPORT_*_REFRESH_*_COUNT).
WCO_BUSY, WCO_IDLE, OVR_BUSY, OVR_IDLE = 30, 10, 20, 10

MESSAGES = {
    "critical": "Reset to continue", "alarm_lock": "'$H'|'$X' to unlock", "unlocked": "Caution: Unlocked",
    "enabled": "Enabled", "disabled": "Disabled", "door": "Check Door", "check_limits": "Check Limits",
    "program_end": "Pgm End", "restore": "Restoring defaults", "spindle_restore": "Restoring spindle",
    "sleeping": "Sleeping",
}
HELP = "[HLP:$$ $# $G $I $N $x=val $Nx=line $J=line $SLP $C $X $H ~ ! ? ctrl-x]"


def fmt_float(n: float, decimals: int) -> str:
    """GRBL's ``printFloat``: round half up at ``decimals`` places, sign kept for any negative value."""
    sign = ""
    if n < 0:
        sign, n = "-", -n
    scaled = int(n * (10 ** decimals) + 0.5)
    digits = str(scaled).rjust(decimals + 1, "0")
    if decimals == 0:
        return sign + digits
    return f"{sign}{digits[:-decimals]}.{digits[-decimals:]}"


def fmt_coord(v_mm: float, inches: bool) -> str:
    """A position or offset: mm with 3 decimals, or inches with 4 (``$13=1``)."""
    return fmt_float(v_mm / MM_PER_INCH, 4) if inches else fmt_float(v_mm, 3)


def fmt_rate(v_mm_per_min: float, inches: bool) -> str:
    """A feed or speed: mm/min with no decimal, or in/min with 1."""
    return fmt_float(v_mm_per_min / MM_PER_INCH, 1) if inches else fmt_float(v_mm_per_min, 0)


def fmt_axes(values: Sequence[float] | np.ndarray, inches: bool) -> str:
    return ",".join(fmt_coord(float(v), inches) for v in values)


def message(key: str) -> str:
    """A feedback message line, ``[MSG:...]``."""
    return f"[MSG:{MESSAGES[key]}]"


class ReportCounters:
    """When the ``WCO:`` and ``Ov:`` fields are due (report.c): WCO every 10 idle / 30 busy reports,
    Ov every 10 / 20, Ov one report after a WCO when its counter had run out; zero means "next"."""

    def __init__(self) -> None:
        self.wco = 0
        self.ovr = 0

    def due(self, busy: bool) -> tuple[bool, bool]:
        """(WCO due, Ov due) for the report being printed now; advances the counters."""
        show_wco = show_ovr = False
        if self.wco > 0:
            self.wco -= 1
        else:
            self.wco = (WCO_BUSY if busy else WCO_IDLE) - 1
            if self.ovr == 0:
                self.ovr = 1
            show_wco = True
        if self.ovr > 0:
            self.ovr -= 1
        else:
            self.ovr = (OVR_BUSY if busy else OVR_IDLE) - 1
            show_ovr = True
        return show_wco, show_ovr


@dataclass
class StatusSnapshot:
    """What one ``?`` report shows; positions in machine mm, rates in mm/min."""

    state: str  # Idle, Run, Hold:0, Jog, Home, Alarm, Check, Sleep, Door:N
    mpos: np.ndarray
    wco: np.ndarray
    mask: int  # $10
    inches: bool  # $13
    planner_free: int
    rx_free: int
    feed_mm_per_min: float
    spindle_rpm: float
    pins: str = ""
    overrides: tuple[int, int, int] = (100, 100, 100)
    accessories: str = ""
    busy: bool = False


def status_report(s: StatusSnapshot, counters: ReportCounters) -> str:
    """``<State|MPos:...|Bf:...|FS:...|Pn:...|WCO:...|Ov:...|A:...>`` in report.c's order."""
    machine = bool(s.mask & gp.MASK_MPOS)
    pos = s.mpos if machine else s.mpos - s.wco
    parts = [s.state, f"{'MPos' if machine else 'WPos'}:{fmt_axes(pos, s.inches)}"]
    if s.mask & gp.MASK_BUFFER:
        parts.append(f"Bf:{s.planner_free},{s.rx_free}")
    parts.append(f"FS:{fmt_rate(s.feed_mm_per_min, s.inches)},{fmt_float(s.spindle_rpm, 0)}")
    if s.pins:
        parts.append(f"Pn:{s.pins}")
    show_wco, show_ovr = counters.due(s.busy)
    if show_wco:
        parts.append(f"WCO:{fmt_axes(s.wco, s.inches)}")
    if show_ovr:
        parts.append(f"Ov:{s.overrides[0]},{s.overrides[1]},{s.overrides[2]}")
        if s.accessories:
            parts.append(f"A:{s.accessories}")
    return "<" + "|".join(parts) + ">"


def settings_lines(settings: Mapping[int, float]) -> list[str]:
    """``$$``: ``$N=value`` for every setting, integers plain, RPM without decimals, the rest 3 decimals."""
    out = []
    for n in sorted(settings):
        v = settings[n]
        if n in INTEGER_SETTINGS:
            text = str(int(v))
        elif n in RPM_SETTINGS:
            text = fmt_float(v, 0)
        else:
            text = fmt_float(v, SETTING_DECIMALS)
        out.append(f"${n}={text}")
    return out


def ngc_parameters(coords: Sequence[np.ndarray], g92: np.ndarray, tlo_mm: float, probe_mpos: np.ndarray,
                   probe_ok: bool, inches: bool) -> list[str]:
    """``$#``: G54..G59, G28, G30, G92, TLO and the last probe (PRB), in machine coordinates."""
    names = [f"G{54 + i}" for i in range(gcode.N_COORDINATE_SYSTEMS)] + ["G28", "G30"]
    out = [f"[{name}:{fmt_axes(coords[i], inches)}]" for i, name in enumerate(names)]
    out.append(f"[G92:{fmt_axes(g92, inches)}]")
    out.append(f"[TLO:{fmt_coord(tlo_mm, inches)}]")
    out.append(probe_line(probe_mpos, probe_ok, inches))
    return out


def probe_line(probe_mpos: np.ndarray, probe_ok: bool, inches: bool) -> str:
    """``[PRB:x,y,z:1]`` (``:0`` when the last probe touched nothing)."""
    return f"[PRB:{fmt_axes(probe_mpos, inches)}:{1 if probe_ok else 0}]"


def gcode_modes(modal: gcode.ModalState, tool: int, feed_rate: float, spindle_rpm: float, inches: bool) -> str:
    """``$G``: ``[GC:G0 G54 G17 G21 G90 G94 M5 M9 T0 F0 S0]``; F follows ``$13``, not G20."""
    m = modal.motion
    motion = f"{m:.1f}" if m in gcode.PROBES else str(int(m))
    words = [f"G{motion}", f"G{54 + modal.coord_select}", f"G{modal.plane}", f"G{20 if modal.inches else 21}",
             f"G{91 if modal.incremental else 90}", f"G{93 if modal.inverse_time else 94}"]
    if modal.program_flow:
        words.append(f"M{modal.program_flow if modal.program_flow != gcode.FLOW_PAUSED else 0}")
    words.append(f"M{modal.spindle}")
    words.append("M8" if modal.coolant_flood else "M9")
    words.append(f"T{tool}")
    words.append(f"F{fmt_rate(feed_rate, inches)}")
    words.append(f"S{fmt_float(spindle_rpm, 0)}")
    return "[GC:" + " ".join(words) + "]"


def build_info(info: str, planner_blocks: int, rx_bytes: int) -> list[str]:
    """``$I``: version and build date with the stored build-info text, then the option letters."""
    return [f"[VER:{gp.VERSION}.{gp.BUILD_DATE}:{info}]", f"[OPT:V,{planner_blocks - 1},{rx_bytes}]"]


def startup_lines(lines: Sequence[str]) -> list[str]:
    """``$N``: ``$N0=...`` and ``$N1=...``."""
    return [f"$N{i}={text}" for i, text in enumerate(lines)]


def startup_result(line: str, status: int) -> str:
    """A startup block's result after the banner: ``>G20:ok`` or ``>G5:error:20``."""
    return f">{line}:{'ok' if status == 0 else f'error:{status}'}"
