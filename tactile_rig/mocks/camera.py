"""A simulated UVC fingertip camera, in process and on any clock.

:class:`SimulatedCamera` is a :class:`~tactile_rig.drivers.camera_source.FrameSource`: a UVC control
table (Logitech C310 values by default: ranges, steps, menus, manual controls inactive while their
auto switch is on, power-on values after a replug), frames paced at the configured fps on a
:class:`Clock`, exposure/gain/white balance applied to the rendered image, optional auto-exposure
and white-balance drift (so a test proves the driver locked them), and faults: freeze, stall,
unplug/replug, controls the firmware silently ignores, duplicated frames, RGB channel order.

What it claims a camera does is what OpenCVSource observes on OpenCV's own V4L2 backend over an
emulated C310 (:mod:`tactile_rig.mocks.v4l2`): ``tests/drivers/test_camera_source_contract.py`` runs
the same session, faults included, on both. It serves the driver's tests in virtual time and is the
sensor of the V4L2 emulation and the rehearsal bench's HTTP cameras.
"""

from __future__ import annotations

import math
from typing import Any, Callable

import cv2
import numpy as np

from tactile_rig.core.clock import Clock, RealClock
from tactile_rig.core.errors import NotConnected
from tactile_rig.core.types import RawFrame
from tactile_rig.devices.camera import canonical_control
from tactile_rig.devices.camera_models import C310_CONTROLS, C310_MODES, UvcControl, uvc_size_distance
from tactile_rig.sim.render.gelsight import SensorNoise

__all__ = ["UvcControl", "C310_CONTROLS", "C310_MODES", "UvcControlTable", "SimulatedCamera"]
# UvcControl, C310_CONTROLS and C310_MODES live in tactile_rig.devices.camera_models; re-exported here.


class UvcControlTable:
    """Values of a control table with uvcvideo's rules (:meth:`UvcControl.clamp`): ints rounded to the
    nearest step and clamped, menu indices the camera does not offer and writes to inactive controls
    refused. A new table, and :meth:`reset`, hold the camera's power-on values."""

    def __init__(self, controls: tuple[UvcControl, ...] = C310_CONTROLS) -> None:
        self.controls = {c.name: c for c in controls}
        self.values: dict[str, int] = {}
        self.reset()

    def reset(self) -> None:
        """The values the camera powers up with."""
        self.values = {c.name: c.initial for c in self.controls.values()}

    def by_id(self, cid: int) -> UvcControl | None:
        """The control with V4L2 id ``cid``, or None."""
        return next((c for c in self.controls.values() if c.cid == cid), None)

    def is_active(self, name: str) -> bool:
        c = self.controls[name]
        return c.active_when is None or self.values[c.active_when[0]] == c.active_when[1]

    def set(self, name: str, value: float) -> bool:
        name = canonical_control(name)
        c = self.controls.get(name)
        if c is None or not math.isfinite(value) or not self.is_active(name):
            return False
        v = int(round(value))
        if not -2**31 <= v < 2**31:  # a V4L2 control value is an s32
            return False
        if c.kind == "menu":
            if c.menu_errno(v):
                return False
        else:
            v = c.clamp(v)
        self.values[name] = v
        return True

    def get(self, name: str) -> int | None:
        """The control's value, or None for a control this camera does not have."""
        return self.values.get(canonical_control(name))

    def value(self, name: str) -> int:
        """The value of a control this camera has (KeyError names it otherwise)."""
        v = self.get(name)
        if v is None:
            raise KeyError(f"simulated camera has no control {name!r}")
        return v


def _renderer_from_url(url: str, world: Any) -> Any:
    """``rigsim://camera?model=gelsight``: the renderer model of that name in ``world`` (default: the
    only model with ``render_now``); no world: the test pattern."""
    from urllib.parse import parse_qs, urlsplit

    parts = urlsplit(url)
    if parts.scheme != "rigsim":
        raise ValueError(f"simulated camera URL {url!r} must start with rigsim://")
    model = parse_qs(parts.query).get("model", [None])[0]
    if world is None:
        if model is not None:
            raise ValueError(f"{url!r} names model {model!r} but no world (scene) was given")
        return None
    if model is not None:
        return world.require(model, f"camera {url}")
    renderers = [n for n in world if hasattr(world.get(n), "render_now")]
    if len(renderers) != 1:
        raise ValueError(f"{url!r}: say which renderer with ?model=NAME; the scene has {renderers or 'none'}")
    return world.get(renderers[0])


