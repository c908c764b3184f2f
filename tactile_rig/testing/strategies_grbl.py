"""Hypothesis strategies for GRBL 1.1 status reports: any field order and presence."""

from __future__ import annotations

from tactile_rig.testing._hypothesis import st

from tactile_rig.devices import grbl as gp


def _coords(n: int) -> st.SearchStrategy[tuple[float, ...]]:
    return st.tuples(*[st.integers(-999_999, 999_999).map(lambda v: v / 1000.0) for _ in range(n)])


@st.composite
def status_reports(draw: st.DrawFn, axes: int | None = None) -> tuple[str, dict]:
    """(report text, the fields it carries) with a random state, field subset and field order."""
    n = axes or draw(st.sampled_from([3, 4]))
    state = draw(st.sampled_from(gp.STATES))
    sub = None
    if state == "Hold":
        sub = draw(st.sampled_from([0, 1]))
    elif state == "Door":
        sub = draw(st.integers(0, 3))
    expect: dict = {"state": state, "substate": sub}
    fields: list[str] = []
    pos_name = draw(st.sampled_from(["MPos", "WPos"]))
    pos = draw(_coords(n))
    fields.append(f"{pos_name}:{','.join(f'{v:.3f}' for v in pos)}")
    expect[pos_name.lower()] = pos
    if draw(st.booleans()):
        bf = (draw(st.integers(0, gp.PLANNER_BLOCKS - 1)), draw(st.integers(0, gp.RX_BUFFER_SIZE)))
        fields.append(f"Bf:{bf[0]},{bf[1]}")
        expect["planner_free"], expect["rx_free"] = bf
    if draw(st.booleans()):
        ln = draw(st.integers(0, 9_999_999))
        fields.append(f"Ln:{ln}")
        expect["line_number"] = ln
    feed = draw(st.integers(0, 60000))
    if draw(st.booleans()):
        rpm = draw(st.integers(0, 30000))
        fields.append(f"FS:{feed},{rpm}")
        expect["spindle_rpm"] = float(rpm)
    else:
        fields.append(f"F:{feed}")
    expect["feed_mm_per_min"] = float(feed)
    if draw(st.booleans()):
        wco = draw(_coords(n))
        fields.append(f"WCO:{','.join(f'{v:.3f}' for v in wco)}")
        expect["wco"] = wco
    if draw(st.booleans()):
        pins = "".join(draw(st.sets(st.sampled_from(gp.PIN_LETTERS), min_size=1)))
        fields.append(f"Pn:{pins}")
        expect["pins"] = pins
    if draw(st.booleans()):
        ov = (draw(st.integers(10, 200)), draw(st.sampled_from([25, 50, 100])), draw(st.integers(10, 200)))
        fields.append(f"Ov:{ov[0]},{ov[1]},{ov[2]}")
        expect["overrides"] = ov
    if draw(st.booleans()):
        acc = "".join(draw(st.sets(st.sampled_from("SCFM"), min_size=1)))
        fields.append(f"A:{acc}")
        expect["accessories"] = acc
    order = draw(st.permutations(fields))
    head = state if sub is None else f"{state}:{sub}"
    return "<" + "|".join([head, *order]) + ">", expect


# -- G-code and byte streams ------------------------------------------------------------------------------
_LETTERS = "GMXYZIJKFNPRSTLABCDEHOQUVW"


@st.composite
def gcode_numbers(draw: st.DrawFn) -> str:
    """Number text as senders write it, and as they should not: signs, dots, many digits, nothing."""
    return draw(st.one_of(
        st.integers(-10**9, 10**9).map(str),
        st.decimals(-100000, 100000, places=4, allow_nan=False, allow_infinity=False).map(str),
        st.sampled_from(["", ".", "-", "+.5", "-.", "1.2.3", "00000000001", "123456789012", "38.2", "59.1"])))


@st.composite
def gcode_lines(draw: st.DrawFn, max_words: int = 6) -> str:
    """A line of G-code words with spaces, comments and mixed case (valid or not)."""
    words = [draw(st.sampled_from(_LETTERS)) + draw(gcode_numbers()) for _ in range(draw(st.integers(0, max_words)))]
    parts = []
    for w in words:
        parts.append(w.lower() if draw(st.booleans()) else w)
        parts.append(draw(st.sampled_from(["", " ", "  ", "\t", "(note)"])))
    if draw(st.booleans()):
        parts.append(draw(st.sampled_from([";", "; end", "(", "(open"])))
    return "".join(parts)


@st.composite
def splits(draw: st.DrawFn, data: bytes) -> list[bytes]:
    """``data`` cut into consecutive chunks at arbitrary points (what a USB adapter may deliver)."""
    cuts = sorted(set(draw(st.lists(st.integers(0, len(data)), max_size=8))))
    bounds = [0, *cuts, len(data)]
    return [data[a:b] for a, b in zip(bounds, bounds[1:]) if b > a]
