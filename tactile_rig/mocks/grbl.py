"""GRBL 1.1, emulated: the firmware of the x-y-θ jig (θ on the Z channel, or A on grblHAL).

Faithful where a host can tell: the 128-byte serial receive buffer (bytes past it are lost, as on
the AVR; lines leave it when the protocol loop reads them, and ``ok`` comes when the block is in
the planner), realtime bytes acted on out of band (``? ! ~ ^X 0x85`` and the overrides), a
16-block planner with per-axis maximum rate and acceleration (moves take real or virtual time),
soft limits (ALARM:2 after a controlled stop), hard-limit switches just past the travel (ALARM:1,
instant halt), homing, check mode, ``$$ $# $G $I $N $X $H $C $J= $RST=``, settings that persist for
the session, and status reports shaped by ``$10``. Replies and messages are GRBL's own text.

Deviations, documented: arcs (G2/G3), inverse-time feed (G93), probing (G38) and G28/G30 answer
``error:20`` (grbl-streamer cuts arcs into lines anyway); the planner stops at the end of each
block instead of blending junctions; machine coordinates are centred (travel ±$13x/2, homing
finds a centre index) so that MPos is the stage pose; and the position survives a port-open
reset (the stage does not move, and the mock counts its steps exactly).

The machine position IS the world's ``stage`` model pose (x = X, y = Y, θ = the θ channel).
"""

from __future__ import annotations

import math
import re
from collections import deque
from dataclasses import dataclass
from typing import Any

import numpy as np

from tactile_rig.core.clock import Clock
from tactile_rig.devices import grbl as gp
from tactile_rig.mocks.grbl_motion import Profile, line_limits, trapezoid
from tactile_rig.mocks.registry import Params, register_kind
from tactile_rig.mocks.serial_device import SerialDevice
from tactile_rig.sim.world.stage import Stage

_WORD_RE = re.compile(r"([A-Z])([-+]?(?:\d+\.?\d*|\.\d+))?")
_MAX_STEP_RATE_HZ = 30000.0
_LINE_DELAY_S = 0.0005  # an AVR parses and plans a line in about half a millisecond
_STATUS_DELAY_S = 0.002
_HOME_PULLOFF_TIME_S = 0.25  # debounce + locate at $24 after the seek: a fixed slice of time


def default_settings(axes: int = 3, theta_axis: str = "Z") -> dict[int, float]:
    """The jig's settings: ±20 mm in x/y on 2 mm leadscrews, θ ±180° on a 4:1 belt."""
    s: dict[int, float] = {0: 10, 1: 25, 2: 0, 3: 0, 4: 0, 5: 0, 6: 0, 10: 1, 11: 0.010, 12: 0.002, 13: 0,
                           20: 1, 21: 1, 22: 1, 23: 0, 24: 100.0, 25: 1200.0, 26: 250, 27: 1.0,
                           30: 1000.0, 31: 0.0, 32: 0}
    xy = (1600.0, 1200.0, 100.0, 40.0)  # steps/mm (200×16 / 2 mm), mm/min, mm/s², travel mm
    theta = (35.556, 3600.0, 360.0, 360.0)  # steps/deg (200×16×4/360), deg/min, deg/s², deg
    lift = (400.0, 300.0, 10.0, 20.0)  # an unused Z on grblHAL
    per_axis = [xy, xy, theta if theta_axis == "Z" else lift]
    if axes == 4:
        per_axis.append(theta)
    for i, (steps, rate, acc, travel) in enumerate(per_axis):
        s[100 + i], s[110 + i], s[120 + i], s[130 + i] = steps, rate, acc, travel
    return s


@dataclass
class _Block:
    target: np.ndarray  # machine coordinates
    feed_mm_per_min: float | None  # None: a rapid (G0) or a homing leg
    jog: bool = False
    dwell_s: float = 0.0


@dataclass
class _GcState:
    motion: int = 0  # G0 / G1 / 80
    wcs: int = 0  # 0..5 for G54..G59
    plane: int = 17
    inches: bool = False
    incremental: bool = False
    feed_mm_per_min: float = 0.0
    spindle: int = 5
    coolant: int = 9
    tool: int = 0
    rpm: float = 0.0


