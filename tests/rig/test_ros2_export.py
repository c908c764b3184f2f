"""``export ros2``: a session as a ROS 2 bag that rosbags reads with the standard types, frame ids,
stamps and SI units; one-line refusals for foreign, damaged and cut-off files and an existing OUT."""

from __future__ import annotations

import json
import math
from pathlib import Path

import cv2
import numpy as np
import pytest
from mcap.writer import Writer as McapWriter

from tactile_rig.cli import main
from tactile_rig.core.clock import VirtualClock
from tactile_rig.core.geometry import Pose
from tactile_rig.rig.recording import Recorder
from tests._typed import bag_connections, bag_messages


def _session(path: Path) -> dict:
    clock = VirtualClock()
    img = (np.arange(24 * 32 * 3) % 253).astype(np.uint8).reshape(24, 32, 3)
    h = np.zeros((24, 32))
    h[5:9, 10:20] = 0.25
    with Recorder(path, clock=clock) as rec:
        for i in range(3):
            clock.advance(0.5)
            rec.write_frame("cam", img, compress="png")
            rec.write_height("cam", h, 0.05, 0.05)
            rec.write_jig_pose(Pose(x_mm=1.0 * i, y_mm=2.0, theta_deg=10.0 * i))
            rec.write_state("gripper", {"opening_m": 0.04 + 0.001 * i, "velocity_mps": 0.0, "current_a": 0.2})
            rec.write_wrench("cam", [0.1, 0.0, -1.0 * i], torque_nmm=[0.0, 0.0, 5.0])
            rec.write_scale(0.5 * i)
            rec.write_markers("cam", [[4.0, 4.0], [10.0, 8.0]], displacements_px=[[1.0, 0.0], [0.0, 1.0]],
                              image_size_px=(32, 24), mm_per_px=0.05)
            rec.write_command("jig", "move_to", x_mm=1.0 * i)
            rec.write_contact_pose("cam/localize", "tactile_map", 0.5, 0.25, 3.0)
            rec.write_perception("cam/fingervision", {"marker_count": 2})
    return {"img": img, "h": h}


