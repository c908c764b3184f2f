"""The one mapping from rig data to typed messages, read back by the field's own reader (``mcap`` +
``mcap-protobuf-support``), and its geometry (quaternions, pixels to the sensor frame) as properties."""

from __future__ import annotations

import json
import math
from pathlib import Path

import cv2
import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from tactile_rig.core.clock import VirtualClock
from tactile_rig.core.geometry import Pose
from tactile_rig.rig.messages import Encoded, Tee, TopicWriter
from tactile_rig.rig.messages.heights import height_point_cloud, height_stride
from tactile_rig.rig.messages.markers import _quaternion_from_x
from tactile_rig.rig.recording import Recorder
from tests._typed import full_names, typed_messages


def _rotate(q, v):
    """Rotate ``v`` by the unit quaternion ``q`` (x, y, z, w), independently of the package."""
    x, y, z, w = q
    u = np.array([x, y, z])
    v = np.asarray(v, float)
    return 2 * np.dot(u, v) * u + (w * w - np.dot(u, u)) * v + 2 * w * np.cross(u, v)


def _session(path: Path) -> dict:
    clock = VirtualClock()
    img = (np.arange(24 * 32 * 3) % 251).astype(np.uint8).reshape(24, 32, 3)
    with Recorder(path, clock=clock) as rec:
        clock.advance(0.25)
        rec.write_frame("cam", img, compress="png")
        rec.write_frame("cam", img[:, :, 0])
        rec.write_markers("cam", [[4.0, 5.0], [20.0, 10.0], [30.0, 20.0]], displacements_px=[[1.0, 0.0], [0.0, -2.0],
                          [0.0, 0.0]], valid=[True, True, False], image_size_px=(32, 24), mm_per_px=0.05,
                          force_n=[0.0, 0.1, -0.4])
        h = np.zeros((24, 32))
        h[10:14, 12:20] = 0.3
        rec.write_height("cam", h, 0.05, 0.04)
        rec.write_jig_pose(Pose(x_mm=2.0, y_mm=-1.0, theta_deg=30.0))
        rec.write_state("gripper", {"opening_m": 0.042, "velocity_mps": -0.01, "current_a": 0.3, "moving": True})
        rec.write_command("jig", "move_to", x_mm=2.0)
        rec.write_contact_pose("cam/localize", "tactile_map", 1.5, -0.5, 12.0)
        rec.write_scale(1.25, grams=127.5)
        rec.write_wrench("cam", [0.0, 0.1, -0.4], torque_nmm=[0.0, 0.0, 2.0])
    return {"img": img, "h": h}


def test_every_kind_decodes_as_foxgloves_type_with_the_field_reader(tmp_path: Path) -> None:
    path = tmp_path / "s.mcap"
    made = _session(path)
    msgs = typed_messages(path)
    assert full_names(msgs) == {
        "/cam/image/compressed": "foxglove.CompressedImage", "/cam/image": "foxglove.RawImage",
        "/cam/markers": "foxglove.ImageAnnotations", "/cam/marker_arrows": "foxglove.SceneUpdate",
        "/cam/height/points": "foxglove.PointCloud", "/tf": "foxglove.FrameTransforms",
        "/gripper/joint_states": "foxglove.JointStates", "/log": "foxglove.Log",
        "/cam/localize/pose": "foxglove.PoseInFrame"}
    png = msgs["/cam/image/compressed"][0][1]
    assert png.format == "png" and png.frame_id == "cam" and png.timestamp.nanos == 250_000_000
    assert np.array_equal(cv2.imdecode(np.frombuffer(png.data, np.uint8), cv2.IMREAD_COLOR), made["img"])
    raw = msgs["/cam/image"][0][1]
    assert (raw.encoding, raw.width, raw.height, raw.step) == ("mono8", 32, 24, 32) and raw.data == made["img"][:, :, 0].tobytes()
    # JSON topics carry their JSON schema (units in the field names and descriptions).
    schema, scale, _ = msgs["/scale/force"][0]
    assert schema == "tactile_rig.ScaleReading" and scale == {"force_n": 1.25, "grams": 127.5, "t_s": 0.25}
    wrench = msgs["/cam/wrench"][0][1]
    assert wrench["frame_id"] == "cam" and wrench["torque_nmm"] == {"x": 0.0, "y": 0.0, "z": 2.0}


