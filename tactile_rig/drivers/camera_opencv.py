"""A V4L2 camera through OpenCV's own V4L2 backend (``cv2.VideoCapture(path, cv2.CAP_V4L2)``), the
:class:`~tactile_rig.drivers.camera_source.FrameSource` of the hardware path.

What the backend does (opencv-contrib-python-headless 5.0, ``modules/videoio/src/cap_v4l.cpp``; each
point is pinned by a test against the real backend on an emulated C310, listed in ``docs/cameras.md``):

- ``read()`` waits for a frame in ``select()`` for ``OPENCV_VIDEOIO_V4L_SELECT_TIMEOUT`` seconds
  (default 10) and then returns False; the same capture reads again once frames come back. The
  variable is read once per process, at the first wait of any capture, in whole seconds.
- After an unplug ``read()`` returns False at once (poll reports POLLERR) and for good, even once the
  camera is back; ``isOpened()`` stays True. A new capture on the path works again.
- A FOURCC change stops the stream, frees the buffers and sets the format again; uvcvideo keeps the
  controls. Width and height apply as a pair, on the second of the two calls.
- Controls are raw V4L2 values (``AUTO_EXPOSURE`` 1 manual, 3 aperture priority); ``set`` returns
  False for a control the camera lacks or refuses (inactive under its auto switch) and True for a
  value uvcvideo clamps or rounds, so every value is read back. There is no property for the power
  line frequency or ``exposure_dynamic_framerate``: those go through
  :class:`~tactile_rig.drivers.camera_v4l2.V4L2Controls` by their V4L2 ids.
- ``CAP_PROP_POS_MSEC`` is the buffer's timestamp (CLOCK_MONOTONIC, ms); the V4L2 sequence number is
  not passed on, so frames a camera dropped are not counted on this path.

This source bounds the backend's wait: before its first capture it sets
``OPENCV_VIDEOIO_V4L_SELECT_TIMEOUT`` to ``select_timeout_s`` (1 s) unless the environment already
holds a value. A capture thread then returns from a stalled read within that time, so closing or
reconfiguring the camera waits at most that long (releasing a capture while another thread is in its
``read()`` is not safe), and a stall longer than that shows as failed reads besides the consumer's
own deadline. One second is the shortest the variable allows (whole seconds; 0 would make every read
that finds no frame queued fail) and longer than a frame period of every mode a fingertip camera runs
(5 fps and up). The variable is per process: a process whose other captures need longer waits sets
it itself before the first capture.
"""

from __future__ import annotations

import errno
import logging
import os
import time
from typing import Any

from tactile_rig.core.errors import NotConnected
from tactile_rig.core.types import RawFrame
from tactile_rig.devices.camera import canonical_control, fourcc_text
from tactile_rig.drivers.camera_v4l2 import EXTRA_HINT, V4L2Controls, linuxpy_problem

__all__ = ["OpenCVSource", "SELECT_TIMEOUT_ENV", "backend_select_timeout_s", "fourcc_code", "opencv_control_props"]

log = logging.getLogger("tactile_rig.camera")

SELECT_TIMEOUT_ENV = "OPENCV_VIDEOIO_V4L_SELECT_TIMEOUT"
OPENCV_DEFAULT_SELECT_TIMEOUT_S = 10


def _cv2() -> Any:
    import cv2

    return cv2


