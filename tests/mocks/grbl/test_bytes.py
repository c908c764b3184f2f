"""The GRBL mock at the byte level: receive buffer, realtime bytes, reports, and a byte-exact driver call."""

from __future__ import annotations

import re

import pytest

from tactile_rig.core.clock import VirtualClock
from tactile_rig.drivers.grbl import Jig, parse_status
from tactile_rig.drivers.transport import SerialTransport
from tactile_rig.mocks.grbl import GrblMock
from tactile_rig.testing import expected_protocol, serve_in_process


def _lines(tr: SerialTransport, wait_s: float = 0.05) -> list[str]:
    out = []
    while True:
        data = tr.read_some(4096, wait_s)
        if not data:
            return [l for l in b"".join(out).decode().split("\r\n") if l]
        out.append(data)


@pytest.fixture
def wire():
    clock = VirtualClock()
    mock = GrblMock(clock=clock, homing=False)
    with serve_in_process(mock, clock) as url:
        tr = SerialTransport(url, device="jig")
        assert _lines(tr) == ["Grbl 1.1h ['$' for help]"]
        yield tr, mock, clock


def test_realtime_bytes_are_taken_out_of_a_line_and_answered_at_once(wire) -> None:
    tr, mock, clock = wire
    tr.write(b"G0 X?1\n")  # '?' mid-line is a status request; the line still reads G0X1
    lines = _lines(tr)
    assert lines[0].startswith("<Idle|") and lines[1] == "ok"
    clock.advance(2.0)
    tr.write(b"?")
    assert parse_status(_lines(tr)[0]).mpos == (1.0, 0.0, 0.0)


def test_a_full_receive_buffer_drops_what_the_host_sends_past_128_bytes(wire) -> None:
    tr, mock, clock = wire
    tr.write(b"G1 F60\n" + b"".join(b"G1 X%d.000 Y0.000\n" % ((i + 1) % 2 * 10) for i in range(20)))
    lines = _lines(tr, 0.1)  # the planner fills (15 blocks) and the rest waits in the buffer
    assert lines.count("ok") == 16
    tr.write(b"G1 X5.000 Y5.000 Z5.000 (this line cannot fit any more)\n" * 2)
    assert mock.rx_overflow_bytes > 0 and len(mock.rx) == 128


def test_system_commands_print_grbls_shapes(wire) -> None:
    tr, mock, clock = wire
    tr.write(b"$I\n$#\n$G\n$N\n$\n$$\n")
    text = "\n".join(_lines(tr))
    # GRBL 1.1h: grbl/grbl.h GRBL_VERSION "1.1h", GRBL_VERSION_BUILD "20190830"; report.c prints [VER:...]
    assert "[VER:1.1h.20190830:]" in text and "[OPT:V,15,128]" in text
    assert re.search(r"\[G54:0\.000,0\.000,0\.000\]", text) and "[PRB:0.000,0.000,0.000:0]" in text
    assert "[GC:G0 G54 G17 G21 G90 G94 M5 M9 T0 F0 S0]" in text
    assert "$N0=" in text and text.startswith("[VER")
    assert "$10=1" in text and "$110=1200.000" in text and "$132=360.000" in text
    assert text.count("ok") == 6


def test_status_fields_follow_the_report_mask_and_refresh_counters(wire) -> None:
    tr, mock, clock = wire
    tr.write(b"G92 X-2\n$10=3\n")
    assert _lines(tr) == ["ok", "ok"]
    reports = []
    for _ in range(12):
        tr.write(b"?")
        reports.append(_lines(tr)[0])
    parsed = [parse_status(r) for r in reports]
    assert all(p.mpos == (0.0, 0.0, 0.0) and p.planner_free == 15 and p.rx_free == 128 for p in parsed)
    with_wco = [p for p in parsed if p.wco is not None]
    assert 1 <= len(with_wco) <= 2 and with_wco[0].wco == (2.0, 0.0, 0.0)  # WCO every 10th idle report
    assert any(p.overrides == (100, 100, 100) for p in parsed)
    tr.write(b"$10=0\n")
    _lines(tr)
    tr.write(b"?")
    st = parse_status(_lines(tr)[0], wco=(2.0, 0.0, 0.0))
    assert st.raw.startswith("<Idle|WPos:-2.000,") and "Bf:" not in st.raw and st.mpos == (0.0, 0.0, 0.0)


def test_feed_override_slows_a_feed_move(wire) -> None:
    tr, mock, clock = wire
    tr.write(b"G1 X10 F600\n")
    _lines(tr, 0.01)
    clock.advance(0.5)
    tr.write(b"?")
    assert parse_status(_lines(tr)[0]).feed_mm_per_min == 600
    tr.write(bytes([0x92] * 5))  # -10 % five times: 50 %
    clock.advance(0.5)
    tr.write(b"?")
    st = parse_status(_lines(tr)[0])
    assert st.feed_mm_per_min == 300


def test_move_to_sends_exactly_one_gcode_line() -> None:
    banner = b"\r\nGrbl 1.1h ['$' for help]\r\n"
    with expected_protocol([(None, banner), (b"G90G0X1.000Y-2.000Z45.000\n", b"ok\r\n"),
                            (b"G90G1X3.000F600.0\n", b"ok\r\n"), (b"$J=G91Y0.500F300.0\n", b"ok\r\n")]) as url:
        jig = Jig(url)
        jig.move_to(1.0, -2.0, 45.0)
        jig.move_to(3.0, feed_mm_per_min=600.0)
        jig.jog(dy_mm=0.5, feed_mm_per_min=300.0)
