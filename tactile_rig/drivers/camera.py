"""Fingertip camera driver: format, locked and read-back controls, newest-frame capture, watchdog.

The seam is a :class:`FrameSource` (open / set_format / set_control / get_control / read /
close). :class:`OpenCVSource` is the hardware path (``cv2.VideoCapture(path, cv2.CAP_V4L2)``);
:class:`tactile_rig.mocks.camera.SimulatedCamera` renders frames from a scene. The
:class:`FingertipCamera` works on either:

- FOURCC is set before size and fps (a FOURCC change re-initialises the V4L2 stream and many UVC
  cameras reset their controls), then controls are written auto-switches first and **read back**;
  a value the camera did not take raises :class:`ControlReadbackError`.
- Capture keeps only the newest frame. With a real clock a thread captures (OpenCV's V4L2
  ``read()`` has no timeout, so only a thread lets :meth:`FingertipCamera.read` time out); with a
  virtual clock the caller's thread pulls frames, so tests are deterministic and never sleep.
- Each :class:`Frame` carries a sequence number, host monotonic time, device time, and a
  ``duplicate`` flag (same content or same device timestamp as the previous frame). A run of
  identical frames raises :class:`FrozenStream`; no frame within the timeout raises
  :class:`~tactile_rig.core.errors.DeviceTimeout`.
- A vanished device is reopened with exponential backoff (:class:`ReopenPolicy`), reconfigured and
  re-verified; the frames are always BGR (:attr:`FrameSource.channel_order` says what the source
  gives, so an RGB source is converted once, here, and nowhere else).
"""

from __future__ import annotations

import dataclasses
import logging
import threading
import zlib
from collections import deque
from dataclasses import dataclass, field
from typing import Any, Callable, Protocol, runtime_checkable

import numpy as np

from tactile_rig.core.clock import Clock, Deadline, RealClock
from tactile_rig.core.errors import (
    ControlReadbackError,
    DeviceTimeout,
    FrozenStream,
    NotConnected,
    RigError,
)
from tactile_rig.core.types import RawFrame
from tactile_rig.drivers.base import Driver, Lifecycle
from tactile_rig.drivers.camera_http import HttpCameraSource, is_http_camera
from tactile_rig.devices.camera import (
    AUTO_SWITCHES,
    PHOTOMETRIC_CONTROLS,
    canonical_control,
    fourcc_text,
)

log = logging.getLogger("tactile_rig.camera")

__all__ = [
    "Frame",
    "RawFrame",
    "FrameSource",
    "CameraConfig",
    "ReopenPolicy",
    "CameraStats",
    "FingertipCamera",
    "OpenCVSource",
    "ControlReadbackError",
    "FrozenStream",
    "PHOTOMETRIC_CONTROLS",
    "canonical_control",
]

@dataclass(frozen=True)
class Frame:
    """A captured frame: ``image`` is BGR uint8; ``seq`` counts frames this driver accepted."""

    image: np.ndarray
    seq: int
    t_host_s: float
    t_device_s: float | None
    device_seq: int | None = None
    duplicate: bool = False


@runtime_checkable
class FrameSource(Protocol):
    """A camera backend. ``read`` returns None when no frame came within ``timeout_s`` (a backend
    that cannot time out may block) and raises :class:`NotConnected` when the device is gone."""

    name: str
    channel_order: str  # "BGR" or "RGB"

    def open(self) -> None: ...

    def close(self) -> None: ...

    @property
    def is_open(self) -> bool: ...

    def set_format(self, fourcc: str, width: int, height: int, fps: float) -> tuple[str, int, int, float]: ...

    def set_control(self, name: str, value: float) -> bool: ...

    def get_control(self, name: str) -> float | None: ...

    def read(self, timeout_s: float | None) -> RawFrame | None: ...


@dataclass(frozen=True)
class ReopenPolicy:
    """Reopen a vanished camera up to ``max_attempts`` times, waiting ``initial_backoff_s`` × ``factor``^k
    (capped at ``max_backoff_s``) before attempt k."""

    max_attempts: int = 5
    initial_backoff_s: float = 0.2
    factor: float = 2.0
    max_backoff_s: float = 5.0

    def delays_s(self) -> list[float]:
        return [min(self.max_backoff_s, self.initial_backoff_s * self.factor**k) for k in range(self.max_attempts)]


