"""A session recording as a ROS 2 bag (rosbag2, MCAP storage, CDR) in the standard message types.

:func:`export_ros2` reads a tactile-rig recording (CRCs checked; protobuf or JSON channels) and writes
what ROS 2 has a standard type for, with each header's stamp and frame id and the message's log time
as its bag time, so ``ros2 bag play OUT`` feeds a ROS 2 system:

===================================  ===================================  ===============================
recording (type)                     bag topic                            ROS 2 type
===================================  ===================================  ===============================
``/<cam>/image/compressed``          same                                 ``sensor_msgs/msg/CompressedImage``
``/<cam>/image`` (RawImage)          same                                 ``sensor_msgs/msg/Image``
``/<cam>/height/points`` (PointCloud) same                                ``sensor_msgs/msg/PointCloud2``
``/<cam>/wrench`` (tactile_rig.Wrench) same                               ``geometry_msgs/msg/WrenchStamped``
``/scale/force`` (ScaleReading)      same (frame ``scale``, force on z)    ``geometry_msgs/msg/WrenchStamped``
``/gripper/joint_states``            same                                 ``sensor_msgs/msg/JointState``
``/tf`` (FrameTransforms)            ``/tf`` and ``/tf_static``           ``tf2_msgs/msg/TFMessage``
``/jig/pose`` (JigPose)              same (frame ``world``)               ``geometry_msgs/msg/PoseStamped``
``/.../pose`` (PoseInFrame)          same                                 ``geometry_msgs/msg/PoseStamped``
``/<cam>/marker_arrows`` (SceneUpdate) same                               ``visualization_msgs/msg/MarkerArray``
``/log`` (Log)                       ``/rosout``                          ``rcl_interfaces/msg/Log``
===================================  ===================================  ===============================

Lengths become metres and torques N·m (REP 103); the recording's 3-D scene is in mm. The frames that
never move (``jig_stage -> part``, ``world -> <camera>``) go once to ``/tf_static`` (transient local,
as ``robot_state_publisher`` offers them). Topics without a standard type (perception results,
commands, device states, image annotations) are left out and counted in the outcome.

``rosbags`` is the optional extra ``ros2``; it is imported when an export starts.
"""

from __future__ import annotations

import base64
import math
import os
import shutil
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Literal

import numpy as np

from tactile_rig.core.errors import BadFile
from tactile_rig.rig.files import check_file
from tactile_rig.rig.messages.frames import WORLD, moves
from tactile_rig.rig.recording import LIBRARY, MAX_RECORDING_BYTES, Message, Recording, iter_messages

__all__ = ["export_ros2", "Ros2Export", "require_rosbags", "BAG_VERSION"]

BAG_VERSION: Literal[8, 9] = 8  # rosbag2 metadata version (rosbags writes 8 or 9)
MM = 1e-3  # m per mm
_LOG_LEVELS = {1: 10, 2: 20, 3: 30, 4: 40, 5: 50}  # foxglove.LogLevel -> rcl_interfaces/msg/Log


@dataclass
class Ros2Export:
    """What an export wrote: messages per bag topic (with its type), and what it left out."""

    path: Path
    topics: dict[str, dict[str, Any]] = field(default_factory=dict)  # topic -> {"type", "count"}
    skipped: dict[str, int] = field(default_factory=dict)  # recording topic -> messages left out


def require_rosbags() -> Any:
    """The ``rosbags`` package, or ModuleNotFoundError naming the extra."""
    try:
        import rosbags.rosbag2
        import rosbags.typesys
    except ModuleNotFoundError as exc:
        raise ModuleNotFoundError("export ros2 needs the 'rosbags' package: pip install 'tactile-rig[ros2]'",
                                  name=exc.name) from exc
    return rosbags


