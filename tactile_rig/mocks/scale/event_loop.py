"""The scale sketch's event loop: :class:`ScaleMock`, the Arduino on a serial line, event by event.

What the host sees, and why, is told in :mod:`tactile_rig.mocks.scale`; the sketch's numbers (its
arithmetic, framing, buffer sizes and measured timings) are :mod:`.sketch`. Here the bootloader, the
receive ring, the start-up tare, the commands, the conversions and the stock example share one state
and one clock.
"""

from __future__ import annotations

import math
from collections import deque
from typing import Any

import numpy as np

from tactile_rig.core.clock import Clock
from tactile_rig.devices import scale as sp
from tactile_rig.mocks.hx711 import Hx711
from tactile_rig.mocks.scale.sketch import (
    BOOTLOADER_S,
    CAL_MILLI_MAX,
    CAL_MILLI_MIN,
    DEFAULT_CAL_MILLI,
    HX711_TIMEOUT_S,
    LINE_MAX,
    MIN_CAL_COUNTS,
    RX_RING_BYTES,
    SETTLE_CONVERSIONS,
    T_BANNER_S,
    T_CAL_ERROR_S,
    T_CAL_S,
    T_E4_S,
    T_ERROR_S,
    T_HX_RESET_S,
    T_ID_S,
    T_MASS_ERROR_S,
    T_RESET_HX_AGAIN_S,
    T_TARE_S,
    TX_IN_FLIGHT_BYTES,
    UART_BAUD_ACTUAL,
    WINDOW,
    div_round,
    frame,
    milli_str,
    parse_mass_mg,
    sample_latency_s,
    smoothed_counts,
)
from tactile_rig.mocks.serial_device import BITS_PER_BYTE, SerialDevice
from tactile_rig.sim.world.load_cell import LoadCell

__all__ = ["ScaleMock"]


