"""An independent client, grbl-streamer, streams a G-code file to ``tactile-rig mock serve jig`` on a pty."""

from __future__ import annotations

import threading
import time

import pytest

import grbl_streamer  # noqa: E402  (the independent real client is a test dependency: never skip it)

from tactile_rig.core.clock import RealClock
from tactile_rig.mocks.grbl import GrblMock
from tactile_rig.mocks.pty_server import PtyServer
from tactile_rig.testing.serve import serve_in_subprocess
from tests._slow_client import GRBL_BANNER, read_banner

GCODE = """(a zig-zag with theta on Z; more than 128 bytes, so character counting matters)
G21 G90
G1 F1200
G1 X0.5 Y0.25
G1 X1.0 Y0.0 Z5
G1 X1.5 Y0.25
G1 X2.0 Y0.0 Z10 ; quarter turn of the jog wheel
G1 X2.5 Y0.25

G1 X3.0 Y0.0 Z5
G1 X3.5 Y0.25
G1 X4.0 Y0.0 Z0
G1 X3.5 Y-0.25
G1 X3.0 Y0.0 Z-5
G1 X2.5 Y-0.25
G0 X2.0 Y-0.5 Z-10
"""
N_COMMANDS = 15  # non-empty commands once grbl-streamer has split "G21 G90" in two
FINAL = (2.0, -0.5, -10.0)


@pytest.mark.pty
def test_grbl_streamer_streams_a_file_and_sees_every_ok_and_the_final_position(tmp_path) -> None:
    path = tmp_path / "zigzag.nc"
    path.write_text(GCODE)
    events: list[tuple[str, tuple]] = []
    lock = threading.Lock()

    def callback(event: str, *data: object) -> None:
        with lock:
            events.append((event, data))

    def seen(name: str, since: int = 0) -> list[tuple]:
        with lock:
            return [d for e, d in events[since:] if e == name]

    def wait_for(pred, timeout_s: float) -> bool:
        end = time.monotonic() + timeout_s
        while time.monotonic() < end:
            if pred():
                return True
            time.sleep(0.02)
        return False

    with serve_in_subprocess("jig", "--param", "homing=0") as info:
        assert info["device"] == "jig" and info["port"].startswith("/dev/")
        grbl = grbl_streamer.GrblStreamer(callback, name="pty-jig")
        grbl.cnect(info["port"], 115200)
        try:
            assert wait_for(lambda: seen("on_boot"), 3.0), "no boot banner"
            grbl.poll_interval = 0.05
            grbl.poll_start()
            # grbl-streamer asks for $$, $# and $G after booting, outside its character count; their
            # oks must be in before the job, or it would credit them to job lines (its own race).
            assert wait_for(lambda: any(d and d[0] == "Idle" for d in seen("on_stateupdate")), 3.0)
            assert wait_for(lambda: seen("on_hash_stateupdate"), 3.0), "no answer to $#"
            assert wait_for(lambda: any(d and str(d[0]).startswith("[GC:") for d in seen("on_read")), 3.0)

            def settled() -> bool:  # no query pending and nothing read for 0.3 s
                before = len(seen("on_read"))
                time.sleep(0.3)
                return (not grbl.hash_state_requested and not grbl.gcode_parser_state_requested
                        and len(seen("on_read")) == before)

            assert wait_for(settled, 5.0)
            start = len(events)
            grbl.load_file(str(path))
            grbl.job_run()
            assert wait_for(lambda: seen("on_job_completed", start), 15.0), "job did not complete"
            assert wait_for(lambda: any(d[0] == "Idle" and tuple(d[1]) == pytest.approx(FINAL, abs=0.03)
                                        for d in seen("on_stateupdate", start)), 10.0), \
                f"final state: {seen('on_stateupdate', start)[-1:]}"
            # grbl-streamer splits "G21 G90" and sends blank lines for comments: every line it sent
            # was answered by exactly one ok. (Which text it files each ok under can be off by one
            # under load: its job_run and reader threads share the backlog without a lock.)
            sent = [d[1] for d in seen("on_line_sent", start)]
            processed = [d[1] for d in seen("on_processed_command", start)]
            assert len(processed) == len(sent) and len([p for p in sent if p]) == N_COMMANDS
            assert not seen("on_error", start) and not seen("on_alarm", start)
        finally:
            grbl.disconnect()


@pytest.mark.pty
def test_every_connect_over_a_pty_gets_a_clean_banner() -> None:
    """report.c report_init_message after every reset; the server holds the output until the client has
    set its line rate (a real Uno's bootloader covers that), so no connect sees a garbled banner, even
    from a client that sets its rate up to 30 ms after opening."""
    mock = GrblMock(clock=RealClock(), homing=False)
    with PtyServer(mock) as server:
        banners = [read_banner(server.port, lag_s=0.03 * (i % 3) / 2) for i in range(12)]
    assert server.error is None and server.opens == 12
    assert banners == [GRBL_BANNER] * 12