class _Bag:
    """The open bag: connections per topic, the typestore's classes, counts."""

    def __init__(self, writer: Any, typestore: Any, outcome: Ros2Export) -> None:
        self.w = writer
        self.ts = typestore
        self.t = typestore.types
        self.outcome = outcome
        self.conns: dict[str, Any] = {}
        self.static_seen: set[tuple[str, str]] = set()

    def write(self, topic: str, msgtype: str, msg: Any, t_ns: int, *, latched: bool = False) -> None:
        conn = self.conns.get(topic)
        if conn is None:
            qos = (_transient_local(),) if latched else ()
            conn = self.w.add_connection(topic, msgtype, typestore=self.ts, offered_qos_profiles=qos)
            self.conns[topic] = conn
        self.w.write(conn, max(0, int(t_ns)), self.ts.serialize_cdr(msg, msgtype))
        row = self.outcome.topics.setdefault(topic, {"type": msgtype, "count": 0})
        row["count"] += 1

    def stamp(self, ns: int) -> Any:
        ns = max(0, int(ns))
        return self.t["builtin_interfaces/msg/Time"](sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)

    def header(self, ns: int, frame_id: str) -> Any:
        return self.t["std_msgs/msg/Header"](stamp=self.stamp(ns), frame_id=str(frame_id))

    def vec3(self, x: float, y: float, z: float) -> Any:
        return self.t["geometry_msgs/msg/Vector3"](x=float(x), y=float(y), z=float(z))

    def quat(self, q: dict[str, Any] | None) -> Any:
        q = q or {}
        return self.t["geometry_msgs/msg/Quaternion"](x=float(q.get("x", 0.0)), y=float(q.get("y", 0.0)),
                                                     z=float(q.get("z", 0.0)), w=float(q.get("w", 1.0)))

    def pose(self, p: dict[str, Any] | None) -> Any:
        p = p or {}
        pos = p.get("position") or {}
        point = self.t["geometry_msgs/msg/Point"](x=float(pos.get("x", 0.0)) * MM, y=float(pos.get("y", 0.0)) * MM,
                                                 z=float(pos.get("z", 0.0)) * MM)
        return self.t["geometry_msgs/msg/Pose"](position=point, orientation=self.quat(p.get("orientation")))


def _transient_local() -> Any:
    from rosbags.interfaces import Qos, QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime

    zero = QosTime(0, 0)
    return Qos(QosHistory.KEEP_LAST, 1, QosReliability.RELIABLE, QosDurability.TRANSIENT_LOCAL, zero, zero,
               QosLiveliness.AUTOMATIC, zero, False)


def _ns(m: Message) -> int:
    """A message's header time: its own timestamp when it has one, else its log time."""
    ts = m.data.get("timestamp")
    if isinstance(ts, dict) and "sec" in ts:
        return int(ts["sec"]) * 1_000_000_000 + int(ts.get("nsec", 0))
    return m.log_time_ns


def _u8(data: Any) -> np.ndarray:
    if isinstance(data, str):  # a JSON recording's image: base64
        return np.frombuffer(base64.b64decode(data, validate=True), np.uint8)
    return np.frombuffer(bytes(data), np.uint8)


def _compressed(b: _Bag, m: Message) -> None:
    msg = b.t["sensor_msgs/msg/CompressedImage"](header=b.header(_ns(m), m.data["frame_id"]),
                                                 format=str(m.data["format"]), data=_u8(m.data["data"]))
    b.write(m.topic, "sensor_msgs/msg/CompressedImage", msg, m.log_time_ns)


def _raw(b: _Bag, m: Message) -> None:
    d = m.data
    msg = b.t["sensor_msgs/msg/Image"](header=b.header(_ns(m), d["frame_id"]), height=int(d["height"]),
                                       width=int(d["width"]), encoding=str(d["encoding"]), is_bigendian=0,
                                       step=int(d["step"]), data=_u8(d["data"]))
    b.write(m.topic, "sensor_msgs/msg/Image", msg, m.log_time_ns)


_PB_TYPES = {1: ("u1", 2), 2: ("i1", 1), 3: ("<u2", 4), 4: ("<i2", 3), 5: ("<u4", 6), 6: ("<i4", 5),
             7: ("<f4", 7), 8: ("<f8", 8)}  # foxglove numeric type -> (numpy, sensor_msgs/PointField datatype)