def moving_bar_pattern(shape_px: tuple[int, int]) -> Callable[[float], np.ndarray]:
    """A default scene: a grey gradient with a bar moving at 1 cycle/s (consecutive frames differ)."""
    rows, cols = shape_px
    base = np.tile(np.linspace(60, 190, cols, dtype=np.float32), (rows, 1))

    def render(t_s: float) -> np.ndarray:
        img = base.copy()
        x = int((t_s % 1.0) * cols)
        img[:, x:x + max(1, cols // 16)] = 230
        return np.repeat(img[..., None], 3, axis=2).astype(np.uint8)

    return render


class SimulatedCamera:
    """A UVC camera that renders ``render(t_s) -> BGR`` (or a renderer model's ``render_now()``)."""

    def __init__(self, render: Callable[[float], np.ndarray] | Any | None = None, *, clock: Clock | None = None,
                 name: str = "simcam", fourcc: str = "MJPG", width: int = 320, height: int = 240, fps: float = 30.0,
                 modes: dict[tuple[str, int, int], float] | None = None,
                 controls: tuple[UvcControl, ...] = C310_CONTROLS, auto_drift: bool = True,
                 reset_controls_on_format: bool = False, ignore_controls: tuple[str, ...] = (),
                 channel_order: str = "BGR", noise_sigma: float = 0.5, seed: int = 0, world: Any = None,
                 optics: Callable[[np.ndarray, int, int], np.ndarray] | None = None) -> None:
        """``render``: a function ``t_s -> BGR``, a renderer model (``render_now()``), None (a test
        pattern), or a ``rigsim://camera?model=NAME`` URL naming the renderer model in ``world``.
        ``optics(image, width, height)``: how the lens places the rendered (and exposed) scene on the
        sensor at a mode's size (default: a resize before exposure)."""
        if isinstance(render, str):
            render = _renderer_from_url(render, world)
        self.name = name
        self.clock = clock or RealClock()
        self.modes = dict(modes) if modes is not None else dict(C310_MODES)
        self.modes.setdefault((fourcc, int(width), int(height)), float(fps))  # the format it was built for
        self.table = UvcControlTable(controls)
        self.auto_drift = auto_drift
        self.reset_controls_on_format = reset_controls_on_format
        self.ignore_controls = {canonical_control(n) for n in ignore_controls}
        self.channel_order = channel_order
        self._render_fn = render
        self.optics = optics
        self._seed = int(seed)
        self._rng = np.random.default_rng(seed)
        self.noise_sigma = float(noise_sigma)  # read noise: no two live frames are byte-identical
        self._noise: SensorNoise | None = None
        self.fourcc, self.width, self.height, self.fps = fourcc, width, height, fps
        self._open = False
        self._opened_at = -math.inf
        self._t0 = self.clock.now_s()
        self._k_last = -1
        self._last_image: np.ndarray | None = None
        self._last_t_dev: float | None = None
        # Faults: intervals of clock time [start, end).
        self.freezes: list[tuple[float, float]] = []
        self.stalls: list[tuple[float, float]] = []
        self.unplugged: list[tuple[float, float]] = []
        self._replugs_seen = 0
        self.duplicate_every = 0  # every n-th frame is sent twice (same timestamp), 0 = never

    def reseed(self, rng: np.random.Generator) -> None:
        """Draw the read noise from ``rng`` from now on (a run reseeds per step to be resumable)."""
        self._rng = rng
        if self._noise is not None:
            self._noise.reseed(rng)

    # -- faults ---------------------------------------------------------------------------------
    def freeze(self, start_s: float, end_s: float = math.inf) -> None:
        self.freezes.append((start_s, end_s))

    def stall(self, start_s: float, end_s: float = math.inf) -> None:
        self.stalls.append((start_s, end_s))

    def unplug(self, start_s: float, end_s: float = math.inf) -> None:
        self.unplugged.append((start_s, end_s))

    @staticmethod
    def _in(intervals: list[tuple[float, float]], t: float) -> bool:
        return any(a <= t < b for a, b in intervals)

    # -- FrameSource ----------------------------------------------------------------------------
    @property
    def is_open(self) -> bool:
        return self._open

    def open(self) -> None:
        now = self.clock.now_s()
        if self._in(self.unplugged, now):
            raise NotConnected("no such device (unplugged)", device=self.name)
        replugs = sum(1 for _, b in self.unplugged if b <= now)
        if replugs > self._replugs_seen:
            self.table.reset()  # a replugged camera powers up with its default controls
            self._replugs_seen = replugs
        self._open = True
        self._opened_at = now

    def close(self) -> None:
        self._open = False

    def _check(self) -> None:
        if not self._open:
            raise NotConnected("camera is not open", device=self.name)
        now = self.clock.now_s()
        # An unplug kills the open handle for good, even if the camera is back already (it
        # re-enumerates as a new device): any unplug that began since open counts.
        if any(self._opened_at < a <= now for a, _ in self.unplugged) or self._in(self.unplugged, now):
            self._open = False
            raise NotConnected("device disappeared (ENODEV)", device=self.name)

    def set_format(self, fourcc: str, width: int, height: int, fps: float) -> tuple[str, int, int, float]:
        self._check()
        key = (fourcc, int(width), int(height))
        if key not in self.modes:  # uvcvideo: the closest size of that fourcc (else of the first format)
            cands = [m for m in self.modes if m[0] == fourcc] or [m for m in self.modes if m[0] == next(iter(self.modes))[0]]
            key = min(cands, key=lambda m: uvc_size_distance(m[1], m[2], int(width), int(height)))
        self.fourcc, self.width, self.height = key
        self.fps = min(float(fps), self.modes[key]) if fps > 0 else self.modes[key]
        if self.reset_controls_on_format:
            self.table.reset()
        self._t0, self._k_last = self.clock.now_s(), -1
        return self.fourcc, self.width, self.height, self.fps

    def set_control(self, name: str, value: float) -> bool:
        self._check()
        if canonical_control(name) in self.ignore_controls:
            return True  # the firmware acknowledges, and keeps its own value
        return self.table.set(name, value)

    def get_control(self, name: str) -> float | None:
        self._check()
        v = self.table.get(name)
        return None if v is None else float(v)

    def read(self, timeout_s: float | None = 1.0) -> RawFrame | None:
        self._check()
        now = self.clock.now_s()
        period = 1.0 / self.fps
        k = max(self._k_last + 1, math.ceil((now - self._t0) / period - 1e-9))
        t_frame = self._t0 + k * period
        limit = math.inf if timeout_s is None else now + max(0.0, timeout_s)
        while True:
            if t_frame > limit:
                self.clock.sleep(limit - self.clock.now_s())
                return None
            self.clock.sleep(t_frame - self.clock.now_s())
            self._check()  # raises if unplugged (or closed by another thread) meanwhile
            if not self._in(self.stalls, t_frame):
                break
            k += 1
            t_frame = self._t0 + k * period
        if self.duplicate_every and self._last_image is not None and k % self.duplicate_every == 0:
            self._k_last = k
            return RawFrame(self._last_image, self._last_t_dev, k)
        if self._in(self.freezes, t_frame) and self._last_image is not None:
            img = self._last_image
        else:
            img = self.render_frame(t_frame)
        self._k_last, self._last_image, self._last_t_dev = k, img, t_frame - self._t0
        out = img[..., ::-1].copy() if self.channel_order == "RGB" else img
        return RawFrame(out, t_frame - self._t0, k)

    # -- image formation ------------------------------------------------------------------------
    def render_frame(self, t_s: float, width: int | None = None, height: int | None = None) -> np.ndarray:
        """The image the sensor forms at ``t_s`` (BGR, ``height`` x ``width`` px, default the current
        format's): the scene rendered, exposed with the current controls, placed on the sensor."""
        w = self.width if width is None else int(width)
        h = self.height if height is None else int(height)
        if self.optics is None:
            return self._expose(self._render(t_s, (h, w)), t_s)
        return self.optics(self._expose(self._render(t_s, None), t_s), w, h)

    def _render(self, t_s: float, shape_px: tuple[int, int] | None) -> np.ndarray:
        fn = self._render_fn
        if fn is None:
            self._render_fn = fn = moving_bar_pattern(shape_px or (self.height, self.width))
        img = fn.render_now() if hasattr(fn, "render_now") else fn(t_s)
        if shape_px is not None and img.shape[:2] != shape_px:
            img = cv2.resize(img, (shape_px[1], shape_px[0]), interpolation=cv2.INTER_AREA)
        return img

    def _relative(self, name: str) -> float | None:
        """A control's value relative to its default (1.0 at the default), None if the camera lacks it.
        A control whose default is 0 counts from a quarter of its range."""
        c = self.table.controls.get(name)
        if c is None:
            return None
        ref = c.default if c.default > 0 else (c.maximum - c.minimum) / 4.0
        return (self.table.values[name] + (ref - c.default)) / ref

    def effective_exposure(self, t_s: float) -> float:
        """Exposure relative to the camera's default: the manual value, or auto exposure's drifting choice
        (1.0 for a camera without exposure controls)."""
        if self.table.get("auto_exposure") == 1:
            return self._relative("exposure_time_absolute") or 1.0
        if "auto_exposure" not in self.table.controls:
            return 1.0
        drift = 0.25 * math.sin(2 * math.pi * t_s / 7.0) if self.auto_drift else 0.0
        return 1.0 + drift

    def channel_gains(self, t_s: float) -> np.ndarray:
        """BGR gains from white balance (manual temperature, or auto WB's drifting choice) and, on a
        camera whose LEDs are a control (the DIGIT's ``zoom_absolute``: 4 bits each of R, G, B), the LEDs."""
        shift = 0.0
        wb = self.table.controls.get("white_balance_temperature")
        if self.table.get("white_balance_automatic") == 0 and wb is not None:
            shift = (self.table.values[wb.name] - wb.default) / 20000.0
        elif "white_balance_automatic" in self.table.controls and self.auto_drift:
            shift = 0.08 * math.sin(2 * math.pi * t_s / 5.0)
        gains = np.array([1.0 + shift, 1.0, 1.0 - shift], dtype=np.float32)
        led = self.table.get("zoom_absolute")
        if led is not None:
            gains *= np.array([(led & 15) / 15.0, ((led >> 4) & 15) / 15.0, ((led >> 8) & 15) / 15.0], np.float32)
        return gains

    def _expose(self, img: np.ndarray, t_s: float) -> np.ndarray:
        """Exposure x gain x white balance, brightness offset, read noise; saturating 8-bit arithmetic."""
        gain = self.effective_exposure(t_s) * max(0.0, self._relative("gain") or 1.0) ** 0.5
        wb = self.channel_gains(t_s) * gain
        b = self.table.controls.get("brightness")
        bright = (self.table.values[b.name] - b.default) * 0.5 * 255.0 / (b.maximum - b.minimum) if b else 0.0
        out = img
        if not np.allclose(wb, 1.0):
            out = cv2.multiply(out, (float(wb[0]), float(wb[1]), float(wb[2]), 0.0))
        if bright != 0:
            out = cv2.add(out, (bright, bright, bright, 0.0))
        if self.noise_sigma > 0:
            if self._noise is None or self._noise.shape != out.shape:
                # The field depends on the seed only (not on when the first frame came); the crops
                # come from the camera's stream, which reseed() may replace.
                self._noise = SensorNoise(out.shape, self.noise_sigma, np.random.default_rng([self._seed, 1]))
                self._noise.reseed(self._rng)
            out = cv2.add(out, self._noise.sample(), dtype=cv2.CV_8U)
        return out
