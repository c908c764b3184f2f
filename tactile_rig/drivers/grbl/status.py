"""GRBL 1.1 status reports (``<Idle|MPos:...|FS:...>``) parsed strictly into :class:`GrblStatus`.

GRBL's lines carry no checksum, so the parser accepts only what GRBL prints: the states and
substates it knows, its field names (and grblHAL's, kept as text), each field at most once, and
every number in GRBL's fixed format (see :func:`parse_status`). A report that fails is
:class:`~tactile_rig.core.errors.LinkCorrupt`, never a value. Pure: no I/O.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field

from tactile_rig.core.errors import LinkCorrupt
from tactile_rig.devices import grbl as gp

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


def reported_position(st: GrblStatus) -> tuple[float, ...] | None:
    """The position field a report printed (MPos or WPos), for comparing reports."""
    return st.mpos if "MPos:" in st.raw else st.wpos
