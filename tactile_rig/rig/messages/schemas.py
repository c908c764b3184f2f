"""JSON schemas of the rig's own topics, where Foxglove has no type: each names its fields' units.

Every body also carries ``t_s``, the session time (s) of the message (the session clock: virtual
in simulations, monotonic on a bench). Foxglove plots any numeric field of these (``/scale/force.force_n``).
"""

from __future__ import annotations

from typing import Any

__all__ = ["SCHEMAS", "TIME_S"]

TIME_S = {"type": "number", "description": "session time (s): virtual in simulations, monotonic on a bench"}
_TIME = {"type": "object", "title": "time",
         "properties": {"sec": {"type": "integer", "minimum": 0},
                        "nsec": {"type": "integer", "minimum": 0, "maximum": 999999999}}}
_VEC3 = {"type": "object", "properties": {"x": {"type": "number"}, "y": {"type": "number"}, "z": {"type": "number"}}}


def _obj(title: str, description: str, props: dict[str, Any], required: tuple[str, ...] = ()) -> dict[str, Any]:
    return {"title": title, "description": description, "type": "object",
            "properties": {"t_s": TIME_S, **props}, "required": ["t_s", *required]}


SCHEMAS: dict[str, dict[str, Any]] = {
    "tactile_rig.ScaleReading": _obj(
        "tactile_rig.ScaleReading", "One sample of the load-cell scale, as its sketch sent it.",
        {"force_n": {"type": "number", "description": "force on the load cell (N), positive in compression"},
         "grams": {"type": "number", "description": "the same load as the sketch reports it (g)"},
         "raw": {"type": "integer", "description": "HX711 reading (ADC counts)"},
         "seq": {"type": "integer", "description": "the sketch's sample counter"},
         "saturated": {"type": "boolean", "description": "the ADC is at a rail: force_n is a bound"}},
        ("force_n",)),
    "tactile_rig.JigPose": _obj(
        "tactile_rig.JigPose", "The x-y-θ jig's work pose (true_* fields: the simulated truth).",
        {"x_mm": {"type": "number"}, "y_mm": {"type": "number"}, "z_mm": {"type": "number"},
         "theta_deg": {"type": "number", "description": "stage rotation about z, counter-clockwise (deg)"}}),
    "tactile_rig.GripperState": _obj(
        "tactile_rig.GripperState", "A snapshot of the Dynamixel gripper.",
        {"opening_m": {"type": "number", "description": "distance between the fingertips (m)"},
         "opening_frac": {"type": "number", "description": "0 closed .. 1 open calibration point"},
         "velocity_mps": {"type": "number", "description": "rate of change of the opening (m/s)"},
         "current_a": {"type": "number", "description": "motor current (A), signed"},
         "effort_frac": {"type": "number", "description": "|current| / current limit"},
         "temperature_c": {"type": "number"}, "hardware_error": {"type": "integer"},
         "moving": {"type": "boolean"}, "active": {"type": "boolean"}}),
    "tactile_rig.DeviceState": _obj(
        "tactile_rig.DeviceState", "A device's state snapshot (fields named with their units).", {}),
    "tactile_rig.Command": _obj(
        "tactile_rig.Command", "A command sent to a device, with its arguments (named with their units).",
        {"command": {"type": "string"}}, ("command",)),
    "tactile_rig.Perception": _obj(
        "tactile_rig.Perception", "A perception or controller result (fields named with their units).", {}),
    "tactile_rig.Wrench": _obj(
        "tactile_rig.Wrench", "Force and torque on a fingertip sensor, in its frame (frame_id).",
        {"frame_id": {"type": "string"},
         "force_n": {**_VEC3, "description": "force on the sensor (N)"},
         "torque_nmm": {**_VEC3, "description": "torque on the sensor about its origin (N·mm)"}},
        ("frame_id", "force_n")),
    "tactile_rig.Json": {"title": "tactile_rig.Json", "type": "object"},
    # The JSON encodings of Foxglove's image types (recordings in the JSON encoding carry these).
    "foxglove.RawImage": {
        "title": "foxglove.RawImage", "type": "object",
        "properties": {"timestamp": _TIME, "frame_id": {"type": "string"},
                       "width": {"type": "integer"}, "height": {"type": "integer"},
                       "encoding": {"type": "string"}, "step": {"type": "integer"},
                       "data": {"type": "string", "contentEncoding": "base64"}},
    },
    "foxglove.CompressedImage": {
        "title": "foxglove.CompressedImage", "type": "object",
        "properties": {"timestamp": _TIME, "frame_id": {"type": "string"},
                       "format": {"type": "string"},
                       "data": {"type": "string", "contentEncoding": "base64"}},
    },
}
