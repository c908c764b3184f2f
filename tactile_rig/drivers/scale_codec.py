"""The scale's wire codec on the host side: lines of the sketch (or the stock example) into values, pure.

:class:`ScaleLineParser` takes bytes in any split and returns each line decoded as a
:class:`ParsedLine` (its :class:`LineKind`, and a :class:`ScaleReading` or :class:`ScaleInfo` where
the line carries one). Framed lines are checked before they become values: CRC-8, field count,
number formats, ranges; a framed line that fails is ``CORRUPT``, never a reading. :func:`mg_from_raw`
is the sketch's integer arithmetic from raw counts to milligrams, so the driver can compute grams
with its own zero. The line format is a device fact (:mod:`tactile_rig.devices.scale`); this codec
and the mock's printer are written separately so that one bug cannot hide on both sides.
"""

from __future__ import annotations

import enum
import math
import re
from dataclasses import dataclass

from tactile_rig.core.deprecation import deprecated_alias, deprecated_function
from tactile_rig.devices import scale as sp
from tactile_rig.drivers.lines import LineSplitter


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
    """What the banner (or ``?``) says: firmware, version, samples per second, and the calibration
    factor in raw counts per gram (the sketch prints it with 3 decimals; None from the stock sketch)."""

    firmware: str
    version: str
    rate_sps: int | None
    cal_factor_counts_per_g: float | None

    cal_factor = deprecated_alias("cal_factor_counts_per_g")


class LineKind(str, enum.Enum):
    """What a line of the scale is. Members equal (and hash as) their value strings."""

    SAMPLE = "sample"  #: S, our sketch's sample
    BANNER = "banner"  #: B, the boot banner
    ID = "id"  #: I, the answer to ``?``
    TARE = "tare"  #: T, tare done
    CAL = "cal"  #: K, calibration done
    ERROR = "error"  #: E, a command failed
    STOCK_SAMPLE = "stock_sample"  #: the stock example's ``Load_cell output val:``
    STOCK_START = "stock_start"  #: ``Starting...``
    STOCK_READY = "stock_ready"  #: ``Startup is complete``
    STOCK_TARE = "stock_tare"  #: ``Tare complete``
    CORRUPT = "corrupt"  #: framed, but the checksum or a field is wrong
    INVALID = "invalid"  #: the stock example printed nan / inf / ovf
    OTHER = "other"  #: anything else

    def __str__(self) -> str:
        return str.__str__(self)

    def __format__(self, spec: str) -> str:
        return str.__format__(self, spec)

    def __hash__(self) -> int:
        return str.__hash__(self)


@dataclass(frozen=True)
class ParsedLine:
    """One decoded line: its :class:`LineKind`, the text, when it arrived, and what it carries
    (``reading`` for samples, ``info`` for banner/id, ``value`` for cal, ``code`` for error)."""

    kind: LineKind
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
#: a first line that is one of these may be the tail of a line sent before the port was opened
_UNSYNCED = (LineKind.OTHER, LineKind.CORRUPT, LineKind.INVALID)


