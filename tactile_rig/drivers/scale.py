"""Driver of the Arduino HX711 load-cell scale (``firmware/arduino_scale``, or the stock example).

:class:`Scale` opens a path or URL, survives the Arduino's reset on open (banner wait with a
deadline; garbage and half lines dropped; explicit DTR toggles guarded, since a pty refuses them),
and delivers every sample in order as a :class:`ScaleReading` (grams, raw counts, newtons, sequence
number, host time). Drops and device resets are detected from the sequence numbers and the banner,
bad checksums are counted and rejected, and a scale that stops talking raises
:class:`~tactile_rig.core.errors.DeviceTimeout`. Nothing is lost or duplicated without being counted in
:attr:`Scale.stats`. The driver computes grams itself from the sketch's absolute raw counts with its
own zero, so a sketch reboot (which re-tares) changes no reading; where grams cannot be trusted
(the stock sketch rebooted) :class:`~tactile_rig.core.errors.ZeroLost` is raised instead.

The pump, the reconnect with backoff after an unplug and the shared counters are the driver
template's (:class:`~tactile_rig.drivers.lines.LineDriver`); the wire codec is
:mod:`tactile_rig.drivers.scale_codec` (its names are re-exported here).
"""

from __future__ import annotations

import logging
import math
from collections import deque
from dataclasses import dataclass, replace
from typing import Callable

import serial

from tactile_rig.core.clock import Clock, Deadline
from tactile_rig.core.errors import (
    CalibrationError,
    DeviceTimeout,
    NotConnected,
    ZeroLost,
    check_range,
)
from tactile_rig.devices import scale as sp
from tactile_rig.drivers.base import DriverStats, Lifecycle, locked
from tactile_rig.drivers.lines import LineDriver
from tactile_rig.drivers.reconnect import Reconnect
from tactile_rig.drivers.scale_codec import (
    LineKind,
    ParsedLine,
    ScaleInfo,
    ScaleLineParser,
    ScaleReading,
    crc8,
    grams_mg,
    infer_zero_raw,
    mg_from_raw,
    parse_line,
)
from tactile_rig.drivers.transport import SerialTransport, stable_port_path

__all__ = [
    "LineKind", "ParsedLine", "Scale", "ScaleEvent", "ScaleInfo", "ScaleLineParser", "ScaleReading", "ScaleStats",
    "crc8", "grams_mg", "infer_zero_raw", "mg_from_raw", "parse_line", "stable_port_path",
]

log = logging.getLogger("tactile_rig.scale")


@dataclass
class ScaleStats(DriverStats):
    """Counters: every line the driver did not deliver as a reading is counted here."""

    readings: int = 0  # delivered into the queue
    dropped: int = 0  # sequence-number gaps: samples the sketch sent that never arrived intact
    resets: int = 0  # the Arduino rebooted mid-session (banner or sequence restart)
    bad_checksum: int = 0  # framed lines whose CRC or fields were wrong (LinkCorrupt, rejected)
    invalid_values: int = 0  # nan / inf / ovf readings
    rejected_lines: int = 0  # lines that are neither readings nor known messages
    saturated: int = 0  # readings at the 24-bit limit (delivered, flagged)
    overflowed: int = 0  # readings discarded because the caller did not consume them
    rezeroed: int = 0  # the sketch's zero moved with no reboot or tare seen (a missed reboot)
    untrusted: int = 0  # readings withheld because the zero was lost (stock sketch rebooted)


@dataclass(frozen=True)
class ScaleEvent:
    """Something the driver detected: ``kind`` ∈ drop, reset (the sketch rebooted), rezero (its zero
    moved with no reboot seen), zero_lost (grams can no longer be trusted), checksum, disconnect,
    reconnect; ``count`` how many."""

    kind: str
    t_host_s: float
    count: int = 1
    detail: str = ""