@dataclass
class CameraConfig:
    """Format and controls. ``controls`` are written in order, auto switches first."""

    fourcc: str = "MJPG"
    width: int = 640
    height: int = 480
    fps: float = 30.0
    controls: dict[str, float] = field(default_factory=lambda: dict(PHOTOMETRIC_CONTROLS))
    readback_tolerance: float = 0.5
    warmup_frames: int = 2  # discarded after (re)configuration: the first frames use old settings
    frozen_after: int = 15  # this many identical frames in a row mean the stream is frozen
    reopen: ReopenPolicy = field(default_factory=ReopenPolicy)

    def __post_init__(self) -> None:
        if len(self.fourcc) != 4:
            raise ValueError(f"fourcc={self.fourcc!r} must be 4 characters, e.g. 'MJPG' or 'YUYV'")
        if not (self.width > 0 and self.height > 0):
            raise ValueError(f"size {self.width}x{self.height} must be positive")
        if not (0 < self.fps <= 1000):
            raise ValueError(f"fps={self.fps!r} must be in (0, 1000]")
        if self.frozen_after < 2:
            raise ValueError(f"frozen_after={self.frozen_after!r} must be >= 2")


@dataclass
class CameraStats:
    """Counters since open: frames accepted, duplicates, device frames skipped, reopenings, fps."""

    frames: int = 0
    duplicates: int = 0
    dropped: int = 0
    reopens: int = 0
    timeouts: int = 0
    measured_fps: float = 0.0
    frozen: bool = False


