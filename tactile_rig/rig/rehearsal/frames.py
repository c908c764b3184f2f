"""Recorded camera footage as a camera sees it: a video file or an MCAP recording's image topic, decoded
with OpenCV, played back at its recorded rate (looping), as a ``render(t_s) -> BGR`` function for a
:class:`~tactile_rig.mocks.camera.SimulatedCamera`.

A source is written ``FILE`` (any video OpenCV's FFmpeg backend decodes: .mp4, .avi, .mkv, an image
sequence ``frames/%04d.png``), ``FOLDER`` (its images in name order, at ``DEFAULT_FPS``) or
``FILE.mcap[#TOPIC]`` (a ``foxglove.CompressedImage`` or ``foxglove.RawImage`` topic; default: the
first image topic of the file).

:func:`write_fingervision_footage` makes a video for a rehearsal that has no footage of its own: the
FingerVision renderer pressing and shearing the skin, written as MJPG AVI and then decoded back like
any other footage.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import math

import cv2
import numpy as np

from tactile_rig.rig.files import read_image
from tactile_rig.rig.recording import read_recording
from tactile_rig.sim.render.fingervision import FingerVisionRenderer, contact_shear_field

DEFAULT_FPS = 25.0  # a video whose container states no rate (an image sequence) plays at this
MAX_FRAMES = 3000  # footage is held decoded in memory: two minutes at 25 fps is plenty for a rehearsal


@dataclass
class Footage:
    """Decoded frames and when each is shown (s from the start); ``period_s`` is the loop length."""

    frames: list[np.ndarray]
    times_s: np.ndarray
    period_s: float
    source: str

    @property
    def fps(self) -> float:
        """The recorded frame rate (frames per second)."""
        return len(self.frames) / self.period_s

    @property
    def size_px(self) -> tuple[int, int]:
        """(width, height) of the frames."""
        h, w = self.frames[0].shape[:2]
        return int(w), int(h)

    def render(self, t_s: float) -> np.ndarray:
        """The frame on screen at ``t_s`` (the footage loops)."""
        k = int(np.searchsorted(self.times_s, float(t_s) % self.period_s, side="right")) - 1
        return self.frames[max(0, k)]


def load_footage(source: str) -> Footage:
    """Decode ``source`` (see the module doc); ValueError naming the file when it holds no frames."""
    path, _, topic = source.partition("#")
    if path.endswith(".mcap"):
        return _from_mcap(Path(path), topic or None, source)
    if Path(path).is_dir():
        return _from_folder(Path(path), source)
    if "%" not in path and not Path(path).is_file():
        raise FileNotFoundError(f"camera footage {path!r} does not exist (expected a video file or a .mcap)")
    cap = cv2.VideoCapture(path)
    try:
        if not cap.isOpened():
            raise ValueError(f"camera footage {path!r}: OpenCV cannot decode it (expected a video such as "
                             ".mp4/.avi or an image sequence)")
        fps = float(cap.get(cv2.CAP_PROP_FPS)) or DEFAULT_FPS
        if not 0 < fps <= 1000:
            fps = DEFAULT_FPS
        frames: list[np.ndarray] = []
        while len(frames) < MAX_FRAMES:
            ok, img = cap.read()
            if not ok or img is None:
                break
            frames.append(_bgr(img))
    finally:
        cap.release()
    if not frames:
        raise ValueError(f"camera footage {path!r} has no frames")
    times = np.arange(len(frames)) / fps
    return Footage(frames, times, len(frames) / fps, source)


def _from_mcap(path: Path, topic: str | None, source: str) -> Footage:
    rec = read_recording(path)
    images = [m for m in rec.messages if m.schema in ("foxglove.CompressedImage", "foxglove.RawImage")]
    topics = sorted({m.topic for m in images})
    if topic is not None:
        images = [m for m in images if m.topic == topic]
    elif topics:
        images = [m for m in images if m.topic == topics[0]]
    if not images:
        raise ValueError(f"{path}: no image messages{f' on {topic!r}' if topic else ''}; image topics: "
                         f"{', '.join(topics) or '(none)'}")
    frames = [_bgr(m.image()) for m in images[:MAX_FRAMES]]
    t = np.array([m.log_time_ns for m in images[:MAX_FRAMES]], dtype=np.float64) / 1e9
    t -= t[0]
    # The loop lasts one mean frame interval beyond the last frame, so the last frame is shown too.
    step = float(t[-1] / (len(t) - 1)) if len(t) > 1 and t[-1] > 0 else 1.0 / DEFAULT_FPS
    return Footage(frames, t, float(t[-1]) + step, source)


_IMAGE_EXT = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff")


def _from_folder(folder: Path, source: str) -> Footage:
    files = sorted(p for p in folder.iterdir() if p.suffix.lower() in _IMAGE_EXT)[:MAX_FRAMES]
    frames = []
    for f in files:
        frames.append(read_image(f, "camera footage frame"))
    if not frames:
        raise ValueError(f"camera footage folder {folder} holds no images ({', '.join(_IMAGE_EXT)})")
    if len({f.shape for f in frames}) != 1:
        raise ValueError(f"camera footage folder {folder}: the images differ in size; expected one camera's frames")
    return Footage(frames, np.arange(len(frames)) / DEFAULT_FPS, len(frames) / DEFAULT_FPS, source)


def write_fingervision_footage(path: str | Path, *, seconds: float = 8.0, fps: float = 25.0, seed: int = 0) -> Path:
    """A FingerVision video (MJPG AVI, 320x240): 1 s at rest (the baseline), then presses that shear and
    twist the skin, once every 2 s. Returns ``path``."""
    if not (0 < seconds <= 120 and 0 < fps <= 120):
        raise ValueError(f"seconds={seconds!r} must be in (0, 120] and fps={fps!r} in (0, 120]")
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    renderer = FingerVisionRenderer((240, 320), seed=seed)
    writer = cv2.VideoWriter(str(out), cv2.VideoWriter.fourcc(*"MJPG"), float(fps), (320, 240))
    if not writer.isOpened():
        raise OSError(f"OpenCV cannot write an MJPG video to {out}")
    try:
        for k in range(int(round(seconds * fps))):
            t = k / fps
            press = 0.0 if t < 1.0 else max(0.0, math.sin(math.pi * (t - 1.0) / 2.0)) ** 2
            shift = contact_shear_field(renderer.rest_px, (160.0, 120.0), shift_px=(6.0 * press, 3.0 * press),
                                        twist_deg=4.0 * press, radius_px=90.0)
            img, _ = renderer.render(shift, normal_load=press)
            writer.write(img)
    finally:
        writer.release()
    return out


def _bgr(img: np.ndarray) -> np.ndarray:
    if img.ndim == 2:
        return cv2.cvtColor(img, cv2.COLOR_GRAY2BGR)
    if img.shape[2] == 4:
        return cv2.cvtColor(img, cv2.COLOR_BGRA2BGR)
    return np.ascontiguousarray(img)
