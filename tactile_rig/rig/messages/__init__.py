"""Rig data as the ecosystem's typed messages: one mapping, used by the recording and the live view.

One small module per kind: :mod:`.images` (frames), :mod:`.markers` (FingerVision's marker field),
:mod:`.heights` (GelSight height maps as point clouds), :mod:`.frames` (the jig's frame tree, poses),
:mod:`.devices` (the gripper's joint, logs), :mod:`.schemas` (the JSON schemas of the rig's own
topics); :mod:`.writer` puts them together (:class:`TopicWriter`, :class:`Tee`).
"""

from tactile_rig.rig.messages.base import Encoded, SchemaDef, foxglove_schema, is_typed, json_schema, schema_for
from tactile_rig.rig.messages.images import IMAGE_SCHEMAS, camera_topic
from tactile_rig.rig.messages.schemas import SCHEMAS
from tactile_rig.rig.messages.writer import LOG_TOPIC, TF_TOPIC, Tee, TopicWriter, as_dict

__all__ = ["Encoded", "SchemaDef", "foxglove_schema", "is_typed", "json_schema", "schema_for", "IMAGE_SCHEMAS",
           "camera_topic", "SCHEMAS", "LOG_TOPIC", "TF_TOPIC", "Tee", "TopicWriter", "as_dict"]