class FingertipCamera(Driver):
    """A fingertip camera on any :class:`FrameSource`; see the module doc for the behaviour."""

    def __init__(self, source: FrameSource | str | int, config: CameraConfig | None = None, *,
                 clock: Clock | None = None, threaded: bool | None = None, name: str | None = None,
                 fourcc: str | None = None, width: int | None = None, height: int | None = None,
                 fps: float | None = None, controls: dict[str, float] | None = None) -> None:
        """``source`` is a :class:`FrameSource`, a V4L2 path/index opened through :class:`OpenCVSource`, or
        an ``http://`` MJPEG stream URL (:class:`~tactile_rig.drivers.camera_http.HttpCameraSource`).
        ``fourcc``, ``width``, ``height``, ``fps``, ``controls`` override fields of ``config``."""
        if is_http_camera(source):
            source = HttpCameraSource(str(source), name=name)
        elif isinstance(source, (str, int)):
            source = OpenCVSource(source)
        self.source = source
        native = getattr(source, "native_format", None)
        if config is None and callable(native):
            # A source with a format of its own (a recording) is opened in it unless told otherwise.
            nw, nh, nfps = native()
            width, height, fps = width or nw, height or nh, fps or nfps
        config = config or CameraConfig()
        overrides: dict[str, Any] = {k: v for k, v in (("fourcc", fourcc), ("width", width), ("height", height),
                                                       ("fps", fps), ("controls", controls)) if v is not None}
        if overrides:
            config = dataclasses.replace(config, **overrides)
        self.config = config
        self.clock: Clock = clock or RealClock()
        self.threaded = (not self.clock.is_virtual) if threaded is None else bool(threaded)
        self.name = name or f"camera@{getattr(source, 'name', source)}"
        super().__init__(self.name)
        self.lifecycle = Lifecycle.CLOSED  # until open()
        self.format: tuple[str, int, int, float] | None = None
        self.stats = CameraStats()
        self._cond = threading.Condition()
        self._latest: Frame | None = None
        self._last_read_seq = -1
        self._last_crc: int | None = None
        self._last_t_dev: float | None = None
        self._last_dev_seq: int | None = None
        self._same_run = 0
        self._t_hist: deque[float] = deque(maxlen=30)
        self._error: BaseException | None = None
        self._thread: threading.Thread | None = None
        self._listeners: list[Callable[[Frame], None]] = []
        self._running = False
        self._discard = 0

    # -- lifecycle --------------------------------------------------------------------------
    def open(self) -> FingertipCamera:
        """Open the source, set the format, lock and verify the controls, start capture."""
        self._open_and_configure()
        self.lifecycle = Lifecycle.CONNECTED
        if self.threaded:
            self._running = True
            self._thread = threading.Thread(target=self._capture_loop, name=f"{self.name}-capture", daemon=True)
            self._thread.start()
        return self

    def close(self) -> None:
        """Stop capture and close the source (safe to call twice, and before open())."""
        self._running = False
        with self._cond:
            self._cond.notify_all()
        try:
            self.source.close()  # a source ends or waits out a read in progress (OpenCV's: its select() timeout)
        finally:
            if self._thread is not None:
                self._thread.join(timeout=2.0)
                self._thread = None
            self.lifecycle = Lifecycle.CLOSED

    def __enter__(self) -> FingertipCamera:
        return self.open()

    def _open_and_configure(self) -> None:
        self.source.open()
        try:
            self._configure()
        except BaseException:
            self.source.close()  # a half-configured camera must not stay open
            raise

    def _configure(self) -> None:
        cfg = self.config
        got = self.source.set_format(cfg.fourcc, cfg.width, cfg.height, cfg.fps)
        want = (cfg.fourcc, cfg.width, cfg.height)
        if (got[0], int(got[1]), int(got[2])) != want:
            raise ControlReadbackError(f"format {want[0]} {want[1]}x{want[2]} was not accepted; the camera runs "
                                       f"{got[0]} {got[1]}x{got[2]}", device=self.name)
        if abs(float(got[3]) - cfg.fps) > 0.5:
            raise ControlReadbackError(f"fps {cfg.fps} was not accepted; the camera runs {got[3]}", device=self.name)
        self.format = (got[0], int(got[1]), int(got[2]), float(got[3]))
        self.apply_controls(cfg.controls)
        # The first frames after a change may still use the old settings; they are dropped by the
        # capture path (not read here: an OpenCV read could block open() forever).
        self._discard = cfg.warmup_frames

    def apply_controls(self, controls: dict[str, float]) -> dict[str, float]:
        """Write ``controls`` (auto switches first), read each back; raise listing every mismatch."""
        items = [(canonical_control(k), float(v)) for k, v in controls.items()]
        items.sort(key=lambda kv: 0 if kv[0] in AUTO_SWITCHES else 1)
        problems: list[str] = []
        readback: dict[str, float] = {}
        for name, value in items:
            accepted = self.source.set_control(name, value)
            got = self.source.get_control(name)
            if got is not None:  # a control that reads back nothing is a problem below
                readback[name] = got
            if not accepted:
                problems.append(f"{name}={value:g} was refused")
            elif got is None or abs(got - value) > self.config.readback_tolerance:
                problems.append(f"{name}={value:g} reads back as {got}")
        if problems:
            raise ControlReadbackError("camera ignored locked controls: " + "; ".join(problems) +
                                       " (expected every value to read back as written)", device=self.name)
        return readback

    # -- capture ----------------------------------------------------------------------------
    def _accept(self, raw: RawFrame) -> Frame:
        img = raw.image
        order = getattr(self.source, "channel_order", "BGR")
        if order == "RGB":
            img = np.ascontiguousarray(img[..., ::-1])
        elif order != "BGR":
            raise ValueError(f"{self.name}: channel_order={order!r}; expected 'BGR' or 'RGB'")
        crc = zlib.crc32(np.ascontiguousarray(img).data)
        same_content = crc == self._last_crc
        same_time = raw.t_device_s is not None and raw.t_device_s == self._last_t_dev
        duplicate = same_content or same_time
        self._same_run = self._same_run + 1 if same_content else 0
        if raw.device_seq is not None and self._last_dev_seq is not None and raw.device_seq > self._last_dev_seq + 1:
            self.stats.dropped += raw.device_seq - self._last_dev_seq - 1
        self._last_crc, self._last_t_dev, self._last_dev_seq = crc, raw.t_device_s, raw.device_seq
        t_host = self.clock.now_s()
        with self._cond:
            seq = self.stats.frames
            frame = Frame(img, seq, t_host, raw.t_device_s, raw.device_seq, duplicate)
            self.stats.frames += 1
            self.stats.duplicates += int(duplicate)
            self.stats.frozen = self._same_run + 1 >= self.config.frozen_after
            if not duplicate:
                self._t_hist.append(t_host)
            if len(self._t_hist) >= 2 and self._t_hist[-1] > self._t_hist[0]:
                self.stats.measured_fps = (len(self._t_hist) - 1) / (self._t_hist[-1] - self._t_hist[0])
            self._latest = frame
            self._cond.notify_all()
            listeners = list(self._listeners)
        for fn in listeners:
            fn(frame)
        return frame

    def add_listener(self, fn: Callable[[Frame], None]) -> None:
        """Call ``fn(frame)`` with every frame captured from now on, in the capturing thread (keep it
        short, e.g. put the frame on a queue): a recorder that must not miss a frame while it is
        busy, where :meth:`read` gives only the newest."""
        with self._cond:
            self._listeners.append(fn)

    def remove_listener(self, fn: Callable[[Frame], None]) -> None:
        with self._cond:
            if fn in self._listeners:
                self._listeners.remove(fn)

    def _pump(self, timeout_s: float | None) -> bool:
        """Capture one frame (reopening a vanished device); False if none came in time."""
        try:
            raw = self.source.read(timeout_s)
        except (NotConnected, OSError) as exc:
            if self.threaded and not self._running:
                return False  # close() released the source under this read: not a lost device
            self._reopen(exc)
            return False
        if raw is None:
            return False
        if self._discard > 0:
            self._discard -= 1
        else:
            self._accept(raw)
        return True

    def _reopen(self, cause: BaseException) -> None:
        log.warning("%s: lost (%s); reopening", self.name, cause)
        try:
            self.source.close()
        except Exception:  # noqa: BLE001  (a dead device may fail to close; reopening is what matters)
            pass
        last: BaseException = cause
        for delay in self.config.reopen.delays_s():
            if self.threaded and not self._running:
                return
            self.clock.sleep(delay)
            try:
                self._open_and_configure()
            except (NotConnected, OSError) as exc:
                last = exc
                continue
            self.stats.reopens += 1
            # A new stream: its device clock and counter start afresh.
            self._last_crc, self._last_t_dev, self._last_dev_seq, self._same_run = None, None, None, 0
            return
        err = NotConnected(f"gone and not back after {self.config.reopen.max_attempts} reopen attempts: {last}",
                           device=self.name)
        with self._cond:
            self._error = err
            self._cond.notify_all()
        raise err

    def _capture_loop(self) -> None:
        watchdog_s = max(0.5, 4.0 / self.config.fps)
        while self._running:
            try:
                if not self._pump(watchdog_s):
                    self.stats.timeouts += 1
            except RigError as exc:  # gave up reopening, or the replugged camera refused its controls
                with self._cond:
                    self._error = self._error or exc
                    self._cond.notify_all()
                return
            except Exception as exc:  # noqa: BLE001  (surface any backend failure to the reader)
                with self._cond:
                    self._error = NotConnected(f"capture failed: {exc!r}", device=self.name)
                    self._cond.notify_all()
                return

    def read(self, timeout_s: float = 1.0) -> Frame:
        """The next frame newer than the last one returned; raises DeviceTimeout, FrozenStream, NotConnected."""
        deadline = Deadline(self.clock, timeout_s)
        while True:
            with self._cond:
                if self._error is not None:
                    raise self._error
                fr = self._latest
                if fr is not None and fr.seq > self._last_read_seq:
                    self._last_read_seq = fr.seq  # consumed, even if it is reported as frozen
                    if self.stats.frozen:
                        raise FrozenStream(f"stream frozen: the last {self._same_run + 1} frames are identical "
                                           f"(expected changing frames)", device=self.name)
                    return fr
                remaining = deadline.remaining_s()
                if remaining is not None and remaining <= 0:
                    self.stats.timeouts += 1
                    raise DeviceTimeout(f"no new frame within {timeout_s} s (configured {self.config.fps} fps)",
                                        device=self.name)
                if self.threaded and not self.clock.is_virtual:
                    self._cond.wait(timeout=remaining)
                    continue
            if self.threaded:  # a thread captures on a virtual clock: let time pass in small steps
                step = 0.25 / self.config.fps
                self.clock.sleep(step if remaining is None else min(remaining, step))
            else:
                self._pump(remaining)

    def read_latest(self, max_age_s: float) -> Frame:
        """The newest frame if younger than ``max_age_s`` (it may have been returned before)."""
        if not self.threaded:
            self._pump(0.0)
        with self._cond:
            fr = self._latest
        if fr is None or self.clock.now_s() - fr.t_host_s > max_age_s:
            age = None if fr is None else self.clock.now_s() - fr.t_host_s
            raise DeviceTimeout(f"newest frame is stale (age {age} s > {max_age_s} s)", device=self.name)
        return fr


