"""Driver of the x-y-θ jig on GRBL 1.1 (θ on a configurable channel: Z on stock GRBL, A on grblHAL).

:class:`Jig` survives the reset on open (banner wait, alarm-on-boot noted), homes (``$H``),
unlocks (``$X``), moves (``move_to``), jogs and cancels jogs, sends feed hold / resume / soft reset
as realtime bytes, parses status reports whatever fields ``$10`` enables (:func:`parse_status`),
waits for Idle, reads and writes settings, and streams G-code with character counting (never more
than GRBL's 128-byte receive buffer in flight). Every ``error:N`` becomes :class:`GrblError` and
every ``ALARM:N`` :class:`GrblAlarm`, with GRBL's own message. It satisfies the controllers'
``Motion`` protocol (``move_toward``, ``pose``, ``stop``).

GRBL's lines carry no checksum, so the wire is checked the ways GRBL allows: status reports are
parsed strictly (GRBL's fixed decimals, known fields; corrupt is ``LinkCorrupt``), Idle positions
are confirmed by two reports, an ``ok``/``error`` lost on the wire is found from later status
reports and resynchronised out of the character counting (``ReplyLost`` for that line), an
unplugged port fails fast and reopens with backoff, and every call holds the driver's lock.
"""

from __future__ import annotations

import logging
import math
import re
from collections import deque
from dataclasses import dataclass, field
from typing import Callable, Iterable

from tactile_rig.core.clock import Clock, Deadline
from tactile_rig.core.errors import (
    DeviceTimeout,
    GrblError,
    GrblReset,
    LimitError,
    LinkCorrupt,
    NotConnected,
    ReplyLost,
    check_range,
)
from tactile_rig.core.geometry import Pose
from tactile_rig.devices import grbl as gp
from tactile_rig.drivers.base import Driver, Lifecycle, locked
from tactile_rig.drivers.reconnect import Reconnect
from tactile_rig.drivers.transport import SerialTransport

log = logging.getLogger("tactile_rig.jig")


# -- status reports -----------------------------------------------------------------------------------

@dataclass(frozen=True)
class GrblStatus:
    """A parsed ``<...>`` report. Positions are tuples in mm (deg on the θ channel); fields the
    ``$10`` mask or the refresh counters left out are None. ``wpos``/``mpos`` are filled from the
    other and the last known WCO when only one is reported."""

    state: str
    substate: int | None = None
    mpos: tuple[float, ...] | None = None
    wpos: tuple[float, ...] | None = None
    wco: tuple[float, ...] | None = None
    feed_mm_per_min: float | None = None
    spindle_rpm: float | None = None
    planner_free: int | None = None
    rx_free: int | None = None
    line_number: int | None = None
    pins: str = ""
    overrides: tuple[int, int, int] | None = None
    accessories: str | None = None
    extras: dict[str, str] = field(default_factory=dict)
    t_host_s: float = 0.0
    raw: str = ""
    inches: bool = False  # GRBL reported in inches ($13=1); the values above are converted to mm

    @property
    def idle(self) -> bool:
        return self.state == "Idle"


# GRBL prints integers and integer parts without leading zeros (print.c): "0.339", never "00.339".
_INT_PART = r"(?:0|[1-9][0-9]{0,6})"
_UINT = re.compile(_INT_PART)
_COORD = {d: re.compile(r"-?%s\.[0-9]{%d}" % (_INT_PART, d)) for d in gp.COORD_DECIMALS.values()}
_RATE = {d: re.compile(_INT_PART + (r"\.[0-9]{%d}" % d if d else "")) for d in gp.RATE_DECIMALS.values()}
_LETTERS = re.compile(r"[A-Z]+")
MM_PER_INCH = 25.4


def _corrupt(what: str, line: str) -> LinkCorrupt:
    return LinkCorrupt(f"corrupt status report {line!r}: {what}")


def _coords(name: str, text: str, line: str) -> tuple[int, tuple[float, ...]]:
    """(decimals, values) of a coordinate field; every value must print with GRBL's fixed decimals."""
    vals = text.split(",")
    if not 1 <= len(vals) <= gp.MAX_AXES:
        raise _corrupt(f"{name} has {len(vals)} values (expected 1 to {gp.MAX_AXES})", line)
    for d, rx in _COORD.items():
        if all(rx.fullmatch(v) for v in vals):
            return d, tuple(float(v) for v in vals)
    raise _corrupt(f"{name}:{text!r} is not GRBL's fixed-decimal format (3 decimals in mm, 4 in inches)", line)


def _uints(name: str, text: str, n: int, line: str) -> tuple[int, ...]:
    vals = text.split(",")
    if len(vals) != n or not all(_UINT.fullmatch(v) for v in vals):
        raise _corrupt(f"{name}:{text!r} is not {n} unsigned integer(s)", line)
    return tuple(int(v) for v in vals)