class GrblMock(SerialDevice):
    """GRBL 1.1 on a serial line; see the module docstring."""

    kind = "jig"

    def __init__(self, *, clock: Clock | None = None, stage: Stage | None = None, axes: int = 3,
                 theta_axis: str = "Z", firmware: str = "grbl", baud: int = gp.BAUD, timing: bool = True,
                 seed: int = 0, homing: bool = True, boot_s: float = 0.0,
                 settings: dict[int, float] | None = None) -> None:
        super().__init__(baud=baud, timing=timing, seed=seed)
        if axes not in (3, 4):
            raise ValueError(f"jig axes={axes!r}: GRBL 1.1 drives 3 axes (grblHAL 4)")
        if theta_axis not in gp.AXIS_LETTERS[:axes] or theta_axis in ("X", "Y"):
            raise ValueError(f"jig theta_axis={theta_axis!r} must be Z{' or A' if axes == 4 else ''} with {axes} axes")
        if firmware not in ("grbl", "grblhal"):
            raise ValueError(f"jig firmware={firmware!r}: expected 'grbl' or 'grblhal'")
        self.clock = clock
        self.n_axes = axes
        self.letters = gp.AXIS_LETTERS[:axes]
        self.theta_index = self.letters.index(theta_axis)
        self.firmware = firmware
        self.boot_s = float(boot_s)
        self.stage = stage if stage is not None else Stage()
        self.stage.attach(self)
        self.settings = default_settings(axes, theta_axis)
        if not homing:
            self.settings[20] = self.settings[22] = 0  # hard limits stay: switches need no homing
        self.settings.update(settings or {})
        self.startup_lines = ["", ""]
        self.pos = np.zeros(axes)  # machine position, mm (deg on the θ channel)
        self.pos[[0, 1, self.theta_index]] = self.stage.pose()
        self.wcs_offsets = np.zeros((6, axes))
        self.homed = False
        self.faults: list[tuple[float, str]] = []
        self.rx_overflow_bytes = 0
        self.rx_high_water = 0  # most bytes ever waiting in the receive buffer
        self.lines_executed = 0
        self._fail_next_homing = False
        self._power_up(0.0 if clock is None else clock.now_s())

    # -- machine state -----------------------------------------------------------------------
    def _power_up(self, t_s: float) -> None:
        self.state = "Alarm" if self.settings[22] and not self.homed else "Idle"
        self._reset_runtime(t_s)

    def _reset_runtime(self, t_s: float) -> None:
        self.gc = _GcState()
        self.g92 = np.zeros(self.n_axes)
        self.gc_pos = self.pos.copy()  # the parser's idea of where the last block ends
        self.rx = bytearray()
        self._blocked: str | None = None
        self.planner: deque[_Block] = deque()
        self.active: Profile | None = None
        self.active_block: _Block | None = None
        self._limit_hit: tuple[float, int] | None = None  # (distance along the block, axis)
        self.hold = False
        self.hold_done = False
        self._dwell_until: float | None = None
        self._home_legs: list[tuple[float, np.ndarray, np.ndarray, float]] = []  # (t0, p0, p1, t1)
        self._home_fail: int | None = None
        self._critical = False  # an ALARM:1/2 that only a reset clears
        self._pending_soft_alarm = False
        self.line_number = 0
        self.feed_ovr, self.rapid_ovr, self.spindle_ovr = 100, 100, 100
        self._wco_counter = 0
        self._ovr_counter = 0
        self._booted_at = t_s + self.boot_s
        self._jog_cancel = False
        self._blocked_home = False
        self._t_now = max(t_s, getattr(self, "_t_now", 0.0))

    @property
    def wco(self) -> np.ndarray:
        return self.wcs_offsets[self.gc.wcs] + self.g92

    def _steps(self) -> np.ndarray:
        return np.array([self.settings[100 + i] for i in range(self.n_axes)])

    def _rates(self) -> np.ndarray:
        return np.array([self.settings[110 + i] for i in range(self.n_axes)])

    def _accels(self) -> np.ndarray:
        return np.array([self.settings[120 + i] for i in range(self.n_axes)])

    def _half_travel(self) -> np.ndarray:
        return np.array([self.settings[130 + i] for i in range(self.n_axes)]) / 2.0

    def _switch_at(self) -> np.ndarray:
        return self._half_travel() + 1.0  # limit switches sit 1 mm (1°) past the travel

    def _quantize(self, target: np.ndarray) -> np.ndarray:
        steps = self._steps()
        return np.round(target * steps) / steps

    # -- host connection -----------------------------------------------------------------------
    def on_open(self, t_s: float) -> None:
        self._reset_runtime(t_s)  # the Uno resets on open (DTR): RAM state is lost, settings kept
        self.state = "Alarm" if self.settings[22] and not self.homed else "Idle"
        self._banner(t_s + self.boot_s)

    def on_dtr(self, state: bool, t_s: float) -> None:
        if state:
            self.on_open(t_s)

    def _banner(self, t_s: float) -> None:
        text = "GrblHAL 1.1f ['$' or '$HELP' for help]" if self.firmware == "grblhal" else gp.BANNER
        out = b"\r\n" + text.encode() + b"\r\n"
        if self.state == "Alarm":
            out += b"[MSG:'$H'|'$X' to unlock]\r\n"
        self.emit(out, t_s, reply=False)

    def inject(self, fault: str, *, axis: str = "X", t_s: float | None = None) -> None:
        """``hard_limit`` (a switch trips now, on ``axis``), ``homing_fail`` (the next $H finds no
        switch), ``reset`` (a brown-out or DTR glitch: the board reboots and prints its banner)."""
        t = t_s if t_s is not None else (self.clock.now_s() if self.clock is not None else self._t_now)
        self.advance_to(t)
        self.faults.append((t, fault))
        if fault == "hard_limit":
            if self.settings[21]:
                self._hard_limit(t, self.letters.index(axis))
        elif fault == "homing_fail":
            self._fail_next_homing = True
        elif fault == "reset":
            self._halt()
            self.on_open(t)
        else:
            raise ValueError(f"jig mock: unknown fault {fault!r}; known: hard_limit, homing_fail, reset")

    # -- bytes in --------------------------------------------------------------------------------
    def on_bytes(self, data: bytes, t_s: float) -> None:
        if t_s < self._booted_at:
            return  # the bootloader eats it
        for b in data:
            if b in gp.REALTIME_BYTES:
                self._realtime(b, t_s)
            else:
                if len(self.rx) >= gp.RX_BUFFER_SIZE:
                    self._process(t_s)  # the main loop empties the ring while bytes arrive
                if len(self.rx) < gp.RX_BUFFER_SIZE:
                    self.rx.append(b)
                    self.rx_high_water = max(self.rx_high_water, len(self.rx))
                else:
                    self.rx_overflow_bytes += 1  # the ring is full: the AVR drops the byte
        self._process(t_s)

    def _realtime(self, b: int, t_s: float) -> None:
        if b == 0x3F:  # '?'
            self.emit(self._status_report().encode() + b"\r\n", t_s, delay_s=_STATUS_DELAY_S)
        elif b == 0x18:
            self._soft_reset(t_s)
        elif self._critical:
            return
        elif b == 0x21:  # '!'
            self._feed_hold(t_s)
        elif b == 0x7E:  # '~'
            self._cycle_start(t_s)
        elif b == 0x85:
            if self.state == "Jog":
                self._feed_hold(t_s)
        elif 0x90 <= b <= 0x9D:
            self._override(b, t_s)

    def _override(self, b: int, t_s: float) -> None:
        if b <= 0x94:
            step = {0x90: None, 0x91: 10, 0x92: -10, 0x93: 1, 0x94: -1}[b]
            self.feed_ovr = 100 if step is None else int(min(200, max(10, self.feed_ovr + step)))
        elif b <= 0x97:
            self.rapid_ovr = {0x95: 100, 0x96: 50, 0x97: 25}[b]
        elif 0x99 <= b <= 0x9D:
            step = {0x99: None, 0x9A: 10, 0x9B: -10, 0x9C: 1, 0x9D: -1}[b]
            self.spindle_ovr = 100 if step is None else int(min(200, max(10, self.spindle_ovr + step)))
        self._ovr_counter = 0
        if self.active is not None and not self.hold:
            self._replan(t_s)

    # -- the protocol loop ---------------------------------------------------------------------
    def _process(self, t_s: float) -> None:
        """Execute complete lines while nothing blocks (planner full, a sync, a critical alarm)."""
        while not self._critical:
            if self._blocked is not None and (self._home_legs or self._dwell_until is not None):
                return  # $H and G4 answer when they finish
            if self._blocked is None:
                idx = self.rx.find(b"\n")
                idx_r = self.rx.find(b"\r")
                if idx < 0 or (0 <= idx_r < idx):
                    idx = idx_r
                if idx < 0:
                    return
                raw = bytes(self.rx[:idx])
                del self.rx[: idx + 1]
                self._blocked = raw.decode("ascii", "replace")
            line = self._blocked
            result = self._execute(line, t_s)
            if result == "wait":
                return
            self._blocked = None
            if result is None:
                continue  # no answer (an alarm took over)
            self.lines_executed += 1
            self.emit(result.encode() + b"\r\n", t_s, delay_s=_LINE_DELAY_S)

    def _execute(self, raw: str, t_s: float) -> str | None:
        line = _normalize(raw)
        if len(line) >= gp.LINE_MAX - 1:
            return "error:11"
        if not line:
            return "ok"
        if line.startswith("$"):
            return self._system(line, t_s)
        if self.state in ("Alarm", "Jog") or (self.state == "Home"):
            return "error:9"
        return self._gcode(line, t_s, jog=False)

    # -- $ commands ----------------------------------------------------------------------------
    def _system(self, line: str, t_s: float) -> str | None:
        body = line[1:]
        idle = self.state in ("Idle", "Alarm")
        if body == "":
            self._say("[HLP:$$ $# $G $I $N $x=val $Nx=line $J=line $SLP $C $X $H ~ ! ? ctrl-x]", t_s)
            return "ok"
        if body.startswith("J="):
            if self.state not in ("Idle", "Jog"):
                return "error:8"
            return self._gcode(body[2:], t_s, jog=True)
        if body == "$":
            if self.state in ("Run", "Hold"):
                return "error:8"
            for n in sorted(self.settings):
                self._say(f"${n}={_fmt_setting(n, self.settings[n])}", t_s)
            return "ok"
        if body == "G":
            g = self.gc
            self._say(f"[GC:G{g.motion} G{54 + g.wcs} G{g.plane} G{20 if g.inches else 21} "
                      f"G{91 if g.incremental else 90} G94 M{g.spindle} M{g.coolant} T{g.tool} "
                      f"F{_num(g.feed_mm_per_min / (25.4 if g.inches else 1.0), 0)} S{_num(g.rpm, 0)}]", t_s)
            return "ok"
        if body == "C":
            if self.state == "Check":
                self._say("[MSG:Disabled]", t_s)
                self.emit(b"ok\r\n", t_s, delay_s=_LINE_DELAY_S)
                self._soft_reset(t_s)
                return None
            if self.state != "Idle":
                return "error:8"
            self.state = "Check"
            self._say("[MSG:Enabled]", t_s)
            return "ok"
        if body == "X":
            if self.state == "Alarm":
                self.state = "Idle"
                self._say("[MSG:Caution: Unlocked]", t_s)
            return "ok"
        if not idle:
            return "error:8"
        if body == "#":
            for i in range(6):
                self._say(f"[G{54 + i}:{_vec(self.wcs_offsets[i])}]", t_s)
            zero = _vec(np.zeros(self.n_axes))
            self._say(f"[G28:{zero}]", t_s)
            self._say(f"[G30:{zero}]", t_s)
            self._say(f"[G92:{_vec(self.g92)}]", t_s)
            self._say("[TLO:0.000]", t_s)
            self._say(f"[PRB:{zero}:0]", t_s)
            return "ok"
        if body == "I":
            self._say(f"[VER:{gp.VERSION}.{gp.BUILD_DATE}:]", t_s)
            self._say(f"[OPT:V,{gp.PLANNER_BLOCKS - 1},{gp.RX_BUFFER_SIZE}]", t_s)
            return "ok"
        if body == "N":
            for i, s in enumerate(self.startup_lines):
                self._say(f"$N{i}={s}", t_s)
            return "ok"
        if body == "H":
            return self._start_homing(t_s)
        if body == "SLP":
            self.state = "Sleep"
            self._say("[MSG:Sleeping]", t_s)
            return "ok"
        if body.startswith("RST="):
            what = body[4:]
            if what not in ("$", "#", "*"):
                return "error:3"
            if what in ("$", "*"):
                keep = self.settings[10]
                self.settings = default_settings(self.n_axes, self.letters[self.theta_index])
                self.settings[10] = keep if what == "$" else self.settings[10]
            if what in ("#", "*"):
                self.wcs_offsets[:] = 0
            self._say("[MSG:Restoring defaults]", t_s)
            return "ok"
        m = re.fullmatch(r"N(\d)=(.*)", body)
        if m:
            idx = int(m.group(1))
            if idx >= len(self.startup_lines):
                return "error:3"
            self.startup_lines[idx] = m.group(2)
            return "ok"
        m = re.fullmatch(r"(\d+)=(.*)", body)
        if m:
            return self._write_setting(int(m.group(1)), m.group(2))
        return "error:3"

    def _write_setting(self, n: int, text: str) -> str:
        try:
            value = float(text)
        except ValueError:
            return "error:2"
        if not math.isfinite(value):
            return "error:2"
        if value < 0:
            return "error:4"
        if n not in self.settings:
            return "error:3"
        if n == 0 and value < 3:
            return "error:6"
        if n == 20 and value and not self.settings[22]:
            return "error:10"
        if n in gp.INTEGER_SETTINGS:
            value = float(int(value))
        axis = n % 10
        if 100 <= n < 100 + self.n_axes and value * self.settings[110 + axis] > _MAX_STEP_RATE_HZ * 60:
            return "error:12"
        if 110 <= n < 110 + self.n_axes and value * self.settings[100 + axis] > _MAX_STEP_RATE_HZ * 60:
            return "error:12"
        self.settings[n] = value
        return "ok"

    def _say(self, text: str, t_s: float) -> None:
        self.emit(text.encode() + b"\r\n", t_s, delay_s=_LINE_DELAY_S)

    # -- G-code ----------------------------------------------------------------------------------
    def _gcode(self, line: str, t_s: float, *, jog: bool) -> str | None:
        words: dict[str, float] = {}
        gwords: list[float] = []
        mwords: list[float] = []
        pos = 0
        while pos < len(line):
            m = _WORD_RE.match(line, pos)
            if m is None:
                return "error:1"
            if m.group(2) is None:
                return "error:2"
            letter, value = m.group(1), float(m.group(2))
            pos = m.end()
            if letter == "G":
                gwords.append(value)
            elif letter == "M":
                mwords.append(value)
            elif letter not in "FIJKLNPRSTXYZABC":
                return "error:20"  # a word GRBL does not know (Q, D, H, ...)
            elif letter in words:
                return "error:25"
            else:
                words[letter] = value
        axes_here = [c for c in words if c in "XYZABCUVW"]
        for c in axes_here:
            if c not in self.letters:
                return "error:20"
        g = self.gc
        motion, nonmodal, units, dist, wcs = None, None, None, None, None
        groups: dict[str, float] = {}
        for v in gwords:
            if v in (0, 1, 80):
                grp = "motion"
            elif v in (2, 3, 38.2, 38.3, 38.4, 38.5, 93, 28, 30, 28.1, 30.1):
                return "error:20"
            elif v in (4, 10, 53, 92, 92.1):
                grp = "nonmodal"
            elif v in (20, 21):
                grp = "units"
            elif v in (90, 91):
                grp = "distance"
            elif v in (54, 55, 56, 57, 58, 59):
                grp = "wcs"
            elif v in (17, 18, 19, 94, 40, 49, 43.1, 61, 91.1):
                grp = f"other{v}"
            else:
                return "error:20"
            if grp in groups:
                return "error:21"
            groups[grp] = v
        motion, nonmodal = groups.get("motion"), groups.get("nonmodal")
        units, dist, wcs = groups.get("units"), groups.get("distance"), groups.get("wcs")
        if jog:
            if any(k not in ("units", "distance", "nonmodal") for k in groups) or mwords or \
                    (nonmodal is not None and nonmodal != 53) or any(c not in self.letters + ("F", "N") for c in words):
                return "error:16"
        for v in mwords:
            if v not in (0, 1, 2, 30, 3, 4, 5, 7, 8, 9):
                return "error:20"
        if "N" in words:
            if not (0 <= words["N"] <= 9999999) or words["N"] != int(words["N"]):
                return "error:27"
        if "F" in words and words["F"] < 0:
            return "error:4"
        if "S" in words and words["S"] < 0:
            return "error:4"
        if "T" in words and (words["T"] != int(words["T"]) or words["T"] < 0):
            return "error:23" if words["T"] != int(words["T"]) else "error:4"
        for c in "IJKR":
            if c in words:
                return "error:36"
        if "P" in words and nonmodal not in (4, 10):
            return "error:36"
        if "L" in words and nonmodal != 10:
            return "error:36"
        # Resolve modal state of this block (not yet committed: an error must leave state untouched).
        inches = g.inches if units is None else units == 20
        scale = 25.4 if inches else 1.0
        incremental = g.incremental if dist is None else dist == 91
        wcs_i = g.wcs if wcs is None else int(round(wcs)) - 54
        feed = g.feed_mm_per_min if "F" not in words else words["F"] * scale
        motion_mode = g.motion if motion is None else int(motion)
        if jog:
            motion_mode = 1
            if "F" not in words:
                return "error:22"
            incremental = g.incremental if dist is None else dist == 91
        wco = self.wcs_offsets[wcs_i] + self.g92
        target = self.gc_pos.copy()
        uses_axes = nonmodal in (10, 92) or (motion_mode in (0, 1) and axes_here)
        if axes_here and not uses_axes and nonmodal != 53:
            if motion_mode == 80:
                return "error:31"
        if nonmodal == 53 and motion_mode not in (0, 1):
            return "error:30"
        # Non-modal commands that do not move.
        if nonmodal == 4:
            if "P" not in words:
                return "error:28"
            if words["P"] < 0:
                return "error:4"
            if self.state == "Check":
                self._commit_modal(units, dist, wcs_i, words, motion)
                return "ok"
            if self.planner or self.active is not None:
                return "wait"  # G4 waits for the planner to empty, then dwells; ok comes after
            self._commit_modal(units, dist, wcs_i, words, motion)
            self._dwell_until = t_s + words["P"]
            return "wait"
        if nonmodal == 10:
            if "L" not in words or "P" not in words:
                return "error:28"
            p = int(words["P"])
            if words["L"] not in (2, 20) or not (0 <= p <= 6):
                return "error:29" if p > 6 else "error:20"
            idx = wcs_i if p == 0 else p - 1
            for i, c in enumerate(self.letters):
                if c in words:
                    v = words[c] * scale
                    if words["L"] == 2:
                        self.wcs_offsets[idx, i] = v
                    else:
                        self.wcs_offsets[idx, i] = self.gc_pos[i] - self.g92[i] - v
            self._commit_modal(units, dist, wcs_i, words, motion)
            return "ok"
        if nonmodal in (92, 92.1):
            if nonmodal == 92.1:
                self.g92[:] = 0
            else:
                if not axes_here:
                    return "error:26"
                for i, c in enumerate(self.letters):
                    if c in words:
                        self.g92[i] = self.gc_pos[i] - self.wcs_offsets[wcs_i, i] - words[c] * scale
            self._commit_modal(units, dist, wcs_i, words, motion)
            return "ok"
        if not axes_here or motion_mode == 80:
            self._commit_modal(units, dist, wcs_i, words, motion)
            return self._m_words(mwords, t_s)
        if motion_mode == 1 and feed <= 0:
            return "error:22"
        for i, c in enumerate(self.letters):
            if c in words:
                v = words[c] * scale
                if incremental:
                    target[i] = self.gc_pos[i] + v
                elif nonmodal == 53:
                    target[i] = v
                else:
                    target[i] = v + wco[i]
        # The parser keeps the exact programmed position (so incremental moves do not accumulate
        # rounding); the planner gets whole steps, as GRBL's lround(target * steps_per_mm).
        steps_target = self._quantize(target)
        soft = bool(self.settings[20]) and bool(np.any(np.abs(target) > self._half_travel() + 1e-9))
        if jog:
            if soft:
                return "error:15"
        elif soft and self.state != "Check":
            self._soft_limit(t_s)
            return None
        if self.state == "Check":
            self._commit_modal(units, dist, wcs_i, words, motion)
            self.gc_pos = target
            return "ok"
        if len(self.planner) >= gp.PLANNER_BLOCKS - 1:
            return "wait"
        self._commit_modal(units, dist, wcs_i, words, motion)
        if "F" in words:
            self.gc.feed_mm_per_min = feed
        self.gc_pos = target
        self.planner.append(_Block(steps_target, None if motion_mode == 0 else feed, jog=jog))
        if "N" in words:
            self.line_number = int(words["N"])
        if jog and self.state == "Idle":
            self.state = "Jog"
        self._kick(t_s)
        return self._m_words(mwords, t_s)

    def _m_words(self, mwords: list[float], t_s: float) -> str:
        for v in mwords:
            if v in (3, 4, 5):
                self.gc.spindle = int(v)
            elif v in (7, 8, 9):
                self.gc.coolant = int(v)
            elif v in (2, 30):
                self.gc.spindle, self.gc.coolant, self.gc.motion = 5, 9, 1
        return "ok"

    def _commit_modal(self, units: float | None, dist: float | None, wcs_i: int, words: dict[str, float],
                      motion: float | None) -> None:
        g = self.gc
        if units is not None:
            g.inches = units == 20
        if dist is not None:
            g.incremental = dist == 91
        g.wcs = wcs_i
        if motion is not None:
            g.motion = int(motion)
        if "F" in words:
            g.feed_mm_per_min = words["F"] * (25.4 if g.inches else 1.0)
        if "S" in words:
            g.rpm = words["S"]
        if "T" in words:
            g.tool = int(words["T"])

    # -- motion ----------------------------------------------------------------------------------
    def _kick(self, t_s: float) -> None:
        """Start the next planner block if the machine is free to move."""
        if self.active is not None or self.hold or self._critical:
            return
        while self.planner and self.active is None:
            blk = self.planner[0]
            delta = blk.target - self.pos
            length = float(np.linalg.norm(delta))
            if length < 1e-9:
                self.planner.popleft()
                continue
            u = delta / length
            feed = blk.feed_mm_per_min
            if feed is not None and not blk.jog:
                feed *= self.feed_ovr / 100.0
            rates = self._rates() * (self.rapid_ovr / 100.0 if feed is None else 1.0)
            vmax, acc = line_limits(u, rates, self._accels(), feed)
            self.active = Profile(self.pos.copy(), u, length, t_s, trapezoid(length, 0.0, vmax, acc))
            self.active_block = blk
            self._limit_hit = self._switch_crossing(self.active)
            if self.state in ("Idle", "Hold"):
                self.state = "Jog" if blk.jog else "Run"
        if self.active is None and not self.planner and self.state in ("Run", "Jog"):
            self.state = "Idle"

    def _switch_crossing(self, prof: Profile) -> tuple[float, int] | None:
        if not self.settings[21]:
            return None
        sw = self._switch_at()
        best: tuple[float, int] | None = None
        for i in range(self.n_axes):
            if abs(prof.u[i]) < 1e-12 or abs(prof.p0[i]) >= sw[i]:
                continue  # already on the switch: only an edge trips the alarm
            bound = sw[i] if prof.u[i] > 0 else -sw[i]
            d = (bound - prof.p0[i]) / prof.u[i]
            if 0 <= d <= prof.length and (best is None or d < best[0]):
                best = (d, i)
        return best

    def _replan(self, t_s: float) -> None:
        prof, blk = self.active, self.active_block
        assert prof is not None and blk is not None
        d, v = prof.at(t_s)
        here = prof.point(d)
        rest = prof.length - d
        feed = blk.feed_mm_per_min
        if feed is not None and not blk.jog:
            feed *= self.feed_ovr / 100.0
        rates = self._rates() * (self.rapid_ovr / 100.0 if feed is None else 1.0)
        vmax, acc = line_limits(prof.u, rates, self._accels(), feed)
        self.pos = here
        self.active = Profile(here.copy(), prof.u, rest, t_s, trapezoid(rest, v, vmax, acc))
        self._limit_hit = self._switch_crossing(self.active)

    def _feed_hold(self, t_s: float) -> None:
        if self.state in ("Alarm", "Sleep", "Check", "Home") or self.hold:
            return
        if self.state == "Idle":
            self.state, self.hold, self.hold_done = "Hold", True, True
            return
        jog = self.state == "Jog"
        self.advance_to(t_s)
        if self.active is not None:
            prof = self.active
            d, v = prof.at(t_s)
            here = prof.point(d)
            acc = line_limits(prof.u, self._rates(), self._accels(), None)[1]
            stop = min(v * v / (2 * acc), prof.length - d)
            self.pos = here
            self.active = Profile(here.copy(), prof.u, stop, t_s, trapezoid(stop, v, v, acc))
            self._limit_hit = self._switch_crossing(self.active)
        if jog:
            # A jog cancel: decelerate, then drop every queued jog block.
            self.planner.clear()
            self._jog_cancel = True
            if self.active is None:
                self._finish_jog_cancel()
            return
        self.state, self.hold, self.hold_done = "Hold", True, self.active is None

    def _finish_jog_cancel(self) -> None:
        self._jog_cancel = False
        self.active_block = None
        self.gc_pos = self.pos.copy()
        self.state = "Idle"

    def _cycle_start(self, t_s: float) -> None:
        if self.state == "Hold" and self.hold_done:
            self.hold = self.hold_done = False
            self.state = "Idle"
            self._kick(t_s)

    def _start_homing(self, t_s: float) -> str:
        if not self.settings[22]:
            return "error:5"
        self.state = "Home"
        seek = self.settings[25] / 60.0
        sw = self._switch_at()
        if self._fail_next_homing:
            self._fail_next_homing = False
            search_s = float(np.max(1.5 * 2 * self._half_travel() / seek))
            self._home_fail = 9
            self._home_legs = [(t_s, self.pos.copy(), self.pos.copy(), t_s + search_s)]
            self._blocked_home = True
            return "wait"
        legs = []
        t, p = t_s, self.pos.copy()
        # Cycle 0: the θ channel alone; cycle 1: X and Y together (GRBL's default HOMING_CYCLE_0/1).
        for group in ([self.theta_index], [0, 1]):
            at_switch = p.copy()
            at_switch[group] = sw[group]
            dt = float(np.max(np.abs(at_switch[group] - p[group]))) / seek + _HOME_PULLOFF_TIME_S
            legs.append((t, p.copy(), at_switch, t + dt))
            t, p = t + dt, at_switch
            centre = p.copy()
            centre[group] = 0.0
            dt = float(np.max(np.abs(centre[group] - p[group]))) / seek
            legs.append((t, p.copy(), centre, t + dt))
            t, p = t + dt, centre
        self._home_legs = legs
        self._blocked_home = True
        return "wait"

    _blocked_home = False
    _jog_cancel = False

    # -- alarms and resets -----------------------------------------------------------------------
    def _hard_limit(self, t_s: float, axis: int) -> None:
        self._halt()
        self._alarm(1, t_s, critical=True)

    def _soft_limit(self, t_s: float) -> None:
        if self.active is not None and not self.hold:
            self._feed_hold(t_s)
            self._pending_soft_alarm = True  # raised once the hold has stopped the machine
            self._critical = True
            return
        self._halt()
        self._alarm(2, t_s, critical=True)

    def _halt(self) -> None:
        self.planner.clear()
        self.active = None
        self.active_block = None
        self._home_legs = []
        self._blocked_home = False
        self._dwell_until = None
        self.hold = self.hold_done = False
        self.pos = self._quantize(self.pos)
        self.gc_pos = self.pos.copy()

    def _alarm(self, code: int, t_s: float, *, critical: bool) -> None:
        self.state = "Alarm"
        self._critical = critical
        self._blocked = None
        self.rx.clear()
        self.emit(f"ALARM:{code}\r\n".encode(), t_s, reply=False)
        if critical:
            self.emit(b"[MSG:Reset to continue]\r\n", t_s, reply=False)

    def _soft_reset(self, t_s: float) -> None:
        self.advance_to(t_s)
        moving = self.active is not None or bool(self._home_legs)
        alarm = None
        if self._home_legs:
            alarm = 6
        elif moving and self.state in ("Run", "Jog", "Hold"):
            alarm = 3
        latched = self.state == "Alarm"
        self._halt()
        if alarm is not None:
            self.emit(f"ALARM:{alarm}\r\n".encode(), t_s, reply=False)
            if alarm in (3, 6):
                self.homed = False
        self._reset_runtime(t_s)
        self.state = "Alarm" if (alarm is not None or latched or (self.settings[22] and not self.homed)) else "Idle"
        self._booted_at = t_s
        self._banner(t_s)

    # -- time --------------------------------------------------------------------------------------
    def next_event_s(self) -> float | None:
        times = []
        if self.active is not None:
            times.append(self.active.t_end_s if self._limit_hit is None
                         else self.active.time_at_distance(self._limit_hit[0]))
        if self._dwell_until is not None:
            times.append(self._dwell_until)
        if self._home_legs:
            times.append(self._home_legs[-1][3])
        return min(times) if times else None

    def on_tick(self, t_s: float) -> None:
        for _ in range(100000):
            nxt = self.next_event_s()
            if nxt is None or nxt > t_s:
                break
            self._event(nxt)
        self._t_now = max(self._t_now, t_s)
        if self.active is not None:
            d, _ = self.active.at(t_s)
            self.pos = self.active.point(d)
        elif self._home_legs:
            for t0, p0, p1, t1 in self._home_legs:
                if t0 <= t_s <= t1:
                    f = (t_s - t0) / (t1 - t0) if t1 > t0 else 1.0
                    self.pos = p0 + (p1 - p0) * f
                    break
        self._write_stage(t_s)

    def _event(self, t_s: float) -> None:
        self._t_now = max(self._t_now, t_s)
        if self.active is not None and (self._limit_hit is not None and
                                        self.active.time_at_distance(self._limit_hit[0]) <= t_s):
            self.pos = self._quantize(self.active.point(self._limit_hit[0]))
            self._write_stage(t_s)
            self._hard_limit(t_s, self._limit_hit[1])
            return
        if self.active is not None and self.active.t_end_s <= t_s:
            # Steppers stop on a whole step: after a hold or a jog cancel too.
            self.pos = self._quantize(self.active.point(self.active.length))
            self.active = None
            if self.hold:
                self.hold_done = True
            elif self._jog_cancel:
                self._finish_jog_cancel()
            else:
                self.planner.popleft()
            if self._pending_soft_alarm:
                self._pending_soft_alarm = False
                self._halt()
                self._alarm(2, t_s, critical=True)
                return
            self._kick(t_s)
            self._process(t_s)
            return
        if self._dwell_until is not None and self._dwell_until <= t_s:
            self._dwell_until = None
            self._blocked = None
            self.emit(b"ok\r\n", t_s, delay_s=_LINE_DELAY_S)
            self._process(t_s)
            return
        if self._home_legs and self._home_legs[-1][3] <= t_s:
            self.pos = self._home_legs[-1][2].copy()
            self._home_legs = []
            self._blocked_home = False
            self._blocked = None
            if self._home_fail is not None:
                code, self._home_fail = self._home_fail, None
                self._alarm(code, t_s, critical=False)
                return
            self.homed = True
            self.state = "Idle"
            self.gc_pos = self.pos.copy()
            self.emit(b"ok\r\n", t_s, delay_s=_LINE_DELAY_S)
            self._process(t_s)

    def _write_stage(self, t_s: float) -> None:
        self.stage.set_pose(float(self.pos[0]), float(self.pos[1]), float(self.pos[self.theta_index]), t_s)

    # -- reports -------------------------------------------------------------------------------------
    def _speed_mm_per_min(self, t_s: float) -> float:
        if self.active is not None:
            return self.active.at(t_s)[1] * 60.0
        if self._home_legs:
            return self.settings[25]
        return 0.0

    def _status_report(self) -> str:
        t = self._t_now
        state = self.state
        if state == "Hold":
            state = f"Hold:{0 if self.hold_done else 1}"
        mask = int(self.settings[10])
        pos = self.pos if mask & gp.MASK_MPOS else self.pos - self.wco
        parts = [state, f"{'MPos' if mask & gp.MASK_MPOS else 'WPos'}:{_vec(pos)}"]
        if mask & gp.MASK_BUFFER:
            used = len(self.planner)
            parts.append(f"Bf:{gp.PLANNER_BLOCKS - 1 - min(used, gp.PLANNER_BLOCKS - 1)},"
                         f"{gp.RX_BUFFER_SIZE - len(self.rx)}")
        parts.append(f"FS:{_num(self._speed_mm_per_min(t), 0)},{_num(self.gc.rpm if self.gc.spindle != 5 else 0, 0)}")
        sw = self._switch_at()
        pins = "".join(c for i, c in enumerate(self.letters) if abs(self.pos[i]) >= sw[i] - 1e-9)
        if pins:
            parts.append(f"Pn:{pins}")
        busy = state not in ("Idle", "Alarm")
        if self._wco_counter > 0:
            self._wco_counter -= 1
            wco_now = False
        else:
            self._wco_counter = 29 if busy else 9
            wco_now = True
        if self._ovr_counter > 0:
            self._ovr_counter -= 1
        elif not wco_now:
            self._ovr_counter = 19 if busy else 9
            parts.append(f"Ov:{self.feed_ovr},{self.rapid_ovr},{self.spindle_ovr}")
        if wco_now:
            parts.append(f"WCO:{_vec(self.wco)}")
        return "<" + "|".join(parts) + ">"

    def describe(self) -> dict[str, Any]:
        return {"axes": self.n_axes, "theta_axis": self.letters[self.theta_index], "firmware": self.firmware,
                "homing": bool(self.settings[22]), "travel": [self.settings[130 + i] for i in range(self.n_axes)]}