def test_markers_over_the_image_and_as_arrows_in_the_sensor_frame(tmp_path: Path) -> None:
    path = tmp_path / "s.mcap"
    _session(path)
    msgs = typed_messages(path)
    ann = msgs["/cam/markers"][0][1]
    good, lost, lines = ann.points
    assert [(p.x, p.y) for p in good.points] == [(4.0, 5.0), (20.0, 10.0)] and [(p.x, p.y) for p in lost.points] == [(30.0, 20.0)]
    # Each tracked marker's displacement drawn from where it rests, 10 times longer.
    seg = [(p.x, p.y) for p in lines.points]
    assert seg == [(3.0, 5.0), (13.0, 5.0), (20.0, 12.0), (20.0, -8.0)]
    assert [t.text for t in ann.texts] == ["0", "1", "2"]
    stamp = msgs["/cam/image/compressed"][0][1].timestamp
    assert (ann.timestamp.seconds, ann.timestamp.nanos) == (stamp.seconds, stamp.nanos)  # the Image panel pairs them
    ents = {e.id: e for e in msgs["/cam/marker_arrows"][0][1].entities}
    arrows = ents["cam/markers"].arrows
    assert ents["cam/markers"].frame_id == "cam" and len(arrows) == 2  # the lost marker has none
    # Marker 1 rests at (20, 12) px: about the image centre (15.5, 11.5) at 0.05 mm/px; moved 2 px up.
    a = arrows[1]
    assert math.isclose(a.pose.position.x, 4.5 * 0.05) and math.isclose(a.pose.position.y, 0.5 * 0.05)
    q = (a.pose.orientation.x, a.pose.orientation.y, a.pose.orientation.z, a.pose.orientation.w)
    assert np.allclose(_rotate(q, [1, 0, 0]), [0, -1, 0], atol=1e-9)
    assert math.isclose(a.shaft_length + a.head_length, 10 * 2 * 0.05)
    force = ents["cam/force"].arrows[0]
    fq = (force.pose.orientation.x, force.pose.orientation.y, force.pose.orientation.z, force.pose.orientation.w)
    f = np.array([0.0, 0.1, -0.4])
    assert np.allclose(_rotate(fq, [1, 0, 0]), f / np.linalg.norm(f), atol=1e-9)
    assert math.isclose(force.shaft_length + force.head_length, 5.0 * np.linalg.norm(f))


def test_height_map_as_a_point_cloud_and_the_frame_tree(tmp_path: Path) -> None:
    path = tmp_path / "s.mcap"
    made = _session(path)
    msgs = typed_messages(path)
    pc = msgs["/cam/height/points"][0][1]
    assert pc.frame_id == "cam" and pc.point_stride == 16 and [f.name for f in pc.fields] == ["x", "y", "z", "height_mm"]
    pts = np.frombuffer(pc.data, "<f4").reshape(-1, 4)
    assert len(pts) == 24 * 32
    r, c = 11, 13
    x, y, z, h = pts[r * 32 + c]
    assert math.isclose(x, (c - 15.5) * 0.05, rel_tol=1e-6) and math.isclose(y, (r - 11.5) * 0.04, rel_tol=1e-6)
    assert math.isclose(h, made["h"][r, c], rel_tol=1e-6) and z == -h  # pressed in towards the camera
    tfs = {(t.parent_frame_id, t.child_frame_id): t for t in msgs["/tf"][0][1].transforms}
    assert set(tfs) == {("world", "jig_stage"), ("jig_stage", "part"), ("world", "cam")}
    st_ = tfs[("world", "jig_stage")]
    assert (st_.translation.x, st_.translation.y) == (2.0, -1.0)
    q = (st_.rotation.x, st_.rotation.y, st_.rotation.z, st_.rotation.w)
    assert np.allclose(_rotate(q, [1, 0, 0]), [math.cos(math.radians(30)), math.sin(math.radians(30)), 0])
    cam = tfs[("world", "cam")].rotation  # looks down at the stage: its optical z is the world's -z
    assert np.allclose(_rotate((cam.x, cam.y, cam.z, cam.w), [0, 0, 1]), [0, 0, -1])
    joint = msgs["/gripper/joint_states"][0][1].joints[0]
    assert (joint.name, joint.position, joint.velocity, joint.effort) == ("gripper", 0.042, -0.01, 0.3)
    log = msgs["/log"][0][1]
    assert (log.name, log.message, log.level) == ("jig", "move_to x_mm=2", 2)
    pose = msgs["/cam/localize/pose"][0][1]
    assert pose.frame_id == "tactile_map" and (pose.pose.position.x, pose.pose.position.y) == (1.5, -0.5)


class _Collect(TopicWriter):
    def __init__(self, epoch_ns: int) -> None:
        self.clock = VirtualClock()
        self.epoch_ns = epoch_ns
        self.got: list[Encoded] = []

    def publish(self, msg: Encoded) -> None:
        self.got.append(msg)

    def log_time_ns(self, t_s: float) -> int:
        return self.epoch_ns + int(round(t_s * 1e9))