def opencv_control_props() -> dict[str, int]:
    """Control name -> the ``CAP_PROP_*`` OpenCV's V4L2 backend maps onto it (the controls a
    fingertip camera has that the backend reaches)."""
    cv2 = _cv2()
    return {
        "auto_exposure": cv2.CAP_PROP_AUTO_EXPOSURE,
        "exposure_time_absolute": cv2.CAP_PROP_EXPOSURE,
        "white_balance_automatic": cv2.CAP_PROP_AUTO_WB,
        "white_balance_temperature": cv2.CAP_PROP_WB_TEMPERATURE,
        "gain": cv2.CAP_PROP_GAIN,
        "brightness": cv2.CAP_PROP_BRIGHTNESS,
        "contrast": cv2.CAP_PROP_CONTRAST,
        "saturation": cv2.CAP_PROP_SATURATION,
        "hue": cv2.CAP_PROP_HUE,
        "gamma": cv2.CAP_PROP_GAMMA,
        "sharpness": cv2.CAP_PROP_SHARPNESS,
        "backlight_compensation": cv2.CAP_PROP_BACKLIGHT,
        "zoom_absolute": cv2.CAP_PROP_ZOOM,
        "focus_automatic_continuous": cv2.CAP_PROP_AUTOFOCUS,
    }


def fourcc_code(fourcc: str) -> int:
    return int(_cv2().VideoWriter_fourcc(*fourcc))


def backend_select_timeout_s() -> float:
    """How long the backend's ``select()`` waits, as the environment says now (whole seconds)."""
    raw = os.environ.get(SELECT_TIMEOUT_ENV)
    if raw is None:
        return float(OPENCV_DEFAULT_SELECT_TIMEOUT_S)
    try:
        return float(max(0, int(raw.strip())))
    except ValueError:
        return float(OPENCV_DEFAULT_SELECT_TIMEOUT_S)


