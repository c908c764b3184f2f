"""Property tests of the GRBL mock's parser and byte handling: any text, any split, no crash, no hang."""

from __future__ import annotations

import math
import re

import numpy as np
from hypothesis import given, settings, strategies as st

from tactile_rig.devices import grbl as gp
from tactile_rig.mocks.grbl import gcode
from tactile_rig.testing.strategies_grbl import gcode_lines, splits
from tests._grbl import Host

REPLY = re.compile(r"^(ok|error:\d+|ALARM:\d+|<[^>]*>|\[[^\]]*\]|\$N?\d+=.*|Grbl 1\.1h \['\$' for help\]|>.*:(ok|error:\d+))$")


def _clean(line: str) -> str:
    """protocol.c's filter, written out plainly: drop spaces and comments, upper-case."""
    out, paren = [], False
    for ch in line:
        if paren:
            paren = ch != ")"
        elif ch == "(":
            paren = True
        elif ch == ";":
            break
        elif ch > " " and ch != "/":
            out.append(ch.upper())
    return "".join(out)


@given(gcode_lines())
def test_any_line_parses_to_a_block_or_a_known_error(line: str) -> None:
    """gcode.c gc_execute_line either returns a status code from GRBL's table or a finite block."""
    state = gcode.ParserState.fresh(3, np.zeros(3), np.zeros(3))
    got = gcode.parse_block(_clean(line), state, [np.zeros(3)] * 8)
    if isinstance(got, int):
        assert got in gp.ERRORS
    else:
        assert got.target is None or np.all(np.isfinite(got.target))
        assert math.isfinite(got.feed_rate) and math.isfinite(got.dwell_s)


@given(st.text(alphabet=st.characters(min_codepoint=32, max_codepoint=126), max_size=60))
def test_arbitrary_text_never_breaks_the_parser(text: str) -> None:
    """gcode.c gc_execute_line on any printable text: a status code (nuts_bolts.c read_float refuses
    what is not a number) or a block, never an exception."""
    state = gcode.ParserState.fresh(3, np.zeros(3), np.zeros(3))
    got = gcode.parse_block(_clean(text), state, [np.zeros(3)] * 8)
    assert isinstance(got, int) and got in gp.ERRORS or isinstance(got, gcode.Block)


@settings(max_examples=25)
@given(st.lists(gcode_lines(max_words=4), min_size=1, max_size=6), st.data())
def test_a_program_gets_the_same_replies_however_the_bytes_are_split(lines: list[str], data: st.DataObject) -> None:
    """serial.c serial_read + protocol.c protocol_main_loop: bytes are read one at a time, so how they
    arrive never changes a reply."""
    program = ("$C\n" + "".join(line + "\n" for line in lines)).encode()  # check mode: replies only
    whole = Host(homing=False)
    expect = whole.send(program, 0.5)
    parts = Host(homing=False)
    got: list[str] = []
    for chunk in data.draw(splits(program)):
        got += parts.send(chunk, 0.001)
    got += parts.read(0.5)
    assert got == expect
    assert all(REPLY.match(r) for r in got), got
    assert got.count("ok") + sum(r.startswith("error:") for r in got) == len(lines) + 1


@settings(max_examples=30)
@given(st.binary(max_size=300))
def test_garbage_bytes_get_grbls_own_replies_only(junk: bytes) -> None:
    """report.c: whatever arrives, the firmware answers in its own line forms (report_status_message,
    report_feedback_message...) and a reset (mc_reset) brings back status reports."""
    h = Host(homing=False)
    out = h.send(junk + b"\n", 0.3)
    assert all(REPLY.match(r) for r in out), out
    h.send(b"\x18", 0.1)
    assert h.status(0.1) is not None


def test_a_full_receive_buffer_drops_what_does_not_fit_and_drains_at_once_when_free() -> None:
    """serial.c SERIAL_RX ISR: a byte is stored only if the 128-byte ring has room; protocol.c reads
    nothing during a feed hold (protocol_exec_rt_suspend), so a burst then loses all but 128 bytes."""
    h = Host(homing=False, settings={10: 3})
    h.send("!", 0.01)  # feed hold while idle: Hold:0, the main loop is suspended
    assert h.line("G4 P0") == []
    burst = b"(junk junk junk junk junk junk junk)" * 100  # 3700 bytes, no line end
    h.send(burst, 0.5)  # 0.32 s on the wire at 115200 baud
    assert h.mock.rx_overflow_bytes == len(burst) + len(b"G4 P0\n") - 128
    assert "|Bf:15,0|" in h.status()
    out = h.send("~\n", 0.05)  # resume: the ring is read: "G4 P0", then the 122 kept comment bytes
    assert out == ["ok", "ok"]
    assert "|Bf:15,128|" in h.status()
