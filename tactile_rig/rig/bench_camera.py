"""Camera workflows on a bench: list the cameras, open one, grab frames, measure its frame rate."""

from __future__ import annotations

import glob
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2

from tactile_rig.core.errors import BenchError
from tactile_rig.rig.bench import Bench, Rig, connect_bench


def camera_name(bench: Bench, name: str | None, sensor: str | None = None) -> str:
    """The bench camera ``name`` (default: the first, of ``sensor`` when given); BenchError listing them."""
    cams = {k: c for k, c in bench.cameras.items() if sensor is None or c.sensor == sensor}
    if name is None:
        if not cams:
            what = f"{sensor} camera" if sensor else "camera"
            raise BenchError(bench.source, [(None, f"the bench has no {what} ([camera] or [camera_<name>] "
                                                   f"with sensor = \"{sensor or 'gelsight'}\")")])
        return next(iter(cams))
    if name not in bench.cameras:
        raise BenchError(bench.source, [(None, f"no camera '{name}'; the bench's cameras: "
                                               f"{', '.join(bench.cameras) or '(none)'}")])
    return name


def open_camera(bench: Bench, name: str) -> Rig:
    """Connect camera ``name`` alone; the driver is ``rig[name]`` (close the rig when done)."""
    sub = Bench(name=bench.name, devices={name: bench.devices[name]}, source=bench.source, path=bench.path,
                text=bench.text, scene=bench.scene, seed=bench.seed)
    return connect_bench(sub)


def describe_camera(cam: Any, cfg: Any, *, frames: int = 10) -> dict[str, Any]:
    """What an open bench camera is, as configured from its bench table (and model) and as found:
    the model, the format it runs, each locked control as written and as read back now, the vendor
    SDK view applied to its frames, and ``frames`` frames read (their shape, the measured rate)."""
    locked = cam.config.locked_controls()
    readback = cam.read_controls(list(locked))
    frame = None
    for _ in range(int(frames)):
        frame = cam.read(timeout_s=max(2.0, 4.0 / float(cam.config.fps)))
    view = cam.config.view
    model = getattr(cfg, "camera_model", None)
    return {"model": model.key if model is not None else None, "title": model.title if model is not None else None,
            "format": list(cam.format), "locked": locked, "controls": readback,
            "mains_hz": getattr(cfg, "mains_hz", None),
            "view": (f"{view.name}: {view.source}" if view is not None else None),
            "frame_shape": list(frame.image.shape) if frame is not None else None,
            "frames": cam.stats.frames, "measured_fps": round(cam.stats.measured_fps, 2)}


def video_devices() -> list[dict[str, Any]]:
    """V4L2 capture nodes of this machine with their stable links (by-id, by-path)."""
    links: dict[str, list[str]] = {}
    for link in sorted(glob.glob("/dev/v4l/by-id/*") + glob.glob("/dev/v4l/by-path/*")):
        links.setdefault(os.path.realpath(link), []).append(link)
    return [{"device": dev, "links": links.get(dev, [])} for dev in sorted(glob.glob("/dev/video*"))]


@dataclass
class FpsMeasurement:
    """Frames over a window: rate from the host arrival times and from the device counter (fps),
    duplicates and frames the device counter says were skipped."""

    camera: str
    configured_fps: float
    frames: int
    duration_s: float
    host_fps: float
    device_fps: float | None
    duplicates: int
    dropped: int
    max_gap_s: float


def measure_fps(cam: Any, duration_s: float, *, name: str = "camera") -> FpsMeasurement:
    """Read every frame for ``duration_s`` (after one warm-up frame) and measure the rate."""
    if not duration_s > 0:
        raise ValueError(f"duration_s={duration_s!r} must be > 0 s")
    period = 1.0 / float(cam.config.fps)
    first = cam.read(timeout_s=max(2.0, 4 * period))
    dup0, drop0 = cam.stats.duplicates, cam.stats.dropped
    times, dev_t = [first.t_host_s], [first.t_device_s]
    while times[-1] - times[0] < duration_s:
        fr = cam.read(timeout_s=max(2.0, 4 * period))
        times.append(fr.t_host_s)
        dev_t.append(fr.t_device_s)
    span = times[-1] - times[0]
    dev_span = (dev_t[-1] - dev_t[0]) if dev_t[0] is not None and dev_t[-1] is not None else None
    gaps = [b - a for a, b in zip(times, times[1:])]
    return FpsMeasurement(name, float(cam.config.fps), len(times) - 1, round(span, 4),
                          round((len(times) - 1) / span, 3) if span > 0 else 0.0,
                          round((len(dev_t) - 1) / dev_span, 3) if dev_span else None,
                          cam.stats.duplicates - dup0, cam.stats.dropped - drop0, round(max(gaps), 4))


def grab_frames(cam: Any, count: int, out_dir: str | Path, *, name: str = "camera") -> list[Path]:
    """Save the next ``count`` frames as PNG files ``<name>-<seq>.png`` in ``out_dir``."""
    if count < 1:
        raise ValueError(f"count={count!r} must be >= 1")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = []
    for _ in range(int(count)):
        fr = cam.read(timeout_s=max(2.0, 4.0 / float(cam.config.fps)))
        p = out / f"{name}-{fr.seq:06d}.png"
        if not cv2.imwrite(str(p), fr.image):
            raise OSError(f"could not write {p}")
        paths.append(p)
    return paths