def parse_status(line: str, t_s: float = 0.0, wco: tuple[float, ...] | None = None) -> GrblStatus:
    """Parse a GRBL 1.1 status report (any field order and presence); raise LinkCorrupt if malformed.

    Strict, because GRBL's lines carry no checksum: the state must be one GRBL prints (with a
    substate only on Hold and Door), field names GRBL's own or grblHAL's (each at most once),
    exactly one of MPos and WPos, and every number in GRBL's fixed format (coordinates with 3
    decimals in mm or 4 in inches, the same in every coordinate field; rates with 0 or 1 decimal to
    match; counters unsigned integers). Inch reports are converted to mm. ``wco`` is the last work
    coordinate offset seen, used to derive the position not reported.
    """
    s = line.strip()
    if len(s) < 3 or s[0] != "<" or s[-1] != ">":
        raise LinkCorrupt(f"not a status report: {line!r} (expected '<State|...>')")
    parts = s[1:-1].split("|")
    state, colon, sub = parts[0].partition(":")
    if state not in gp.STATES:
        raise LinkCorrupt(f"unknown machine state {parts[0]!r} in {line!r}; expected one of {gp.STATES}")
    kw: dict = {"state": state, "raw": s, "t_host_s": t_s}
    if colon:
        allowed = gp.SUBSTATES.get(state)
        if allowed is None or not (sub.isascii() and sub.isdigit() and len(sub) == 1 and int(sub) in allowed):
            raise LinkCorrupt(f"bad substate {parts[0]!r} in {line!r}")
        kw["substate"] = int(sub)
    extras: dict[str, str] = {}
    seen: set[str] = set()
    decimals: set[int] = set()
    coords: dict[str, tuple[float, ...]] = {}
    rates: dict[str, str] = {}
    for part in parts[1:]:
        name, sep, val = part.partition(":")
        if not sep:
            raise LinkCorrupt(f"status field {part!r} has no ':' in {line!r}")
        if name in seen:
            raise _corrupt(f"field {name} appears twice", line)
        seen.add(name)
        if name in gp.COORD_FIELDS:
            d, vals = _coords(name, val, line)
            decimals.add(d)
            coords[name] = vals
        elif name == "Bf":
            kw["planner_free"], kw["rx_free"] = _uints(name, val, 2, line)
        elif name == "Ln":
            kw["line_number"] = _uints(name, val, 1, line)[0]
        elif name in ("F", "FS"):
            if {"F", "FS"} & (seen - {name}):
                raise _corrupt("both F and FS", line)
            texts = val.split(",")
            if len(texts) != (1 if name == "F" else 2):
                raise _corrupt(f"{name}:{val!r} has {len(texts)} value(s)", line)
            rates["feed"] = texts[0]
            if name == "FS":
                if not _UINT.fullmatch(texts[1]):
                    raise _corrupt(f"spindle speed {texts[1]!r} is not an integer (GRBL prints RPM without decimals)",
                                   line)
                kw["spindle_rpm"] = float(texts[1])
        elif name == "Pn":
            if not val or any(c not in gp.PIN_LETTERS + gp.PIN_OVERRIDE_LETTERS for c in val) \
                    or len(set(val)) != len(val):
                raise LinkCorrupt(f"unknown pin letters in Pn:{val!r} in {line!r}")
            kw["pins"] = val
        elif name == "Ov":
            ov = _uints(name, val, 3, line)
            if not all(lo <= v <= hi for v, (lo, hi) in zip(ov, gp.OVERRIDE_LIMITS)) or ov[1] not in gp.RAPID_OVERRIDES:
                raise _corrupt(f"overrides Ov:{val!r} outside GRBL's ranges (feed and spindle 10-200 %, "
                               "rapid 25, 50 or 100 %)", line)
            kw["overrides"] = ov
        elif name == "A":
            if not val or any(c not in gp.ACCESSORY_LETTERS for c in val) or len(set(val)) != len(val):
                raise _corrupt(f"unknown accessory letters in A:{val!r}", line)
            kw["accessories"] = val
        elif name in gp.GRBLHAL_FIELDS:
            extras[name] = val  # grblHAL's own fields, kept as text
        else:
            raise _corrupt(f"unknown field name {name!r} (GRBL 1.1 prints {', '.join(gp.STATUS_FIELDS)})", line)
    if ("MPos" in coords) == ("WPos" in coords):
        raise _corrupt("exactly one of MPos and WPos expected", line)
    if len(decimals) > 1:
        raise _corrupt("coordinate fields mix 3 and 4 decimals", line)
    if len({len(v) for v in coords.values()}) > 1:
        raise _corrupt("coordinate fields have different numbers of axes", line)
    inches = decimals == {gp.COORD_DECIMALS["inch"]}
    unit = "inch" if inches else "mm"
    if "feed" in rates:
        if not _RATE[gp.RATE_DECIMALS[unit]].fullmatch(rates["feed"]):
            raise _corrupt(f"feed {rates['feed']!r} is not GRBL's format for {unit} "
                           f"({gp.RATE_DECIMALS[unit]} decimal(s))", line)
        kw["feed_mm_per_min"] = float(rates["feed"]) * (MM_PER_INCH if inches else 1.0)
    for name, vals in coords.items():
        kw[name.lower()] = tuple(v * MM_PER_INCH for v in vals) if inches else vals
    kw["extras"] = extras
    kw["inches"] = inches
    offset = kw.get("wco") or wco
    if offset is not None:
        if "mpos" in kw and "wpos" not in kw and len(offset) == len(kw["mpos"]):
            kw["wpos"] = tuple(m - o for m, o in zip(kw["mpos"], offset))
        elif "wpos" in kw and "mpos" not in kw and len(offset) == len(kw["wpos"]):
            kw["mpos"] = tuple(w + o for w, o in zip(kw["wpos"], offset))
    return GrblStatus(**kw)


# -- the driver ---------------------------------------------------------------------------------------

@dataclass
class StreamResult:
    """What a character-counted stream did: lines sent, ``ok`` count, rejected lines (number, code,
    text), and lines whose answer was lost on the wire (GRBL executed them; the result is unknown)."""

    sent: int = 0
    ok: int = 0
    errors: list[tuple[int, int, str]] = field(default_factory=list)
    lost: list[int] = field(default_factory=list)
    uncertain: list[int] = field(default_factory=list)  # errors whose line a lost answer makes ambiguous


@dataclass
class _Outstanding:
    ident: int
    line: str
    nbytes: int


@dataclass
class _Fence:
    """A ``?`` in flight: lines with ``ident < next_ident`` reached GRBL before it; ``reports_seen``
    how many reports the host had read when it sent it; ``t_s`` when."""

    next_ident: int
    reports_seen: int
    t_s: float


_DWELL = re.compile(r"G0*4(?![0-9.])")
# Lines that may move the machine (axis words, G28/G30 to a stored position, homing, jogging, sleep)
# and lines that may change the work offset (WCO = coordinate system + G92 + tool length offset).
_MAY_MOVE = re.compile(r"[XYZABC][-+.0-9]|G0*28|G30|^\$H|^\$J|^\$SLP")
_MAY_OFFSET = re.compile(r"G10|G92|G5[4-9]|G43|G49|^\$RST")
# Absolute straight moves (what move_to and move_toward send): their targets bound the path.
_ABS_MOVE = re.compile(r"^(?:\$J=G90|G90G([01]))(?![0-9.])")
_AXIS_WORD = re.compile(r"([XYZA])(-?[0-9]+(?:\.[0-9]*)?)")
_FEED_WORD = re.compile(r"F([0-9]+(?:\.[0-9]*)?)")
ENVELOPE_TOL = 0.03  # mm (deg on θ): a step of the θ axis, plus the printed rounding
FEED_OVERRIDE_MAX = 2.0  # GRBL's feed override tops out at 200 %


