"""What the scale's sketch computes, and how long it takes: the facts the scale mock is built from.

The sketch's integer arithmetic (milligrams and milli-counts per gram, rounded half away from zero),
its smoothing window, its framing (``body*CC\\r\\n`` with a bitwise CRC-8), the ``c,<g>`` grammar, the
Arduino core's buffer sizes and UART rate, and the time from each event to the first byte of the
answer, measured on the compiled sketch running on the simulated board (cycle-exact at 16 MHz).
:class:`~tactile_rig.mocks.scale.ScaleMock` runs the sketch's event loop on them.
"""

from __future__ import annotations

from tactile_rig.devices import scale as sp

__all__ = [
    "BOOTLOADER_S", "CAL_MILLI_MAX", "CAL_MILLI_MIN", "DEFAULT_CAL_MILLI", "HX711_TIMEOUT_S", "LINE_MAX",
    "MASS_G_MAX", "MIN_CAL_COUNTS", "RX_RING_BYTES", "SETTLE_CONVERSIONS", "TX_IN_FLIGHT_BYTES", "UART_BAUD_ACTUAL",
    "WINDOW", "div_round", "frame", "milli_str", "parse_mass_mg", "sample_latency_s", "smoothed_counts",
]

BOOTLOADER_S = 1.529  # the Uno's optiboot after an external reset (see firmware/sim/scale_board.c)
WINDOW = sp.SMOOTHING_SAMPLES + 2  # the sketch's smoothing window: 16 averaged + highest + lowest
SETTLE_CONVERSIONS = 2  # discarded after the sketch resets the HX711
RX_RING_BYTES = 63  # HardwareSerial's 64-byte receive ring holds 63
TX_IN_FLIGHT_BYTES = 65  # 63 in the transmit ring + UDR + the shift register; more and write() blocks
LINE_MAX = 32  # longest command line the sketch accepts
HX711_TIMEOUT_S = 1.0  # no conversion for this long: E,4
UART_BAUD_ACTUAL = 16_000_000 / (16 * (16 + 1))  # 58824: the core's UBRR0 = 16 without U2X for 57600 (+2.1 %)
DEFAULT_CAL_MILLI = round(sp.DEFAULT_CAL_FACTOR * 1000)
CAL_MILLI_MIN = 100  # 0.1 counts per gram
CAL_MILLI_MAX = 100_000_000  # 100000 counts per gram
MIN_CAL_COUNTS = 100  # a calibration mass must move the reading at least this much
MASS_G_MAX = 1_000_000

# From an event to the first byte of the sketch's answer starting on the wire, measured on the
# compiled sketch on the simulated board (cycle-exact at 16 MHz).
T_HX_RESET_S = 366e-6  # sketch start -> the HX711 leaves reset (C runtime, Serial.begin, EEPROM, pins)
T_BANNER_S = 913e-6  # last start-up conversion -> B line
T_TARE_S = 574e-6  # conversion ready -> T,ok
T_CAL_S = 989e-6  # conversion ready -> K
T_CAL_ERROR_S = 899e-6  # conversion ready -> E,3 / E,5
T_ID_S = 407e-6  # newline received -> I line
T_ERROR_S = 133e-6  # newline received -> E,1
T_MASS_ERROR_S = 294e-6  # newline received -> E,2
T_E4_S = 0.0  # HX711 time-out -> E,4 (millis() granularity: +-1 ms on the board)
T_RESET_HX_AGAIN_S = 240e-6  # E,4 at start-up -> the next HX711 reset
# Conversion ready -> S line: shifting 25 bits, smoothing and 64-bit maths take 0.5 ms, each printed
# digit some 30-50 us more (least squares over 718 lines, residual under 35 us).
_T_SAMPLE_FIT_S = (497.7e-6, 30.2e-6, 50.2e-6, 27.1e-6, -42.5e-6, -37.1e-6)


def sample_latency_s(seq: str, grams: str, raw: str) -> float:
    """Conversion ready -> the S line's first byte on the wire, for the fields it prints."""
    c = _T_SAMPLE_FIT_S
    return (c[0] + c[1] * len(seq) + c[2] * len(grams) + c[3] * len(raw)
            + c[4] * grams.startswith("-") + c[5] * raw.startswith("-"))


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


def div_round(n: int, d: int) -> int:
    """``n / d`` rounded half away from zero, the sketch's integer rounding (``d != 0``)."""
    if d < 0:
        n, d = -n, -d
    return (n + d // 2) // d if n >= 0 else -((-n + d // 2) // d)


def milli_str(v: int) -> str:
    """A value in thousandths with 3 decimals, as the sketch's ``putMilli`` prints it."""
    sign = "-" if v < 0 else ""
    a = abs(v)
    return f"{sign}{a // 1000}.{a % 1000:03d}"


def parse_mass_mg(text: str) -> int | None:
    """The sketch's ``c,<g>`` grammar: ``<1-7 digits>[.<1-3 digits>]``, 0 < g <= 1e6; milligrams or None."""
    whole, dot, frac = text.partition(".")
    if not (1 <= len(whole) <= 7 and whole.isascii() and whole.isdigit()):
        return None
    if dot and not (1 <= len(frac) <= 3 and frac.isascii() and frac.isdigit()):
        return None
    if int(whole) > MASS_G_MAX:
        return None
    mg = int(whole) * 1000 + (int(frac.ljust(3, "0")) if dot else 0)
    return mg if 0 < mg <= MASS_G_MAX * 1000 else None


def smoothed_counts(window: list[int]) -> int:
    """Mean of the window without its highest and lowest value, rounded like the sketch."""
    return div_round(sum(window) - min(window) - max(window), len(window) - 2)