def _normalize(raw: str) -> str:
    """What GRBL's protocol loop keeps of a line: no whitespace, no comments, upper case."""
    out = []
    in_paren = False
    for ch in raw:
        if in_paren:
            in_paren = ch != ")"
        elif ch == "(":
            in_paren = True
        elif ch == ";":
            break
        elif ch.isspace():
            continue
        else:
            out.append(ch.upper())
    return "".join(out)


def _num(v: float, decimals: int) -> str:
    return f"{v:.{decimals}f}"


def _vec(v: np.ndarray) -> str:
    return ",".join(f"{x:.3f}" for x in v)


def _fmt_setting(n: int, v: float) -> str:
    return str(int(v)) if n in gp.INTEGER_SETTINGS else f"{v:.3f}"


def _factory(params: Params, *, clock: Clock, world: Any = None) -> GrblMock:
    stage_name = params.str("stage", "stage") or "stage"
    stage = world.require(stage_name, who="the jig mock") if world is not None else None
    firmware = params.str("firmware", "grbl") or "grbl"
    axes = params.int("axes", 4 if firmware == "grblhal" else 3)
    return GrblMock(
        clock=clock, stage=stage, axes=axes,
        theta_axis=params.str("theta_axis", "A" if axes == 4 else "Z") or "Z",
        firmware=firmware, baud=params.int("baud", gp.BAUD), timing=params.bool("timing", True),
        seed=params.int("seed", 0), homing=params.bool("homing", True), boot_s=params.float("boot_s", 0.0),
    )


register_kind("jig", _factory, default_baud=gp.BAUD,
              description="GRBL 1.1 x-y-theta jig (theta on Z; A with firmware=grblhal)")
