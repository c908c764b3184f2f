"""Driver of the Arduino HX711 load-cell scale (``firmware/arduino_scale``, or the stock example).

:class:`Scale` opens a path or URL, survives the Arduino's reset on open (banner wait with a
deadline; garbage and half lines dropped; explicit DTR toggles guarded, since a pty refuses them),
and delivers every sample in order as a :class:`ScaleReading` (grams, raw counts, newtons, sequence
number, host time). Drops and device resets are detected from the sequence numbers and the banner,
bad checksums are counted and rejected, and a scale that stops talking raises
:class:`~tactile_rig.core.errors.DeviceTimeout`. Nothing is lost or duplicated without being counted in
:attr:`Scale.stats`. The driver computes grams itself from the sketch's absolute raw counts with its
own zero, so a sketch reboot (which re-tares) changes no reading; where grams cannot be trusted
(the stock sketch rebooted) :class:`~tactile_rig.core.errors.ZeroLost` is raised instead. An
unplugged port is ``NotConnected`` at once while it is away and reopened with backoff when it
returns; every call holds the driver's lock. The wire codec (:class:`ScaleLineParser`) is pure and
usable on its own.
"""

from __future__ import annotations

import logging
import math
import os
import re
from collections import deque
from dataclasses import dataclass, replace
from pathlib import Path
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
from tactile_rig.drivers.base import Driver, Lifecycle, locked
from tactile_rig.drivers.reconnect import Reconnect
from tactile_rig.drivers.transport import SerialTransport

log = logging.getLogger("tactile_rig.scale")


def _crc8_table(poly: int) -> list[int]:
    table = []
    for i in range(256):
        c = i
        for _ in range(8):
            c = ((c << 1) ^ poly) if c & 0x80 else (c << 1)
        table.append(c & 0xFF)
    return table


_CRC_TABLE = _crc8_table(sp.CRC8_POLY)


def crc8(data: bytes) -> int:
    """CRC-8 (poly 0x07, init 0) of ``data``, the checksum of the sketch's lines."""
    c = 0
    for b in data:
        c = _CRC_TABLE[c ^ b]
    return c


# -- the line codec ---------------------------------------------------------------------------

@dataclass(frozen=True)
class ScaleReading:
    """One HX711 sample. ``grams`` is the load relative to the driver's zero; ``newtons`` = weight force.

    With our sketch the driver computes ``grams`` itself from the absolute ``raw`` counts, its own
    zero (``Scale.zero_raw``) and the calibration factor, in the sketch's integer arithmetic, so a
    sketch reboot (which re-tares) changes nothing; ``sketch_grams`` is what the sketch printed.
    ``raw`` is None for the stock sketch (its grams are the sketch's), ``seq`` the sketch's sequence
    number mod 65536 (the stock sketch has none: the driver numbers those), ``t_host_s`` when the
    line arrived on the host (on the port's clock), ``saturated`` when the ADC clamped.
    """

    grams: float
    raw: int | None
    seq: int | None
    t_host_s: float
    saturated: bool = False
    source: str = "tactile"
    sketch_grams: float | None = None

    @property
    def newtons(self) -> float:
        return self.grams * 1e-3 * sp.STANDARD_GRAVITY_MPS2


@dataclass(frozen=True)
class ScaleInfo:
    """What the banner (or ``?``) says: firmware, version, samples per second, calibration factor."""

    firmware: str
    version: str
    rate_sps: int | None
    cal_factor: float | None


@dataclass(frozen=True)
class ParsedLine:
    """One decoded line: ``kind`` ∈ sample, banner, id, tare, cal, error, stock_sample, stock_start,
    stock_ready, stock_tare, corrupt (framed but bad checksum or fields), invalid (nan/inf/ovf),
    other (anything else)."""

    kind: str
    text: str
    t_s: float
    reading: ScaleReading | None = None
    info: ScaleInfo | None = None
    value: float | None = None
    code: int | None = None