# ------------------------------------------------------------------------------------------
# OpenCV V4L2 backend


def _cv2() -> Any:
    import cv2

    return cv2


def _control_props() -> dict[str, int]:
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
        "sharpness": cv2.CAP_PROP_SHARPNESS,
        "backlight_compensation": cv2.CAP_PROP_BACKLIGHT,
        "focus_automatic_continuous": cv2.CAP_PROP_AUTOFOCUS,
    }


def fourcc_code(fourcc: str) -> int:
    return int(_cv2().VideoWriter_fourcc(*fourcc))


class OpenCVSource:
    """A V4L2 camera through ``cv2.VideoCapture(device, cv2.CAP_V4L2)``.

    ``device`` is a stable path (``/dev/v4l/by-id/...-video-index0``) or an index. ``capture_factory``
    replaces ``cv2.VideoCapture`` (tests pass a fake). ``read`` cannot time out (the V4L2 backend
    has no read timeout): the driver's capture thread owns that. After ``fail_limit`` failed reads
    in a row the device counts as gone.
    """

    channel_order = "BGR"  # OpenCV converts YUYV/MJPG to BGR (CAP_PROP_CONVERT_RGB is on by default)

    def __init__(self, device: str | int, *, capture_factory: Any = None, buffer_size: int = 1,
                 fail_limit: int = 3, name: str | None = None) -> None:
        self.device = device
        self.name = name or str(device)
        self._factory = capture_factory
        self.buffer_size = int(buffer_size)
        self.fail_limit = int(fail_limit)
        self._cap: Any = None
        self._fails = 0
        self._seq = 0
        # One call into the capture at a time: cv2.VideoCapture is not thread-safe, and release()
        # while another thread's read() waits in select() frees the buffers that read fills (SIGSEGV).
        self._io = threading.Lock()

    @property
    def is_open(self) -> bool:
        return self._cap is not None and bool(self._cap.isOpened())

    def open(self) -> None:
        cv2 = _cv2()
        factory = self._factory or cv2.VideoCapture
        cap = factory(self.device, cv2.CAP_V4L2)
        if not cap.isOpened():
            cap.release()
            raise NotConnected(f"cannot open video device {self.device!r} with CAP_V4L2 (absent, busy, or no access)",
                               device=self.name)
        self._cap, self._fails = cap, 0

    def close(self) -> None:
        with self._io:  # after a read in progress returns (a frame, or the backend's select() timeout)
            if self._cap is not None:
                self._cap.release()
                self._cap = None

    def _need(self) -> Any:
        if self._cap is None:
            raise NotConnected("camera is not open", device=self.name)
        return self._cap

    def set_format(self, fourcc: str, width: int, height: int, fps: float) -> tuple[str, int, int, float]:
        cv2 = _cv2()
        with self._io:
            return self._set_format(self._need(), cv2, fourcc, width, height, fps)

    def _set_format(self, cap: Any, cv2: Any, fourcc: str, width: int, height: int,
                    fps: float) -> tuple[str, int, int, float]:
        cap.set(cv2.CAP_PROP_FOURCC, fourcc_code(fourcc))  # first: it re-initialises the stream
        cap.set(cv2.CAP_PROP_FRAME_WIDTH, int(width))
        cap.set(cv2.CAP_PROP_FRAME_HEIGHT, int(height))  # the pair is applied on the second call
        cap.set(cv2.CAP_PROP_FPS, float(fps))
        cap.set(cv2.CAP_PROP_BUFFERSIZE, self.buffer_size)
        return (fourcc_text(cap.get(cv2.CAP_PROP_FOURCC)), int(cap.get(cv2.CAP_PROP_FRAME_WIDTH)),
                int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT)), float(cap.get(cv2.CAP_PROP_FPS)))

    def set_control(self, name: str, value: float) -> bool:
        prop = _control_props().get(canonical_control(name))
        if prop is None:
            return False
        with self._io:
            return bool(self._need().set(prop, float(value)))

    def get_control(self, name: str) -> float | None:
        prop = _control_props().get(canonical_control(name))
        if prop is None:
            return None
        with self._io:
            v = float(self._need().get(prop))
        return None if v == -1.0 else v

    def read(self, timeout_s: float | None = None) -> RawFrame | None:
        with self._io:
            return self._read(self._need())

    def _read(self, cap: Any) -> RawFrame | None:
        ok, img = cap.read()
        if not ok or img is None:
            self._fails += 1
            if self._fails >= self.fail_limit or not cap.isOpened():
                raise NotConnected(f"{self._fails} failed reads in a row: device unplugged or stalled",
                                   device=self.name)
            return None
        self._fails = 0
        self._seq += 1
        t_ms = float(cap.get(_cv2().CAP_PROP_POS_MSEC))
        return RawFrame(img, t_ms / 1000.0 if t_ms > 0 else None, None)