def clean_gcode_line(line: str) -> str:
    """A G-code line as worth sending: comments and surrounding whitespace removed."""
    out = []
    depth = 0
    for ch in line:
        if ch == "(":
            depth += 1
        elif ch == ")" and depth:
            depth -= 1
        elif ch == ";" and not depth:
            break
        elif not depth:
            out.append(ch)
    return "".join(out).strip()


class Jig(Driver):
    """The jig's GRBL controller on ``port`` (path or URL), opened here.

    ``theta_axis`` is the GRBL channel θ rides on (``"Z"`` on stock GRBL 1.1, ``"A"`` on grblHAL; its
    steps/mm setting holds steps per degree). ``x_range_mm`` / ``y_range_mm`` / ``theta_range_deg``
    (optional) are checked before a move is sent; the firmware's own soft limits apply as well.

    Lifecycle (:mod:`tactile_rig.drivers.base`): ``active`` once GRBL is unlocked (after a clean boot,
    :meth:`home`, :meth:`unlock` or :meth:`activate`); ``connected`` while it is locked in its boot
    alarm; an ``ALARM:N`` or an unasked reset puts it in ``fault``, where moves are refused until
    :meth:`activate` (soft reset if needed, then home or unlock) starts again from the measured pose.
    """

    def __init__(
        self,
        port: str,
        *,
        baudrate: int = gp.BAUD,
        theta_axis: str = "Z",
        clock: Clock | None = None,
        boot_timeout_s: float = 3.0,
        x_range_mm: tuple[float, float] | None = None,
        y_range_mm: tuple[float, float] | None = None,
        theta_range_deg: tuple[float, float] | None = None,
        device: str | None = None,
        reconnect_policy: Reconnect | None = None,
    ) -> None:
        theta_axis = theta_axis.upper()
        if theta_axis not in ("Z", "A"):
            raise ValueError(f"theta_axis={theta_axis!r}: expected 'Z' (stock GRBL 1.1) or 'A' (grblHAL)")
        super().__init__(device or f"jig@{port}")
        self.port = port
        self.theta_axis = theta_axis
        self.ranges = {"x_mm": x_range_mm, "y_mm": y_range_mm, "theta_deg": theta_range_deg}
        self.transport = SerialTransport(port, baudrate=baudrate, device=self.device, clock=clock)
        self.clock: Clock = self.transport.clock
        self.baudrate = baudrate
        self.boot_timeout_s = boot_timeout_s
        #: when to try reopening a port that vanished (backoff on the port's clock)
        self.reconnect_policy = reconnect_policy if reconnect_policy is not None else Reconnect(self.clock)
        self.disconnects = 0
        self.reconnects = 0
        self._rx = bytearray()
        self._responses: deque[str] = deque()
        self._outstanding: deque[_Outstanding] = deque()
        self._results: dict[int, str] = {}
        self._info: list[str] = []
        self.messages: list[str] = []
        self._alarms: deque[int] = deque()
        self._statuses: deque[GrblStatus] = deque()
        self._next_id = 0
        self._expect_banner = True
        self._unexpected_reset = False
        self.banner: str | None = None
        self.resets = 0
        self.lines_lost = 0
        self.alarm_on_boot = False
        self.needs_reset = False
        self.last_alarm: int | None = None
        self.last_status: GrblStatus | None = None
        self._wco: tuple[float, ...] | None = None
        # Resynchronisation of the character counting (see _reconcile).
        self.rx_buffer_bytes = gp.RX_BUFFER_SIZE
        self.ack_poll_s = 0.1  # no answer for this long while lines are outstanding: ask for a report
        self.replies_lost = 0  # ok/error lines GRBL printed that never arrived intact (detected)
        self.corrupt_reports = 0
        self._fences: deque[_Fence] = deque()
        self._status_errors: deque[LinkCorrupt] = deque()
        self._reports_seen = 0
        self._replies_seen = 0
        self._quiet: tuple[int, int, int] | None = None  # (report no, replies seen, fence ident) of a quiet report
        self._clean_mark = 0  # first ident sent since nothing was outstanding
        # (position field, lines sent) of the last Idle report returned, and of the one before it
        self._last_idle: tuple[tuple[float, ...] | None, int] | None = None
        self._motion_mark = 0  # lines sent that may move the machine
        # Where the machine can be while it moves: the box spanned by the last confirmed Idle work
        # position and the targets of the absolute moves sent since (None: not known), and the
        # fastest feed they asked for (None: a rapid or an unknown line, no bound).
        self._envelope: tuple[list[float], list[float]] | None = None
        self._feed_cap: float | None = None
        #: how far (mm, deg on θ) a report while moving may lie outside the commanded box: at least
        #: half a step of the coarsest axis (θ on the default jig: 0.028 deg per step)
        self.path_tolerance = ENVELOPE_TOL
        self._offset_mark = 0  # lines sent that may change the work offset
        self._wco_mark = -1  # _offset_mark when the remembered WCO was adopted
        self._uncertain: list[tuple[int, int]] = []  # ident ranges whose answers may be shifted by a loss
        try:
            self._await_banner(boot_timeout_s)
        except BaseException:
            self.transport.close()
            raise
        self.lifecycle = Lifecycle.CONNECTED if self.alarm_on_boot else Lifecycle.ACTIVE

    # -- unplug and replug --------------------------------------------------------------------------------
    def _on_not_connected(self, error: NotConnected) -> None:
        """The port failed (unplugged): release it; calls fail fast until the backoff allows a reopen."""
        if self.reconnect_policy.away:
            return
        self.transport.close()
        self.reconnect_policy.lost(str(error))
        self.disconnects += 1
        log.warning("%s: port lost (%s)", self.device, error)

    def _before_call(self) -> None:
        """While the port is away: ``NotConnected`` at once, or, when the backoff allows, a reopen.
        GRBL resets on the reopen: motion in its buffers is gone, so the jig comes back in fault
        (``GrblReset``) and moves are refused until :meth:`activate` starts from the measured pose."""
        policy = getattr(self, "reconnect_policy", None)
        if policy is None or not policy.away or self.closed:
            return
        if not policy.due():
            raise policy.not_connected(self.device, self.port)
        try:
            self.transport = SerialTransport(self.port, baudrate=self.baudrate, device=self.device, clock=self.clock)
            self._rx.clear()
            self.lines_lost += len(self._outstanding)
            for item in (self._outstanding, self._results, self._statuses, self._status_errors, self._fences,
                         self._alarms):
                item.clear()
            self._quiet = None
            self._expect_banner = True
            self._await_banner(self.boot_timeout_s)
        except (NotConnected, DeviceTimeout) as exc:
            self.transport.close()
            policy.failed(str(exc))
            raise NotConnected(f"port {self.port!r} is still gone: {exc}", device=self.device) from exc
        policy.succeeded()
        self.reconnects += 1
        self._unexpected_reset = False
        self.resets += 1
        self.fault(GrblReset("the port came back after an unplug: GRBL rebooted and buffered motion was lost; "
                             "activate() to continue from the measured pose", device=self.device))

    # -- plumbing ---------------------------------------------------------------------------------------
    def _await_banner(self, timeout_s: float) -> None:
        dl = Deadline(self.clock, timeout_s)
        nudged = False
        while self._expect_banner:
            if dl.expired():
                if not nudged:
                    # No reset on open (a board without auto-reset, or GRBL already running): ask for one.
                    nudged = True
                    self.transport.write(gp.RT_SOFT_RESET)
                    dl = Deadline(self.clock, timeout_s)
                    continue
                raise DeviceTimeout(f"no GRBL banner ('{gp.BANNER_PREFIX}...') within {timeout_s:.3g} s of "
                                   f"opening and a soft reset (check the port, the baud rate, and that "
                                   f"the board runs GRBL)", device=self.device)
            self._pump(dl.remaining_s() or 0.0)
        # The unlock hint follows the banner by a line; give it a moment to arrive.
        self._pump(0.02)
        self._alarms.clear()

    def _pump(self, wait_s: float) -> int:
        data = self.transport.read_some(1, wait_s)
        if data:
            data += self.transport.read_available()
        if not data:
            return 0
        self._rx += data
        n = 0
        t = self.clock.now_s()
        while True:
            idx = self._rx.find(b"\n")
            if idx < 0:
                break
            raw = bytes(self._rx[:idx]).strip().decode("ascii", "replace")
            del self._rx[: idx + 1]
            if raw:
                self._on_line(raw, t)
                n += 1
        return n

    def _on_line(self, line: str, t_s: float) -> None:
        if line == "ok" or (line.startswith("error:") and line[6:].isdigit()):
            self._replies_seen += 1
            if self._outstanding:
                item = self._outstanding.popleft()
                self._results[item.ident] = line
                if not self._outstanding:
                    self._clean_mark = self._next_id
            else:
                log.warning("%s: %r with no line outstanding", self.device, line)
        elif line.startswith("<"):
            fence = self._answer_fence(t_s)
            try:
                st = parse_status(line, t_s, self._wco)
            except LinkCorrupt as exc:
                self.corrupt_reports += 1
                log.warning("%s: %s", self.device, exc)
                exc.device = self.device
                self._status_errors.append(exc)
                self._quiet = None
                return
            if (st.wco is not None and self._wco is not None and st.wco != self._wco
                    and self._wco_mark == self._offset_mark):
                # No line that changes the work offset was sent since it was last seen: the report
                # was corrupted on the wire (its WCO would make every work position after it wrong).
                self.corrupt_reports += 1
                err = LinkCorrupt(f"corrupt status report {line!r}: WCO changed from {self._wco} with no "
                                  "offset-changing line sent", device=self.device)
                log.warning("%s: %s", self.device, err)
                self._status_errors.append(err)
                self._quiet = None
                return
            self._reports_seen += 1
            if st.wco is not None:
                self._wco = st.wco
                self._wco_mark = self._offset_mark
            self.last_status = st
            self._statuses.append(st)
            while len(self._statuses) > 8:
                self._statuses.popleft()
            if fence is not None:
                self._reconcile(st, fence)
        elif line.startswith("ALARM:"):
            try:
                self._alarms.append(int(line[6:]))
                self.last_alarm = self._alarms[-1]
                if self.last_alarm in (1, 2):
                    self.needs_reset = True  # hard and soft limits are critical: GRBL waits for a reset
            except ValueError:
                log.warning("%s: bad alarm line %r", self.device, line)
        elif line.startswith("Grbl"):
            self.banner = line
            self.needs_reset = False
            self.lines_lost += len(self._outstanding)
            self._outstanding.clear()  # a reset empties GRBL's buffers: those lines never run
            self._fences.clear()
            self._quiet = None
            self._clean_mark = self._next_id
            self._last_idle = None  # a reboot may have lost the position without a line sent
            self._envelope = None
            self._wco = None  # ... and clears G92
            if self._expect_banner:
                self._expect_banner = False
            else:
                self.resets += 1
                self._unexpected_reset = True
        elif line.startswith("[MSG:"):
            self.messages.append(line)
            if "Reset to continue" in line:
                self.needs_reset = True  # a critical alarm: GRBL reads no line until a soft reset
            if "to unlock" in line:
                self.alarm_on_boot = True
        else:
            self._info.append(line)

    # -- resynchronisation -------------------------------------------------------------------------------
    def _request_status(self) -> None:
        """Write ``?`` unless one is already in flight (GRBL merges ``?`` sent before it reports)."""
        now = self.clock.now_s()
        while self._fences and now - self._fences[0].t_s > self.ack_poll_s:
            self._fences.popleft()  # its report never arrived intact
        if self._fences:
            return
        self._fences.append(_Fence(self._next_id, self._reports_seen, now))
        self.transport.write(gp.RT_STATUS)

    def _answer_fence(self, t_s: float) -> _Fence | None:
        while self._fences and t_s - self._fences[0].t_s > 1.0:
            self._fences.popleft()
        return self._fences.popleft() if self._fences else None

    def _reconcile(self, st: GrblStatus, fence: _Fence) -> None:
        """Find answers GRBL printed that never arrived, from a status report, and stop waiting for them.

        GRBL prints a report only at a checkpoint of its main loop: before executing a line it has
        read, or when its receive buffer is empty. Every line written before the ``?`` had reached
        it, and every answer printed before the report arrives before it. So (1) with ``Bf:`` the
        unread lines are the newest outstanding ones whose sizes add up to the bytes in its buffer;
        the line before them may be executing; any older one was answered and the answer lost.
        (2) Two reports in a quiescent state (Idle, Alarm, Check; buffer empty when reported), the
        second asked for after the first arrived, with no answer between them: every line written
        before the first has been answered (a dwell, G4, excepted: it waits in Idle).
        """
        out = self._outstanding
        if any(o.ident >= fence.next_ident for o in out):
            self._quiet = None  # a line may still be on the wire: nothing can be concluded
            return
        lost = 0
        if st.rx_free is not None:
            used = self.rx_buffer_bytes - st.rx_free
            k, acc = len(out), 0
            while acc < used and k > 0:
                k -= 1
                acc += out[k].nbytes
            if acc == used:
                lost = max(0, k - 1)
        quiet = st.state in gp.QUIESCENT_STATES and (st.rx_free is None or st.rx_free >= self.rx_buffer_bytes)
        if quiet and self._quiet is not None:
            q_report, q_replies, q_fence = self._quiet
            if fence.reports_seen >= q_report and self._replies_seen == q_replies:
                n = 0
                for o in out:
                    if o.ident >= q_fence or _DWELL.search(o.line):
                        break
                    n += 1
                lost = max(lost, n)
        self._quiet = (self._reports_seen, self._replies_seen, fence.next_ident) if quiet else None
        if lost:
            self._uncertain.append((self._clean_mark, out[lost - 1].ident + 1))
            del self._uncertain[:-16]
            for _ in range(lost):
                item = out.popleft()
                self._results[item.ident] = "lost"
                self.replies_lost += 1
                log.warning("%s: the answer to %r was lost on the wire (GRBL has executed it: %s)",
                            self.device, item.line, st.raw)
            if not out:
                self._clean_mark = self._next_id

    def _wait_progress(self, deadline: Deadline) -> None:
        """Read what arrives; while lines are outstanding and nothing comes, ask for a status report
        (the report is how a lost answer is found)."""
        got = self._pump(min(self.ack_poll_s, deadline.remaining_s() or 0.0))
        if not got and self._outstanding and not deadline.expired():
            self._request_status()

    def _check_events(self) -> None:
        if self._unexpected_reset:
            self._unexpected_reset = False
            raise self.fault(GrblReset("GRBL reset unexpectedly (banner mid-session): buffered motion was lost",
                                       device=self.device))
        if self._alarms:
            raise self.fault(gp.alarm(self._alarms.popleft(), device=self.device))

    def _send_line(self, line: str, deadline: Deadline) -> int:
        """Send one line when GRBL's receive buffer has room for it (character counting)."""
        data = line.encode("ascii") + b"\n"
        if len(data) > gp.RX_BUFFER_SIZE:
            raise ValueError(f"G-code line of {len(data)} bytes exceeds GRBL's {gp.RX_BUFFER_SIZE}-byte buffer: {line!r}")
        while sum(o.nbytes for o in self._outstanding) + len(data) > gp.RX_BUFFER_SIZE:
            self._check_events()
            if deadline.expired():
                raise DeviceTimeout(f"GRBL's receive buffer did not drain within {deadline.timeout_s:.3g} s",
                                    device=self.device)
            self._wait_progress(deadline)
        ident = self._next_id
        if not self._outstanding:
            self._clean_mark = ident
        upper = line.upper()
        if _MAY_MOVE.search(upper):
            self._motion_mark += 1
            self._extend_envelope(upper)
        if _MAY_OFFSET.search(upper):
            self._offset_mark += 1
            self._envelope = None
        self._next_id += 1
        self._outstanding.append(_Outstanding(ident, line, len(data)))
        self.transport.write(data)
        return ident

    def _await_result(self, ident: int, deadline: Deadline, what: str) -> str:
        while ident not in self._results:
            self._check_events()
            if not any(o.ident == ident for o in self._outstanding):
                raise self.fault(GrblReset(f"{what} was lost: GRBL reset before answering", device=self.device))
            if deadline.expired():
                raise DeviceTimeout(f"no 'ok' or 'error' for {what} within {deadline.timeout_s:.3g} s",
                                    device=self.device)
            self._wait_progress(deadline)
        return self._results.pop(ident)

    @locked
    def command(self, line: str, timeout_s: float = 2.0) -> list[str]:
        """Send one line, wait for its ``ok``; return the info lines it printed. ``error:N`` → GrblError."""
        self._check_events()
        if self.needs_reset:
            raise self.fault(gp.alarm(self.last_alarm or 0, device=self.device, hint=f"{line!r} not sent: only "
                                      "a soft reset (soft_reset() or activate()) clears this alarm"))
        dl = Deadline(self.clock, timeout_s)
        self._info.clear()
        ident = self._send_line(line, dl)
        result = self._await_result(ident, dl, repr(line))
        info = list(self._info)
        self._info.clear()
        if result == "lost":
            raise ReplyLost(f"GRBL executed {line!r} but its answer was lost on the wire (a later status "
                            "report shows its buffer empty); read the state back before relying on it",
                            device=self.device, line=line)
        if result != "ok":
            raise gp.error(_error_code(result), device=self.device, line=line)
        return info

    # -- status and waiting ---------------------------------------------------------------------------------
    @locked
    def status(self, timeout_s: float = 0.5) -> GrblStatus:
        """Ask for a status report (``?``) and return it parsed. GRBL answers none in a critical
        alarm (hard or soft limit) until a soft reset: that, or a report that an alarm held back
        past ``timeout_s``, raises :class:`GrblAlarm` instead of a timeout.

        GRBL's lines carry no checksum, and a flipped digit is still a number in GRBL's format. A
        machine that was Idle and has been sent no line that moves it since (no axis word, G28/G30,
        $H, $J) cannot have moved: when such a report disagrees with the previous one, a third
        decides (two that agree), else :class:`LinkCorrupt`; the first Idle report after motion is
        confirmed by a second one. Reports while moving cannot be checked this way. Likewise a
        report whose WCO changed with no offset-changing line sent (G10, G92, G54-G59, G43.1/G49,
        $RST) is ``LinkCorrupt``.
        """
        st = self._status_once(timeout_s)
        if st.state != "Idle":
            self._last_idle = None
            if st.state in ("Run", "Jog", "Hold"):
                self._check_moving(st)
            return st
        prev = self._last_idle
        if prev is None or prev[1] != self._motion_mark:
            # Nothing to hold this position against yet: a second report must agree.
            other = self._status_once(timeout_s)
            if other.state != "Idle":  # it started moving (a queued line): that is the news
                self._last_idle = None
                return other
            prev_pos = _position(other)
            if prev_pos == _position(st):
                return self._idle(other)
        else:
            prev_pos = prev[0]
            if prev_pos == _position(st):
                return self._idle(st)
        third = self._status_once(timeout_s)
        if third.state == "Idle" and _position(third) in (_position(st), prev_pos):
            self.corrupt_reports += 1  # the odd one out was corrupted on the wire
            return self._idle(third)
        self._last_idle = None
        raise LinkCorrupt(f"three Idle reports with no motion line sent between them disagree on the position: "
                          f"{prev_pos}, {st.raw!r}, {third.raw!r}", device=self.device)

    def _idle(self, st: GrblStatus) -> GrblStatus:
        self._last_idle = (_position(st), self._motion_mark)
        if st.wpos is not None and not st.inches:
            self._envelope = (list(st.wpos), list(st.wpos))
            self._feed_cap = 0.0
        else:
            self._envelope = None
        return st

    def _extend_envelope(self, upper: str) -> None:
        """A line that may move was sent: widen the box to its target, or forget the box."""
        m = _ABS_MOVE.match(upper)
        if self._envelope is None or m is None or "G9" in upper[m.end():]:
            self._envelope = None
            self._feed_cap = None
            return
        lo, hi = self._envelope
        for letter, value in _AXIS_WORD.findall(upper[m.end():]):
            i = gp.AXIS_LETTERS.index(letter)
            if i >= len(lo):
                self._envelope = None
                return
            lo[i], hi[i] = min(lo[i], float(value)), max(hi[i], float(value))
        feed = _FEED_WORD.search(upper)
        if m.group(1) == "0" or feed is None or self._feed_cap is None:
            self._feed_cap = None  # a rapid runs at each axis's maximum rate, which the driver need not know
        else:
            self._feed_cap = max(self._feed_cap, float(feed.group(1)))

    def _check_moving(self, st: GrblStatus) -> None:
        """A report while moving must lie on the way the driver sent the machine, at a feed it asked
        for: else it was corrupted on the wire (a digit flipped into a digit parses)."""
        env = self._envelope
        if env is not None and st.wpos is not None and not st.inches and len(st.wpos) == len(env[0]):
            for i, v in enumerate(st.wpos):
                if not env[0][i] - self.path_tolerance <= v <= env[1][i] + self.path_tolerance:
                    self.corrupt_reports += 1
                    raise LinkCorrupt(f"corrupt status report {st.raw!r}: axis {gp.AXIS_LETTERS[i]} at {v:.3f}, "
                                      f"outside the path commanded [{env[0][i]:.3f}, {env[1][i]:.3f}]",
                                      device=self.device)
        if (self._feed_cap is not None and st.feed_mm_per_min is not None
                and st.feed_mm_per_min > self._feed_cap * FEED_OVERRIDE_MAX + 1.0):
            self.corrupt_reports += 1
            raise LinkCorrupt(f"corrupt status report {st.raw!r}: feed {st.feed_mm_per_min:g} mm/min, above the "
                              f"{self._feed_cap:g} mm/min commanded (x{FEED_OVERRIDE_MAX:g} override)",
                              device=self.device)

    def _status_once(self, timeout_s: float) -> GrblStatus:
        if self.needs_reset:
            raise self.fault(gp.alarm(self.last_alarm or 0, device=self.device,
                                      hint="GRBL sends no status until a soft reset (soft_reset() or activate())"))
        self._statuses.clear()
        self._status_errors.clear()
        self._request_status()
        dl = Deadline(self.clock, timeout_s)
        while not self._statuses:
            if self._status_errors:
                err = self._status_errors.popleft()
                self._status_errors.clear()
                raise err
            if dl.expired():
                if self._alarms:
                    raise self.fault(gp.alarm(self._alarms.popleft(), device=self.device))
                raise DeviceTimeout(f"no status report within {timeout_s:.3g} s of '?'", device=self.device)
            self._pump(min(self.ack_poll_s, dl.remaining_s() or 0.0))
            if not self._statuses and not self._status_errors:
                self._request_status()  # re-asks only once the first '?' has gone unanswered
        st = self._statuses.pop()
        self._statuses.clear()
        return st

    @locked
    def wait_idle(self, timeout_s: float = 30.0, poll_s: float = 0.05) -> GrblStatus:
        """Poll until every sent line is answered and the machine is Idle; alarms raise GrblAlarm."""
        dl = Deadline(self.clock, timeout_s)
        while True:
            self._check_events()
            st = self.status(min(0.5, max(0.05, dl.remaining_s() or 0.05)))
            self._check_events()
            if st.state == "Idle" and not self._outstanding:
                return st
            if st.state == "Alarm":
                raise self.fault(gp.alarm(self._alarms.popleft() if self._alarms else 0, device=self.device))
            if dl.expired():
                raise DeviceTimeout(f"not Idle within {timeout_s:.3g} s (state {st.state}, "
                                    f"{len(self._outstanding)} line(s) unanswered)", device=self.device)
            self.clock.sleep(min(poll_s, dl.remaining_s() or 0.0))
            self._pump(0.0)

    # -- machine commands -------------------------------------------------------------------------------------
    @locked
    def home(self, timeout_s: float = 60.0) -> None:
        """Run the homing cycle (``$H``); returns when GRBL answers ``ok`` (the cycle is done)."""
        self.command("$H", timeout_s)
        self.alarm_on_boot = False
        self._unlocked()

    @locked
    def unlock(self) -> None:
        """Clear an alarm lock without homing (``$X``): only if you know where the stage is."""
        self.command("$X")
        self.alarm_on_boot = False
        self._unlocked()

    def _unlocked(self) -> None:
        self.lifecycle = Lifecycle.ACTIVE
        self.last_fault = None

    @locked
    def activate(self, *, home: bool = True, timeout_s: float = 60.0) -> None:
        """Make the jig ready to move from wherever it is: a soft reset if a critical alarm needs one,
        then, if GRBL is locked (Alarm), ``$H`` (``home=True``) or ``$X`` (only if you know where the
        stage is). Clears a fault; the next move starts from the measured pose."""
        self.require_open()
        if self.needs_reset:
            self.soft_reset()
        self._alarms.clear()
        self._unexpected_reset = False
        st = self.status()
        if st.state.startswith("Alarm"):
            if home:
                self.home(timeout_s)
            else:
                self.unlock()
        self._unlocked()

    def feed_hold(self) -> None:
        """Decelerate to a stop, keeping the rest of the program (``!``); ``resume`` continues.
        Takes no lock (like ``resume`` and ``jog_cancel``): another thread can stop a stream at once."""
        self.transport.write(gp.RT_FEED_HOLD)

    def resume(self) -> None:
        """Cycle start / resume after a feed hold (``~``)."""
        self.transport.write(gp.RT_CYCLE_START)

    def jog_cancel(self) -> None:
        """Stop a jog and drop the queued jog motions (0x85)."""
        self.transport.write(gp.RT_JOG_CANCEL)

    @locked
    def soft_reset(self, timeout_s: float = 2.0) -> None:
        """Ctrl-X: GRBL stops at once and reboots; waits for the banner. Unanswered lines are lost
        (counted in ``lines_lost``); a reset while moving leaves ALARM:3 (reported by ``status``)."""
        self._expect_banner = True
        self.transport.write(gp.RT_SOFT_RESET)
        dl = Deadline(self.clock, timeout_s)
        while self._expect_banner:
            if dl.expired():
                raise DeviceTimeout(f"no banner within {timeout_s:.3g} s of a soft reset", device=self.device)
            self._pump(dl.remaining_s() or 0.0)
        self._pump(0.02)
        self._alarms.clear()
        self._results.clear()

    def _axis_words(self, x_mm: float | None, y_mm: float | None, theta_deg: float | None) -> str:
        words = []
        for letter, name, v in (("X", "x_mm", x_mm), ("Y", "y_mm", y_mm), (self.theta_axis, "theta_deg", theta_deg)):
            if v is None:
                continue
            if not math.isfinite(v):
                raise ValueError(f"{name}={v!r} must be a finite number")
            words.append(f"{letter}{v:.3f}")
        return "".join(words)

    def _check_ranges(self, **pose: float | None) -> None:
        for name, v in pose.items():
            rng = self.ranges.get(name)
            if v is not None and rng is not None and not (rng[0] <= v <= rng[1]):
                unit = "deg" if name == "theta_deg" else "mm"
                raise LimitError(f"{name}={v!r} {unit} is outside the jig's travel [{rng[0]}, {rng[1]}] {unit}",
                                 device=self.device)

    @locked
    def move_to(self, x_mm: float | None = None, y_mm: float | None = None, theta_deg: float | None = None,
                feed_mm_per_min: float | None = None, *, wait: bool = False, timeout_s: float = 60.0) -> None:
        """Go to a work-coordinate pose (None: that axis stays). ``feed_mm_per_min`` None: a rapid (G0),
        each axis at its own maximum rate. With ``wait`` returns when Idle there."""
        self.require_not_faulted("move_to")
        self._check_ranges(x_mm=x_mm, y_mm=y_mm, theta_deg=theta_deg)
        words = self._axis_words(x_mm, y_mm, theta_deg)
        if not words:
            return
        if feed_mm_per_min is None:
            line = f"G90G0{words}"
        else:
            check_range("feed_mm_per_min", feed_mm_per_min, 1e-3, 1e6, "mm/min")
            line = f"G90G1{words}F{feed_mm_per_min:.1f}"
        self.command(line, timeout_s)
        if wait:
            self.wait_idle(timeout_s)

    @locked
    def jog(self, dx_mm: float = 0.0, dy_mm: float = 0.0, dtheta_deg: float = 0.0, *,
            feed_mm_per_min: float, relative: bool = True) -> None:
        """Jog (``$J=``): relative by default; absolute work coordinates with ``relative=False``.
        A jog past the soft limits is refused by GRBL (error:15 → GrblError)."""
        self.require_not_faulted("jog")
        check_range("feed_mm_per_min", feed_mm_per_min, 1e-3, 1e6, "mm/min")
        if not relative:
            self._check_ranges(x_mm=dx_mm, y_mm=dy_mm, theta_deg=dtheta_deg)
            words = self._axis_words(dx_mm, dy_mm, dtheta_deg)
        else:  # a zero step is no motion: leave the word out (an all-zero jog sends nothing)
            words = self._axis_words(*(v if v != 0.0 else None for v in (dx_mm, dy_mm, dtheta_deg)))
            if not words:
                return
        self.command(f"$J={'G91' if relative else 'G90'}{words}F{feed_mm_per_min:.1f}")

    # -- settings --------------------------------------------------------------------------------------------------
    @locked
    def read_settings(self) -> dict[int, float]:
        """``$$`` → {setting number: value}."""
        out: dict[int, float] = {}
        for line in self.command("$$"):
            if line.startswith("$") and "=" in line:
                key, _, val = line[1:].partition("=")
                try:
                    out[int(key)] = float(val.split(" ")[0])
                except ValueError:
                    continue
        return out

    @locked
    def write_setting(self, number: int, value: float) -> None:
        """``$N=value`` (persists in GRBL's EEPROM); unknown numbers are refused here, bad values by GRBL."""
        if number not in gp.SETTINGS:
            raise ValueError(f"GRBL setting ${number} does not exist; known: {sorted(gp.SETTINGS)}")
        text = str(int(value)) if number in gp.INTEGER_SETTINGS else f"{float(value):.3f}"
        self.command(f"${number}={text}")

    @locked
    def set_check_mode(self, enabled: bool, timeout_s: float = 2.0) -> None:
        """Enter or leave check mode (``$C``: lines are parsed and answered but nothing moves).
        Leaving it soft-resets GRBL, as the firmware does; this waits for that banner."""
        if (self.status().state == "Check") == bool(enabled):
            return
        if not enabled:
            self._expect_banner = True
        self.command("$C", timeout_s)
        dl = Deadline(self.clock, timeout_s)
        while self._expect_banner:
            if dl.expired():
                raise DeviceTimeout(f"no banner within {timeout_s:.3g} s of leaving check mode", device=self.device)
            self._pump(dl.remaining_s() or 0.0)

    @locked
    def build_info(self) -> list[str]:
        return self.command("$I")

    @locked
    def parser_state(self) -> list[str]:
        return self.command("$G")

    # -- streaming ------------------------------------------------------------------------------------------------------
    @locked
    def stream(self, lines: Iterable[str], *, timeout_s: float = 600.0, stop_on_error: bool = True,
               on_progress: Callable[[int, str, str], None] | None = None) -> StreamResult:
        """Stream G-code with character counting; returns when every sent line is answered.

        On ``error:N`` with ``stop_on_error`` nothing more is sent and :class:`GrblError` is raised
        (naming the line) once the lines already in GRBL's buffer are answered.
        """
        self.require_not_faulted("stream")
        self._check_events()
        dl = Deadline(self.clock, timeout_s)
        res = StreamResult()
        pending: deque[tuple[int, int, str]] = deque()  # (ident, line number, text)
        first_error: tuple[int, int, int, str] | None = None  # (ident, line number, code, text)
        numbers: dict[int, int] = {}  # ident -> line number, to name the lines an answer may belong to
        errors_at: list[int] = []  # idents of res.errors, in order
        self._uncertain.clear()

        def window(ident: int) -> list[int] | None:
            # An answer lost before this one shifts it by a line: the line numbers it may belong to.
            for lo, hi in self._uncertain:
                if lo <= ident < hi:
                    nos = [numbers[i] for i in range(lo, hi) if i in numbers]
                    return nos if len(nos) > 1 else None
            return None

        def which(ident: int, no: int, text: str) -> str:
            nos = window(ident)
            if nos is not None:
                return f"one of lines {nos[0]}-{nos[-1]} (an answer was lost on the wire)"
            return f"{no}: {text}"

        def collect() -> None:
            nonlocal first_error
            while pending and pending[0][0] in self._results:
                ident, no, text = pending.popleft()
                r = self._results.pop(ident)
                if on_progress is not None:
                    on_progress(no, text, r)
                if r == "ok":
                    res.ok += 1
                elif r == "lost":
                    res.lost.append(no)
                else:
                    code = _error_code(r)
                    res.errors.append((no, code, text))
                    errors_at.append(ident)
                    if first_error is None:
                        first_error = (ident, no, code, text)

        for no, raw in enumerate(lines, start=1):
            text = clean_gcode_line(raw)
            if not text:
                continue
            collect()
            if first_error is not None and stop_on_error:
                break
            ident = self._send_line(text, dl)
            numbers[ident] = no
            pending.append((ident, no, text))
            res.sent += 1
            self._pump(0.0)
        while pending:
            collect()
            if not pending:
                break
            self._check_events()
            if dl.expired():
                raise DeviceTimeout(f"{len(pending)} streamed line(s) unanswered after {timeout_s:.3g} s",
                                    device=self.device)
            self._wait_progress(dl)
        # Attribution is settled only once every answer is in: a loss found late shifts earlier ones.
        res.uncertain = [no for (no, _, _), ident in zip(res.errors, errors_at) if window(ident) is not None]
        if first_error is not None and stop_on_error:
            ident, no, code, text = first_error
            raise gp.error(code, device=self.device, line=which(ident, no, text))
        return res

    # -- Motion protocol -------------------------------------------------------------------------------------------------
    @locked
    def move_toward(self, target: Pose, speed_mps: float) -> None:
        """Start moving toward ``target`` (a Pose: x_mm, y_mm, theta_deg) at ``speed_mps`` (mm/s × 1000
        along the combined path, θ counted in degrees as GRBL does). A newer call replaces an older one."""
        self.require_not_faulted("move_toward")
        check_range("speed_mps", speed_mps, 1e-6, 10.0, "m/s")
        self._check_ranges(x_mm=target.x_mm, y_mm=target.y_mm, theta_deg=target.theta_deg)
        st = self.last_status
        if st is not None and st.state == "Jog":
            self.jog_cancel()
        words = self._axis_words(target.x_mm, target.y_mm, target.theta_deg)
        self.command(f"$J=G90{words}F{speed_mps * 60000.0:.1f}")

    @locked
    def pose(self) -> Pose:
        """The work-coordinate pose now (mm, θ in degrees)."""
        return self.pose_from_status(self.status())

    def pose_from_status(self, st: GrblStatus) -> Pose:
        """The work-coordinate pose in a status report (WPos, else MPos); ``LinkCorrupt`` if it has none."""
        pos = st.wpos or st.mpos
        if pos is None:
            raise LinkCorrupt(f"status report has no position: {st.raw!r}", device=self.device)
        idx = gp.AXIS_LETTERS.index(self.theta_axis)
        if idx >= len(pos):
            raise LinkCorrupt(f"status reports {len(pos)} axes; θ is on {self.theta_axis}: {st.raw!r}",
                              device=self.device)
        return Pose(x_mm=pos[0], y_mm=pos[1], z_mm=0.0, theta_deg=pos[idx])

    @locked
    def stop(self) -> None:
        """Stop as fast as GRBL allows: jog cancel when jogging, else feed hold, then flush the plan
        with a soft reset once stopped (position is kept; no alarm)."""
        st = self.status()
        if st.state == "Jog":
            self.jog_cancel()
            return
        if st.state in ("Run", "Hold"):
            self.feed_hold()
            dl = Deadline(self.clock, 5.0)
            while not (st.state == "Hold" and st.substate == 0) and st.state != "Idle" and not dl.expired():
                self.clock.sleep(0.01)
                st = self.status()
            self.soft_reset()

    def _close(self) -> None:
        self.transport.close()


def _position(st: GrblStatus) -> tuple[float, ...] | None:
    """The position field a report printed (MPos or WPos), for comparing reports."""
    return st.mpos if "MPos:" in st.raw else st.wpos


def _error_code(line: str) -> int:
    try:
        return int(line.split(":", 1)[1])
    except (IndexError, ValueError):
        raise LinkCorrupt(f"unreadable GRBL error line {line!r}") from None
