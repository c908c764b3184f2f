"""What the emulated camera's sensor sees and how a frame travels: the scene (a renderer, a scene's
renderer model, or a recorded video), the lens placing it on the sensor as the vendor SDK expects to
find it, and the bytes of the negotiated format (real JPEG for MJPG, BT.601 limited-range 4:2:2 for
YUYV, as UVC cameras send them).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Callable

import cv2
import numpy as np

from tactile_rig.devices.camera_models import CameraModel, SdkView
from tactile_rig.mocks.camera import SimulatedCamera
from tactile_rig.sim.render.gelsight import BACKGROUNDS, GelSightRendererModel
from tactile_rig.sim.scenes import load_scene

__all__ = ["encode_frame", "bgr_to_yuyv", "sensor_optics", "VideoFile", "build_camera", "RENDERERS"]

RENDERERS = ("gelsight", "fingervision")
_YUY2 = getattr(cv2, "COLOR_BGR2YUV_YUY2", None)


def bgr_to_yuyv(image: np.ndarray) -> np.ndarray:
    """BGR -> packed YUYV (Y0 U Y1 V), BT.601 limited range, chroma averaged over each pixel pair."""
    if _YUY2 is not None:
        return np.ascontiguousarray(cv2.cvtColor(image, _YUY2))
    f = image.astype(np.float32)
    b, g, r = f[..., 0], f[..., 1], f[..., 2]
    y = 16.0 + (65.481 * r + 128.553 * g + 24.966 * b) / 255.0
    u = 128.0 + (-37.797 * r - 74.203 * g + 112.0 * b) / 255.0
    v = 128.0 + (112.0 * r - 93.786 * g - 18.214 * b) / 255.0
    out = np.empty(image.shape[:2] + (2,), np.uint8)
    out[..., 0] = np.clip(np.rint(y), 0, 255)
    uu = np.clip(np.rint((u[:, 0::2] + u[:, 1::2]) / 2), 0, 255)
    vv = np.clip(np.rint((v[:, 0::2] + v[:, 1::2]) / 2), 0, 255)
    out[:, 0::2, 1] = uu
    out[:, 1::2, 1] = vv
    return out


def encode_frame(image: np.ndarray, fourcc: str, jpeg_quality: int = 90) -> np.ndarray:
    """The payload of one frame in ``fourcc`` (uint8, flat)."""
    if fourcc == "MJPG":
        ok, buf = cv2.imencode(".jpg", image, [int(cv2.IMWRITE_JPEG_QUALITY), int(jpeg_quality)])
        if not ok:
            raise RuntimeError("OpenCV could not encode a JPEG frame")
        return buf.reshape(-1)
    if fourcc == "YUYV":
        return bgr_to_yuyv(image).reshape(-1)
    raise ValueError(f"cannot encode pixel format {fourcc!r}; expected MJPG or YUYV")


def _uncrop(view: SdkView) -> Callable[[np.ndarray, int, int], np.ndarray]:
    def place(image: np.ndarray, width: int, height: int) -> np.ndarray:
        x0, y0, x1, y1 = view.crop_box(width, height)
        # Outside what the SDK keeps the sensor sees the housing: a dim view of the same scene
        # (dimmed before the upscale: the full-size frame is the costly part of an 8 MP mode).
        raw = cv2.resize(cv2.convertScaleAbs(image, alpha=0.35), (width, height), interpolation=cv2.INTER_LINEAR)
        raw[y0:y1, x0:x1] = cv2.resize(image, (x1 - x0, y1 - y0), interpolation=cv2.INTER_LINEAR)
        return raw
    return place


def _sensor_from_portrait(image: np.ndarray, width: int, height: int) -> np.ndarray:
    # digit-interface shows flip(transpose(raw), vertical); the sensor's raw frame is the inverse.
    raw = cv2.transpose(cv2.flip(image, 0))
    if raw.shape[:2] != (height, width):
        raw = cv2.resize(raw, (width, height), interpolation=cv2.INTER_AREA)
    return raw


def sensor_optics(model: CameraModel) -> Callable[[np.ndarray, int, int], np.ndarray] | None:
    """How the camera's raw frame holds the scene its SDK shows: None (a plain resize) for the C310;
    the GelSight Mini's scene inside gs_sdk's crop box; the DIGIT's portrait view rotated back onto its
    landscape sensor (see :class:`~tactile_rig.devices.camera_models.SdkView`)."""
    views = {v.name: v for v in model.sdk_views}
    if any(v.transpose_flip for v in views.values()):
        return _sensor_from_portrait
    if "gs_sdk" in views:
        return _uncrop(views["gs_sdk"])
    return None


class VideoFile:
    """A recorded video (any file OpenCV's FFmpeg backend decodes) as ``render(t_s) -> BGR``, looping
    at its recorded rate; at most ``max_frames`` frames are held decoded."""

    def __init__(self, path: str | Path, *, max_frames: int = 3000) -> None:
        self.path = Path(path)
        cap = cv2.VideoCapture(str(self.path))
        try:
            if not cap.isOpened():
                raise ValueError(f"video {self.path}: OpenCV cannot open it (a file FFmpeg decodes was expected)")
            fps = float(cap.get(cv2.CAP_PROP_FPS))
            frames: list[np.ndarray] = []
            while len(frames) < max_frames:
                ok, img = cap.read()
                if not ok:
                    break
                frames.append(img)
        finally:
            cap.release()
        if not frames:
            raise ValueError(f"video {self.path}: no frames decoded")
        self.frames = frames
        self.fps = fps if 0.1 < fps < 1000 else 25.0

    def __call__(self, t_s: float) -> np.ndarray:
        return self.frames[int(t_s * self.fps) % len(self.frames)]


def _scene_renderer(model: CameraModel, renderer: str, scene: str | None, seed: int, clock: Any) -> Any:
    if scene is not None:
        world = load_scene(scene, clock=clock, seed=seed).world
        candidates = [n for n in world if hasattr(world.get(n), "render_now")]
        wanted = [n for n in candidates if renderer in n] or candidates
        if len(wanted) != 1:
            raise ValueError(f"scene {scene!r}: name the renderer with --model; it has {candidates or 'none'}")
        return world.get(wanted[0])
    if renderer == "gelsight":
        if model.background not in BACKGROUNDS:
            raise ValueError(f"camera {model.key}: unknown background {model.background!r}")
        return GelSightRendererModel(None, np.random.default_rng(seed), background=model.background)
    if renderer == "fingervision":
        world = load_scene("fingervision_rest", clock=clock, seed=seed).world
        return world.require("fingervision", "the FingerVision renderer")
    raise ValueError(f"unknown renderer {renderer!r}; expected one of {', '.join(RENDERERS)}")


def build_camera(model: CameraModel, *, renderer: str = "gelsight", video: str | Path | None = None,
                 scene: str | None = None, seed: int = 0, clock: Any = None, name: str | None = None) -> SimulatedCamera:
    """A :class:`SimulatedCamera` with ``model``'s controls, modes and optics, seeing ``video`` (a
    recorded file) or ``renderer``'s view (of ``scene`` when given, else of an empty world: the gel
    at rest)."""
    source: Any = VideoFile(video) if video is not None else _scene_renderer(model, renderer, scene, seed, clock)
    fmt = model.formats[0]
    frame = fmt.frames[fmt.default_frame]
    modes = model.modes()
    return SimulatedCamera(source, clock=clock, name=name or model.key, fourcc=fmt.fourcc, width=frame.width_px,
                           height=frame.height_px, fps=modes[(fmt.fourcc, frame.width_px, frame.height_px)],
                           modes=modes, controls=model.controls, seed=seed, optics=sensor_optics(model),
                           auto_drift=True)
