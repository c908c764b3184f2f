"""The camera driver's seam: a :class:`FrameSource` gives raw frames and takes a format and controls.

Sources: :class:`~tactile_rig.drivers.camera_opencv.OpenCVSource` (the hardware path, OpenCV's V4L2
backend), :class:`~tactile_rig.drivers.camera_http.HttpCameraSource` (MJPEG over HTTP),
:class:`~tactile_rig.mocks.camera.SimulatedCamera` (in process, any clock) and
:class:`~tactile_rig.rig.replay.RecordedFrameSource` (a recording). The contract suite
(``tests/drivers/test_camera_source_contract.py``) runs one session on the simulated camera and on
OpenCVSource over an emulated C310 and checks both observe it the same way.
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

from tactile_rig.core.types import RawFrame

__all__ = ["FrameSource", "RawFrame"]


@runtime_checkable
class FrameSource(Protocol):
    """A camera backend.

    ``read`` returns the next frame, or None when none came within its wait: ``timeout_s`` where the
    source can honour it, the backend's own wait where it cannot (OpenCV's select timeout); it
    raises :class:`~tactile_rig.core.errors.NotConnected` when the device is gone or the source is
    closed. ``set_control`` returns whether the camera took the write (a value it clamps counts as
    taken: read it back); ``get_control`` gives None for a control the camera lacks.
    ``channel_order`` is ``"BGR"`` or ``"RGB"``: what ``read`` gives. A source may also say why a
    write was refused (``refusal(name) -> str | None``) and how long a read can block
    (``max_read_wait_s``)."""

    name: str
    channel_order: str

    def open(self) -> None: ...

    def close(self) -> None: ...

    @property
    def is_open(self) -> bool: ...

    def set_format(self, fourcc: str, width: int, height: int, fps: float) -> tuple[str, int, int, float]: ...

    def set_control(self, name: str, value: float) -> bool: ...

    def get_control(self, name: str) -> float | None: ...

    def read(self, timeout_s: float | None) -> RawFrame | None: ...