_TAGS = frozenset(b"BISTKE")
_FRAME_RE = re.compile(rb"([BISTKE]),([^*\r\n]*)\*([0-9A-Fa-f]{2})\s*$")
_STOCK_RE = re.compile(rb"Load_cell output val:\s*(\S+)\s*$")
_NUM_RE = re.compile(r"^-?\d+(?:\.\d+)?$")


class ScaleLineParser:
    """Bytes in (any split), decoded lines out. ``sync=True`` drops everything up to the first
    newline (a half line from before the host opened the port)."""

    def __init__(self, *, sync: bool = True, max_line: int = 256) -> None:
        self._buf = bytearray()
        self._synced = not sync
        self.max_line = max_line
        self.overlong = 0

    def resync(self) -> None:
        self._buf.clear()
        self._synced = False

    def feed(self, data: bytes, t_s: float) -> list[ParsedLine]:
        out: list[ParsedLine] = []
        self._buf += data
        while True:
            idx = self._buf.find(b"\n")
            if idx < 0:
                if len(self._buf) > self.max_line:  # a stream of garbage with no newline
                    self.overlong += 1
                    del self._buf[: -self.max_line]
                return out
            line = bytes(self._buf[:idx])
            del self._buf[: idx + 1]
            parsed = parse_line(line, t_s)
            if not self._synced:
                # The first line may be the tail of one sent before we opened: keep it only if whole.
                self._synced = True
                if parsed is None or parsed.kind in ("other", "corrupt", "invalid"):
                    continue
            if parsed is not None:
                out.append(parsed)


def parse_line(line: bytes, t_s: float) -> ParsedLine | None:
    """Decode one line (without its ``\\n``); None for a blank line. Garbage before a frame is skipped."""
    line = line.rstrip(b"\r")
    if not line.strip():
        return None
    text = line.decode("ascii", "replace")
    framed = False
    # A frame may follow line noise: try each place a tag starts, leftmost first.
    for i in range(len(line) - 1):
        if line[i] not in _TAGS or line[i + 1] != 0x2C:
            continue
        m = _FRAME_RE.match(line, i)
        if m is None:
            continue
        framed = True
        body = line[i: m.start(3) - 1]
        if crc8(body) != int(m.group(3), 16):
            continue
        parsed = _decode_frame(m.group(1).decode(), m.group(2).decode("ascii", "replace"), text, t_s)
        if parsed is not None:
            return parsed
    if framed:
        return ParsedLine("corrupt", text, t_s)
    m = _STOCK_RE.search(line)
    if m is not None:
        value = m.group(1).decode("ascii", "replace")
        if not _NUM_RE.match(value):
            return ParsedLine("invalid", text, t_s)  # nan, inf, ovf from Serial.print(float)
        reading = ScaleReading(float(value), None, None, t_s, source="stock")
        return ParsedLine("stock_sample", text, t_s, reading=reading)
    stripped = text.strip()
    if stripped.endswith(sp.STOCK_STARTING):
        return ParsedLine("stock_start", stripped, t_s)
    if stripped.endswith(sp.STOCK_STARTUP_DONE):
        return ParsedLine("stock_ready", stripped, t_s)
    if stripped.endswith(sp.STOCK_TARE_DONE):
        return ParsedLine("stock_tare", stripped, t_s)
    return ParsedLine("other", stripped, t_s)