def _points(b: _Bag, m: Message) -> None:
    d = m.data
    stride = int(d["point_stride"])
    raw = bytes(d["data"])
    if stride <= 0 or len(raw) % stride:
        raise BadFile(m.topic, f"a PointCloud declares point_stride {stride} for {len(raw)} bytes",
                      "whole points of point_stride bytes")
    fields = []
    for f in d["fields"]:
        kind = _PB_TYPES.get(int(f["type"]))
        if kind is None or int(f["offset"]) + np.dtype(kind[0]).itemsize > stride:
            raise BadFile(m.topic, f"PointCloud field {f['name']!r} has type {f['type']} at offset {f['offset']}",
                          f"a numeric field inside the {stride}-byte point")
        fields.append((str(f["name"]), int(f["offset"]), kind))
    n = len(raw) // stride
    rows = np.frombuffer(raw, np.uint8).reshape(n, stride)
    cols = {name: rows[:, off: off + np.dtype(k[0]).itemsize].copy().view(k[0]).reshape(n).astype(np.float64)
            for name, off, k in fields}
    if all(c in cols for c in "xyz"):
        xyz = np.stack([cols["x"], cols["y"], cols["z"]], axis=1)
        p = d.get("pose") or {}
        rot = _rotation(p.get("orientation"))
        pos = p.get("position") or {}
        xyz = (xyz @ rot.T + [float(pos.get(a, 0.0)) for a in "xyz"]) * MM
        cols.update(x=xyz[:, 0], y=xyz[:, 1], z=xyz[:, 2])
    names = [name for name, _, _ in fields]
    out = np.empty(n, dtype=[(name, "<f4") for name in names])
    for name in names:
        out[name] = cols[name]
    pf = b.t["sensor_msgs/msg/PointField"]
    msg = b.t["sensor_msgs/msg/PointCloud2"](
        header=b.header(_ns(m), d["frame_id"]), height=1, width=n,
        fields=[pf(name=name, offset=4 * i, datatype=7, count=1) for i, name in enumerate(names)],
        is_bigendian=False, point_step=4 * len(names), row_step=4 * len(names) * n,
        data=np.frombuffer(out.tobytes(), np.uint8), is_dense=True)
    b.write(m.topic, "sensor_msgs/msg/PointCloud2", msg, m.log_time_ns)


def _rotation(q: dict[str, Any] | None) -> np.ndarray:
    q = q or {}
    x, y, z, w = (float(q.get(k, 0.0 if k != "w" else 1.0)) for k in "xyzw")
    n = math.sqrt(x * x + y * y + z * z + w * w) or 1.0
    x, y, z, w = x / n, y / n, z / n, w / n
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def _tf(b: _Bag, m: Message) -> None:
    moving, fixed = [], []
    for tf in m.data.get("transforms", []):
        ts = tf.get("timestamp") or {}
        ns = int(ts.get("sec", 0)) * 1_000_000_000 + int(ts.get("nsec", 0)) if ts else m.log_time_ns
        tr = tf.get("translation") or {}
        msg = b.t["geometry_msgs/msg/TransformStamped"](
            header=b.header(ns, tf["parent_frame_id"]), child_frame_id=str(tf["child_frame_id"]),
            transform=b.t["geometry_msgs/msg/Transform"](
                translation=b.vec3(*(float(tr.get(a, 0.0)) * MM for a in "xyz")), rotation=b.quat(tf.get("rotation"))))
        key = (str(tf["parent_frame_id"]), str(tf["child_frame_id"]))
        if moves(*key):
            moving.append(msg)
        elif key not in b.static_seen:
            b.static_seen.add(key)
            fixed.append(msg)
    tfm = b.t["tf2_msgs/msg/TFMessage"]
    if fixed:
        b.write("/tf_static", "tf2_msgs/msg/TFMessage", tfm(transforms=fixed), m.log_time_ns, latched=True)
    if moving:
        b.write("/tf", "tf2_msgs/msg/TFMessage", tfm(transforms=moving), m.log_time_ns)


def _joints(b: _Bag, m: Message) -> None:
    joints = m.data.get("joints", [])
    msg = b.t["sensor_msgs/msg/JointState"](
        header=b.header(_ns(m), ""), name=[str(j["name"]) for j in joints],
        position=np.array([float(j.get("position") or 0.0) for j in joints]),
        velocity=np.array([float(j.get("velocity") or 0.0) for j in joints]),
        effort=np.array([float(j.get("effort") or 0.0) for j in joints]))
    b.write(m.topic, "sensor_msgs/msg/JointState", msg, m.log_time_ns)


def _pose_in_frame(b: _Bag, m: Message) -> None:
    msg = b.t["geometry_msgs/msg/PoseStamped"](header=b.header(_ns(m), m.data["frame_id"]), pose=b.pose(m.data["pose"]))
    b.write(m.topic, "geometry_msgs/msg/PoseStamped", msg, m.log_time_ns)


