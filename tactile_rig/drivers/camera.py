"""Fingertip camera driver: a format, locked and read-back controls, the newest frame, faults as typed errors.

:class:`FingertipCamera` works on any :class:`~tactile_rig.drivers.camera_source.FrameSource`: a V4L2
path or index (:class:`~tactile_rig.drivers.camera_opencv.OpenCVSource`, OpenCV's V4L2 backend), an
``http://`` MJPEG stream (:class:`~tactile_rig.drivers.camera_http.HttpCameraSource`), a simulated
camera or a recording. It is a :class:`~tactile_rig.drivers.base.PortDriver`: a vanished camera is
reopened with the base's backoff (:class:`~tactile_rig.drivers.reconnect.Reconnect`) and counted in
``stats.disconnects`` / ``stats.reconnects``.

- **Format, then controls.** FOURCC, then width and height, then the frame rate (a FOURCC change sets
  the format again), then the controls: auto switches first (a manual value is refused while its
  switch is on), each **read back**; a value the camera refused, clamped or ignored raises
  :class:`ControlReadbackError` listing every mismatch. The default lock is
  :data:`PHOTOMETRIC_CONTROLS` (manual exposure and white balance, ``exposure_dynamic_framerate``
  off) plus the power line frequency when ``mains_hz`` is given.
- **The newest frame.** Capture keeps only the newest frame (:class:`~.camera_frames.NewestFrame`);
  :meth:`FingertipCamera.read` returns the next one within its deadline or raises
  :class:`~tactile_rig.core.errors.DeviceTimeout`. With a real clock a capture thread reads the
  source, so a consumer's deadline holds whatever the source's own wait (OpenCV's ``read()`` waits up
  to its select timeout) and a slow consumer never works through a backlog; with a virtual clock the
  reader's thread pulls frames, so tests are deterministic and never sleep.
- **Stall.** No frame within the reader's deadline: DeviceTimeout (a stall shorter than OpenCV's
  select timeout shows only so; a longer one also as ``stats.source_timeouts``). The stream resumes by
  itself when frames come back.
- **Freeze.** ``Frame.duplicate`` flags a frame with the previous one's content or device timestamp;
  ``frozen_after`` identical frames in a row raise :class:`FrozenStream`.
- **Unplug.** The source reports the device gone (OpenCV: its reads fail at once while the capture
  stays "opened"; the control file answers ENODEV): the source is released and reads fail fast with
  NotConnected naming the port and the next attempt; when the backoff allows, the camera is reopened
  by its path, its format set and its controls locked and verified again (a replugged camera is back
  at its power-on values). A camera that comes back and refuses the lock raises ControlReadbackError.
- Frames are BGR, and when ``view`` names a vendor SDK's crop and resize, that SDK's view.
"""

from __future__ import annotations

import dataclasses
import logging
import threading
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any, Callable, Iterator

from tactile_rig.core.clock import Clock, Deadline, RealClock
from tactile_rig.core.deprecation import warn_renamed
from tactile_rig.core.errors import ControlReadbackError, DeviceTimeout, FrozenStream, NotConnected, RigError
from tactile_rig.core.types import RawFrame
from tactile_rig.devices.camera import (AUTO_SWITCHES, PHOTOMETRIC_CONTROLS, canonical_control, fourcc_text,
                                        power_line_control)
from tactile_rig.devices.camera_models import SdkView
from tactile_rig.drivers.base import Lifecycle, PortDriver, locked
from tactile_rig.drivers.camera_frames import CameraStats, Frame, NewestFrame
from tactile_rig.drivers.camera_http import HttpCameraSource, is_http_camera
from tactile_rig.drivers.camera_opencv import OpenCVSource
from tactile_rig.drivers.camera_source import FrameSource
from tactile_rig.drivers.reconnect import Reconnect

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
    "fourcc_text",
]


