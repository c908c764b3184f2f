"""Camera frames as ``foxglove.CompressedImage`` (PNG/JPEG bytes) or ``foxglove.RawImage`` (bgr8, mono8).

Topics follow ROS image_transport: ``/<camera>/image`` (raw) and ``/<camera>/image/compressed``; the
``frame_id`` is the camera's name, which is also the sensor's frame in the 3-D scene
(:mod:`tactile_rig.rig.messages.frames`).
"""

from __future__ import annotations

import cv2
import numpy as np

from tactile_rig.rig.messages.base import SchemaDef, foxglove_messages, foxglove_schema, timestamp

__all__ = ["camera_topic", "check_frame", "encode_frame", "IMAGE_SCHEMAS"]

IMAGE_SCHEMAS = ("foxglove.RawImage", "foxglove.CompressedImage")


def camera_topic(camera: str, *, compressed: bool = False) -> str:
    """``/<camera>/image`` or ``/<camera>/image/compressed`` (a bench camera named ``camera_left``
    records on ``/camera_left/image``); find image topics by schema, not by name."""
    name = camera.strip("/")
    if not name:
        raise ValueError("camera name is empty; expected the bench table name, e.g. 'camera_left'")
    return f"/{name}/image/compressed" if compressed else f"/{name}/image"


def check_frame(camera: str, image: np.ndarray) -> np.ndarray:
    """``image`` as a contiguous uint8 HxW or HxWx3 (BGR) array, else ValueError naming ``camera``."""
    img = np.ascontiguousarray(image)
    if img.dtype != np.uint8 or img.ndim not in (2, 3) or (img.ndim == 3 and img.shape[2] != 3):
        raise ValueError(f"camera {camera!r}: frame must be uint8 HxW or HxWx3 BGR, got {img.dtype} {img.shape}")
    return img


def encode_frame(camera: str, image: np.ndarray, log_time_ns: int, *, compress: str | None = None,
                 jpeg_quality: int = 95) -> tuple[str, SchemaDef, bytes]:
    """``(topic, schema, bytes)`` of one frame: raw for ``compress=None``, else ``'png'`` / ``'jpeg'``
    (``jpeg_quality`` 1..100)."""
    img = check_frame(camera, image)
    fm = foxglove_messages()
    stamp = timestamp(log_time_ns)
    if compress is None:
        h, w = img.shape[:2]
        msg = fm.RawImage(timestamp=stamp, frame_id=camera, width=w, height=h,
                          encoding="bgr8" if img.ndim == 3 else "mono8", step=int(img.strides[0]),
                          data=img.tobytes())
        return camera_topic(camera), foxglove_schema("RawImage"), msg.encode()
    fmt = {"png": "png", "jpeg": "jpeg", "jpg": "jpeg"}.get(compress)
    if fmt is None:
        raise ValueError(f"compress={compress!r} must be None, 'png' or 'jpeg'")
    if not 1 <= int(jpeg_quality) <= 100:
        raise ValueError(f"jpeg_quality={jpeg_quality!r} must be in 1..100")
    params = [int(cv2.IMWRITE_JPEG_QUALITY), int(jpeg_quality)] if fmt == "jpeg" else []
    ok, buf = cv2.imencode(".jpg" if fmt == "jpeg" else ".png", img, params)
    if not ok:
        raise ValueError(f"camera {camera!r}: OpenCV could not encode the frame as {fmt}")
    msg = fm.CompressedImage(timestamp=stamp, frame_id=camera, data=buf.tobytes(), format=fmt)
    return camera_topic(camera, compressed=True), foxglove_schema("CompressedImage"), msg.encode()