def _jig_pose(b: _Bag, m: Message) -> None:
    d = m.data
    th = math.radians(float(d.get("theta_deg") or 0.0))
    pose = {"position": {a: float(d.get(f"{a}_mm") or 0.0) for a in "xyz"},
            "orientation": {"x": 0.0, "y": 0.0, "z": math.sin(th / 2), "w": math.cos(th / 2)}}
    msg = b.t["geometry_msgs/msg/PoseStamped"](header=b.header(m.log_time_ns, WORLD), pose=b.pose(pose))
    b.write(m.topic, "geometry_msgs/msg/PoseStamped", msg, m.log_time_ns)


def _wrench(b: _Bag, m: Message) -> None:
    d = m.data
    f = d.get("force_n") or {}
    tq = d.get("torque_nmm") or {}
    msg = b.t["geometry_msgs/msg/WrenchStamped"](
        header=b.header(m.log_time_ns, d.get("frame_id", "")),
        wrench=b.t["geometry_msgs/msg/Wrench"](force=b.vec3(*(float(f.get(a) or 0.0) for a in "xyz")),
                                               torque=b.vec3(*(float(tq.get(a) or 0.0) * MM for a in "xyz"))))
    b.write(m.topic, "geometry_msgs/msg/WrenchStamped", msg, m.log_time_ns)


def _scale(b: _Bag, m: Message) -> None:
    f = m.data.get("force_n")
    if not isinstance(f, (int, float)) or not math.isfinite(f):
        return  # a sample without a finite force (the JSON encoding writes NaN as null)
    msg = b.t["geometry_msgs/msg/WrenchStamped"](
        header=b.header(m.log_time_ns, "scale"),
        wrench=b.t["geometry_msgs/msg/Wrench"](force=b.vec3(0.0, 0.0, float(f)), torque=b.vec3(0.0, 0.0, 0.0)))
    b.write(m.topic, "geometry_msgs/msg/WrenchStamped", msg, m.log_time_ns)


def _scene(b: _Bag, m: Message) -> None:
    mk = b.t["visualization_msgs/msg/Marker"]
    dur = b.t["builtin_interfaces/msg/Duration"](sec=0, nanosec=0)
    color = b.t["std_msgs/msg/ColorRGBA"]
    markers = [mk(header=b.header(m.log_time_ns, ""), ns="", id=0, type=0, action=3, pose=b.pose(None),
                  scale=b.vec3(0, 0, 0), color=color(r=0.0, g=0.0, b=0.0, a=0.0), lifetime=dur, frame_locked=False,
                  points=[], colors=[], texture_resource="", texture=b.t["sensor_msgs/msg/CompressedImage"](
                      header=b.header(0, ""), format="", data=np.zeros(0, np.uint8)),
                  uv_coordinates=[], text="", mesh_resource="",
                  mesh_file=b.t["visualization_msgs/msg/MeshFile"](filename="", data=np.zeros(0, np.uint8)),
                  mesh_use_embedded_materials=False)]  # DELETEALL: an update replaces the arrows
    for e in m.data.get("entities", []):
        for k, a in enumerate(e.get("arrows", [])):
            c = a.get("color") or {}
            markers.append(mk(
                header=b.header(_ns(m) if not e.get("timestamp") else _ns_of(e["timestamp"]), e["frame_id"]),
                ns=str(e["id"]), id=k, type=0, action=0, pose=b.pose(a.get("pose")),
                scale=b.vec3((float(a["shaft_length"]) + float(a["head_length"])) * MM,
                             float(a["shaft_diameter"]) * MM, float(a["head_diameter"]) * MM),
                color=color(r=float(c.get("r", 1.0)), g=float(c.get("g", 1.0)), b=float(c.get("b", 1.0)),
                            a=float(c.get("a", 1.0))),
                lifetime=dur, frame_locked=bool(e.get("frame_locked", False)), points=[], colors=[],
                texture_resource="", texture=markers[0].texture, uv_coordinates=[], text="", mesh_resource="",
                mesh_file=markers[0].mesh_file, mesh_use_embedded_materials=False))
    b.write(m.topic, "visualization_msgs/msg/MarkerArray", b.t["visualization_msgs/msg/MarkerArray"](markers=markers),
            m.log_time_ns)


def _ns_of(ts: dict[str, Any]) -> int:
    return int(ts.get("sec", 0)) * 1_000_000_000 + int(ts.get("nsec", 0))


def _log(b: _Bag, m: Message) -> None:
    d = m.data
    msg = b.t["rcl_interfaces/msg/Log"](stamp=b.stamp(_ns(m)), level=_LOG_LEVELS.get(int(d.get("level", 2)), 20),
                                        name=str(d.get("name", "")), msg=str(d.get("message", "")),
                                        file=str(d.get("file", "")), function="", line=int(d.get("line", 0)))
    b.write("/rosout", "rcl_interfaces/msg/Log", msg, m.log_time_ns)