@dataclass(frozen=True)
class ReopenPolicy:
    """Deprecated: the backoff of a vanished camera is :class:`~tactile_rig.drivers.reconnect.Reconnect`
    (``FingertipCamera(reconnect_policy=...)``); a ``CameraConfig(reopen=...)`` still sets its waits
    (``max_attempts`` is not used: the camera is tried again for as long as it is away)."""

    max_attempts: int = 5
    initial_backoff_s: float = 0.2
    factor: float = 2.0
    max_backoff_s: float = 5.0


@dataclass
class CameraConfig:
    """Format and controls. ``controls`` are written auto switches first; ``mains_hz`` (50 or 60) adds
    the power line frequency to them; ``view`` is the vendor SDK's crop and resize applied to frames."""

    fourcc: str = "MJPG"
    width: int = 640
    height: int = 480
    fps: float = 30.0
    controls: dict[str, float] = field(default_factory=lambda: dict(PHOTOMETRIC_CONTROLS))
    mains_hz: float | None = None
    view: SdkView | None = None
    readback_tolerance: float = 0.5
    warmup_frames: int = 2  # discarded after (re)configuration: the first frames use old settings
    frozen_after: int = 15  # this many identical frames in a row mean the stream is frozen
    reopen: ReopenPolicy | None = None  # deprecated: FingertipCamera(reconnect_policy=...)

    def __post_init__(self) -> None:
        if len(self.fourcc) != 4:
            raise ValueError(f"fourcc={self.fourcc!r} must be 4 characters, e.g. 'MJPG' or 'YUYV'")
        if not (self.width > 0 and self.height > 0):
            raise ValueError(f"size {self.width}x{self.height} must be positive")
        if not (0 < self.fps <= 1000):
            raise ValueError(f"fps={self.fps!r} must be in (0, 1000]")
        if self.frozen_after < 2:
            raise ValueError(f"frozen_after={self.frozen_after!r} must be >= 2")
        if self.mains_hz is not None:
            power_line_control(self.mains_hz)  # ValueError naming mains_hz unless 50 or 60
        if self.reopen is not None:
            warn_renamed("CameraConfig(reopen=ReopenPolicy(...))", "FingertipCamera(reconnect_policy=Reconnect(...))")

    def locked_controls(self) -> dict[str, float]:
        """The controls to write and verify, in order: auto switches first, then the rest."""
        items = {canonical_control(k): float(v) for k, v in self.controls.items()}
        if self.mains_hz is not None:
            items.update(power_line_control(self.mains_hz))
        return dict(sorted(items.items(), key=lambda kv: 0 if kv[0] in AUTO_SWITCHES else 1))