class OpenCVSource:
    """A V4L2 camera through ``cv2.VideoCapture(device, cv2.CAP_V4L2)`` (see the module doc).

    ``device`` is a stable path (``/dev/v4l/by-id/...-video-index0``) or an index. Controls OpenCV maps
    go through it; the others through a :class:`V4L2Controls` file of their own when linuxpy is
    installed (else they are refused, :meth:`refusal` says why). ``select_timeout_s`` bounds the
    backend's wait (None: leave ``OPENCV_VIDEOIO_V4L_SELECT_TIMEOUT`` alone). A failed read is a stall
    (``read`` returns None) or an unplug (NotConnected): the control file answers ENODEV once the
    device is gone; without it, ``fail_limit`` failed reads in a row that each came sooner than half
    the backend's wait count as an unplug.
    """

    channel_order = "BGR"  # OpenCV converts YUYV and MJPG to BGR (CAP_PROP_CONVERT_RGB is on by default)

    def __init__(self, device: str | int, *, buffer_size: int = 1, fail_limit: int = 3, name: str | None = None,
                 select_timeout_s: int | None = 1) -> None:
        if select_timeout_s is not None and not 1 <= int(select_timeout_s) <= 3600:
            raise ValueError(f"select_timeout_s={select_timeout_s!r} must be whole seconds in 1..3600 (or None)")
        self.device = device
        self.name = name or str(device)
        self.buffer_size = int(buffer_size)
        self.fail_limit = int(fail_limit)
        self.select_timeout_s = select_timeout_s
        self._cap: Any = None
        self._controls: V4L2Controls | None = None
        self._fails = 0
        self._refusals: dict[str, str] = {}

    @property
    def path(self) -> str:
        return self.device if isinstance(self.device, str) else f"/dev/video{int(self.device)}"

    @property
    def is_open(self) -> bool:
        return self._cap is not None and bool(self._cap.isOpened())

    @property
    def max_read_wait_s(self) -> float:
        """The longest a :meth:`read` can block: the backend's select timeout."""
        return backend_select_timeout_s()

    def open(self) -> None:
        if self.select_timeout_s is not None:
            os.environ.setdefault(SELECT_TIMEOUT_ENV, str(int(self.select_timeout_s)))
        cv2 = _cv2()
        cap = cv2.VideoCapture(self.device, cv2.CAP_V4L2)
        if not cap.isOpened():
            cap.release()
            raise NotConnected(f"cannot open video device {self.device!r} with CAP_V4L2 (absent, busy, or no access)",
                               device=self.name)
        self._cap, self._fails, self._refusals = cap, 0, {}
        if linuxpy_problem() is None:
            controls = V4L2Controls(self.path, name=self.name)
            try:
                controls.open()
            except NotConnected as exc:
                log.warning("%s: no control file (%s): controls OpenCV does not map are unavailable", self.name, exc)
            else:
                self._controls = controls

    def close(self) -> None:
        cap, self._cap = self._cap, None
        if cap is not None:
            cap.release()
        if self._controls is not None:
            self._controls.close()
            self._controls = None

    def _need(self) -> Any:
        if self._cap is None:
            raise NotConnected("camera is not open", device=self.name)
        return self._cap

    def set_format(self, fourcc: str, width: int, height: int, fps: float) -> tuple[str, int, int, float]:
        cv2 = _cv2()
        cap = self._need()
        cap.set(cv2.CAP_PROP_FOURCC, fourcc_code(fourcc))  # first: a FOURCC change sets the format again
        cap.set(cv2.CAP_PROP_FRAME_WIDTH, int(width))
        cap.set(cv2.CAP_PROP_FRAME_HEIGHT, int(height))  # the pair is applied on this second call
        cap.set(cv2.CAP_PROP_FPS, float(fps))
        cap.set(cv2.CAP_PROP_BUFFERSIZE, self.buffer_size)
        return (fourcc_text(cap.get(cv2.CAP_PROP_FOURCC)), int(cap.get(cv2.CAP_PROP_FRAME_WIDTH)),
                int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT)), float(cap.get(cv2.CAP_PROP_FPS)))

    def set_control(self, name: str, value: float) -> bool:
        name = canonical_control(name)
        cap = self._need()
        self._refusals.pop(name, None)
        prop = opencv_control_props().get(name)
        if prop is not None:
            ok = bool(cap.set(prop, float(value)))
            if not ok:
                why = "OpenCV's set() returned False"
                if self._controls is not None and self._controls.inactive(name):
                    why = "inactive: its auto switch is on"
                self._refusals[name] = why
            return ok
        if self._controls is None:
            self._refusals[name] = f"OpenCV has no property for it; {linuxpy_problem() or EXTRA_HINT}"
            return False
        err = self._controls.set(name, value)
        if err:
            self._refusals[name] = f"VIDIOC_S_CTRL: {errno.errorcode.get(err, str(err))}"
        return err == 0

    def get_control(self, name: str) -> float | None:
        name = canonical_control(name)
        cap = self._need()
        prop = opencv_control_props().get(name)
        if prop is not None:
            v = float(cap.get(prop))
            return None if v == -1.0 else v
        if self._controls is None:
            return None
        got = self._controls.get(name)
        return None if got is None else float(got)

    def refusal(self, name: str) -> str | None:
        """Why the last write of ``name`` was refused (None if it was not)."""
        return self._refusals.get(canonical_control(name))

    def read(self, timeout_s: float | None = None) -> RawFrame | None:
        """The next frame (BGR); None when the backend's wait ended without one (a stall; ``timeout_s``
        is not the bound: the backend's select timeout is); NotConnected once the device is gone."""
        cap = self._need()
        t0 = time.monotonic()
        ok, img = cap.read()
        if ok and img is not None:
            self._fails = 0
            t_ms = float(cap.get(_cv2().CAP_PROP_POS_MSEC))
            return RawFrame(img, t_ms / 1000.0 if t_ms > 0 else None, None)
        took = time.monotonic() - t0
        if self._controls is not None:
            if not self._controls.alive():
                raise NotConnected(f"{self.path} is gone (ENODEV): unplugged", device=self.name)
            return None
        self._fails = self._fails + 1 if took < 0.5 * self.max_read_wait_s else 0
        if self._fails >= self.fail_limit:
            raise NotConnected(f"{self._fails} reads in a row failed at once (not a select() timeout): "
                               f"device unplugged", device=self.name)
        return None
