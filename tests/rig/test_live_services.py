"""Live services and parameters: a call runs in the session's own loop, each refused with a clear
failure when the bench is not in a state to do it; parameters are read-only. Checked with an
independent WebSocket client speaking the Foxglove protocol."""

from __future__ import annotations

import socket
import threading
import time

import pytest

from tactile_rig.cli import main
from tactile_rig.core.errors import RigError
from tactile_rig.rig import live as live_mod
from tactile_rig.rig.bench import connect_bench, load_bench, mock_bench_path
from tactile_rig.rig.bench_record import BenchServices
from tactile_rig.rig.live import LiveServer, ServiceRefused
from tactile_rig.rig.recording import read_recording
from tests._foxglove_client import LiveClient


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_a_call_runs_in_the_loop_that_owns_the_devices() -> None:
    ran_in: list[str] = []

    def tare(args: dict) -> str:
        ran_in.append(threading.current_thread().name)
        return f"tared with {args}"

    def stop(args: dict) -> str:
        raise ServiceRefused("nothing to stop: the jig is Idle", device="jig")

    with LiveServer(port=0) as live:
        live.add_service("tare_scale", tare)
        live.add_service("stop_motion", stop)
        with pytest.raises(ValueError, match="already offered"):
            live.add_service("tare_scale", tare)
        client = LiveClient(live.url).start()
        stop_loop = threading.Event()

        def loop() -> None:  # the session: polls its devices and, between polls, runs queued calls
            while not stop_loop.is_set():
                live.run_pending()
                time.sleep(0.01)

        th = threading.Thread(target=loop, name="session-loop")
        th.start()
        try:
            assert client.call_service("tare_scale", {"why": "test"}) == (True, {"ok": True, "message": "tared with {'why': 'test'}"})
            ok, message = client.call_service("stop_motion")
            assert not ok and message == "ServiceRefused: stop_motion refused: jig: nothing to stop: the jig is Idle"
        finally:
            stop_loop.set()
            th.join()
            client.stop()
    assert ran_in == ["session-loop"]


def test_a_call_the_session_never_takes_fails_after_the_timeout(monkeypatch) -> None:
    monkeypatch.setattr(live_mod, "SERVICE_TIMEOUT_S", 0.3)
    with LiveServer(port=0) as live:
        live.add_service("tare_scale", lambda args: "never")
        client = LiveClient(live.url).start()
        try:
            ok, message = client.call_service("tare_scale")
        finally:
            client.stop()
    assert not ok and "did not take the request within 0.3 s" in message


def test_parameters_describe_the_session_and_cannot_be_set() -> None:
    with LiveServer(port=0) as live:
        live.set_parameters({"bench.name": "mock", "session.duration_s": 2.5})
        client = LiveClient(live.url).start()
        try:
            assert client.get_parameters(["bench.name", "session.duration_s"]) == {"bench.name": "mock",
                                                                                   "session.duration_s": 2.5}
            assert client.set_parameters({"bench.name": "other"}) == {"bench.name": "mock"}
            deadline = time.monotonic() + 5
            while not client.statuses and time.monotonic() < deadline:
                time.sleep(0.01)
        finally:
            client.stop()
    assert "read-only" in client.statuses[0]["message"]


def test_bench_services_refuse_what_the_bench_cannot_do_now() -> None:
    rig = connect_bench(load_bench(mock_bench_path(), env={}))
    try:
        rig.jig.activate(home=True)  # GRBL starts locked (Alarm) until homed
        services = BenchServices(rig)
        with pytest.raises(ServiceRefused, match="no scale readings"):
            services.tare_scale({})
        for k in range(10):
            services.saw_force(0.1 * k, 0.2 + 0.001 * k)
        services.jig_state = "Run"
        with pytest.raises(ServiceRefused, match=r"jig is moving \(Run\)"):
            services.tare_scale({})
        services.jig_state = "Idle"
        services.gripper_moving = True
        with pytest.raises(ServiceRefused, match="gripper is moving"):
            services.tare_scale({})
        services.gripper_moving = False
        services.saw_force(1.0, 0.5)
        with pytest.raises(ServiceRefused, match="load is changing"):
            services.tare_scale({})
        with pytest.raises(ServiceRefused, match="nothing to stop: the jig is Idle"):
            services.stop_motion({})
        x_start = rig.jig.status().wpos[0]
        rig.jig.move_to(-15.0, 0.0, 0.0, feed_mm_per_min=300.0)
        assert services.stop_motion({}).startswith("jig stopped (was Run")
        x_stopped = rig.jig.status().wpos[0]
        assert -15.0 < x_stopped < x_start  # stopped on the way, not at the target
        assert rig.jig.status().state == "Idle"
    finally:
        rig.close()
    assert issubclass(ServiceRefused, RigError)


def test_record_live_offers_tare_and_stop_and_records_their_outcome(tmp_path, capsys) -> None:
    port = _free_port()
    out = tmp_path / "s.mcap"
    client = LiveClient(f"ws://127.0.0.1:{port}")
    rc: list[int] = []
    run = threading.Thread(target=lambda: rc.append(main([
        "record", "--mock", "--duration", "60", "--out", str(out), "--live", "--live-port", str(port),
        "--live-wait", "30", "--json"])))
    run.start()
    client.start()
    try:
        assert client.wait_for("/scale/force", 20, timeout_s=30)
        ok, stop = client.call_service("stop_motion")
        tare = client.call_service("tare_scale")
        params = client.get_parameters(["bench.name", "session.recording"])
    finally:
        run.join(120)
        client.stop()
    assert rc == [0]
    assert not ok and "stop_motion refused: jig: nothing to stop: the jig is" in stop
    assert tare[0] and tare[1]["message"].startswith("scale tared"), tare
    assert params == {"bench.name": "mock", "session.recording": str(out)}
    logs = [m.data for m in read_recording(out).on("/log") if m.data["name"] == "live"]
    assert [d["message"].split(":")[0] for d in logs] == ["stop_motion refused", "tare_scale"]
    assert logs[0]["level"] == 3  # warning