class FingertipCamera(PortDriver):
    """A fingertip camera on any :class:`FrameSource`; see the module doc for the behaviour."""

    stats: CameraStats

    def __init__(self, source: FrameSource | str | int, config: CameraConfig | None = None, *,
                 clock: Clock | None = None, threaded: bool | None = None, name: str | None = None,
                 fourcc: str | None = None, width: int | None = None, height: int | None = None,
                 fps: float | None = None, controls: dict[str, float] | None = None, mains_hz: float | None = None,
                 view: SdkView | None = None, reconnect_policy: Reconnect | None = None) -> None:
        """``source`` is a :class:`FrameSource`, a V4L2 path or index (:class:`OpenCVSource`), or an
        ``http://`` MJPEG stream URL. ``fourcc`` ... ``view`` override fields of ``config``.
        ``reconnect_policy``: the backoff of a vanished camera (default: :class:`Reconnect` on ``clock``)."""
        if is_http_camera(source):
            source = HttpCameraSource(str(source), name=name)
        elif isinstance(source, (str, int)):
            source = OpenCVSource(source, name=name)
        native = getattr(source, "native_format", None)
        if config is None and callable(native):
            # A source with a format of its own (a recording) is opened in it unless told otherwise.
            nw, nh, nfps = native()
            width, height, fps = width or nw, height or nh, fps or nfps
        config = config or CameraConfig()
        overrides: dict[str, Any] = {k: v for k, v in (("fourcc", fourcc), ("width", width), ("height", height),
                                                       ("fps", fps), ("controls", controls), ("mains_hz", mains_hz),
                                                       ("view", view)) if v is not None}
        if overrides:
            config = dataclasses.replace(config, **overrides)
        self.source: FrameSource = source
        self.config = config
        self.clock: Clock = clock or RealClock()
        self.threaded = (not self.clock.is_virtual) if threaded is None else bool(threaded)
        self.name = name or f"camera@{getattr(source, 'name', source)}"
        # the path or URL reopened after an unplug, as the messages name it
        port = getattr(source, "path", None) or getattr(source, "url", None) or getattr(source, "name", source)
        super().__init__(self.name, reconnect_port=str(port), stats=CameraStats())
        self.lifecycle = Lifecycle.CLOSED  # until open()
        self.format: tuple[str, int, int, float] | None = None
        self.readback: dict[str, float] = {}
        self._newest = NewestFrame(self.stats, frozen_after=config.frozen_after, view=config.view)
        self._policy_given = reconnect_policy
        self._discard = 0
        self._reopen_error: RigError | None = None
        self._thread: threading.Thread | None = None
        self._thread_error: BaseException | None = None
        self._stop = threading.Event()
        self._turns = 0  # callers waiting for the source while the capture thread reads it
        self._turns_lock = threading.Lock()

    # -- lifecycle --------------------------------------------------------------------------------
    def open(self) -> FingertipCamera:
        """Open the source, set the format, lock and verify the controls, start capture."""
        with self.call_lock:
            if not self.closed:
                return self
            self._open_and_configure()
            self.lifecycle = Lifecycle.CONNECTED
            self.reconnect_policy = self._policy_given or self._default_policy()
            self._stop.clear()
            self._thread_error = None
        if self.threaded:
            self._thread = threading.Thread(target=self._capture_loop, name=f"{self.name}-capture", daemon=True)
            self._thread.start()
        return self

    def _default_policy(self) -> Reconnect:
        p = self.config.reopen
        if p is None:
            return Reconnect(self.clock)
        return Reconnect(self.clock, initial_s=p.initial_backoff_s, factor=p.factor, max_s=p.max_backoff_s)

    def close(self) -> None:
        """Stop capture and close the source (safe to call twice, and before open()).

        The capture thread is stopped first and the source released after its read returns (within
        the source's wait: OpenCV's select timeout); a source is never released under a read."""
        self._stop.set()
        with self._newest.cond:
            self._newest.cond.notify_all()
        t = self._thread
        if t is not None and t is not threading.current_thread():
            t.join(timeout=max(2.0, float(getattr(self.source, "max_read_wait_s", 0.0)) + 1.0))
            if t.is_alive():
                log.warning("%s: the capture thread is still in a read; the source is left open", self.name)
                self.lifecycle = Lifecycle.CLOSED
                return
        self._thread = None
        super().close()

    def __enter__(self) -> FingertipCamera:
        return self.open()

    def _close(self) -> None:
        self._release_port()

    # -- the driver template's primitives ----------------------------------------------------------
    def _release_port(self) -> None:
        try:
            self.source.close()
        except Exception as exc:  # noqa: BLE001  (a vanished camera may fail to close; it is gone either way)
            log.debug("%s: closing the source: %s", self.name, exc)

    def _reopen(self) -> None:
        try:
            self._open_and_configure()
        except ControlReadbackError as exc:  # back, but not as configured: report it, try again later
            self._reopen_error = exc
            if self.reconnect_policy is not None:
                self.reconnect_policy.failed(str(exc))
            raise
        self._reopen_error = None
        self._newest.new_stream()

    def _on_port_lost(self, reason: str) -> None:
        log.warning("%s: lost (%s); reopening %s when the backoff allows", self.name, reason, self.reconnect_port)

    def _on_port_back(self) -> None:
        log.info("%s: reopened %s, format and controls verified", self.name, self.reconnect_port)

    def _before_call(self) -> None:
        policy = self.reconnect_policy
        if self._reopen_error is not None and policy is not None and policy.away and not policy.due():
            raise self._reopen_error
        super()._before_call()

    def _away_error(self) -> RigError | None:
        policy = self.reconnect_policy
        if policy is None or not policy.away:
            return None
        return self._reopen_error or policy.not_connected(self.device, self.reconnect_port)

    # -- configuration ------------------------------------------------------------------------------
    def _open_and_configure(self) -> None:
        self.source.open()
        try:
            self._configure()
        except BaseException:
            self._release_port()  # a half-configured camera must not stay open
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
        self.readback = self._apply(cfg.locked_controls())
        # The first frames after a change may still use the old settings; the capture path drops them.
        self._discard = cfg.warmup_frames

    def _apply(self, controls: dict[str, float]) -> dict[str, float]:
        problems: list[str] = []
        readback: dict[str, float] = {}
        refusal = getattr(self.source, "refusal", None)
        for name, value in controls.items():
            accepted = self.source.set_control(name, value)
            got = self.source.get_control(name)
            if got is not None:
                readback[name] = got
            if not accepted:
                why = refusal(name) if callable(refusal) else None
                problems.append(f"{name}={value:g} was refused" + (f" ({why})" if why else ""))
            elif got is None or abs(got - value) > self.config.readback_tolerance:
                problems.append(f"{name}={value:g} reads back as {got}")
        if problems:
            raise ControlReadbackError("camera ignored locked controls: " + "; ".join(problems) +
                                       " (expected every value to read back as written)", device=self.name)
        return readback

    @contextmanager
    def _source_turn(self) -> Iterator[None]:
        """Hold the source for a caller besides the capture thread (which yields to it between reads)."""
        with self._turns_lock:
            self._turns += 1
        try:
            with self.call_lock:
                yield
        finally:
            with self._turns_lock:
                self._turns -= 1

    def apply_controls(self, controls: dict[str, float]) -> dict[str, float]:
        """Write ``controls`` (auto switches first), read each back; raise listing every mismatch."""
        ordered = CameraConfig(controls=controls).locked_controls()
        with self._source_turn():
            self.require_open()
            return self._apply(ordered)

    def read_controls(self, names: list[str] | None = None) -> dict[str, float | None]:
        """The current values of ``names`` (default: the locked ones) as the camera reports them."""
        wanted = list(names) if names is not None else list(self.config.locked_controls())
        with self._source_turn():
            self.require_open()
            return {canonical_control(n): self.source.get_control(n) for n in wanted}

    # -- capture ------------------------------------------------------------------------------------
    def add_listener(self, fn: Callable[[Frame], None]) -> None:
        """Call ``fn(frame)`` with every frame captured from now on, in the capturing thread (keep it
        short, e.g. put the frame on a queue): a recorder that must not miss a frame while it is
        busy, where :meth:`read` gives only the newest."""
        self._newest.add_listener(fn)

    def remove_listener(self, fn: Callable[[Frame], None]) -> None:
        self._newest.remove_listener(fn)

    def _pump(self, timeout_s: float | None) -> bool:
        """Read one frame from the source; False if none came in its wait. NotConnected: gone."""
        try:
            raw = self.source.read(timeout_s)
        except NotConnected:
            raise
        except OSError as exc:  # a source's own I/O error: the device is gone as far as reading goes
            raise NotConnected(f"reading failed: {exc}", device=self.name) from exc
        if raw is None:
            self.stats.source_timeouts += 1
            return False
        if self._discard > 0:
            self._discard -= 1
        else:
            self._newest.accept(raw, getattr(self.source, "channel_order", "BGR"), self.clock.now_s())
        return True

    def _capture_loop(self) -> None:
        watchdog_s = max(0.5, 4.0 / self.config.fps)
        while not self._stop.is_set():
            if self._turns:
                self._stop.wait(0.001)  # let a caller waiting for the source have it
                continue
            policy = self.reconnect_policy
            try:
                if policy is not None and policy.away:
                    wait_s = policy.next_attempt_s - self.clock.now_s()
                    if wait_s > 0:
                        self._sleep(min(wait_s, 0.2))
                        continue
                    with self.call_lock:
                        if not self._stop.is_set():
                            self._ensure_port()  # reopen, reconfigure, re-verify (or fail: backoff)
                else:
                    with self.call_lock:
                        if self._stop.is_set():
                            break
                        try:
                            self._pump(watchdog_s)
                        except NotConnected as exc:
                            self._port_lost(str(exc))
            except (NotConnected, DeviceTimeout, ControlReadbackError):
                pass  # still away (the policy holds why); the reader is told so
            except Exception as exc:  # noqa: BLE001  (surface any backend failure to the reader)
                with self._newest.cond:
                    self._thread_error = NotConnected(f"capture failed: {exc!r}", device=self.name)
                    self._newest.cond.notify_all()
                return
            with self._newest.cond:
                self._newest.cond.notify_all()

    def _sleep(self, seconds: float) -> None:
        if self.clock.is_virtual:
            self.clock.sleep(seconds)
        else:
            self._stop.wait(seconds)

    def read(self, timeout_s: float = 1.0) -> Frame:
        """The next frame newer than the last one returned, within ``timeout_s`` (driver clock).

        Raises DeviceTimeout (none came), FrozenStream (the last ``frozen_after`` frames are
        identical), NotConnected (closed, or the camera is gone: the error names when the next reopen
        attempt is), ControlReadbackError (it came back and refuses the lock)."""
        if self.threaded:
            return self._read_captured(timeout_s)
        return self._read_pulled(timeout_s)

    def _next_or_raise(self, deadline: Deadline, timeout_s: float) -> Frame | None:
        fr, frozen = self._newest.take_newer()
        if fr is not None:
            if frozen:
                raise FrozenStream(f"stream frozen: the last {self._newest.same_run + 1} frames are identical "
                                   f"(expected changing frames)", device=self.name)
            return fr
        remaining = deadline.remaining_s()
        if remaining is not None and remaining <= 0:
            self.stats.timeouts += 1
            raise DeviceTimeout(f"no new frame within {timeout_s} s (configured {self.config.fps} fps)",
                                device=self.name)
        return None

    @locked
    def _read_pulled(self, timeout_s: float) -> Frame:
        deadline = Deadline(self.clock, timeout_s)
        while True:
            with self._newest.cond:
                fr = self._next_or_raise(deadline, timeout_s)
            if fr is not None:
                return fr
            self._pump(deadline.remaining_s())

    def _read_captured(self, timeout_s: float) -> Frame:
        self.require_open()
        deadline = Deadline(self.clock, timeout_s)
        while True:
            with self._newest.cond:
                if self._thread_error is not None:
                    raise self._thread_error
                away = self._away_error()
                if away is not None:
                    raise away
                fr = self._next_or_raise(deadline, timeout_s)
                if fr is not None:
                    return fr
                if not self.clock.is_virtual:
                    self._newest.cond.wait(deadline.remaining_s())
                    continue
            # A thread captures on a virtual clock: let time pass in small steps.
            remaining = deadline.remaining_s()
            step = 0.25 / self.config.fps
            self.clock.sleep(step if remaining is None else min(remaining, step))

    def read_latest(self, max_age_s: float) -> Frame:
        """The newest frame if younger than ``max_age_s`` (it may have been returned before)."""
        if not self.threaded:
            self._read_pulled_once()
        with self._newest.cond:
            fr = self._newest.latest
        age = None if fr is None else self.clock.now_s() - fr.t_host_s
        if fr is None or age is None or age > max_age_s:
            raise DeviceTimeout(f"newest frame is stale (age {age} s > {max_age_s} s)", device=self.name)
        return fr

    @locked
    def _read_pulled_once(self) -> None:
        self._pump(0.0)