class ScaleLineParser:
    """Bytes in (any split), decoded lines out. ``sync=True`` drops everything up to the first
    newline (a half line from before the host opened the port)."""

    def __init__(self, *, sync: bool = True, max_line: int = 256) -> None:
        self._lines = LineSplitter(max_line=max_line)
        self._synced = not sync

    @property
    def max_line(self) -> int:
        return self._lines.max_line or 0

    @property
    def overlong(self) -> int:
        """Runs of bytes with no newline cut to ``max_line``."""
        return self._lines.overlong

    def resync(self) -> None:
        self._lines.clear()
        self._synced = False

    def feed(self, data: bytes, t_s: float) -> list[ParsedLine]:
        out: list[ParsedLine] = []
        for line in self._lines.feed(data):
            parsed = parse_line(line, t_s)
            if not self._synced:
                # The first line may be the tail of one sent before we opened: keep it only if whole.
                self._synced = True
                if parsed is None or parsed.kind in _UNSYNCED:
                    continue
            if parsed is not None:
                out.append(parsed)
        return out


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
        return ParsedLine(LineKind.CORRUPT, text, t_s)
    m = _STOCK_RE.search(line)
    if m is not None:
        value = m.group(1).decode("ascii", "replace")
        if not _NUM_RE.match(value):
            return ParsedLine(LineKind.INVALID, text, t_s)  # nan, inf, ovf from Serial.print(float)
        reading = ScaleReading(float(value), None, None, t_s, source="stock")
        return ParsedLine(LineKind.STOCK_SAMPLE, text, t_s, reading=reading)
    stripped = text.strip()
    if stripped.endswith(sp.STOCK_STARTING):
        return ParsedLine(LineKind.STOCK_START, stripped, t_s)
    if stripped.endswith(sp.STOCK_STARTUP_DONE):
        return ParsedLine(LineKind.STOCK_READY, stripped, t_s)
    if stripped.endswith(sp.STOCK_TARE_DONE):
        return ParsedLine(LineKind.STOCK_TARE, stripped, t_s)
    return ParsedLine(LineKind.OTHER, stripped, t_s)


def _decode_frame(tag: str, body: str, text: str, t_s: float) -> ParsedLine | None:
    f = body.split(",")
    try:
        if tag == sp.TAG_SAMPLE and len(f) == 3:
            seq, grams, raw = int(f[0]), float(f[1]), int(f[2])
            if not (0 <= seq < sp.SEQ_MODULO and sp.RAW_MIN <= raw <= sp.RAW_MAX and math.isfinite(grams)):
                return None
            sat = raw in (sp.RAW_MIN, sp.RAW_MAX)
            return ParsedLine(LineKind.SAMPLE, text, t_s, reading=ScaleReading(grams, raw, seq, t_s, sat))
        if tag in (sp.TAG_BANNER, sp.TAG_ID) and len(f) == 4:
            info = ScaleInfo(f[0], f[1], int(f[2]), float(f[3]))
            return ParsedLine(LineKind.BANNER if tag == sp.TAG_BANNER else LineKind.ID, text, t_s, info=info)
        if tag == sp.TAG_TARE and f == ["ok"]:
            return ParsedLine(LineKind.TARE, text, t_s)
        if tag == sp.TAG_CAL and len(f) == 1:
            return ParsedLine(LineKind.CAL, text, t_s, value=float(f[0]))
        if tag == sp.TAG_ERROR and len(f) >= 2:
            return ParsedLine(LineKind.ERROR, text, t_s, code=int(f[0]), info=None, value=None)
    except ValueError:
        return None
    return None


# -- milligrams from raw counts ------------------------------------------------------------------

def _div_round(n: int, d: int) -> int:
    """``n / d`` rounded half away from zero (the sketch's integer rounding; ``d != 0``)."""
    if d < 0:
        n, d = -n, -d
    return (n + d // 2) // d if n >= 0 else -((-n + d // 2) // d)


def mg_from_raw(raw: int, zero_raw: int, cal_milli: int) -> int:
    """Milligrams for ``raw`` counts above ``zero_raw`` at ``cal_milli`` thousandths of a count per
    gram, computed as the sketch computes it (so the host's grams equal the sketch's for one zero)."""
    return _div_round((raw - zero_raw) * 1_000_000, cal_milli)


grams_mg = deprecated_function(mg_from_raw, "grams_mg")


def infer_zero_raw(raw: int, mg: int, cal_milli: int) -> int | None:
    """The sketch's zero (raw counts) that turns ``raw`` into ``mg`` milligrams; None if none does."""
    guess = round(mg * cal_milli / 1_000_000)
    for d in sorted(range(guess - 3, guess + 4), key=lambda v: abs(v - mg * cal_milli / 1_000_000)):
        if mg_from_raw(raw, raw - d, cal_milli) == mg:
            return raw - d
    return None
