"""The Arduino HX711 scale, emulated: ``firmware/arduino_scale`` (or the stock HX711_ADC example).

What the host sees, and why:

* Opening the port (or a DTR edge) resets the Arduino: it is silent for the bootloader time
  (``boot_s``, ~1.6 s on an Uno), may glitch a byte or two, then prints its banner.
* The HX711 converts at 10 or 80 samples/s (its RATE pin). Each conversion is the load on the
  cell (from the world's ``load_cell`` model) times the bridge sensitivity, plus the zero offset,
  white noise, a warm-up drift that settles over minutes (strain gauges and the HX711 warm up),
  rare spikes (the glitches users report as sign flips), clamped to 24 bits.
* The sketch smooths like HX711_ADC (16 samples plus one high and one low ignored), prints one
  framed line per conversion (grams and the smoothed raw counts), answers ``t`` (tare, done after the smoothing window refills),
  ``c,<grams>`` (calibration, factor kept in "EEPROM" across resets) and ``?`` (ID line).

``firmware=stock`` emulates the unmodified ``Read_1x_load_cell`` example instead.
Faults: :meth:`ScaleMock.inject` ``hang`` (the sketch stops printing) and ``reset`` (reboot now).
"""

from __future__ import annotations

import math
from collections import deque
from typing import Any

import numpy as np

from tactile_rig.core.clock import Clock
from tactile_rig.devices import scale as sp
from tactile_rig.mocks.registry import Params, register_kind
from tactile_rig.mocks.serial_device import SerialDevice
from tactile_rig.sim.world.load_cell import LoadCell


def _crc8(body: bytes) -> int:
    # Bitwise, as the sketch computes it on the AVR (the driver uses a table: separate codecs).
    crc = 0
    for byte in body:
        crc ^= byte
        for _ in range(8):
            crc = ((crc << 1) ^ sp.CRC8_POLY) & 0xFF if crc & 0x80 else (crc << 1) & 0xFF
    return crc


def frame(body: str) -> bytes:
    """``body*CC\\r\\n`` as the sketch prints it."""
    raw = body.encode("ascii")
    return raw + b"*%02X\r\n" % _crc8(raw)


