"""GRBL 1.1's line protocol on a serial port: banner, answers, alarms, status reports, commands, streaming.

:class:`GrblController` survives the reset on open (banner wait, alarm-on-boot noted), sends a
line and waits for its ``ok`` (``error:N`` → :class:`~tactile_rig.core.errors.GrblError`, ``ALARM:N``
→ :class:`~tactile_rig.core.errors.GrblAlarm`, with GRBL's own messages), sends feed hold / resume
/ soft reset as realtime bytes, reads status reports, waits for Idle, and streams G-code with
character counting (never more than GRBL's 128-byte receive buffer in flight).

GRBL's lines carry no checksum, so the wire is checked the ways GRBL allows: reports are parsed
strictly (:mod:`.status`), Idle positions are confirmed by two reports, reports read in motion must
lie on the commanded path (:mod:`.envelope`), and an ``ok``/``error`` lost on the wire is found from
later reports and resynchronised out of the character counting (:mod:`.link`; ``ReplyLost`` for
that line). The line pump, the reconnect with backoff after an unplug and the counters are the
driver template's (:class:`~tactile_rig.drivers.lines.LineDriver`). The jig's axes, limits and
motion are :class:`~tactile_rig.drivers.grbl.jig.Jig`, built on this.
"""

from __future__ import annotations

import logging
from collections import deque
from dataclasses import dataclass
from typing import Iterable

from tactile_rig.core.clock import Clock, Deadline
from tactile_rig.core.deprecation import deprecated_alias
from tactile_rig.core.errors import DeviceTimeout, GrblReset, LinkCorrupt, ReplyLost
from tactile_rig.devices import grbl as gp
from tactile_rig.drivers.base import DriverStats, Lifecycle, locked
from tactile_rig.drivers.grbl.envelope import PathEnvelope
from tactile_rig.drivers.grbl.link import (
    CharacterCounter,
    ProgressCallback,
    StreamResult,
    StreamTracker,
    clean_gcode_line,
    error_code,
    is_answer,
)
from tactile_rig.drivers.grbl.status import GrblStatus, parse_status, reported_position
from tactile_rig.drivers.lines import LineDriver, LineSplitter
from tactile_rig.drivers.reconnect import Reconnect
from tactile_rig.drivers.transport import SerialTransport

log = logging.getLogger("tactile_rig.jig")


@dataclass
class GrblStats(DriverStats):
    """Counters of a GRBL link (besides the port's disconnects and reconnects)."""

    resets: int = 0  #: GRBL rebooted when no reset was asked for (a banner mid-session, a replug)
    lines_lost: int = 0  #: lines sent but never run (a reset emptied GRBL's buffers first)
    replies_lost: int = 0  #: ``ok``/``error`` lines GRBL printed that never arrived intact (detected)
    corrupt_reports: int = 0  #: status reports refused as corrupted on the wire


