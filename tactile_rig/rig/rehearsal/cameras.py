"""A rehearsal camera: a UVC camera model (:mod:`tactile_rig.devices.camera_models`, a Logitech C310 by
default) seeing a scene or footage, served in its device process either as an emulated V4L2 device
(``/dev/videoN``, which OpenCV's own V4L2 backend streams from in any process started with the
emulation's library: :mod:`tactile_rig.mocks.v4l2`) or as MJPEG over HTTP
(:mod:`.camera_server`).

Both transports serve the same simulated sensor (:func:`rehearsal_camera`: the model's controls and
optics, the same read noise for a seed), so what differs between them is only how a frame travels.
"""

from __future__ import annotations

from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Iterator

from tactile_rig.devices.camera_models import CameraModel, fps_of_interval, uvc_size_distance
from tactile_rig.mocks.camera import SimulatedCamera
from tactile_rig.mocks.v4l2 import V4L2Camera
from tactile_rig.mocks.v4l2.frames import sensor_optics
from tactile_rig.rig.rehearsal.camera_server import CameraServer

TRANSPORTS = ("v4l2", "http")
DEFAULT_TRANSPORT = "v4l2"
DEFAULT_MODEL = "c310"
FOURCCS = ("MJPG", "YUYV")


def offered_rates(model: CameraModel, fourcc: str, width: int, height: int) -> list[float]:
    """The frame rates (frames/s, fastest first) ``model`` offers for that format and size; [] if none."""
    fmt = model.format(fourcc)
    frame = fmt.frame(width, height) if fmt is not None else None
    return [] if frame is None else [fps_of_interval(i) for i in frame.intervals_100ns]


def check_mode(model: CameraModel, fourcc: str, width: int, height: int, fps: float, *, what: str) -> None:
    """ValueError naming ``what`` when ``model`` does not offer ``fourcc`` ``width``x``height`` at ``fps``
    (a driver configuring it would have its format refused, as by the real camera)."""
    fmt = model.format(fourcc)
    if fmt is None:
        raise ValueError(f"{what}: a {model.title} offers {', '.join(f.fourcc for f in model.formats)}, "
                         f"not {fourcc}")
    rates = offered_rates(model, fourcc, width, height)
    if not rates:
        sizes = ", ".join(f"{f.width_px}x{f.height_px}" for f in fmt.frames)
        raise ValueError(f"{what}: a {model.title} offers {fourcc} at {sizes}, not {width}x{height}")
    if not any(abs(r - fps) < 1e-6 for r in rates):
        raise ValueError(f"{what}: a {model.title} offers {fourcc} {width}x{height} at "
                         f"{', '.join(f'{r:g}' for r in rates)} frames/s, not {fps:g}")


def footage_mode(model: CameraModel, fourcc: str, width: int, height: int, fps: float) -> tuple[int, int, float]:
    """The mode a camera of ``model`` shows footage of that size and rate in: the footage's size when
    the camera offers it, else the size uvcvideo would choose for it (the least area not shared);
    the offered rate closest to the footage's. The footage is resized onto the camera's frame and
    sampled at the camera's rate (it plays at its own recorded rate)."""
    fmt = model.format(fourcc)
    if fmt is None:
        raise ValueError(f"a {model.title} offers {', '.join(f.fourcc for f in model.formats)}, not {fourcc}")
    frame = fmt.frame(width, height) or min(
        fmt.frames, key=lambda f: uvc_size_distance(f.width_px, f.height_px, width, height))
    rates = [fps_of_interval(i) for i in frame.intervals_100ns]
    return frame.width_px, frame.height_px, min(rates, key=lambda r: (abs(r - fps), -r))


def rehearsal_camera(source: Callable[[float], Any] | Any, *, model: CameraModel, fourcc: str, width: int,
                     height: int, fps: float, transport: str, clock: Any, name: str, seed: int) -> SimulatedCamera:
    """The simulated sensor of a rehearsal camera: ``source`` (``render(t_s) -> BGR`` or a renderer
    model) through ``model``'s controls and optics. Over HTTP it offers exactly the served MJPG mode
    (an MJPEG stream has one format); over V4L2 the emulation offers the model's formats."""
    modes = {(fourcc, width, height): float(fps)} if transport == "http" else model.modes()
    return SimulatedCamera(source, clock=clock, name=name, fourcc=fourcc, width=width, height=height, fps=fps,
                           modes=modes, controls=model.controls, optics=sensor_optics(model), seed=seed)


@dataclass
class ServedCamera:
    """A camera being served: ``info`` is what its process prints (the port or URL, the format, and
    for V4L2 the node's links, registry, library and fault-control FIFO)."""

    info: dict[str, Any]
    server: Any

    @property
    def error(self) -> BaseException | None:
        return getattr(self.server, "error", None)


@contextmanager
def serve_camera(sim: SimulatedCamera, *, transport: str, model: CameraModel, fourcc: str, width: int, height: int,
                 fps: float, jpeg_quality: int, registry: str | Path | None = None, node: int | None = None,
                 serial: str | None = None) -> Iterator[ServedCamera]:
    """Serve ``sim`` as an emulated V4L2 device of ``model`` (node ``node`` of ``registry``, USB serial
    number ``serial``) or over HTTP."""
    fmt: dict[str, Any] = {"fourcc": fourcc, "width": width, "height": height, "fps": fps}
    if transport == "http":
        with CameraServer(sim, jpeg_quality=jpeg_quality) as http:
            yield ServedCamera({"transport": "http", "url": http.url, "port": http.url, "model": model.key, **fmt}, http)
        return
    if transport != "v4l2":
        raise ValueError(f"camera transport {transport!r} must be one of {', '.join(TRANSPORTS)}")
    with V4L2Camera(model, sim, registry=registry, node=node, serial=serial, jpeg_quality=jpeg_quality,
                    control_fifo=True) as cam:
        d = cam.describe()
        yield ServedCamera({"transport": "v4l2", "port": cam.port, "model": model.key, "card": d["card"],
                            "by_id": d["by_id"], "by_path": d["by_path"], "registry": d["registry"],
                            "library": str(cam.library), "control": d["control"], "env": cam.env, **fmt}, cam)

