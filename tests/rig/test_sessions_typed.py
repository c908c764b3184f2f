"""The sessions end to end: ``record``, a calibration session (``--live`` too), a jig accuracy run and
``fingervision track --bench --live --record`` write (and serve) Foxglove's types, which the field's
reader (``mcap`` + ``mcap-protobuf-support``) decodes, and ``export ros2`` turns each into a bag that
rosbags reads with the standard types."""

from __future__ import annotations

import json
import socket
import threading
from pathlib import Path

import pytest
from mcap.reader import make_reader

from tactile_rig.cli import main
from tactile_rig.cli.calibrate_sessions import session_topics
from tactile_rig.rig.rehearsal import RehearsalBench, RehearsalOptions
from tests._foxglove_client import LiveClient
from tests._typed import bag_messages, full_names, typed_messages


def _export(session: Path, out: Path, capsys) -> dict[str, str]:
    assert main(["export", "ros2", str(session), str(out), "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    bag = bag_messages(out)
    assert {t: len(ms) for t, ms in bag.items()} == {t: v["count"] for t, v in summary["topics"].items()}
    return {t: ms[0][0] for t, ms in bag.items()}


def test_record_on_the_mock_bench(tmp_path: Path, capsys) -> None:
    out = tmp_path / "s.mcap"
    assert main(["record", "--mock", "--duration", "2", "--out", str(out), "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    msgs = typed_messages(out)
    assert {t: len(ms) for t, ms in msgs.items()} == summary["topics"]
    assert full_names(msgs) == {"/camera/image/compressed": "foxglove.CompressedImage",
                                "/tf": "foxglove.FrameTransforms", "/gripper/joint_states": "foxglove.JointStates"}
    frames = {(t.parent_frame_id, t.child_frame_id) for t in msgs["/tf"][0][1].transforms}
    assert frames == {("world", "jig_stage"), ("jig_stage", "part"), ("world", "camera")}
    assert summary["dropped"] == {} or set(summary["dropped"]) <= {"camera"}
    types = _export(out, tmp_path / "bag", capsys)
    assert types == {"/camera/image/compressed": "sensor_msgs/msg/CompressedImage", "/tf": "tf2_msgs/msg/TFMessage",
                     "/tf_static": "tf2_msgs/msg/TFMessage", "/gripper/joint_states": "sensor_msgs/msg/JointState",
                     "/jig/pose": "geometry_msgs/msg/PoseStamped", "/scale/force": "geometry_msgs/msg/WrenchStamped"}


def test_a_gelsight_calibration_session_records_and_serves_the_same_messages(tmp_path: Path, capsys) -> None:
    port = _free_port()
    client = LiveClient(f"ws://127.0.0.1:{port}")
    rc: list[int] = []
    run = threading.Thread(target=lambda: rc.append(main([
        "calibrate", "gelsight", "--mock", "--out", str(tmp_path / "gel"), "--json",
        "--live", "--live-port", str(port), "--live-wait", "30"])))
    run.start()
    client.start()
    run.join(120)
    client.stop()
    assert rc == [0]
    capsys.readouterr()
    rec = tmp_path / "gel-v1.mcap"
    msgs = typed_messages(rec)
    assert full_names(msgs) == {"/camera/image/compressed": "foxglove.CompressedImage",
                                "/tf": "foxglove.FrameTransforms", "/log": "foxglove.Log"}
    assert all(m.format == "png" for _, m, _ in msgs["/camera/image/compressed"])
    # Live: the same topics in the same types, and the very bytes recorded (subscribed before the start).
    for topic in ("/camera/image/compressed", "/tf"):
        assert client.advertised[topic] == full_names(msgs)[topic]
        got = client.on(topic)
        assert got and [m.raw for m in got] == [m[1].SerializeToString() for m in msgs[topic]][: len(got)]
    types = _export(rec, tmp_path / "bag", capsys)
    assert types["/camera/image/compressed"] == "sensor_msgs/msg/CompressedImage"
    assert types["/rosout"] == "rcl_interfaces/msg/Log" and types["/tf"] == "tf2_msgs/msg/TFMessage"


def test_a_jig_accuracy_run(tmp_path: Path, capsys) -> None:
    out = tmp_path / "r"
    assert main(["run", "jig-accuracy", "--mock", "--sweep", "rotation", "--rotations", "-10", "10", "10",
                 "--out", str(out), "--no-report", "--json"]) == 0
    capsys.readouterr()
    msgs = typed_messages(out / "run.mcap")
    names = full_names(msgs)
    assert names == {"/camera/image/compressed": "foxglove.CompressedImage", "/camera/height/points": "foxglove.PointCloud",
                     "/tf": "foxglove.FrameTransforms", "/jig_accuracy/estimate/pose": "foxglove.PoseInFrame",
                     "/log": "foxglove.Log"}
    # One point cloud per frame (the run localizes every frame it takes), at the frame's time.
    assert [t for _, _, t in msgs["/camera/height/points"]] == [t for _, _, t in msgs["/camera/image/compressed"]]
    est = [m.pose for _, m, _ in msgs["/jig_accuracy/estimate/pose"]]
    points = [m["estimate"] for _, m, _ in msgs["/perception/jig_accuracy_point"]]
    assert len(est) == len(points) == 3
    for pose, point in zip(est, points):
        assert abs(pose.position.x - point["x_mm"]) < 1e-9 and abs(pose.position.y - point["y_mm"]) < 1e-9
    types = _export(out / "run.mcap", tmp_path / "bag", capsys)
    assert types["/camera/height/points"] == "sensor_msgs/msg/PointCloud2"
    assert types["/jig_accuracy/estimate/pose"] == "geometry_msgs/msg/PoseStamped"
    assert types["/tf_static"] == "tf2_msgs/msg/TFMessage"


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.mark.pty
def test_fingervision_track_live_serves_and_records_the_marker_field(tmp_path: Path, capsys) -> None:
    with RehearsalBench(tmp_path / "bench", RehearsalOptions(cameras={"fingervision": "rendered"})) as rb:
        port = _free_port()
        out = tmp_path / "fv.mcap"
        client = LiveClient(f"ws://127.0.0.1:{port}")
        rc: list[int] = []
        run = threading.Thread(target=lambda: rc.append(main([
            "fingervision", "track", "--bench", str(rb.bench_path), "--camera", "camera_fingervision",
            "--frames-max", "40", "--json", "--live", "--live-port", str(port), "--live-wait", "30",
            "--record", str(out)])))
        run.start()
        client.start()
        run.join(90)
        client.stop()
        assert rb.problems() == []
    assert rc == [0]
    rows = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    assert rows[-1]["recording"] == str(out)
    msgs = typed_messages(out)
    assert full_names(msgs) == {"/camera_fingervision/image/compressed": "foxglove.CompressedImage",
                                "/camera_fingervision/markers": "foxglove.ImageAnnotations",
                                "/camera_fingervision/marker_arrows": "foxglove.SceneUpdate"}
    assert len(msgs["/camera_fingervision/markers"]) == 40
    tracked = [r for r in rows[:-1] if not r["calibrating"]]
    ann = msgs["/camera_fingervision/markers"][-1][1]
    assert sum(len(p.points) for p in ann.points if p.type == 1) == len(tracked[-1]["markers_px"])  # POINTS
    # Live, the same topics in the same types, the same bytes as recorded (subscribed before the start).
    assert client.advertised["/camera_fingervision/markers"] == "foxglove.ImageAnnotations"
    assert client.advertised["/camera_fingervision/marker_arrows"] == "foxglove.SceneUpdate"
    got = client.on("/camera_fingervision/marker_arrows")
    assert [m.raw for m in got] == [m[1].SerializeToString() for m in msgs["/camera_fingervision/marker_arrows"]][: len(got)]
    assert len(got) >= 35 and got[-1].message.entities[0].frame_id == "camera_fingervision"
    types = _export(out, tmp_path / "bag", capsys)
    assert types["/camera_fingervision/marker_arrows"] == "visualization_msgs/msg/MarkerArray"


@pytest.mark.parametrize("kind,args,camera", [
    ("gelsight", [], "camera"), ("scale", ["--known-mass-g", "500"], None), ("gripper", [], None),
    ("fingervision", ["--frames", "3"], "camera")])
def test_a_calibration_session_advertises_what_it_records(tmp_path: Path, capsys, kind: str, args: list[str],
                                                          camera: str | None) -> None:
    """What ``--live`` advertises before a session starts is exactly what the session records."""
    assert main(["calibrate", kind, "--mock", "--out", str(tmp_path / "c"), "--json", *args]) == 0
    recording = Path(json.loads(capsys.readouterr().out)["files"]["recording"])
    with open(recording, "rb") as fh:
        recorded = {ch.topic: schema.name for schema, ch, _ in make_reader(fh).iter_messages()}
    assert recorded == session_topics(kind, camera)