class GrblController(LineDriver):
    """GRBL on ``port`` (path or URL), opened here; waits up to ``boot_timeout_s`` for its banner.

    ``active`` once GRBL is unlocked (after a clean boot); ``connected`` while it is locked in its
    boot alarm; an ``ALARM:N`` or an unasked reset puts it in ``fault``.
    """

    stats: GrblStats
    transport: SerialTransport

    def __init__(
        self,
        port: str,
        *,
        baudrate: int = gp.BAUD,
        clock: Clock | None = None,
        boot_timeout_s: float = 3.0,
        device: str | None = None,
        reconnect_policy: Reconnect | None = None,
    ) -> None:
        super().__init__(device or f"grbl@{port}", reconnect_port=port, stats=GrblStats())
        self.port = port
        self.transport = SerialTransport(port, baudrate=baudrate, device=self.device, clock=clock)
        self.clock: Clock = self.transport.clock
        self.baudrate = baudrate
        self.boot_timeout_s = boot_timeout_s
        self.reconnect_policy = reconnect_policy if reconnect_policy is not None else Reconnect(self.clock)
        self.link = CharacterCounter(rx_buffer_bytes=gp.RX_BUFFER_SIZE)
        self.envelope = PathEnvelope()
        self._lines = LineSplitter()
        self._info: list[str] = []
        self.messages: list[str] = []
        self._alarms: deque[int] = deque()
        self._statuses: deque[GrblStatus] = deque()
        self._status_errors: deque[LinkCorrupt] = deque()
        self._expect_banner = True
        self._unexpected_reset = False
        self.banner: str | None = None
        self.alarm_on_boot = False
        self.needs_reset = False
        self.last_alarm: int | None = None
        self.last_status: GrblStatus | None = None
        self._wco: tuple[float, ...] | None = None
        self._wco_mark = -1  # envelope.offset_mark when the remembered WCO was adopted
        # (position field, lines sent that may move) of the last Idle report returned
        self._last_idle: tuple[tuple[float, ...] | None, int] | None = None
        try:
            self._await_banner(boot_timeout_s)
        except BaseException:
            self.transport.close()
            raise
        self.lifecycle = Lifecycle.CONNECTED if self.alarm_on_boot else Lifecycle.ACTIVE

    #: no answer for this long while lines are outstanding: ask for a status report
    @property
    def ack_poll_s(self) -> float:
        return self.link.ack_poll_s

    @ack_poll_s.setter
    def ack_poll_s(self, value: float) -> None:
        self.link.ack_poll_s = value

    #: how far (mm, deg on θ) a report while moving may lie outside the commanded box
    @property
    def path_tolerance(self) -> float:
        return self.envelope.tolerance

    @path_tolerance.setter
    def path_tolerance(self, value: float) -> None:
        self.envelope.tolerance = value

    resets = deprecated_alias("stats.resets")
    lines_lost = deprecated_alias("stats.lines_lost")
    replies_lost = deprecated_alias("stats.replies_lost")
    corrupt_reports = deprecated_alias("stats.corrupt_reports")
    disconnects = deprecated_alias("stats.disconnects")
    reconnects = deprecated_alias("stats.reconnects")

    # -- the driver template's primitives ---------------------------------------------------------
    def _release_port(self) -> None:
        self.transport.close()

    def _reopen(self) -> None:
        """Open the port again and wait for the banner (GRBL resets on open): what was in flight is gone."""
        self.transport = SerialTransport(self.port, baudrate=self.baudrate, device=self.device, clock=self.clock)
        self._lines.clear()
        self.stats.lines_lost += self.link.reopen()
        for item in (self._statuses, self._status_errors, self._alarms):
            item.clear()
        self._expect_banner = True
        self._await_banner(self.boot_timeout_s)

    def _on_port_lost(self, reason: str) -> None:
        log.warning("%s: port lost (%s)", self.device, reason)

    def _on_port_back(self) -> None:
        """GRBL reset on the reopen: motion in its buffers is gone, so it comes back in fault
        (``GrblReset``) and moves are refused until ``activate()`` starts from the measured pose."""
        self._unexpected_reset = False
        self.stats.resets += 1
        self.fault(GrblReset("the port came back after an unplug: GRBL rebooted and buffered motion was lost; "
                             "activate() to continue from the measured pose", device=self.device))

    def _take_bytes(self, data: bytes, t_s: float) -> int:
        self._lines.push(data)
        n = 0
        while (raw := self._lines.pop()) is not None:
            line = raw.strip().decode("ascii", "replace")
            if line:
                self._on_line(line, t_s)
                n += 1
        return n

    def _close(self) -> None:
        self.transport.close()

    # -- what GRBL prints ------------------------------------------------------------------------
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

    def _on_line(self, line: str, t_s: float) -> None:
        if is_answer(line):
            if not self.link.answer(line):
                log.warning("%s: %r with no line outstanding", self.device, line)
        elif line.startswith("<"):
            self._on_report(line, t_s)
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
            self.stats.lines_lost += self.link.reset()  # a reset empties GRBL's buffers: those lines never run
            self._last_idle = None  # a reboot may have lost the position without a line sent
            self.envelope.forget()
            self._wco = None  # ... and clears G92
            if self._expect_banner:
                self._expect_banner = False
            else:
                self.stats.resets += 1
                self._unexpected_reset = True
        elif line.startswith("[MSG:"):
            self.messages.append(line)
            if "Reset to continue" in line:
                self.needs_reset = True  # a critical alarm: GRBL reads no line until a soft reset
            if "to unlock" in line:
                self.alarm_on_boot = True
        else:
            self._info.append(line)

    def _on_report(self, line: str, t_s: float) -> None:
        fence = self.link.answer_fence(t_s)
        try:
            st = parse_status(line, t_s, self._wco)
        except LinkCorrupt as exc:
            self._report_refused(exc)
            return
        if (st.wco is not None and self._wco is not None and st.wco != self._wco
                and self._wco_mark == self.envelope.offset_mark):
            # No line that changes the work offset was sent since it was last seen: the report
            # was corrupted on the wire (its WCO would make every work position after it wrong).
            self._report_refused(LinkCorrupt(f"corrupt status report {line!r}: WCO changed from {self._wco} with "
                                             "no offset-changing line sent", device=self.device))
            return
        self.link.report_seen()
        if st.wco is not None:
            self._wco = st.wco
            self._wco_mark = self.envelope.offset_mark
        self.last_status = st
        self._statuses.append(st)
        while len(self._statuses) > 8:
            self._statuses.popleft()
        if fence is not None:
            for item in self.link.reconcile(st, fence):
                self.stats.replies_lost += 1
                log.warning("%s: the answer to %r was lost on the wire (GRBL has executed it: %s)",
                            self.device, item.line, st.raw)

    def _report_refused(self, err: LinkCorrupt) -> None:
        self.stats.corrupt_reports += 1
        log.warning("%s: %s", self.device, err)
        err.device = self.device
        self._status_errors.append(err)
        self.link.report_lost()

    # -- sending lines ---------------------------------------------------------------------------
    def _request_status(self) -> None:
        """Write ``?`` unless one is already in flight (GRBL merges ``?`` sent before it reports)."""
        if self.link.ask_status(self.clock.now_s()):
            self.transport.write(gp.RT_STATUS)

    def _wait_progress(self, deadline: Deadline) -> None:
        """Read what arrives; while lines are outstanding and nothing comes, ask for a status report
        (the report is how a lost answer is found)."""
        got = self._pump(min(self.ack_poll_s, deadline.remaining_s() or 0.0))
        if not got and self.link.outstanding and not deadline.expired():
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
        while not self.link.fits(len(data)):
            self._check_events()
            if deadline.expired():
                raise DeviceTimeout(f"GRBL's receive buffer did not drain within {deadline.timeout_s:.3g} s",
                                    device=self.device)
            self._wait_progress(deadline)
        self.envelope.line_sent(line.upper())
        ident = self.link.sent(line, len(data))
        self.transport.write(data)
        return ident

    def _await_result(self, ident: int, deadline: Deadline, what: str) -> str:
        while ident not in self.link.results:
            self._check_events()
            if not self.link.is_outstanding(ident):
                raise self.fault(GrblReset(f"{what} was lost: GRBL reset before answering", device=self.device))
            if deadline.expired():
                raise DeviceTimeout(f"no 'ok' or 'error' for {what} within {deadline.timeout_s:.3g} s",
                                    device=self.device)
            self._wait_progress(deadline)
        return self.link.results.pop(ident)

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
            raise gp.error(error_code(result), device=self.device, line=line)
        return info

    # -- status and waiting --------------------------------------------------------------------------
    @locked
    def status(self, timeout_s: float = 0.5) -> GrblStatus:
        """Ask for a status report (``?``) and return it parsed. GRBL answers none in a critical
        alarm (hard or soft limit) until a soft reset: that, or a report that an alarm held back
        past ``timeout_s``, raises :class:`GrblAlarm` instead of a timeout.

        GRBL's lines carry no checksum, and a flipped digit is still a number in GRBL's format. A
        machine that was Idle and has been sent no line that moves it since (no axis word, G28/G30,
        $H, $J) cannot have moved: when such a report disagrees with the previous one, a third
        decides (two that agree), else :class:`LinkCorrupt`; the first Idle report after motion is
        confirmed by a second one. A report while moving must lie on the commanded path
        (:mod:`.envelope`). Likewise a report whose WCO changed with no offset-changing line sent
        (G10, G92, G54-G59, G43.1/G49, $RST) is ``LinkCorrupt``.
        """
        st = self._status_once(timeout_s)
        if st.state != "Idle":
            self._last_idle = None
            if st.state in ("Run", "Jog", "Hold"):
                self._check_moving(st)
            return st
        prev = self._last_idle
        if prev is None or prev[1] != self.envelope.motion_mark:
            # Nothing to hold this position against yet: a second report must agree.
            other = self._status_once(timeout_s)
            if other.state != "Idle":  # it started moving (a queued line): that is the news
                self._last_idle = None
                return other
            prev_pos = reported_position(other)
            if prev_pos == reported_position(st):
                return self._idle(other)
        else:
            prev_pos = prev[0]
            if prev_pos == reported_position(st):
                return self._idle(st)
        third = self._status_once(timeout_s)
        if third.state == "Idle" and reported_position(third) in (reported_position(st), prev_pos):
            self.stats.corrupt_reports += 1  # the odd one out was corrupted on the wire
            return self._idle(third)
        self._last_idle = None
        raise LinkCorrupt(f"three Idle reports with no motion line sent between them disagree on the position: "
                          f"{prev_pos}, {st.raw!r}, {third.raw!r}", device=self.device)

    def _idle(self, st: GrblStatus) -> GrblStatus:
        self._last_idle = (reported_position(st), self.envelope.motion_mark)
        self.envelope.at_idle(st)
        return st

    def _check_moving(self, st: GrblStatus) -> None:
        """A report while moving must lie on the way the driver sent the machine, at a feed it asked
        for: else it was corrupted on the wire (a digit flipped into a digit parses)."""
        why = self.envelope.violation(st)
        if why is not None:
            self.stats.corrupt_reports += 1
            raise LinkCorrupt(f"corrupt status report {st.raw!r}: {why}", device=self.device)

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
            if st.state == "Idle" and not self.link.outstanding:
                return st
            if st.state == "Alarm":
                raise self.fault(gp.alarm(self._alarms.popleft() if self._alarms else 0, device=self.device))
            if dl.expired():
                raise DeviceTimeout(f"not Idle within {timeout_s:.3g} s (state {st.state}, "
                                    f"{len(self.link.outstanding)} line(s) unanswered)", device=self.device)
            self.clock.sleep(min(poll_s, dl.remaining_s() or 0.0))
            self._pump(0.0)

    # -- realtime bytes and resets -----------------------------------------------------------------
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
        (counted in ``stats.lines_lost``); a reset while moving leaves ALARM:3 (reported by ``status``)."""
        self._expect_banner = True
        self.transport.write(gp.RT_SOFT_RESET)
        self._pump_until(lambda: not self._expect_banner, Deadline(self.clock, timeout_s), lambda: DeviceTimeout(
            f"no banner within {timeout_s:.3g} s of a soft reset", device=self.device))
        self._pump(0.02)
        self._alarms.clear()
        self.link.results.clear()

    # -- streaming ---------------------------------------------------------------------------------------
    @locked
    def stream(self, lines: Iterable[str], *, timeout_s: float = 600.0, stop_on_error: bool = True,
               on_progress: ProgressCallback | None = None) -> StreamResult:
        """Stream G-code with character counting; returns when every sent line is answered.

        On ``error:N`` with ``stop_on_error`` nothing more is sent and :class:`GrblError` is raised
        (naming the line) once the lines already in GRBL's buffer are answered. ``on_progress(number,
        text, answer)`` is called once per line: ``answer`` is ``ok``, ``lost`` or ``error:N``; an
        error is reported once no lost answer can shift it any more, with the range of lines it may
        belong to when one did (:class:`~tactile_rig.drivers.grbl.link.StreamTracker`), exactly as
        :attr:`StreamResult.uncertain` lists it.
        """
        self.require_not_faulted("stream")
        self._check_events()
        dl = Deadline(self.clock, timeout_s)
        tracker = StreamTracker(self.link, on_progress)
        for no, raw in enumerate(lines, start=1):
            text = clean_gcode_line(raw)
            if not text:
                continue
            tracker.collect()
            if tracker.first_error is not None and stop_on_error:
                break
            tracker.sent(self._send_line(text, dl), no, text)
            self._pump(0.0)
        while tracker.pending:
            tracker.collect()
            if not tracker.pending:
                break
            self._check_events()
            if dl.expired():
                raise DeviceTimeout(f"{len(tracker.pending)} streamed line(s) unanswered after {timeout_s:.3g} s",
                                    device=self.device)
            self._wait_progress(dl)
        res = tracker.finish()
        if tracker.first_error is not None and stop_on_error:
            ident, no, code, text = tracker.first_error
            raise gp.error(code, device=self.device, line=tracker.describe(ident, no, text))
        return res