_BY_SCHEMA: dict[str, Callable[[_Bag, Message], None]] = {
    "foxglove.CompressedImage": _compressed, "foxglove.RawImage": _raw, "foxglove.PointCloud": _points,
    "foxglove.FrameTransforms": _tf, "foxglove.JointStates": _joints, "foxglove.PoseInFrame": _pose_in_frame,
    "foxglove.SceneUpdate": _scene, "foxglove.Log": _log, "tactile_rig.Wrench": _wrench,
    "tactile_rig.ScaleReading": _scale, "tactile_rig.JigPose": _jig_pose,
}


def export_ros2(session: str | Path, out: str | Path, *, force: bool = False) -> Ros2Export:
    """Write the ROS 2 bag of ``session`` (a tactile-rig .mcap) to the folder ``out``.

    The bag is written beside ``out`` and renamed into place when complete. A file that is not a
    tactile-rig recording, is damaged or was cut off (a crash) is a :class:`BadFile` and nothing is
    written; an existing ``out`` is refused unless ``force`` (and then only if it is a rosbag2 folder,
    one with a ``metadata.yaml``)."""
    require_rosbags()
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    src = check_file(session, "recording", max_bytes=MAX_RECORDING_BYTES)
    dst = Path(out)
    if dst.exists() or dst.is_symlink():
        if not force:
            raise FileExistsError(f"{dst} exists; pass --force to replace it")
        if not (dst.is_dir() and (dst / "metadata.yaml").is_file()):
            raise FileExistsError(f"{dst} exists and is not a ROS 2 bag folder (no metadata.yaml): not replaced")
    if not dst.parent.is_dir():
        raise FileNotFoundError(f"{dst}: the folder {str(dst.parent)!r} does not exist (create it first)")
    tmp = dst.with_name(f".{dst.name}.partial-{os.getpid()}")
    if tmp.exists():
        shutil.rmtree(tmp)
    outcome = Ros2Export(dst)
    rec = Recording(src)
    writer = Writer(tmp, version=BAG_VERSION, storage_plugin=StoragePlugin.MCAP)
    try:
        writer.open()
        bag = _Bag(writer, get_typestore(Stores.ROS2_HUMBLE), outcome)
        seen_header = False
        for m in iter_messages(src, into=rec):
            if not seen_header:
                _check_origin(src, rec)
                seen_header = True
            fn = _BY_SCHEMA.get(m.schema)
            if fn is None or m.encoding not in ("protobuf", "json"):
                outcome.skipped[m.topic] = outcome.skipped.get(m.topic, 0) + 1
                continue
            try:
                fn(bag, m)
            except (KeyError, TypeError, ValueError) as exc:
                raise BadFile(src, f"a {m.schema} message on {m.topic} at {m.t_s:.6f} s lacks what its type needs "
                              f"({type(exc).__name__}: {str(exc)[:100]})", f"a complete {m.schema}") from None
        if not seen_header:
            _check_origin(src, rec)
        if rec.truncated:
            raise BadFile(src, f"recording was cut off ({rec.error}); export needs a complete recording",
                          "a recording that was closed (tactile-rig replay shows what a cut-off one holds)")
        writer.close()
    except BaseException:
        _abort(writer, tmp)
        raise
    if force and dst.exists():
        old = dst.with_name(f".{dst.name}.old-{os.getpid()}")
        os.replace(dst, old)
        os.replace(tmp, dst)
        shutil.rmtree(old, ignore_errors=True)
    else:
        os.replace(tmp, dst)
    return outcome


def _check_origin(src: Path, rec: Recording) -> None:
    """A recording this rig wrote: the MCAP header names the library and the ``recording`` metadata is there."""
    if rec.library != LIBRARY or "recording" not in rec.metadata:
        raise BadFile(src, f"is not a tactile-rig session recording (MCAP library {rec.library!r}"
                      f"{'' if 'recording' in rec.metadata else ', no recording metadata'})",
                      f"an .mcap written by {LIBRARY} (record, a calibration session, a jig accuracy run)")


def _abort(writer: Any, tmp: Path) -> None:
    try:
        writer.close()
    except Exception:  # noqa: BLE001 - the bag is thrown away either way
        pass
    shutil.rmtree(tmp, ignore_errors=True)
