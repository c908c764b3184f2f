"""The one mapping from rig data to topics and typed messages, shared by the recording and the live view.

:class:`TopicWriter` turns each kind of rig data into its messages (see the table in
``docs/foxglove_and_ros2.md``) and hands each, encoded once, to :meth:`TopicWriter.publish`: the
:class:`~tactile_rig.rig.recording.Recorder` writes it to MCAP, the
:class:`~tactile_rig.rig.live.LiveServer` sends it over the Foxglove WebSocket protocol, and
:class:`Tee` gives the same bytes to both, so a live view shows exactly what is recorded.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

from tactile_rig.core.clock import Clock, RealClock
from tactile_rig.core.jsonable import to_jsonable
from tactile_rig.rig.messages.base import Encoded, SchemaDef, encode_json, is_typed, json_schema
from tactile_rig.rig.messages.devices import gripper_joint_states, log_message
from tactile_rig.rig.messages.frames import jig_transforms, pose_in_frame
from tactile_rig.rig.messages.heights import MAX_POINTS, height_point_cloud
from tactile_rig.rig.messages.images import encode_frame
from tactile_rig.rig.messages.markers import DISPLACEMENT_GAIN, marker_annotations, marker_arrows

__all__ = ["TopicWriter", "Tee", "as_dict", "LOG_TOPIC", "TF_TOPIC", "GRIPPER_JOINTS_TOPIC"]

LOG_TOPIC = "/log"
TF_TOPIC = "/tf"
GRIPPER_JOINTS_TOPIC = "/gripper/joint_states"


def as_dict(obj: Any) -> dict[str, Any]:
    """A result or state as a dict: dataclasses field by field, mappings as they are, objects by
    their public attributes, anything else as ``{"value": obj}``."""
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return dict(to_jsonable(obj))
    if isinstance(obj, Mapping):
        return dict(obj)
    if hasattr(obj, "__dict__"):
        return {k: v for k, v in vars(obj).items() if not k.startswith("_")}
    return {"value": obj}


def _name(s: str) -> str:
    name = str(s).strip("/")
    if not name:
        raise ValueError("a topic name part is empty; expected e.g. a camera or device name")
    return name


class TopicWriter:
    """The typed topics of a session. A sink implements :meth:`publish` and :meth:`log_time_ns`;
    ``clock`` gives the time of a message written without ``t_s``."""

    clock: Clock
    jpeg_quality: int = 95  # OpenCV's default: a recording is a record
    _sensor_frames: set[str]

    # -- what a sink implements -----------------------------------------------------------------
    def publish(self, msg: Encoded) -> None:
        """Send one encoded message on."""
        raise NotImplementedError

    def log_time_ns(self, t_s: float) -> int:
        """The log time (ns) of session time ``t_s`` (s)."""
        raise NotImplementedError

    # -- helpers --------------------------------------------------------------------------------
    def _t(self, t_s: float | None) -> float:
        return self.clock.now_s() if t_s is None else float(t_s)

    def _emit(self, topic: str, schema: SchemaDef, data: bytes, t: float, ns: int | None = None) -> None:
        self.publish(Encoded(topic, schema, data, t, self.log_time_ns(t) if ns is None else ns))

    def add_sensor_frame(self, name: str) -> None:
        """Name a fingertip camera's sensor frame, so the jig's transforms place it over the stage."""
        if not hasattr(self, "_sensor_frames"):
            self._sensor_frames = set()
        self._sensor_frames.add(_name(name))

    @property
    def sensor_frames(self) -> set[str]:
        return set(getattr(self, "_sensor_frames", set()))

    # -- JSON topics ----------------------------------------------------------------------------
    def write(self, topic: str, payload: Mapping[str, Any], *, t_s: float | None = None,
              schema: str = "tactile_rig.Json") -> None:
        """One JSON message on ``topic`` with schema ``schema`` (``t_s`` is added to the body)."""
        if is_typed(schema):
            raise ValueError(f"write(): {schema} is a protobuf type; use its write_* method, or "
                             "write_message() to copy a recorded message")
        t = self._t(t_s)
        body = dict(payload)
        body.setdefault("t_s", t)
        self._emit(topic, json_schema(schema), encode_json(body), t)

    def write_message(self, message: Any) -> None:
        """Copy a message read from a recording (a :class:`~tactile_rig.rig.recording.Message`), bytes
        and schema unchanged, at its session time."""
        schema = getattr(message, "schema_def", None)
        if schema is None:
            self.write(message.topic, message.data, t_s=message.t_s, schema=message.schema)
            return
        self._emit(message.topic, schema, bytes(message.raw), message.t_s)

    def write_perception(self, name: str, result: Any, *, t_s: float | None = None) -> None:
        """A perception result on ``/perception/<name>`` (JSON; fields named with their units)."""
        self.write(f"/perception/{name}", as_dict(result), t_s=t_s, schema="tactile_rig.Perception")

    def write_state(self, device: str, state: Any, *, t_s: float | None = None) -> None:
        """A device's state on ``/state/<device>``; a gripper's also as JointStates on
        ``/gripper/joint_states``."""
        t = self._t(t_s)
        body = as_dict(state)
        joints = gripper_joint_states(body, self.log_time_ns(t))
        self.write(f"/state/{device}", body, t_s=t,
                   schema="tactile_rig.GripperState" if joints is not None else "tactile_rig.DeviceState")
        if joints is not None:
            self._emit(GRIPPER_JOINTS_TOPIC, *joints, t)

    def write_command(self, device: str, command: str, *, t_s: float | None = None, **args: Any) -> None:
        """A command sent to a device: JSON on ``/command/<device>`` and a line on ``/log``."""
        t = self._t(t_s)
        self.write(f"/command/{device}", {"command": command, **args}, t_s=t, schema="tactile_rig.Command")
        text = " ".join([command] + [f"{k}={_short(v)}" for k, v in args.items()])
        self._emit(LOG_TOPIC, *log_message(device, text, self.log_time_ns(t)), t)

    def write_log(self, name: str, message: str, *, level: str = "info", t_s: float | None = None) -> None:
        """An event on ``/log`` from ``name`` (a device or ``session``)."""
        t = self._t(t_s)
        self._emit(LOG_TOPIC, *log_message(name, message, self.log_time_ns(t), level=level), t)

    def write_jig_pose(self, pose: Any, *, t_s: float | None = None, **extra: Any) -> None:
        """The jig's pose (mm, deg): JSON on ``/jig/pose`` and the frame tree on ``/tf``."""
        t = self._t(t_s)
        body = {**as_dict(pose), **extra}
        self.write("/jig/pose", body, t_s=t, schema="tactile_rig.JigPose")
        vals = [body.get(k, 0.0) for k in ("x_mm", "y_mm", "z_mm", "theta_deg")]
        try:
            x, y, z, th = (float(v) if v is not None else 0.0 for v in vals)
        except (TypeError, ValueError):
            return  # a pose without numbers has no place in the frame tree
        self._emit(TF_TOPIC, *jig_transforms(x, y, z, th, self.log_time_ns(t), self.sensor_frames), t)

    def write_scale(self, force_n: float, *, t_s: float | None = None, **extra: Any) -> None:
        """A scale reading (N) on ``/scale/force`` (JSON)."""
        self.write("/scale/force", {"force_n": float(force_n), **extra}, t_s=t_s, schema="tactile_rig.ScaleReading")

    def write_trace(self, name: str, trace: Any, *, t0_s: float = 0.0) -> int:
        """A controller's :class:`~tactile_rig.core.types.Trace`, one JSON message per sample on
        ``/perception/<name>`` at ``t0_s`` + its time; returns the number of samples."""
        for i, t in enumerate(trace.t_s):
            self.write_perception(name, {k: v[i] for k, v in trace.channels.items()}, t_s=t0_s + t)
        return len(trace.t_s)

    # -- typed topics ---------------------------------------------------------------------------
    def write_frame(self, camera: str, image: np.ndarray, *, t_s: float | None = None,
                    compress: str | None = None) -> None:
        """A camera frame: RawImage on ``/<camera>/image`` (bgr8 for HxWx3, mono8 for HxW) or, with
        ``compress='png'|'jpeg'``, CompressedImage on ``/<camera>/image/compressed``."""
        t = self._t(t_s)
        topic, schema, data = encode_frame(camera, image, self.log_time_ns(t), compress=compress,
                                           jpeg_quality=self.jpeg_quality)
        self.add_sensor_frame(camera)
        self._emit(topic, schema, data, t)

    def write_markers(self, camera: str, markers_px: Any, *, t_s: float | None = None,
                      displacements_px: Any = None, valid: Sequence[bool] | None = None,
                      image_size_px: tuple[int, int] | None = None, mm_per_px: float | None = None,
                      force_n: Sequence[float] | None = None, ids: bool = True,
                      displacement_gain: float = DISPLACEMENT_GAIN) -> None:
        """FingerVision markers: ImageAnnotations on ``/<camera>/markers`` (over the image, same
        timestamp as the frame of ``t_s``) and, with ``image_size_px`` (w, h) and ``mm_per_px``, a
        SceneUpdate of arrows in the sensor frame on ``/<camera>/marker_arrows``."""
        cam = _name(camera)
        t = self._t(t_s)
        ns = self.log_time_ns(t)
        self._emit(f"/{cam}/markers", *marker_annotations(cam, markers_px, ns, displacements_px=displacements_px,
                                                          valid=valid, ids=ids, displacement_gain=displacement_gain), t)
        if image_size_px is not None and mm_per_px is not None and mm_per_px > 0:
            self._emit(f"/{cam}/marker_arrows",
                       *marker_arrows(cam, markers_px, displacements_px, image_size_px, mm_per_px, ns, valid=valid,
                                      force_n=force_n, displacement_gain=displacement_gain), t)

    def write_wrench(self, camera: str, force_n: Sequence[float], *, torque_nmm: Sequence[float] | None = None,
                     t_s: float | None = None) -> None:
        """Force (N) and torque (N·mm) on a fingertip, in its sensor frame, on ``/<camera>/wrench``."""
        cam = _name(camera)
        f = [float(v) for v in np.asarray(force_n, float).reshape(-1)[:3]]
        if len(f) != 3:
            raise ValueError(f"force_n of camera {cam!r} must have 3 components (x, y, z N), got {len(f)}")
        body: dict[str, Any] = {"frame_id": cam, "force_n": dict(zip("xyz", f))}
        if torque_nmm is not None:
            tq = [float(v) for v in np.asarray(torque_nmm, float).reshape(-1)[:3]]
            body["torque_nmm"] = dict(zip("xyz", tq + [0.0] * (3 - len(tq))))
        self.write(f"/{cam}/wrench", body, t_s=t_s, schema="tactile_rig.Wrench")

    def write_height(self, camera: str, height_mm: np.ndarray, mm_per_px_x: float, mm_per_px_y: float | None = None,
                     *, t_s: float | None = None, max_points: int = MAX_POINTS) -> None:
        """A GelSight height map (mm) as a PointCloud in the sensor frame on ``/<camera>/height/points``."""
        cam = _name(camera)
        t = self._t(t_s)
        self._emit(f"/{cam}/height/points",
                   *height_point_cloud(cam, height_mm, mm_per_px_x, mm_per_px_y if mm_per_px_y else mm_per_px_x,
                                       self.log_time_ns(t), max_points=max_points), t)

    def write_contact_pose(self, name: str, frame_id: str, x_mm: float, y_mm: float, theta_deg: float, *,
                           t_s: float | None = None) -> None:
        """A contact/localization pose (mm, deg about z) in ``frame_id`` on ``/<name>/pose``."""
        t = self._t(t_s)
        self._emit(f"/{_name(name)}/pose", *pose_in_frame(frame_id, x_mm, y_mm, theta_deg, self.log_time_ns(t)), t)

    # -- what a recording keeps beside its messages (no-ops for a view) -------------------------
    def add_metadata(self, name: str, values: Mapping[str, Any]) -> None:
        pass

    def add_attachment(self, name: str, data: bytes, *, media_type: str = "application/octet-stream") -> None:
        pass

    def add_bench(self, bench: Any) -> None:
        """The bench: its cameras become sensor frames."""
        for name in getattr(bench, "cameras", {}) or {}:
            self.add_sensor_frame(name)

    def add_calibration(self, name: str, *, path: str | Path | None = None,
                        values: Mapping[str, Any] | None = None) -> None:
        pass

    def flush(self) -> None:
        pass


