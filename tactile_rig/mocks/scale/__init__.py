"""The Arduino HX711 scale, emulated: ``firmware/arduino_scale`` (or the stock HX711_ADC example).

This is the compiled sketch's behaviour retold in Python, held against the real thing: the
differential test (``tests/mocks/test_scale_firmware_differential.py``) plays the same sessions against this
mock and against the sketch compiled for the ATmega328P running on the simulated board
(``firmware/sim``), and requires the same lines, byte for byte. What the host sees, and why:

* Opening the port (or a DTR edge) resets the Arduino: the bootloader keeps it silent for
  ``boot_s`` (1.53 s: the Uno's optiboot), a glitch byte or two may arrive (``boot_junk``), bytes
  the host sends meanwhile are lost. Then the sketch resets the HX711, whose first conversion comes
  4 periods later; it discards 2 conversions, fills its smoothing window with 18 for the start-up
  tare and prints its banner: 0.29 s of start-up at 80 samples/s, 2.3 s at 10.
* The HX711 (:mod:`tactile_rig.mocks.hx711`) converts at 10 or 80 samples/s what the world's
  ``load_cell`` model presses on it: offset + counts per gram x grams + warm-up drift, through its
  sinc4 filter, plus noise and rare glitches, clamped to 24 bits.
* One framed line per conversion: smoothed like HX711_ADC (16 samples after dropping the highest
  and the lowest), grams and the smoothed ABSOLUTE raw counts, in the sketch's integer arithmetic
  (milligrams and milli-counts per gram, rounded half away from zero). ``t`` tares and ``c,<g>``
  calibrates once the window has refilled (a repeat restarts the wait and is answered once); the
  factor is kept in "EEPROM" across resets; ``?`` answers at once; anything else is ``E,1``.
* Host bytes wait in the Arduino core's 64-byte receive ring (63 usable) while the sketch is busy
  (its start-up, or a Serial.write that blocks on a full transmit ring); what does not fit is lost.
  Lines longer than 32 bytes, or with a NUL, are answered ``E,1``. Bytes reach the sketch at the
  host's baud; the sketch's UART runs at 58824 baud for "57600" (the Arduino core's exception for
  57600 at 16 MHz: UBRR 16 without U2X, +2.1 %, within what a UART tolerates).
* Each answer starts as long after its cause as the compiled sketch takes to compute and format it
  (measured on the simulated board, cycle-exact): a sample 0.9-1.2 ms after its conversion (more
  digits, more time), ``E,1`` 0.13 ms after the newline, ``I`` 0.41 ms after it, and so on.
* An unplugged HX711 (``inject("hx711_disconnect")``) is reported as ``E,4`` once a second.

``firmware=stock`` emulates the unmodified ``Read_1x_load_cell`` example instead (not compiled here:
it needs the HX711_ADC library). Faults: :meth:`ScaleMock.inject` ``hang`` (the sketch stops),
``reset`` (reboot now), ``hx711_disconnect`` and ``hx711_connect``.

The package: :mod:`.sketch` (the sketch's numbers: arithmetic, framing, buffer sizes, the timings
measured on the simulated board), :mod:`.event_loop` (:class:`ScaleMock`, the sketch event by event).
``rigsim://scale?...`` builds a :class:`ScaleMock`.
"""

from __future__ import annotations

from typing import Any

from tactile_rig.core.clock import Clock
from tactile_rig.devices import scale as sp
from tactile_rig.mocks.registry import Params, register_kind
from tactile_rig.mocks.scale.event_loop import ScaleMock
from tactile_rig.mocks.scale.sketch import (
    BOOTLOADER_S,
    CAL_MILLI_MAX,
    CAL_MILLI_MIN,
    DEFAULT_CAL_MILLI,
    HX711_TIMEOUT_S,
    LINE_MAX,
    MASS_G_MAX,
    MIN_CAL_COUNTS,
    RX_RING_BYTES,
    SETTLE_CONVERSIONS,
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
from tactile_rig.sim.world.load_cell import LoadCell

__all__ = [
    "BOOTLOADER_S", "CAL_MILLI_MAX", "CAL_MILLI_MIN", "DEFAULT_CAL_MILLI", "HX711_TIMEOUT_S", "LINE_MAX", "MASS_G_MAX",
    "MIN_CAL_COUNTS", "RX_RING_BYTES", "SETTLE_CONVERSIONS", "ScaleMock", "TX_IN_FLIGHT_BYTES", "UART_BAUD_ACTUAL",
    "WINDOW", "div_round", "frame", "milli_str", "parse_mass_mg", "sample_latency_s", "smoothed_counts",
]


def _factory(params: Params, *, clock: Clock, world: Any = None) -> ScaleMock:
    baud = params.integer("baud", sp.BAUD)
    if baud != sp.BAUD:
        # The sketch's Serial.begin(57600) is compiled in: a mock that took another rate would hide
        # the mismatch a real scale shows as garbage. Set the client's rate instead.
        raise ValueError(f"{params.source}: baud={baud}: the scale sketch talks at {sp.BAUD} baud only "
                         f"(set the host's baud to {sp.BAUD}; a bench's [scale] baud = {sp.BAUD})")
    cell_name = params.text("load_cell", "load_cell") or "load_cell"
    cell = world.require(cell_name, who="the scale mock") if world is not None else None
    force_n = params.number("force_n")
    if cell is None:
        cell = LoadCell(applied_force_n=force_n or 0.0)
    elif force_n is not None:
        cell.applied_force_n = force_n
    return ScaleMock(
        clock=clock,
        load_cell=cell,
        rate_sps=params.integer("rate", 80),
        boot_s=params.number("boot_s", BOOTLOADER_S),
        baud=baud,
        firmware=params.text("firmware", "tactile") or "tactile",
        timing=params.flag("timing", True),
        seed=params.integer("seed", 0),
        counts_per_g=params.number("counts_per_g", sp.DEFAULT_CAL_FACTOR),
        offset_counts=params.number("offset_counts", 84_000.0),
        noise_counts=params.number("noise_counts"),
        drift_counts=params.number("drift_counts", 1500.0),
        drift_tau_s=params.number("drift_tau_s", 180.0),
        spike_prob=params.number("spike_prob", 0.002),
        boot_junk=params.flag("boot_junk", True),
        stock_settle_s=params.number("stock_settle_s", 2.0),
    )


register_kind("scale", _factory, default_baud=sp.BAUD,
              description="Arduino + HX711 load-cell scale (firmware/arduino_scale, or the stock HX711_ADC example)")
