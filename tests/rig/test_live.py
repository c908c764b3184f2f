"""The live view without a bench: the server's channels and schemas, a WebSocket client on loopback
that subscribes and checks what arrives, and ``--live`` on ``scene run`` and ``run jig-accuracy``."""

from __future__ import annotations

import json
import socket
import threading

import foxglove  # noqa: F401  (the live extra: a broken install fails here)
import numpy as np
import pytest
import websockets  # noqa: F401  (the test client)

from tactile_rig.cli import main
from tactile_rig.core.clock import VirtualClock
from tactile_rig.rig.live import LiveServer, Tee
from tactile_rig.rig.recording import Recorder, read_recording
from tests._foxglove_client import LiveClient


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_the_live_view_sends_what_the_recording_stores(tmp_path) -> None:
    clock = VirtualClock()
    with LiveServer(port=0, clock=clock) as live:
        client = LiveClient(live.url).start()
        live.advertise("/scale/force", "tactile_rig.ScaleReading")
        live.advertise("/left/image/compressed", "foxglove.CompressedImage")
        assert live.wait_for_subscriber(10.0, {"/scale/force", "/left/image/compressed"})
        rec = Recorder(tmp_path / "s.mcap", clock=clock)
        sink = Tee(rec, live)
        img = np.zeros((24, 32, 3), np.uint8)
        for i in range(50):
            sink.write_scale(0.1 * i, seq=i)
            if i % 5 == 0:
                img[:, i % 32] = 255
                sink.write_frame("left", img, compress="jpeg")
            clock.sleep(0.0125)
        assert client.wait_for("/scale/force", 50) and client.wait_for("/left/image/compressed", 10)
        sink.close()
        client.stop()
    recorded = read_recording(tmp_path / "s.mcap")
    got = client.on("/scale/force")
    assert [m.data["seq"] for m in got] == list(range(50))  # subscribed first: every message, in order
    assert [m.data for m in got] == [m.data for m in recorded.on("/scale/force")]
    assert len(client.on("/left/image/compressed")) == 10
    assert client.advertised == {"/scale/force": "tactile_rig.ScaleReading",
                                 "/left/image/compressed": "foxglove.CompressedImage"}
    # The same bytes: the client decodes them with protobuf from the advertised schema.
    frames = client.on("/left/image/compressed")
    assert [m.raw for m in frames] == [m.raw for m in recorded.on("/left/image/compressed")]
    assert frames[0].encoding == "protobuf" and frames[0].message.format == "jpeg"
    assert frames[0].message.frame_id == "left" and frames[0].message.data[:2] == b"\xff\xd8"  # a JPEG


def test_the_live_view_refuses_other_hosts_than_loopback() -> None:
    with pytest.raises(ValueError, match="loopback"):
        LiveServer(host="0.0.0.0", port=0)


def _run_with_client(argv: list[str], port: int) -> tuple[list[int], LiveClient]:
    client = LiveClient(f"ws://127.0.0.1:{port}")
    rc: list[int] = []
    th = threading.Thread(target=lambda: rc.append(main(argv)))
    th.start()
    client.start()
    th.join(120)
    client.stop()
    return rc, client


def test_scene_run_live_serves_each_episode_trace_in_order(capsys) -> None:
    port = _free_port()
    rc, client = _run_with_client(["scene", "run", "handover_dynamixel", "--episodes", "2", "--json", "--live",
                                   "--live-port", str(port), "--live-wait", "20"], port)
    assert rc == [0]
    episodes = client.on("/perception/handover_dynamixel/episode")
    assert [m.data["episode"] for m in episodes] == [0, 1]
    trace = client.on("/perception/handover_dynamixel/trace")
    t = [m.data["t_s"] for m in trace]
    assert len(trace) > 10 and t == sorted(t)
    # The second episode's samples follow the first's: its trace starts after episode 0's end.
    assert max(t) > episodes[0].data["sim_s"]


def test_run_jig_accuracy_live_on_the_mocks(tmp_path, capsys) -> None:
    port = _free_port()
    rc, client = _run_with_client(["run", "jig-accuracy", "--mock", "--sweep", "rotation", "--rotations", "-10",
                                   "10", "10", "--out", str(tmp_path / "r"), "--no-report", "--json", "--live",
                                   "--live-port", str(port), "--live-wait", "20"], port)
    assert rc == [0]
    summary = json.loads(capsys.readouterr().out.splitlines()[-1])
    # The run's topics are advertised before it starts and it waits for the viewer: every message.
    points = client.on("/perception/jig_accuracy_point")
    assert [m.data["index"] for m in points] == [0, 1, 2] and summary["n_points"] == 3
    assert len(client.on("/perception/tactile_map_touch")) == 3
    poses = client.on("/jig/pose")
    assert len(poses) == len(client.on("/command/jig")) == 6  # 3 map touches + 3 points
    assert [round(m.data["theta_deg"]) for m in poses[3:]] == [-10, 0, 10]