def _short(v: Any) -> str:
    if isinstance(v, float):
        return f"{v:.6g}"
    text = str(to_jsonable(v))
    return text if len(text) <= 60 else text[:57] + "..."


class Tee(TopicWriter):
    """Every message, encoded once, to several sinks (a Recorder and a LiveServer); ``None`` sinks are
    skipped. Times are the first sink's; :attr:`path` is the first sink's that has one (the file)."""

    def __init__(self, *sinks: Any) -> None:
        self.sinks = [s for s in sinks if s is not None]
        self.path = next((s.path for s in self.sinks if getattr(s, "path", None) is not None), None)
        self.clock = self.sinks[0].clock if self.sinks else RealClock()
        self.jpeg_quality = min((getattr(s, "jpeg_quality", 95) for s in self.sinks), default=95)
        for s in self.sinks:
            for f in getattr(s, "sensor_frames", ()):
                self.add_sensor_frame(f)

    def log_time_ns(self, t_s: float) -> int:
        return int(self.sinks[0].log_time_ns(t_s)) if self.sinks else int(round(t_s * 1e9))

    def publish(self, msg: Encoded) -> None:
        for s in self.sinks:
            s.publish(msg)

    def add_metadata(self, name: str, values: Mapping[str, Any]) -> None:
        for s in self.sinks:
            s.add_metadata(name, values)

    def add_attachment(self, name: str, data: bytes, *, media_type: str = "application/octet-stream") -> None:
        for s in self.sinks:
            s.add_attachment(name, data, media_type=media_type)

    def add_bench(self, bench: Any) -> None:
        super().add_bench(bench)
        for s in self.sinks:
            s.add_bench(bench)

    def add_calibration(self, name: str, *, path: str | Path | None = None,
                        values: Mapping[str, Any] | None = None) -> None:
        for s in self.sinks:
            s.add_calibration(name, path=path, values=values)

    def flush(self) -> None:
        for s in self.sinks:
            s.flush()

    def close(self) -> None:
        for s in self.sinks:
            s.close()