class Scale(LineDriver):
    """The HX711 scale on ``port`` (a path, a ``/dev/serial/by-id`` link, or a URL); opened here.

    ``boot_timeout_s`` bounds the wait for the banner (or a first reading) after the reset on
    open; ``stale_after_s`` is how long :meth:`read` waits for a sample before
    :class:`DeviceTimeout` (default: 10 sample periods once the rate is known, at least 0.5 s).
    After an unplug, calls fail fast with ``NotConnected`` until ``reconnect_policy`` allows a
    reopen by the stable path (the Arduino resets on it: a ``reset`` event; the driver's zero stands).
    """

    stats: ScaleStats

    def __init__(
        self,
        port: str,
        *,
        baudrate: int = sp.BAUD,
        clock: Clock | None = None,
        boot_timeout_s: float = 5.0,
        stale_after_s: float | None = None,
        toggle_dtr: bool = True,
        max_queue: int = 100_000,
        on_event: Callable[[ScaleEvent], None] | None = None,
        device: str | None = None,
        reconnect_policy: Reconnect | None = None,
    ) -> None:
        check_range("boot_timeout_s", boot_timeout_s, 0.0, 600.0, "s")
        self.port = port
        self.baudrate = int(baudrate)
        super().__init__(device or f"scale@{port}", reconnect_port=stable_port_path(port), stats=ScaleStats())
        self.boot_timeout_s = float(boot_timeout_s)
        self._stale_after_s = stale_after_s
        self.toggle_dtr = toggle_dtr
        self.max_queue = int(max_queue)
        self.on_event = on_event
        self.events: list[ScaleEvent] = []
        self.info: ScaleInfo | None = None
        self.format: str | None = None  # "tactile" or "stock" once known
        self._clock_override = clock
        self._queue: deque[ScaleReading] = deque()
        self._replies: deque[ParsedLine] = deque()
        self._last_seq: int | None = None
        self._stock_seq = 0
        self._started = False
        # The driver's zero in raw counts (None until the first sample with raw counts) and the
        # calibration in the sketch's thousandths of a count per gram: grams are computed here.
        self.zero_raw: int | None = None
        self.cal_milli: int | None = None
        self._sketch_zero: int | None = None  # where the sketch's own zero is, inferred from its grams
        self._sketch_rezero_expected = False  # a reboot or tare was seen: the sketch's zero may move
        self._await_zero = False  # a tare was confirmed: the next sample sets the zero
        self.zero_lost = False
        self._last_sample_s: float | None = None
        self.transport: SerialTransport | None = None
        try:
            self._open(self.port)
        except BaseException:
            self._release_port()
            raise
        assert self.transport is not None
        self.reconnect_policy = reconnect_policy if reconnect_policy is not None else Reconnect(self.transport.clock)

    # -- connection -----------------------------------------------------------------------------
    @property
    def clock(self) -> Clock:
        if self.transport is None:
            raise NotConnected("the scale is closed", device=self.device)
        return self.transport.clock

    @property
    def rate_sps(self) -> int | None:
        return self.info.rate_sps if self.info else None

    @property
    def stale_after_s(self) -> float:
        if self._stale_after_s is not None:
            return self._stale_after_s
        rate = self.rate_sps or 10
        return max(0.5, 10.0 / rate)

    def _open(self, port: str) -> None:
        self.transport = SerialTransport(port, baudrate=self.baudrate, device=self.device,
                                         clock=self._clock_override)
        self.lifecycle = Lifecycle.CONNECTED
        self._parser = ScaleLineParser(sync=True)
        self._last_seq = None
        self._started = False
        self._replies.clear()
        if self.toggle_dtr:
            self._pulse_dtr()
        self._wait_ready()
        if self.info is None and self.format == "tactile":
            # Started mid-stream (no reset on open, or the banner was missed): ask for the ID line.
            try:
                self.identify(timeout_s=0.5)
            except DeviceTimeout:
                log.warning("%s: no banner and no answer to '?': rate and calibration unknown", self.device)

    def _pulse_dtr(self) -> None:
        # A known reset even where opening does not reset (HUPCL off). A pty refuses modem-line
        # ioctls with ENOTTY, so this is best effort.
        ser = self.transport.serial  # type: ignore[union-attr]
        try:
            ser.dtr = False
            self.clock.sleep(0.05)
            ser.dtr = True
        except (OSError, serial.SerialException, ValueError) as exc:
            log.debug("%s: DTR toggle refused (%s); relying on the reset on open", self.device, exc)

    def _wait_ready(self) -> None:
        self._pump_until(lambda: self._started, Deadline(self.clock, self.boot_timeout_s), lambda: DeviceTimeout(
            f"no banner and no valid reading within {self.boot_timeout_s:.3g} s after opening "
            f"(expected a B,{sp.FIRMWARE_NAME} banner or 'Load_cell output val:' lines at "
            f"{self.baudrate} baud; check the sketch, the baud rate and the port)", device=self.device))

    def reconnect(self, timeout_s: float = 10.0) -> None:
        """Close and reopen by the stable path now (the port may come back under another ttyACM name),
        trying every 0.2 s for ``timeout_s``; the backoff of an unplug is bypassed and reset."""
        with self.call_lock:  # not @locked: an explicit reconnect must not fail fast while away
            self.close()
            policy = self.reconnect_policy
            assert policy is not None
            dl = Deadline(self._clock_override or policy.clock, timeout_s)
            last: Exception | None = None
            while True:
                try:
                    self._open(self.reconnect_port)
                    break
                except (NotConnected, DeviceTimeout) as exc:
                    last = exc
                    self._release_port()
                if dl.expired():
                    raise NotConnected(f"could not reopen {self.reconnect_port!r} within {timeout_s} s: {last}",
                                       device=self.device)
                dl.clock.sleep(0.2)
            if policy.away:
                self._port_back()

    def _close(self) -> None:
        self._release_port()

    # -- the driver template's primitives -------------------------------------------------------
    def _release_port(self) -> None:
        if self.transport is not None:
            self.transport.close()
            self.transport = None

    def _reopen(self) -> None:
        self._open(self.reconnect_port)

    def _on_port_lost(self, reason: str) -> None:
        assert self.reconnect_policy is not None
        self._event("disconnect", self.reconnect_policy.clock.now_s(), detail=reason)

    def _on_port_back(self) -> None:
        assert self.reconnect_policy is not None
        self._event("reconnect", self.reconnect_policy.clock.now_s(), detail=self.reconnect_port)

    def _take_bytes(self, data: bytes, t_s: float) -> int:
        lines = self._parser.feed(data, t_s)
        for line in lines:
            self._handle(line)
        return len(lines)

    # -- lines ----------------------------------------------------------------------------------
    def _event(self, kind: str, t_s: float, count: int = 1, detail: str = "") -> None:
        ev = ScaleEvent(kind, t_s, count, detail)
        self.events.append(ev)
        log.info("%s: %s x%d %s", self.device, kind, count, detail)
        if self.on_event is not None:
            self.on_event(ev)

    def _handle(self, line: ParsedLine) -> None:
        k = line.kind
        if k in (LineKind.BANNER, LineKind.STOCK_START):
            if self._started or self.stats.readings:
                self._reset_seen(line.t_s, line.text)
            self._last_seq = None
            if line.info is not None:
                self.info = line.info
                self._set_cal(line.info.cal_factor_counts_per_g)
            self.format = "tactile" if k == LineKind.BANNER else "stock"
            # The stock sketch is ready only after its stabilising time ("Startup is complete").
            self._started = k == LineKind.BANNER
            if k == LineKind.STOCK_START and self.info is None:
                self.info = ScaleInfo("HX711_ADC example", "stock", None, None)
        elif k in (LineKind.SAMPLE, LineKind.STOCK_SAMPLE):
            self._accept(line)
        elif k in (LineKind.ID, LineKind.TARE, LineKind.CAL, LineKind.ERROR, LineKind.STOCK_TARE):
            if line.info is not None:
                self.info = line.info
                self._set_cal(line.info.cal_factor_counts_per_g)
            if k == LineKind.CAL and line.value is not None:
                self._set_cal(line.value)  # the sketch uses it from this conversion on
            if k in (LineKind.TARE, LineKind.STOCK_TARE):
                self._confirm_tare()
            self._replies.append(line)
        elif k == LineKind.CORRUPT:
            self.stats.bad_checksum += 1
            self._event("checksum", line.t_s, detail=line.text[:80])
        elif k == LineKind.INVALID:
            self.stats.invalid_values += 1
        elif k == LineKind.STOCK_READY:
            self._started = True
        else:
            self.stats.rejected_lines += 1

    # -- the zero ------------------------------------------------------------------------------------
    def _set_cal(self, counts_per_g: float | None) -> None:
        if counts_per_g is not None and math.isfinite(counts_per_g) and round(counts_per_g * 1000) != 0:
            self.cal_milli = round(counts_per_g * 1000)

    def _reset_seen(self, t_s: float, detail: str) -> None:
        """The sketch rebooted: it re-tared with whatever is on the scale. Our zero stands if the
        sketch sends raw counts and we know the calibration; else grams are no longer true."""
        self.stats.resets += 1
        self._event("reset", t_s, detail=detail)
        self._sketch_rezero_expected = True
        if self.format == "stock" or self.zero_raw is None or self.cal_milli is None:
            self._lose_zero(t_s, "the sketch rebooted and re-tared with an unknown load on the scale")

    def _lose_zero(self, t_s: float, why: str) -> None:
        if not self.zero_lost:
            self.zero_lost = True
            self._event("zero_lost", t_s, detail=why)

    def _confirm_tare(self) -> None:
        """The sketch confirmed a tare: the host's zero follows it (set from the next sample)."""
        self._await_zero = True
        self._sketch_rezero_expected = True
        self.zero_lost = False

    def _apply_zero(self, r: ScaleReading) -> ScaleReading:
        """Grams from raw counts with the driver's zero (tactile sketch), or the sketch's (stock)."""
        if r.raw is None or self.cal_milli is None:
            return r
        mg = round(r.grams * 1000)
        sketch_zero = infer_zero_raw(r.raw, mg, self.cal_milli)
        if sketch_zero is not None:
            if (self._sketch_zero is not None and abs(sketch_zero - self._sketch_zero) > 1
                    and not self._sketch_rezero_expected):
                # The sketch's zero moved with no reboot or tare seen: its banner and the sequence
                # restart were both lost. Our zero is unaffected; note it.
                self.stats.rezeroed += 1
                self._event("rezero", r.t_host_s, detail=f"sketch zero {self._sketch_zero} -> {sketch_zero}")
            self._sketch_zero = sketch_zero
            self._sketch_rezero_expected = False
        if self._await_zero or self.zero_raw is None:
            if sketch_zero is None:
                return r
            self.zero_raw = sketch_zero
            self._await_zero = False
            self.zero_lost = False
        return replace(r, grams=mg_from_raw(r.raw, self.zero_raw, self.cal_milli) / 1000.0, sketch_grams=r.grams)

    @locked
    def set_zero_raw(self, zero_raw: int) -> None:
        """Use ``zero_raw`` counts as zero from now on (e.g. a zero kept from an earlier session)."""
        check_range("zero_raw", zero_raw, sp.RAW_MIN, sp.RAW_MAX, "counts")
        self.zero_raw = int(zero_raw)
        self._await_zero = False
        self.zero_lost = False

    def _accept(self, line: ParsedLine) -> None:
        r = line.reading
        assert r is not None
        if r.source == "stock":
            self.format = self.format or "stock"
            period = 1.0 / (self.rate_sps or 10)
            if self._last_sample_s is not None and r.t_host_s - self._last_sample_s > max(1.0, 10 * period):
                # The stock sketch goes quiet for its 1.5 s boot and 2 s settling: a gap that long is a
                # reboot whose "Starting..." line may have been lost.
                self._lose_zero(r.t_host_s, f"the stock sketch went quiet for {r.t_host_s - self._last_sample_s:.2g} s "
                                "(a reboot re-tares it)")
            self._last_sample_s = r.t_host_s
            r = ScaleReading(r.grams, None, self._stock_seq, r.t_host_s, False, "stock")
            self._stock_seq = (self._stock_seq + 1) % sp.SEQ_MODULO
        else:
            self.format = "tactile"
            if self._last_seq is not None:
                gap = (r.seq - self._last_seq - 1) % sp.SEQ_MODULO  # type: ignore[operator]
                if gap >= sp.SEQ_MODULO // 2:  # went backwards: the sketch restarted
                    self._reset_seen(r.t_host_s, f"seq {self._last_seq} -> {r.seq}")
                elif gap:
                    self.stats.dropped += gap
                    self._event("drop", r.t_host_s, gap, f"seq {self._last_seq} -> {r.seq}")
            self._last_seq = r.seq
            r = self._apply_zero(r)
        self._started = True
        if self.zero_lost:
            self.stats.untrusted += 1
            return
        if r.saturated:
            self.stats.saturated += 1
        if len(self._queue) >= self.max_queue:
            self._queue.popleft()
            self.stats.overflowed += 1
        self._queue.append(r)
        self.stats.readings += 1

    @locked
    def read(self, timeout_s: float | None = None) -> ScaleReading:
        """The next reading in order; waits up to ``timeout_s`` (default ``stale_after_s``) for one.

        :class:`ZeroLost` when the zero can no longer be trusted (a stock sketch rebooted): ``tare()``."""
        if self._queue:
            return self._queue.popleft()
        timeout = self.stale_after_s if timeout_s is None else timeout_s
        self._pump_until(lambda: bool(self._queue), Deadline(self.clock, timeout), lambda: DeviceTimeout(
            f"no reading for {timeout:.3g} s (expected {self.rate_sps or '10 or 80'} per second): "
            "the scale stopped talking or was unplugged", device=self.device), check=self._check_zero)
        return self._queue.popleft()

    def _check_zero(self) -> None:
        if self.zero_lost:
            raise ZeroLost("the scale's zero is lost: the sketch rebooted and re-tared with the load on it, "
                           "and it sends no raw counts to correct with; call tare() with the scale empty",
                           device=self.device)

    @locked
    def read_many(self, n: int, timeout_s: float | None = None) -> list[ScaleReading]:
        """The next ``n`` readings; each may take up to ``timeout_s`` to come."""
        return [self.read(timeout_s) for _ in range(int(n))]

    @locked
    def poll(self) -> list[ScaleReading]:
        """Every reading that has arrived so far, without waiting."""
        while self._pump(0.0):
            pass
        out = list(self._queue)
        self._queue.clear()
        return out

    @locked
    def latest(self, timeout_s: float | None = None) -> ScaleReading:
        """The newest reading (older queued ones are consumed); waits for one if none is queued."""
        got = self.poll()
        return got[-1] if got else self.read(timeout_s)

    @locked
    def force_n(self, timeout_s: float | None = None) -> float:
        """The newest reading as a force in newtons (weight of the grams on the scale)."""
        return self.latest(timeout_s).newtons

    @property
    def queued(self) -> int:
        return len(self._queue)

    # -- commands -------------------------------------------------------------------------------
    def _window_s(self) -> float:
        rate = self.rate_sps or 10
        return (sp.SMOOTHING_SAMPLES + 2) / rate

    def _await_reply(self, kinds: tuple[LineKind, ...], timeout_s: float, what: str) -> ParsedLine:
        found: list[ParsedLine] = []

        def done() -> bool:
            while self._replies:
                rep = self._replies.popleft()
                if rep.kind in kinds:
                    found.append(rep)
                    return True
            return False

        self._pump_until(done, Deadline(self.clock, timeout_s), lambda: DeviceTimeout(
            f"no answer to {what} within {timeout_s:.3g} s", device=self.device))
        return found[0]

    @locked
    def tare(self, timeout_s: float | None = None) -> None:
        """Zero the scale with what is on it now; returns when the sketch confirms (one smoothing window).

        Readings queued before the confirmation are not tared; the ones after it are."""
        timeout = timeout_s if timeout_s is not None else 2 * self._window_s() + 1.0
        self._replies.clear()
        self.transport.write(sp.CMD_TARE)  # type: ignore[union-attr]
        self._await_reply((LineKind.TARE, LineKind.STOCK_TARE), timeout, "tare ('t')")

    @locked
    def calibrate(self, known_mass_g: float, timeout_s: float | None = None) -> float:
        """Calibrate with ``known_mass_g`` on the (tared) scale; return the new factor (counts per gram)."""
        check_range("known_mass_g", known_mass_g, 1e-3, 1e6, "g")
        if self.format == "stock":
            raise CalibrationError("the stock HX711_ADC example cannot calibrate over serial; flash "
                                   "firmware/arduino_scale", device=self.device)
        timeout = timeout_s if timeout_s is not None else 2 * self._window_s() + 1.0
        self._replies.clear()
        self.transport.write(sp.CMD_CALIBRATE_PREFIX + b"%.3f\n" % known_mass_g)  # type: ignore[union-attr]
        rep = self._await_reply((LineKind.CAL, LineKind.ERROR), timeout, f"calibrate({known_mass_g} g)")
        if rep.kind == LineKind.ERROR:
            raise CalibrationError(f"calibration with {known_mass_g} g refused: "
                                   f"{sp.ERRORS.get(rep.code or 0, rep.text)}", device=self.device)
        assert rep.value is not None
        if self.info is not None:
            self.info = ScaleInfo(self.info.firmware, self.info.version, self.info.rate_sps, rep.value)
        return rep.value

    @locked
    def identify(self, timeout_s: float = 0.5) -> ScaleInfo:
        """Ask the sketch for its ID line (firmware, version, rate, calibration factor)."""
        self._replies.clear()
        self.transport.write(sp.CMD_ID)  # type: ignore[union-attr]
        rep = self._await_reply((LineKind.ID,), timeout_s, "'?'")
        assert rep.info is not None
        return rep.info