def test_a_session_becomes_a_bag_of_standard_types(tmp_path: Path, capsys) -> None:
    made = _session(tmp_path / "s.mcap")
    assert main(["export", "ros2", str(tmp_path / "s.mcap"), str(tmp_path / "bag"), "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    bag = bag_messages(tmp_path / "bag")
    types = {t: ms[0][0] for t, ms in bag.items()}
    assert types == {
        "/cam/image/compressed": "sensor_msgs/msg/CompressedImage", "/cam/height/points": "sensor_msgs/msg/PointCloud2",
        "/cam/wrench": "geometry_msgs/msg/WrenchStamped", "/scale/force": "geometry_msgs/msg/WrenchStamped",
        "/gripper/joint_states": "sensor_msgs/msg/JointState", "/tf": "tf2_msgs/msg/TFMessage",
        "/tf_static": "tf2_msgs/msg/TFMessage", "/jig/pose": "geometry_msgs/msg/PoseStamped",
        "/cam/localize/pose": "geometry_msgs/msg/PoseStamped", "/cam/marker_arrows": "visualization_msgs/msg/MarkerArray",
        "/rosout": "rcl_interfaces/msg/Log"}
    counts = {t: len(ms) for t, ms in bag.items()}
    assert counts == {**{t: 3 for t in types}, "/tf_static": 1}
    assert summary["skipped"] == {"/state/gripper": 3, "/cam/markers": 3, "/command/jig": 3,
                                  "/perception/cam/fingervision": 3}
    # Stamps: header and bag time are the message's log time (session time on a virtual clock).
    for topic, ms in bag.items():
        assert [t for _, _, t in ms] == sorted(t for _, _, t in ms)
    _, img, t_ns = bag["/cam/image/compressed"][1]
    assert t_ns == 1_000_000_000 and (img.header.stamp.sec, img.header.stamp.nanosec) == (1, 0)
    assert img.header.frame_id == "cam" and img.format == "png"
    assert np.array_equal(cv2.imdecode(img.data, cv2.IMREAD_COLOR), made["img"])
    # The tactile point cloud: x, y, z in metres in the sensor frame, the height kept in mm.
    pc = bag["/cam/height/points"][0][1]
    assert pc.header.frame_id == "cam" and pc.width == 24 * 32 and pc.point_step == 16
    assert [(f.name, f.offset, f.datatype) for f in pc.fields] == [("x", 0, 7), ("y", 4, 7), ("z", 8, 7), ("height_mm", 12, 7)]
    pts = np.frombuffer(pc.data.tobytes(), "<f4").reshape(-1, 4)
    r, c = 6, 12
    assert np.allclose(pts[r * 32 + c], [(c - 15.5) * 0.05e-3, (r - 11.5) * 0.05e-3, -0.25e-3, 0.25], rtol=1e-5)
    w = bag["/cam/wrench"][2][1]
    assert w.header.frame_id == "cam" and w.wrench.force.z == -2.0 and math.isclose(w.wrench.torque.z, 5e-3)
    assert bag["/scale/force"][1][1].header.frame_id == "scale" and bag["/scale/force"][1][1].wrench.force.z == 0.5
    js = bag["/gripper/joint_states"][1][1]
    assert list(js.name) == ["gripper"] and js.position.tolist() == [0.041]
    tf = bag["/tf"][2][1].transforms[0]
    assert (tf.header.frame_id, tf.child_frame_id) == ("world", "jig_stage")
    assert math.isclose(tf.transform.translation.x, 2e-3) and math.isclose(tf.transform.rotation.z, math.sin(math.radians(10)))
    static = {(t.header.frame_id, t.child_frame_id) for t in bag["/tf_static"][0][1].transforms}
    assert static == {("jig_stage", "part"), ("world", "cam")}
    assert bag_connections(tmp_path / "bag")["/tf_static"].ext.offered_qos_profiles[0].durability.name == "TRANSIENT_LOCAL"
    pose = bag["/cam/localize/pose"][0][1]
    assert pose.header.frame_id == "tactile_map" and math.isclose(pose.pose.position.x, 0.5e-3)
    arrows = bag["/cam/marker_arrows"][0][1].markers
    assert arrows[0].action == 3 and [m.type for m in arrows[1:]] == [0, 0]  # DELETEALL, then the arrows
    assert math.isclose(arrows[1].scale.x, 10 * 1.0 * 0.05e-3) and arrows[1].header.frame_id == "cam"
    log = bag["/rosout"][0][1]
    assert (log.name, log.msg, log.level) == ("jig", "move_to x_mm=0", 20)


def _one_line(capsys) -> str:
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err, err
    return err


def test_foreign_damaged_and_cut_off_files_are_refused_in_one_line(tmp_path: Path, capsys) -> None:
    foreign = tmp_path / "foreign.mcap"
    with open(foreign, "wb") as f:
        w = McapWriter(f)
        w.start(profile="ros2", library="another-tool")
        sid = w.register_schema(name="x", encoding="jsonschema", data=b"{}")
        cid = w.register_channel(topic="/x", message_encoding="json", schema_id=sid)
        w.add_message(channel_id=cid, log_time=0, publish_time=0, data=b"{}")
        w.finish()
    assert main(["export", "ros2", str(foreign), str(tmp_path / "b1")]) == 2
    assert "not a tactile-rig session recording" in _one_line(capsys) and not (tmp_path / "b1").exists()
    text = tmp_path / "notes.mcap"
    text.write_text("hello")
    assert main(["export", "ros2", str(text), str(tmp_path / "b2")]) == 2
    assert "not an MCAP recording" in _one_line(capsys)
    _session(tmp_path / "s.mcap")
    data = (tmp_path / "s.mcap").read_bytes()
    (tmp_path / "cut.mcap").write_bytes(data[: len(data) * 2 // 3])
    assert main(["export", "ros2", str(tmp_path / "cut.mcap"), str(tmp_path / "b3")]) == 2
    assert "cut off" in _one_line(capsys)
    assert not (tmp_path / "b3").exists() and not list(tmp_path.glob(".b3*"))  # nothing left behind
    assert main(["export", "ros2", str(tmp_path / "missing.mcap"), str(tmp_path / "b4")]) == 2
    _one_line(capsys)


def test_an_existing_out_is_refused_unless_forced_and_a_bag(tmp_path: Path, capsys) -> None:
    _session(tmp_path / "s.mcap")
    out = tmp_path / "bag"
    assert main(["export", "ros2", str(tmp_path / "s.mcap"), str(out)]) == 0
    assert "ros2 bag play" in capsys.readouterr().out
    first = (out / "metadata.yaml").read_text()
    assert main(["export", "ros2", str(tmp_path / "s.mcap"), str(out)]) == 2
    assert "exists; pass --force" in _one_line(capsys)
    assert main(["export", "ros2", str(tmp_path / "s.mcap"), str(out), "--force"]) == 0
    capsys.readouterr()
    assert (out / "metadata.yaml").read_text() == first and len(bag_messages(out)["/cam/image/compressed"]) == 3
    other = tmp_path / "results"
    other.mkdir()
    (other / "keep.txt").write_text("mine")
    assert main(["export", "ros2", str(tmp_path / "s.mcap"), str(other), "--force"]) == 2
    assert "not a ROS 2 bag folder" in _one_line(capsys) and (other / "keep.txt").read_text() == "mine"


@pytest.mark.parametrize("name", ["a.mcap"])
def test_a_malformed_typed_message_fails_the_export_naming_it(tmp_path: Path, capsys, name: str) -> None:
    from tactile_rig.rig.messages import Encoded, foxglove_schema

    p = tmp_path / name
    with Recorder(p, clock=VirtualClock()) as rec:
        rec.publish(Encoded("/cam/height/points", foxglove_schema("PointCloud"), b"\x12\x05ab", 0.0, 0))
    assert main(["export", "ros2", str(p), str(tmp_path / "bag")]) == 2
    assert "/cam/height/points" in _one_line(capsys) and not (tmp_path / "bag").exists()