def _decode_frame(tag: str, body: str, text: str, t_s: float) -> ParsedLine | None:
    f = body.split(",")
    try:
        if tag == sp.TAG_SAMPLE and len(f) == 3:
            seq, grams, raw = int(f[0]), float(f[1]), int(f[2])
            if not (0 <= seq < sp.SEQ_MODULO and sp.RAW_MIN <= raw <= sp.RAW_MAX and math.isfinite(grams)):
                return None
            sat = raw in (sp.RAW_MIN, sp.RAW_MAX)
            return ParsedLine("sample", text, t_s, reading=ScaleReading(grams, raw, seq, t_s, sat))
        if tag in (sp.TAG_BANNER, sp.TAG_ID) and len(f) == 4:
            info = ScaleInfo(f[0], f[1], int(f[2]), float(f[3]))
            return ParsedLine("banner" if tag == sp.TAG_BANNER else "id", text, t_s, info=info)
        if tag == sp.TAG_TARE and f == ["ok"]:
            return ParsedLine("tare", text, t_s)
        if tag == sp.TAG_CAL and len(f) == 1:
            return ParsedLine("cal", text, t_s, value=float(f[0]))
        if tag == sp.TAG_ERROR and len(f) >= 2:
            return ParsedLine("error", text, t_s, code=int(f[0]), info=None, value=None)
    except ValueError:
        return None
    return None


# -- grams from raw counts -----------------------------------------------------------------------------