def test_a_tee_encodes_once_and_hands_the_same_bytes_to_every_sink() -> None:
    a, b = _Collect(0), _Collect(10**18)
    tee = Tee(a, None, b)
    tee.write_frame("cam", np.zeros((4, 6, 3), np.uint8), t_s=1.0, compress="jpeg")
    tee.write_markers("cam", [[1.0, 1.0]], t_s=1.0)
    tee.write_scale(2.0, t_s=1.0)
    assert [m.topic for m in a.got] == ["/cam/image/compressed", "/cam/markers", "/scale/force"]
    assert a.got == b.got and all(m.log_time_ns == 1_000_000_000 for m in b.got)  # the first sink's times


def test_write_refuses_a_protobuf_schema_for_a_json_body(tmp_path: Path) -> None:
    import pytest

    with Recorder(tmp_path / "s.mcap", clock=VirtualClock()) as rec, \
            pytest.raises(ValueError, match="protobuf type; use its write_"):
        rec.write("/x", {"a": 1}, schema="foxglove.CompressedImage")


@settings(max_examples=200, deadline=None)
@given(hnp.arrays(np.float64, 3, elements=st.floats(-1e6, 1e6, allow_nan=False)).filter(
    lambda v: np.linalg.norm(v) > 1e-6))
def test_arrow_orientation_turns_x_onto_any_direction(v: np.ndarray) -> None:
    q = _quaternion_from_x(v)
    assert math.isclose(sum(c * c for c in q), 1.0, rel_tol=1e-9)
    assert np.allclose(_rotate(q, [1.0, 0.0, 0.0]), v / np.linalg.norm(v), atol=1e-7)


@settings(max_examples=60, deadline=None)
@given(hnp.arrays(np.float64, st.tuples(st.integers(1, 60), st.integers(1, 60)),
                  elements=st.floats(-5, 5) | st.sampled_from([math.nan, math.inf, -math.inf])),
       st.integers(1, 4000))
def test_point_clouds_keep_the_finite_pixels_within_the_budget(h: np.ndarray, max_points: int) -> None:
    import foxglove.messages  # noqa: F401

    from tests._foxglove_client import protobuf_class

    schema, data = height_point_cloud("cam", h, 0.1, 0.1, 0, max_points=max_points)
    msg = protobuf_class(schema.name, schema.data).FromString(data)
    pts = np.frombuffer(msg.data, "<f4").reshape(-1, 4)
    assert len(pts) <= max_points
    assert np.isfinite(pts).all()
    step = height_stride(h.shape, max_points)
    assert step == 1 or math.ceil(h.shape[0] / (step - 1)) * math.ceil(h.shape[1] / (step - 1)) > max_points
    sub = h[::step, ::step]
    assert len(pts) == int(np.isfinite(sub.astype(np.float32)).sum())


def test_json_schemas_name_their_units() -> None:
    from tactile_rig.rig.messages.schemas import SCHEMAS

    scale = json.loads(json.dumps(SCHEMAS["tactile_rig.ScaleReading"]))
    assert "(N)" in scale["properties"]["force_n"]["description"]
    assert set(SCHEMAS["tactile_rig.Wrench"]["properties"]) == {"t_s", "frame_id", "force_n", "torque_nmm"}


def test_the_layout_file_is_the_layout_the_package_makes(tmp_path: Path) -> None:
    from tactile_rig.cli import main
    from tactile_rig.rig.messages.layout import session_layout

    repo = Path(__file__).resolve().parents[2] / "docs" / "foxglove" / "tactile-rig-layout.json"
    assert repo.read_text() == session_layout()  # regenerate: tactile-rig export layout docs/foxglove/tactile-rig-layout.json
    assert main(["export", "layout", str(tmp_path / "l.json"), "--camera", "cam_a"]) == 0
    text = (tmp_path / "l.json").read_text()
    doc = json.loads(text)
    panels = []

    def walk(node):
        if isinstance(node, dict):
            if node.get("type") == "panel":
                panels.append(node["panelType"])
            for v in node.values():
                walk(v)
        elif isinstance(node, list):
            for v in node:
                walk(v)

    walk(doc)
    assert {"Image", "ThreeDee", "Plot", "Log", "StateTransitions", "ServiceCall", "Parameters"} <= set(panels), panels
    assert '"/cam_a/image/compressed"' in text and '"/cam_a/markers"' in text and '"/cam_a/height/points"' in text
