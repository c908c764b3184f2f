"""Session recordings in MCAP, in the ecosystem's own types, written so a crash loses at most the last second.

What is recorded comes from one mapping (:class:`tactile_rig.rig.messages.TopicWriter`), the same
the live view publishes: camera frames as ``foxglove.CompressedImage`` / ``foxglove.RawImage``,
FingerVision markers as ``foxglove.ImageAnnotations`` and ``foxglove.SceneUpdate``, GelSight heights
as ``foxglove.PointCloud``, the jig's frames as ``foxglove.FrameTransforms``, contact poses as
``foxglove.PoseInFrame``, the gripper as ``foxglove.JointStates``, events as ``foxglove.Log`` (all
protobuf, the schema in the file); the scale, device states, commands, wrenches and perception
results as JSON with a JSON schema per topic (units in the field names). ``docs/foxglove_and_ros2.md``
lists every topic.

The bench config and every calibration are stored as MCAP metadata records (flat string maps) and
as attachments (the files as they were). The MCAP ``log_time`` of a message is its session time
(the session clock, virtual or monotonic) in nanoseconds, plus the Unix time at the start for
wall-clock sessions (so Foxglove shows real dates; the offset is in the ``recording`` metadata).

Crash safety: chunks are closed and the file flushed whenever the session clock or the wall
clock has moved ``flush_interval_s`` (default 1 s) past the last flush, and, on wall-clock
sessions, by a background timer too, so idle periods do not hold data in memory.
:func:`read_recording` reads a file cut off anywhere (SIGKILL, full disk, power loss) and returns
every complete chunk; it reads recordings in the JSON encoding too (every channel ``json``, images
as base64), telling them apart by each channel's encoding.

``mcap``, ``foxglove-sdk`` and ``protobuf`` are the optional extra ``record``; they are imported
only when a recording is opened.
"""

from tactile_rig.rig.messages import SCHEMAS, TopicWriter, camera_topic
from tactile_rig.rig.recording.reader import (
    MAX_RECORD_BYTES,
    MAX_RECORDING_BYTES,
    MCAP_MAGIC,
    Message,
    Recording,
    decode_image,
    iter_messages,
    read_recording,
)
from tactile_rig.rig.recording.writer import LIBRARY, PROFILE, Recorder, require_mcap

__all__ = ["Recorder", "Recording", "Message", "read_recording", "iter_messages", "SCHEMAS", "camera_topic",
           "MAX_RECORDING_BYTES", "MAX_RECORD_BYTES", "MCAP_MAGIC", "decode_image", "TopicWriter", "LIBRARY",
           "PROFILE", "require_mcap"]