class ScaleMock(SerialDevice):
    """The scale's Arduino on a serial line (see :mod:`tactile_rig.mocks.scale`)."""

    kind = "scale"

    def __init__(
        self,
        *,
        clock: Clock | None = None,
        load_cell: LoadCell | None = None,
        rate_sps: int = 80,
        boot_s: float = BOOTLOADER_S,
        baud: int = sp.BAUD,
        firmware: str = "tactile",
        timing: bool = True,
        seed: int = 0,
        counts_per_g: float = sp.DEFAULT_CAL_FACTOR,
        offset_counts: float = 84_000.0,
        noise_counts: float | None = None,
        drift_counts: float = 1_500.0,
        drift_tau_s: float = 180.0,
        spike_prob: float = 0.002,
        boot_junk: bool = True,
        stock_settle_s: float = 2.0,
    ) -> None:
        super().__init__(baud=baud, timing=timing, seed=seed)
        if rate_sps not in sp.RATES_SPS:
            raise ValueError(f"scale rate={rate_sps!r} samples/s: an HX711 runs at 10 or 80")
        if firmware not in ("tactile", "stock"):
            raise ValueError(f"scale firmware={firmware!r}: expected 'tactile' (our sketch) or 'stock'")
        if not (0.0 <= boot_s <= 30.0):
            raise ValueError(f"scale boot_s={boot_s!r} must be within [0, 30] s")
        if not (0.0 <= spike_prob <= 1.0):
            raise ValueError(f"scale spike_prob={spike_prob!r} must be a probability in [0, 1]")
        if not (drift_tau_s > 0.0 and math.isfinite(drift_tau_s)):
            raise ValueError(f"scale drift_tau_s={drift_tau_s!r} must be a positive number of seconds")
        for name, v in (("counts_per_g", counts_per_g), ("offset_counts", offset_counts),
                        ("drift_counts", drift_counts)):
            if not math.isfinite(v):
                raise ValueError(f"scale {name}={v!r} must be a finite number")
        self.clock = clock
        self.load_cell = load_cell if load_cell is not None else LoadCell()
        self.rate_sps = int(rate_sps)
        self.period_s = 1.0 / self.rate_sps
        self.boot_s = float(boot_s)
        self.firmware = firmware
        self.counts_per_g = float(counts_per_g)
        self.offset_counts = float(offset_counts)
        # HX711 input noise roughly doubles from 10 to 80 SPS (datasheet: 50 vs 90 nV rms).
        self.noise_counts = float(noise_counts if noise_counts is not None else (20.0 if rate_sps == 10 else 40.0))
        self.drift_counts = float(drift_counts)
        self.drift_tau_s = float(drift_tau_s)
        self.spike_prob = float(spike_prob)
        self.boot_junk = bool(boot_junk)
        self.stock_settle_s = float(stock_settle_s)
        self.rng = np.random.default_rng(seed)
        self.power_on_s = clock.now_s() if clock is not None else 0.0
        self.hx711 = Hx711(self.rate_sps, self._input_counts, noise_counts=self.noise_counts,
                           spike_prob=self.spike_prob, rng=self.rng)
        self.hx711.reset(self.power_on_s)
        self.eeprom_cal_milli = DEFAULT_CAL_MILLI  # survives resets, like the AVR's EEPROM
        self.faults: list[tuple[float, str]] = []
        self.samples_sent = 0
        self.rx_dropped = 0  # host bytes lost: sent during the bootloader, or past the full ring
        self._dtr = True
        self._running = False  # False while the port is closed (the next open resets anyway)
        self._inbox: deque[tuple[float, int]] = deque()  # host bytes in flight: (arrival time, byte)
        self._reset_state(None)

    # -- the bridge -------------------------------------------------------------------------
    def _input_counts(self, t_s: float) -> float:
        self.load_cell.advance_to(t_s)
        grams = self.load_cell.force_n / sp.STANDARD_GRAVITY_MPS2 * 1000.0 + self.load_cell.tare_mass_g
        counts = self.offset_counts + self.counts_per_g * grams
        if self.drift_counts:
            counts += self.drift_counts * (1.0 - math.exp(-max(0.0, t_s - self.power_on_s) / self.drift_tau_s))
        return counts

    @property
    def eeprom_cal_factor(self) -> float:
        """The calibration factor in the emulated EEPROM, counts per gram."""
        return self.eeprom_cal_milli / 1000.0

    def byte_time_s(self) -> float:
        # The AVR's UART at UBRR 16 without U2X: 58824 baud when 57600 is asked for.
        scale = sp.BAUD / UART_BAUD_ACTUAL if self.baud == sp.BAUD else 1.0
        return BITS_PER_BYTE / self.baud * scale

    def _lat(self, seconds: float) -> float:
        return seconds if self.timing else 0.0

    # -- firmware state ----------------------------------------------------------------------
    def _reset_state(self, t_s: float | None) -> None:
        self._boot_end_s = math.inf if t_s is None else t_s + self.boot_s
        self._phase = "off" if t_s is None else "boot"  # boot, setup, run, hung
        self._hung = False
        self._busy_until_s = -math.inf  # the sketch's loop is blocked (computing, or on a full TX ring)
        self._ring: deque[tuple[float, int]] = deque()  # HardwareSerial's receive ring: (arrival, byte)
        self._line = bytearray()
        self._line_bad = False
        self._seq = 0
        self._window: list[int] = []
        self._win_pos = 0
        self._smoothed = 0
        self._tare_counts = 0
        self._cal_milli = self.eeprom_cal_milli
        self._tare_left = 0
        self._cal_left = 0
        self._cal_mass_mg = 0
        self._settle_left = SETTLE_CONVERSIONS
        self._pending: tuple[float, int] | None = None  # a conversion ready but not yet read
        self._last_conv_s = -math.inf  # the sketch's lastConversionMs (E,4 time-out)
        self._wait_since_s = -math.inf  # start-up: waiting for the HX711 since
        self._stock_ready_s = math.inf

    def reset(self, t_s: float) -> None:
        """The MCU resets at ``t_s`` (DTR edge, port open, watchdog): RAM state is lost."""
        self._reset_state(t_s)
        self._running = True
        self._inbox.clear()  # bytes on the wire at the reset are lost
        if self.boot_junk:
            # A byte or two of line noise while the USB-serial chip and bootloader start.
            self.emit(bytes(self.rng.integers(0x80, 0x100, size=2, dtype=np.uint8)), t_s, reply=False)

    def on_open(self, t_s: float) -> None:
        self._dtr = True
        self.reset(t_s)

    def on_close(self, t_s: float) -> None:
        # The sketch keeps running with nobody listening; on the next open it resets anyway.
        self._running = False
        self._inbox.clear()

    def on_dtr(self, state: bool, t_s: float) -> None:
        if state and not self._dtr:  # the auto-reset capacitor turns a DTR assertion into a pulse
            self.reset(t_s)
        self._dtr = bool(state)

    def inject(self, fault: str, t_s: float | None = None) -> None:
        """``hang``: the sketch stops; ``reset``: the MCU reboots now; ``hx711_disconnect`` /
        ``hx711_connect``: the HX711 is unplugged / plugged in again."""
        t = self.clock.now_s() if t_s is None and self.clock is not None else (t_s or 0.0)
        known = ("hang", "reset", "hx711_disconnect", "hx711_connect")
        if fault not in known:
            raise ValueError(f"scale mock: unknown fault {fault!r}; known: {', '.join(known)}")
        self.advance_to(t)
        self.faults.append((t, fault))
        if fault == "hang":
            self._hung = True
        elif fault == "reset":
            self.reset(t)
        elif fault == "hx711_disconnect":
            self.hx711.disconnect()
            self._pending = None
        else:
            self.hx711.connect(t)

    # -- time --------------------------------------------------------------------------------
    def next_event_s(self) -> float | None:
        if not self._running or self._hung:
            return None
        return self._next_sketch_event_s()

    def on_tick(self, t_s: float) -> None:
        if self._running:
            self._run_until(t_s)

    def feed(self, data: bytes, t_s: float) -> None:
        """The host wrote ``data`` at ``t_s``: each byte reaches the sketch after its own wire time."""
        if not data:
            return
        with self._lock:
            rate = self.client_baud or self.baud
            if self.client_baud is not None and self.client_baud != self.baud:
                data = self._garble(data, self.client_baud, self.baud)
            start = max(t_s, self._rx_free_s)
            per = BITS_PER_BYTE / rate if self.timing else 0.0
            # The AVR's receiver flags a byte one of its own frames after the start bit.
            own = self.byte_time_s() if self.timing else 0.0
            for i, b in enumerate(data):
                self._inbox.append((start + i * per + own, b))
            self._rx_free_s = start + len(data) * per
            # Process up to the last byte's arrival now, so an immediate answer is already scheduled.
            self.advance_to(self._inbox[-1][0])

    def on_bytes(self, data: bytes, t_s: float) -> None:
        """Bytes that have fully arrived at ``t_s`` (the per-byte path is :meth:`feed`)."""
        for b in data:
            self._inbox.append((t_s, b))
        self._run_until(t_s)

    # -- the sketch, event by event --------------------------------------------------------------
    def _sketch_free(self, t_s: float) -> bool:
        return t_s >= self._busy_until_s

    def _next_sketch_event_s(self) -> float | None:
        cands: list[float] = []
        if self._inbox:
            cands.append(self._inbox[0][0])
        if self._phase == "boot":
            cands.append(self._boot_end_s)
            return min(cands)
        if self._hung or self._phase == "off":
            return min(cands) if cands else None
        nd = self.hx711.next_data_s()
        if nd is not None:
            cands.append(nd)
        if self._phase == "run" and self.firmware == "tactile":
            if self._ring:
                cands.append(max(self._busy_until_s, self._ring[0][0]))
            if self._pending is not None:
                cands.append(max(self._busy_until_s, self._pending[0]))
            cands.append(max(self._last_conv_s + HX711_TIMEOUT_S, self._busy_until_s))
        elif self._phase == "setup" and self.firmware == "tactile":
            cands.append(self._wait_since_s + HX711_TIMEOUT_S)
        elif self._phase == "run" and self._ring:
            cands.append(max(self._busy_until_s, self._ring[0][0]))
        return min(cands) if cands else None

    def _run_until(self, t_s: float) -> None:
        for _ in range(10_000_000):
            nxt = self._next_sketch_event_s()
            if nxt is None or nxt > t_s:
                return
            self._step(nxt)
        raise RuntimeError("scale mock: event loop did not converge")  # a bug, never a device state

    def _step(self, t: float) -> None:
        # Host bytes that have arrived by t (a hung sketch's ring fills up too).
        if self._inbox and self._inbox[0][0] <= t:
            tb, b = self._inbox.popleft()
            if self._phase in ("off", "boot"):
                self.rx_dropped += 1  # the bootloader's UART is not the sketch's: the byte is gone
            elif len(self._ring) < RX_RING_BYTES:
                self._ring.append((tb, b))
            else:
                self.rx_dropped += 1
            return
        if self._hung:
            return
        if self._phase == "boot":
            if t >= self._boot_end_s:
                self._start_sketch(self._boot_end_s)
            return
        # The HX711 presents what it converted by t.
        for tc, value in self.hx711.convert_until(t):
            self._pending = (tc, value)  # an unread older one is overwritten
        if self.firmware == "stock":
            self._step_stock(t)
            return
        if self._phase == "setup":
            if self._pending is not None:
                tc, value = self._pending
                self._pending = None
                self._setup_conversion(tc, value)
            elif t >= self._wait_since_s + HX711_TIMEOUT_S:
                self._emit(frame(f"{sp.TAG_ERROR},4,{sp.ERRORS[4]}"), t + self._lat(T_E4_S))
                self._sketch_reset_hx711(t + self._lat(T_E4_S + T_RESET_HX_AGAIN_S))
            return
        # run: the loop reads commands first, then a waiting conversion, else checks the time-out.
        if not self._sketch_free(t):
            return
        if self._ring:
            self._read_byte(t, self._ring.popleft()[1])
        elif self._pending is not None:
            tc, value = self._pending
            self._pending = None
            self._conversion(max(tc, t), value)
        elif t >= self._last_conv_s + HX711_TIMEOUT_S:
            self._emit(frame(f"{sp.TAG_ERROR},4,{sp.ERRORS[4]}"), t + self._lat(T_E4_S))
            self._last_conv_s = t

    def _emit(self, data: bytes, t_write: float, *, reply: bool = False) -> None:
        """Serial.write at ``t_write``: the sketch is blocked until the TX ring has room for it all."""
        if self._hung:
            return
        ready = self.emit(data, t_write, reply=reply)
        done = ready - TX_IN_FLIGHT_BYTES * self.byte_time_s() if self.timing else t_write
        self._busy_until_s = max(self._busy_until_s, t_write, done)

    # -- start-up ---------------------------------------------------------------------------------
    def _start_sketch(self, t: float) -> None:
        self._phase = "setup"
        if self.firmware == "stock":
            self.emit(b"\r\n" + sp.STOCK_STARTING.encode() + b"\r\n", t, reply=False)
            self._stock_ready_s = t + self.stock_settle_s
        self._sketch_reset_hx711(t + T_HX_RESET_S)

    def _sketch_reset_hx711(self, t: float) -> None:
        # SCK high 100 us (> 60 us: power-down) then low: the HX711 restarts on channel A, gain 128.
        self._pending = None
        self._settle_left = SETTLE_CONVERSIONS
        self._window = []
        self._wait_since_s = t
        if self.hx711.connected:
            self.hx711.reset(t)

    def _setup_conversion(self, tc: float, value: int) -> None:
        self._wait_since_s = tc
        if self._settle_left:
            self._settle_left -= 1
            return
        self._window.append(value)
        if len(self._window) < WINDOW:
            return
        self._win_pos = 0
        self._smoothed = smoothed_counts(self._window)
        self._tare_counts = self._smoothed
        self._last_conv_s = tc
        self._phase = "run"
        self._seq = 0
        self._busy_until_s = tc
        self._emit(frame(self._id_body(sp.TAG_BANNER)), tc + self._lat(T_BANNER_S))

    def _id_body(self, tag: str) -> str:
        return f"{tag},{sp.FIRMWARE_NAME},{sp.FIRMWARE_VERSION},{self.rate_sps},{milli_str(self._cal_milli)}"

    # -- one conversion ---------------------------------------------------------------------------
    def _conversion(self, t: float, value: int) -> None:
        self._last_conv_s = t
        self._window[self._win_pos] = value
        self._win_pos = (self._win_pos + 1) % WINDOW
        self._smoothed = smoothed_counts(self._window)
        if self._tare_left:
            self._tare_left -= 1
            if self._tare_left == 0:
                self._tare_counts = self._smoothed
                self._emit(frame(f"{sp.TAG_TARE},ok"), t + self._lat(T_TARE_S))
        if self._cal_left:
            self._cal_left -= 1
            if self._cal_left == 0:
                self._finish_calibration(t)
        grams = milli_str(div_round((self._smoothed - self._tare_counts) * 1_000_000, self._cal_milli))
        seq, raw = str(self._seq), str(self._smoothed)
        self._emit(frame(f"{sp.TAG_SAMPLE},{seq},{grams},{raw}"), t + self._lat(sample_latency_s(seq, grams, raw)))
        self._seq = (self._seq + 1) % sp.SEQ_MODULO
        self.samples_sent += 1

    def _finish_calibration(self, t: float) -> None:
        delta = self._smoothed - self._tare_counts
        refused = t + self._lat(T_CAL_ERROR_S)
        if abs(delta) < MIN_CAL_COUNTS:
            self._emit(frame(f"{sp.TAG_ERROR},3,{sp.ERRORS[3]}"), refused)
            return
        f = div_round(delta * 1_000_000, self._cal_mass_mg)
        if not (CAL_MILLI_MIN <= abs(f) <= CAL_MILLI_MAX):
            self._emit(frame(f"{sp.TAG_ERROR},5,{sp.ERRORS[5]}"), refused)
            return
        self._cal_milli = f
        self.eeprom_cal_milli = f
        self._emit(frame(f"{sp.TAG_CAL},{milli_str(f)}"), t + self._lat(T_CAL_S))

    # -- commands ---------------------------------------------------------------------------------
    def _read_byte(self, t: float, b: int) -> None:
        if b == 0x0D:
            return
        if b == 0x0A:
            line, bad = bytes(self._line), self._line_bad
            self._line.clear()
            self._line_bad = False
            if bad:
                self._emit(frame(f"{sp.TAG_ERROR},1,{sp.ERRORS[1]}"), t + self._lat(T_ERROR_S), reply=True)
            elif line:
                self._command(line, t)
        elif b == 0 or len(self._line) >= LINE_MAX:
            self._line_bad = True
        else:
            self._line.append(b)

    def _command(self, line: bytes, t: float) -> None:
        if line == sp.CMD_TARE.rstrip(b"\n"):
            self._tare_left = WINDOW  # let the window refill with what is on the scale now
        elif line == sp.CMD_ID.rstrip(b"\n"):
            self._emit(frame(self._id_body(sp.TAG_ID)), t + self._lat(T_ID_S), reply=True)
        elif line.startswith(sp.CMD_CALIBRATE_PREFIX):
            mg = parse_mass_mg(line[len(sp.CMD_CALIBRATE_PREFIX):].decode("latin-1"))
            if mg is None:
                self._emit(frame(f"{sp.TAG_ERROR},2,{sp.ERRORS[2]}"), t + self._lat(T_MASS_ERROR_S), reply=True)
            else:
                self._cal_mass_mg = mg
                self._cal_left = WINDOW
        else:
            self._emit(frame(f"{sp.TAG_ERROR},1,{sp.ERRORS[1]}"), t + self._lat(T_ERROR_S), reply=True)

    # -- the stock HX711_ADC example ---------------------------------------------------------------
    def _step_stock(self, t: float) -> None:
        if self._phase == "setup":
            if self._pending is not None:
                tc, value = self._pending
                self._pending = None
                self._window.append(value)
                del self._window[:-WINDOW]
                if tc >= self._stock_ready_s and len(self._window) == WINDOW:
                    # HX711_ADC's start(2000, true): stabilise, tare on the full window, then report.
                    self._tare_counts = smoothed_counts(self._window)
                    self._phase = "run"
                    self._win_pos = 0
                    self.emit(sp.STOCK_STARTUP_DONE.encode() + b"\r\n", tc, reply=False)
            return
        while self._ring:
            self._read_stock_byte(t, self._ring.popleft()[1])
        if self._pending is not None:
            tc, value = self._pending
            self._pending = None
            self._window[self._win_pos] = value
            self._win_pos = (self._win_pos + 1) % WINDOW
            smoothed = smoothed_counts(self._window)
            if self._tare_left:
                self._tare_left -= 1
                if self._tare_left == 0:
                    self._tare_counts = smoothed
                    self.emit(sp.STOCK_TARE_DONE.encode() + b"\r\n", tc, reply=False)
            grams = (smoothed - self._tare_counts) / (self._cal_milli / 1000.0)
            self.emit(f"{sp.STOCK_DATA_PREFIX}{grams:.2f}\r\n".encode(), tc, reply=False)
            self.samples_sent += 1

    def _read_stock_byte(self, t: float, b: int) -> None:
        if b == ord("t"):  # the stock example reads single characters: only 't' means something
            self._tare_left = WINDOW

    def describe(self) -> dict[str, Any]:
        return {"rate_sps": self.rate_sps, "boot_s": self.boot_s, "firmware": self.firmware,
                "counts_per_g": self.counts_per_g}