class ScaleMock(SerialDevice):
    """The scale's Arduino on a serial line (see the module docstring)."""

    kind = "scale"

    def __init__(
        self,
        *,
        clock: Clock | None = None,
        load_cell: LoadCell | None = None,
        rate_sps: int = 80,
        boot_s: float = 1.6,
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
        self.eeprom_cal_factor = sp.DEFAULT_CAL_FACTOR  # survives resets, like the AVR's EEPROM
        self.faults: list[tuple[float, str]] = []
        self.samples_sent = 0
        self._dtr = True
        self._running = False  # False while powered down / port closed
        self._reset_state(None)

    # -- firmware state ----------------------------------------------------------------------
    def _reset_state(self, t_s: float | None) -> None:
        self._boot_at_s = None if t_s is None else t_s + self.boot_s
        self._booted = False
        self._hung = False
        self._next_sample_s = math.inf
        self._seq = 0
        self._window: deque[float] = deque(maxlen=sp.SMOOTHING_SAMPLES + 2)
        self._tare_counts = 0.0
        self._cal_factor = self.eeprom_cal_factor
        self._rx = bytearray()
        self._pending: list[tuple[str, int, Any]] = []  # (command, samples left, argument)
        self._stock_ready_s = math.inf

    def reset(self, t_s: float) -> None:
        """The MCU resets at ``t_s`` (DTR edge, port open, watchdog): RAM state is lost."""
        self._reset_state(t_s)
        self._running = True
        if self.boot_junk:
            # A byte or two of line noise while the USB-serial chip and bootloader start.
            self.emit(bytes(self.rng.integers(0x80, 0x100, size=2, dtype=np.uint8)), t_s, reply=False)

    def on_open(self, t_s: float) -> None:
        self._dtr = True
        self.reset(t_s)

    def on_close(self, t_s: float) -> None:
        # The sketch keeps running with nobody listening; on the next open it resets anyway.
        self._running = False

    def on_dtr(self, state: bool, t_s: float) -> None:
        if state and not self._dtr:  # the auto-reset capacitor turns a DTR assertion into a pulse
            self.reset(t_s)
        self._dtr = bool(state)

    def inject(self, fault: str, t_s: float | None = None) -> None:
        """``hang``: the sketch stops printing; ``reset``: the MCU reboots now."""
        t = self.clock.now_s() if t_s is None and self.clock is not None else (t_s or 0.0)
        self.advance_to(t)
        self.faults.append((t, fault))
        if fault == "hang":
            self._hung = True
        elif fault == "reset":
            self.reset(t)
        else:
            raise ValueError(f"scale mock: unknown fault {fault!r}; known: hang, reset")

    # -- time --------------------------------------------------------------------------------
    def next_event_s(self) -> float | None:
        if not self._running or self._hung:
            return None
        if not self._booted:
            return self._boot_at_s
        return self._next_sample_s

    def on_tick(self, t_s: float) -> None:
        if not self._running or self._hung:
            return
        if not self._booted:
            if self._boot_at_s is None or t_s < self._boot_at_s:
                return
            self._boot(self._boot_at_s)
        while self._next_sample_s <= t_s and not self._hung:
            ts = self._next_sample_s
            self._next_sample_s = ts + self.period_s
            self._sample(ts)

    def _boot(self, t_s: float) -> None:
        self._booted = True
        # Fill the smoothing window and tare at start-up, as HX711_ADC's start(…, tare=true) does.
        for _ in range(self._window.maxlen or 0):
            self._window.append(self._convert(t_s, spikes=False))
        self._tare_counts = self._smoothed()
        if self.firmware == "tactile":
            self.emit(frame(f"{sp.TAG_BANNER},{sp.FIRMWARE_NAME},{sp.FIRMWARE_VERSION},{self.rate_sps},"
                            f"{self._cal_factor:.3f}"), t_s, reply=False)
            self._next_sample_s = t_s + self.period_s
        else:
            self.emit(b"\r\n" + sp.STOCK_STARTING.encode() + b"\r\n", t_s, reply=False)
            done = t_s + self.stock_settle_s
            self.emit(sp.STOCK_STARTUP_DONE.encode() + b"\r\n", done, reply=False)
            self._next_sample_s = done + self.period_s

    # -- the HX711 -----------------------------------------------------------------------------
    def _convert(self, t_s: float, *, spikes: bool = True) -> float:
        self.load_cell.advance_to(t_s)
        grams = self.load_cell.force_n / sp.STANDARD_GRAVITY_MPS2 * 1000.0 + self.load_cell.tare_mass_g
        warm = self.drift_counts * (1.0 - math.exp(-max(0.0, t_s - self.power_on_s) / self.drift_tau_s))
        raw = self.offset_counts + self.counts_per_g * grams + warm + self.rng.normal(0.0, self.noise_counts)
        if spikes and self.spike_prob and self.rng.random() < self.spike_prob:
            # A glitched read: a flipped high bit, the "sign flip" users report.
            raw = float(int(raw) ^ (1 << int(self.rng.integers(17, 23))))
        return float(min(max(round(raw), sp.RAW_MIN), sp.RAW_MAX))

    def _smoothed(self) -> float:
        data = sorted(self._window)
        if len(data) > 2:
            data = data[1:-1]  # IGN_HIGH_SAMPLE / IGN_LOW_SAMPLE
        return float(sum(data) / len(data)) if data else 0.0

    def _sample(self, t_s: float) -> None:
        raw = self._convert(t_s)
        self._window.append(raw)
        smoothed = self._smoothed()
        self._run_pending(t_s, smoothed)
        grams = (smoothed - self._tare_counts) / self._cal_factor
        if self.firmware == "tactile":
            # The sketch prints HX711_ADC's smoothed counts (tare offset included), as the library
            # exposes no single conversion; lone spikes are mostly dropped by its high/low rejection.
            self.emit(frame(f"{sp.TAG_SAMPLE},{self._seq},{grams:.3f},{int(round(smoothed))}"), t_s, reply=False)
            self._seq = (self._seq + 1) % sp.SEQ_MODULO
        else:
            self.emit(f"{sp.STOCK_DATA_PREFIX}{grams:.2f}\r\n".encode(), t_s, reply=False)
        self.samples_sent += 1

    def _run_pending(self, t_s: float, smoothed: float) -> None:
        still: list[tuple[str, int, Any]] = []
        for cmd, left, arg in self._pending:
            if left > 1:
                still.append((cmd, left - 1, arg))
                continue
            if cmd == "tare":
                self._tare_counts = smoothed
                self.emit(frame(f"{sp.TAG_TARE},ok") if self.firmware == "tactile"
                          else sp.STOCK_TARE_DONE.encode() + b"\r\n", t_s, reply=False)
            elif cmd == "cal":
                delta = smoothed - self._tare_counts
                if abs(delta) < 100.0:
                    self.emit(frame(f"{sp.TAG_ERROR},3,{sp.ERRORS[3]}"), t_s, reply=False)
                else:
                    self._cal_factor = delta / float(arg)
                    self.eeprom_cal_factor = self._cal_factor
                    self.emit(frame(f"{sp.TAG_CAL},{self._cal_factor:.3f}"), t_s, reply=False)
        self._pending = still

    # -- commands ------------------------------------------------------------------------------
    def on_bytes(self, data: bytes, t_s: float) -> None:
        if not self._running or not self._booted or self._hung:
            return  # the bootloader (or a hung sketch) eats what the host sends
        self._rx += data
        while True:
            idx = self._rx.find(b"\n")
            if idx < 0:
                if len(self._rx) > 64:  # the sketch's line buffer
                    self._rx.clear()
                return
            line = bytes(self._rx[:idx]).strip().decode("ascii", "replace")
            del self._rx[: idx + 1]
            if line:
                self._command(line, t_s)

    def _command(self, line: str, t_s: float) -> None:
        window = self._window.maxlen or 1
        if line == "t":
            self._pending.append(("tare", window, None))
        elif self.firmware == "stock":
            return  # the stock example only knows 't'
        elif line == "?":
            self.emit(frame(f"{sp.TAG_ID},{sp.FIRMWARE_NAME},{sp.FIRMWARE_VERSION},{self.rate_sps},"
                            f"{self._cal_factor:.3f}"), t_s, delay_s=0.0002)
        elif line.startswith("c,"):
            try:
                mass = float(line[2:])
            except ValueError:
                mass = float("nan")
            if not (mass > 0 and math.isfinite(mass)):
                self.emit(frame(f"{sp.TAG_ERROR},2,{sp.ERRORS[2]}"), t_s, delay_s=0.0002)
            else:
                self._pending.append(("cal", window, mass))
        else:
            self.emit(frame(f"{sp.TAG_ERROR},1,{sp.ERRORS[1]}"), t_s, delay_s=0.0002)

    def describe(self) -> dict[str, Any]:
        return {"rate_sps": self.rate_sps, "boot_s": self.boot_s, "firmware": self.firmware,
                "counts_per_g": self.counts_per_g}


def _factory(params: Params, *, clock: Clock, world: Any = None) -> ScaleMock:
    cell_name = params.str("load_cell", "load_cell") or "load_cell"
    cell = world.require(cell_name, who="the scale mock") if world is not None else None
    force_n = params.float("force_n")
    if cell is None:
        cell = LoadCell(applied_force_n=force_n or 0.0)
    elif force_n is not None:
        cell.applied_force_n = force_n
    return ScaleMock(
        clock=clock,
        load_cell=cell,
        rate_sps=params.int("rate", 80),
        boot_s=params.float("boot_s", 1.6),
        baud=params.int("baud", sp.BAUD),
        firmware=params.str("firmware", "tactile") or "tactile",
        timing=params.bool("timing", True),
        seed=params.int("seed", 0),
        counts_per_g=params.float("counts_per_g", sp.DEFAULT_CAL_FACTOR),
        noise_counts=params.float("noise_counts"),
        drift_counts=params.float("drift_counts", 1500.0),
        drift_tau_s=params.float("drift_tau_s", 180.0),
        spike_prob=params.float("spike_prob", 0.002),
        boot_junk=params.bool("boot_junk", True),
        stock_settle_s=params.float("stock_settle_s", 2.0),
    )


register_kind("scale", _factory, default_baud=sp.BAUD,
              description="Arduino + HX711 load-cell scale (firmware/arduino_scale, or the stock HX711_ADC example)")