def _div_round(n: int, d: int) -> int:
    """``n / d`` rounded half away from zero (the sketch's integer rounding; ``d != 0``)."""
    if d < 0:
        n, d = -n, -d
    return (n + d // 2) // d if n >= 0 else -((-n + d // 2) // d)


def grams_mg(raw: int, zero_raw: int, cal_milli: int) -> int:
    """Milligrams for ``raw`` counts above ``zero_raw`` at ``cal_milli`` thousandths of a count per
    gram, computed as the sketch computes it (so the host's grams equal the sketch's for one zero)."""
    return _div_round((raw - zero_raw) * 1_000_000, cal_milli)


def infer_zero_raw(raw: int, mg: int, cal_milli: int) -> int | None:
    """The sketch's zero (raw counts) that turns ``raw`` into ``mg`` milligrams; None if none does."""
    guess = round(mg * cal_milli / 1_000_000)
    for d in sorted(range(guess - 3, guess + 4), key=lambda v: abs(v - mg * cal_milli / 1_000_000)):
        if grams_mg(raw, raw - d, cal_milli) == mg:
            return raw - d
    return None


# -- the driver -----------------------------------------------------------------------------------

@dataclass
class ScaleStats:
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
    disconnects: int = 0  # the port vanished (USB unplugged)
    reconnects: int = 0  # ... and came back


@dataclass(frozen=True)
class ScaleEvent:
    """Something the driver detected: ``kind`` ∈ drop, reset (the sketch rebooted), rezero (its zero
    moved with no reboot seen), zero_lost (grams can no longer be trusted), checksum; ``count`` how many."""

    kind: str
    t_host_s: float
    count: int = 1
    detail: str = ""


def stable_port_path(port: str, by_id_dir: str | os.PathLike[str] = "/dev/serial/by-id") -> str:
    """The ``/dev/serial/by-id`` link of ``port`` if there is one (survives re-enumeration), else ``port``."""
    if "://" in port or not os.path.exists(port):
        return port
    real = os.path.realpath(port)
    folder = Path(by_id_dir)
    if folder.is_dir():
        for link in sorted(folder.iterdir()):
            if os.path.realpath(link) == real:
                return str(link)
    return port


class Scale(Driver):
    """The HX711 scale on ``port`` (a path, a ``/dev/serial/by-id`` link, or a URL); opened here.

    ``boot_timeout_s`` bounds the wait for the banner (or a first reading) after the reset on
    open; ``stale_after_s`` is how long :meth:`read` waits for a sample before
    :class:`DeviceTimeout` (default: 10 sample periods once the rate is known, at least 0.5 s).
    """

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
        self.reconnect_port = stable_port_path(port)
        self.baudrate = int(baudrate)
        super().__init__(device or f"scale@{port}")
        self.boot_timeout_s = float(boot_timeout_s)
        self._stale_after_s = stale_after_s
        self.toggle_dtr = toggle_dtr
        self.max_queue = int(max_queue)
        self.on_event = on_event
        self.stats = ScaleStats()
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
        self._open(self.port)
        assert self.transport is not None
        #: when to try reopening a port that vanished (backoff on the port's clock)
        self.reconnect_policy: Reconnect = (reconnect_policy if reconnect_policy is not None
                                            else Reconnect(self.transport.clock))

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
        dl = Deadline(self.clock, self.boot_timeout_s)
        while not self._started:
            if dl.expired():
                raise DeviceTimeout(
                    f"no banner and no valid reading within {self.boot_timeout_s:.3g} s after opening "
                    f"(expected a B,{sp.FIRMWARE_NAME} banner or 'Load_cell output val:' lines at "
                    f"{self.baudrate} baud; check the sketch, the baud rate and the port)",
                    device=self.device,
                )
            self._pump(dl.remaining_s() or 0.0)

    def reconnect(self, timeout_s: float = 10.0) -> None:
        """Close and reopen by the stable path now (the port may come back under another ttyACM name),
        trying every 0.2 s for ``timeout_s``; the backoff of an unplug is bypassed and reset."""
        with self.call_lock:  # not @locked: an explicit reconnect must not fail fast while away
            self.close()
            policy = self.reconnect_policy
            dl = Deadline(self._clock_override or policy.clock, timeout_s)
            last: Exception | None = None
            while True:
                try:
                    self._open(self.reconnect_port)
                    break
                except (NotConnected, DeviceTimeout) as exc:
                    last = exc
                    if self.transport is not None:
                        self.transport.close()
                        self.transport = None
                if dl.expired():
                    raise NotConnected(f"could not reopen {self.reconnect_port!r} within {timeout_s} s: {last}",
                                       device=self.device)
                dl.clock.sleep(0.2)
            if policy.away:
                policy.succeeded()
                self.stats.reconnects += 1
                self._event("reconnect", policy.clock.now_s(), detail=self.reconnect_port)

    def _close(self) -> None:
        if self.transport is not None:
            self.transport.close()
            self.transport = None

    # -- unplug and replug ------------------------------------------------------------------------
    def _on_not_connected(self, error: NotConnected) -> None:
        """The port failed (unplugged): release it; calls fail fast until the backoff allows a reopen."""
        policy = self.reconnect_policy
        if policy.away:
            return
        if self.transport is not None:
            self.transport.close()
            self.transport = None
        policy.lost(str(error))
        self.stats.disconnects += 1
        self._event("disconnect", policy.clock.now_s(), detail=str(error))

    def _before_call(self) -> None:
        """While the port is away: ``NotConnected`` at once, or, when the backoff allows, a reopen by
        the stable path (the Arduino resets on it: a reset event; the driver's zero stands)."""
        policy = getattr(self, "reconnect_policy", None)
        if policy is None or not policy.away or self.closed:
            return
        if not policy.due():
            raise policy.not_connected(self.device, self.reconnect_port)
        try:
            self._open(self.reconnect_port)
        except (NotConnected, DeviceTimeout) as exc:
            if self.transport is not None:
                self.transport.close()
                self.transport = None
            policy.failed(str(exc))
            raise NotConnected(f"port {self.reconnect_port!r} is still gone: {exc}", device=self.device) from exc
        policy.succeeded()
        self.stats.reconnects += 1
        self._event("reconnect", policy.clock.now_s(), detail=self.reconnect_port)

    # -- reading --------------------------------------------------------------------------------
    def _pump(self, wait_s: float) -> int:
        """Read what arrives within ``wait_s`` (returns at the first bytes); return lines decoded."""
        if self.transport is None:
            raise NotConnected("the scale is closed", device=self.device)
        data = self.transport.read_some(1, wait_s)
        if data:
            data += self.transport.read_available()
        if not data:
            return 0
        lines = self._parser.feed(data, self.transport.clock.now_s())
        for line in lines:
            self._handle(line)
        return len(lines)

    def _event(self, kind: str, t_s: float, count: int = 1, detail: str = "") -> None:
        ev = ScaleEvent(kind, t_s, count, detail)
        self.events.append(ev)
        log.info("%s: %s x%d %s", self.device, kind, count, detail)
        if self.on_event is not None:
            self.on_event(ev)

    def _handle(self, line: ParsedLine) -> None:
        k = line.kind
        if k in ("banner", "stock_start"):
            if self._started or self.stats.readings:
                self._reset_seen(line.t_s, line.text)
            self._last_seq = None
            if line.info is not None:
                self.info = line.info
                self._set_cal(line.info.cal_factor)
            self.format = "tactile" if k == "banner" else "stock"
            # The stock sketch is ready only after its stabilising time ("Startup is complete").
            self._started = k == "banner"
            if k == "stock_start" and self.info is None:
                self.info = ScaleInfo("HX711_ADC example", "stock", None, None)
        elif k in ("sample", "stock_sample"):
            self._accept(line)
        elif k in ("id", "tare", "cal", "error", "stock_tare"):
            if line.info is not None:
                self.info = line.info
                self._set_cal(line.info.cal_factor)
            if k == "cal" and line.value is not None:
                self._set_cal(line.value)  # the sketch uses it from this conversion on
            if k in ("tare", "stock_tare"):
                self._confirm_tare()
            self._replies.append(line)
        elif k == "corrupt":
            self.stats.bad_checksum += 1
            self._event("checksum", line.t_s, detail=line.text[:80])
        elif k == "invalid":
            self.stats.invalid_values += 1
        elif k == "stock_ready":
            self._started = True
        else:
            self.stats.rejected_lines += 1

    # -- the zero ------------------------------------------------------------------------------------
    def _set_cal(self, cal_factor: float | None) -> None:
        if cal_factor is not None and math.isfinite(cal_factor) and round(cal_factor * 1000) != 0:
            self.cal_milli = round(cal_factor * 1000)

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
        return replace(r, grams=grams_mg(r.raw, self.zero_raw, self.cal_milli) / 1000.0, sketch_grams=r.grams)

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
        dl = Deadline(self.clock, timeout)
        while not self._queue:
            if self.zero_lost:
                raise ZeroLost("the scale's zero is lost: the sketch rebooted and re-tared with the load on it, "
                               "and it sends no raw counts to correct with; call tare() with the scale empty",
                               device=self.device)
            if dl.expired():
                raise DeviceTimeout(
                    f"no reading for {timeout:.3g} s (expected {self.rate_sps or '10 or 80'} per second): "
                    "the scale stopped talking or was unplugged", device=self.device)
            self._pump(dl.remaining_s() or 0.0)
        return self._queue.popleft()

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

    def _await_reply(self, kinds: tuple[str, ...], timeout_s: float, what: str) -> ParsedLine:
        dl = Deadline(self.clock, timeout_s)
        while True:
            while self._replies:
                rep = self._replies.popleft()
                if rep.kind in kinds:
                    return rep
            if dl.expired():
                raise DeviceTimeout(f"no answer to {what} within {timeout_s:.3g} s", device=self.device)
            self._pump(dl.remaining_s() or 0.0)

    @locked
    def tare(self, timeout_s: float | None = None) -> None:
        """Zero the scale with what is on it now; returns when the sketch confirms (one smoothing window).

        Readings queued before the confirmation are not tared; the ones after it are."""
        timeout = timeout_s if timeout_s is not None else 2 * self._window_s() + 1.0
        self._replies.clear()
        self.transport.write(sp.CMD_TARE)  # type: ignore[union-attr]
        self._await_reply(("tare", "stock_tare"), timeout, "tare ('t')")

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
        rep = self._await_reply(("cal", "error"), timeout, f"calibrate({known_mass_g} g)")
        if rep.kind == "error":
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
        rep = self._await_reply(("id",), timeout_s, "'?'")
        assert rep.info is not None
        return rep.info
