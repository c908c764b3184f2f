"""One configuration class per device kind of a bench: its fields, its own checks, and how it connects.

Adding a device kind to the bench is one subclass of :class:`DeviceConfig` here: fields with units
in their names and defaults, ``kind``, an example port, the command that makes its calibration,
:meth:`DeviceConfig.check` for its own fields and :meth:`DeviceConfig.connect` building the driver.
The loader (:mod:`.load`) finds it by ``kind`` and types each TOML value from the field annotations.
"""

from __future__ import annotations

import difflib
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, ClassVar

from tactile_rig.core.errors import CalibrationError, LimitError
from tactile_rig.rig.files import load_json
from tactile_rig.devices.camera import POWER_LINE_INDEX, photometric_lock
from tactile_rig.devices.camera_models import CAMERA_MODELS, CameraModel, SdkView, fps_of_interval
from tactile_rig.drivers.camera import FingertipCamera
from tactile_rig.drivers.dynamixel.bus import DEFAULT_LATENCY_TIMER_MS
from tactile_rig.drivers.dynamixel.gripper import DynamixelGripper, GripperCalibration
from tactile_rig.drivers.grbl import Jig
from tactile_rig.drivers.scale import Scale
from tactile_rig.mocks.camera import SimulatedCamera
from tactile_rig.rig.replay import RecordedFrameSource

SENSOR_TYPES = ("gelsight", "fingervision")
MAX_FRAME_SIDE_PX = 8192  # no UVC camera a fingertip uses delivers more; a bigger number is a typo

# ``problem(key, message)``: report a problem with one field (the loader adds the line number).
Problem = Callable[[str, str], None]


@dataclass
class ConnectContext:
    """What a device's ``connect`` gets besides its config: the bench (a :class:`~.load.Bench`), its
    clock, and on a bench of mocks the scene's world."""

    bench: Any
    clock: Any
    world: Any = None


@dataclass
class DeviceConfig:
    """What every device table has: where it is and how to reach it."""

    name: str
    port: str
    baud: int
    calibration: Path | None = None
    timeout_s: float = 1.0
    line: int | None = None  # line of the [table] header in the bench file

    kind: ClassVar[str] = "device"
    example_port: ClassVar[str] = "/dev/ttyUSB0"
    calibration_command: ClassVar[str] = ""
    serial: ClassVar[bool] = True  # has a baud rate

    KINDS: ClassVar[dict[str, type["DeviceConfig"]]] = {}

    def __init_subclass__(cls, **kw: Any) -> None:
        super().__init_subclass__(**kw)
        if cls.kind in DeviceConfig.KINDS:
            raise TypeError(f"device kind {cls.kind!r} is defined twice ({DeviceConfig.KINDS[cls.kind].__name__}, "
                            f"{cls.__name__})")
        DeviceConfig.KINDS[cls.kind] = cls

    @property
    def is_mock(self) -> bool:
        return self.port.startswith(("rigsim://", "rigfault://", "loop://"))

    @property
    def calibration_kind(self) -> str:
        """Which calibration command makes this device's calibration file."""
        return self.kind

    def check(self, problem: Problem) -> None:
        """Report every field outside what the device allows (subclasses add their own, calling this)."""
        if not self.port.strip():
            problem("port", "is empty; give a device path (e.g. "
                            f"\"{self.example_port}\") or a rigsim:// mock URL")
        if self.serial and not 300 <= self.baud <= 4_500_000:
            problem("baud", f"= {self.baud} is not a serial baud rate (300 .. 4500000), e.g. 57600 or 115200")
        if not 0 < self.timeout_s <= 60:
            problem("timeout_s", f"= {self.timeout_s} must be in (0, 60] s")

    def connect(self, ctx: ConnectContext) -> Any:
        """Open this device's driver (ports of mocks are already resolved by the caller)."""
        raise NotImplementedError(f"{type(self).__name__} does not say how to connect a {self.kind}")

    def mock_params(self) -> dict[str, str]:
        """URL parameters a ``rigsim://`` mock takes from the bench: only what a lab sets up on the real
        device (a servo's ID, protocol and baud). A firmware's fixed baud (the scale sketch's 57600,
        GRBL's 115200) is not taken from the bench, so a wrong ``baud`` shows on the mock as on hardware."""
        return {}


def _check_limits(problem: Problem, key: str, limits: tuple[float, float], unit: str) -> None:
    lo, hi = limits
    if not (math.isfinite(lo) and math.isfinite(hi)):
        problem(key, f"= [{lo}, {hi}] must be finite {unit} (a jig has a travel)")


@dataclass
class GripperConfig(DeviceConfig):
    """Dynamixel MX-64 gripper: servo IDs, protocol, current limit and opening range (m);
    ``latency_timer_ms`` the USB adapter's latency timer the status timeout allows for (FTDI default
    16 ms; the larger of this and the one read from sysfs counts), ``retries`` of idempotent reads."""

    baud: int = 57600
    ids: list[int] = field(default_factory=lambda: [1])
    protocol: int = 2
    current_limit_frac: float = 1.0
    min_opening_m: float = 0.0
    max_opening_m: float = 0.1
    latency_timer_ms: float = DEFAULT_LATENCY_TIMER_MS
    retries: int = 2

    kind: ClassVar[str] = "gripper"
    example_port: ClassVar[str] = "/dev/serial/by-id/usb-FTDI_...-if00-port0"
    calibration_command: ClassVar[str] = "tactile-rig calibrate gripper"

    def check(self, problem: Problem) -> None:
        super().check(problem)
        if self.protocol not in (1, 2):
            problem("protocol", f"= {self.protocol} must be 1 or 2 (Dynamixel protocol version)")
        if not all(0 <= i <= 252 for i in self.ids):
            problem("ids", f"= {self.ids} must be Dynamixel IDs in 0..252")
        dup = sorted({i for i in self.ids if self.ids.count(i) > 1})
        if dup:
            problem("ids", f"= {self.ids} names ID {', '.join(map(str, dup))} twice; each servo on a bus "
                           "needs its own ID")
        if not 0 < self.current_limit_frac <= 1:
            problem("current_limit_frac", f"= {self.current_limit_frac} must be in (0, 1]")
        if not 0 <= self.min_opening_m < self.max_opening_m <= 1.0:
            problem("max_opening_m", f"= {self.max_opening_m} must exceed min_opening_m = {self.min_opening_m} "
                                     ">= 0 and be at most 1 m")
        if not 0 <= self.latency_timer_ms <= 255:
            problem("latency_timer_ms", f"= {self.latency_timer_ms} must be in [0, 255] ms (an FTDI adapter's "
                                        "latency timer: 16 by default, 1 after the udev rule in docs/your_bench.md)")
        if not 0 <= self.retries <= 10:
            problem("retries", f"= {self.retries} must be in [0, 10] (retries of a read whose status was lost)")

    def mock_params(self) -> dict[str, str]:
        return {"baud": str(self.baud), "ids": ",".join(str(i) for i in self.ids), "protocol": str(self.protocol)}

    def connect(self, ctx: ConnectContext) -> Any:
        cal = None
        if self.calibration is not None:
            try:
                d = load_json(self.calibration, "gripper calibration", expect=None)
                cal = GripperCalibration.from_dict(d.get("calibration", d) if isinstance(d, dict) else d)
            except (OSError, ValueError, TypeError, KeyError, AttributeError, RecursionError) as exc:
                raise CalibrationError(f"gripper calibration {self.calibration} is unreadable: {exc}; re-make it "
                                       f"with: {self.calibration_command}", device=self.name) from None
        return DynamixelGripper(self.port, dxl_id=self.ids[0], protocol=self.protocol, baudrate=self.baud,
                                calibration=cal, latency_timer_ms=self.latency_timer_ms, retries=self.retries)


@dataclass
class ScaleConfig(DeviceConfig):
    """Arduino HX711 load cell running the project's sketch (57600 baud, 10 or 80 samples/s)."""

    baud: int = 57600
    max_force_n: float = 50.0
    rate_hz: float = 10.0

    kind: ClassVar[str] = "scale"
    calibration_command: ClassVar[str] = "tactile-rig calibrate scale"

    def check(self, problem: Problem) -> None:
        super().check(problem)
        if not (math.isfinite(self.max_force_n) and self.max_force_n > 0):
            problem("max_force_n", f"= {self.max_force_n} must be a finite force > 0 N")
        if self.rate_hz not in (10.0, 80.0):
            problem("rate_hz", f"= {self.rate_hz} must be 10 or 80 (the HX711 RATE pin)")

    def connect(self, ctx: ConnectContext) -> Any:
        return Scale(self.port, baudrate=self.baud, device=self.name)


@dataclass
class JigConfig(DeviceConfig):
    """GRBL x-y-θ jig with its travel limits (mm, deg) and speed cap.

    The defaults are the project's jig (GRBL settings of :mod:`tactile_rig.mocks.grbl`): ±20 mm in
    x and y, θ ±180° (a full turn of the stage). Every move the CLI or a session makes is checked
    against these limits before anything is sent (:meth:`check_target`)."""

    baud: int = 115200
    x_limits_mm: tuple[float, float] = (-20.0, 20.0)
    y_limits_mm: tuple[float, float] = (-20.0, 20.0)
    z_limits_mm: tuple[float, float] = (0.0, 10.0)
    theta_limits_deg: tuple[float, float] = (-180.0, 180.0)
    max_speed_mmps: float = 10.0

    kind: ClassVar[str] = "jig"
    example_port: ClassVar[str] = "/dev/ttyACM0"
    calibration_command: ClassVar[str] = "tactile-rig calibrate jig"

    def check(self, problem: Problem) -> None:
        super().check(problem)
        for key, unit in (("x_limits_mm", "mm"), ("y_limits_mm", "mm"), ("z_limits_mm", "mm")):
            _check_limits(problem, key, getattr(self, key), unit)
        _check_limits(problem, "theta_limits_deg", self.theta_limits_deg, "deg")
        lo, hi = self.theta_limits_deg
        if math.isfinite(lo) and math.isfinite(hi) and not (-360.0 <= lo and hi <= 360.0):
            problem("theta_limits_deg", f"= [{lo}, {hi}] must lie within [-360, 360] deg")
        if not (math.isfinite(self.max_speed_mmps) and self.max_speed_mmps > 0):
            problem("max_speed_mmps", f"= {self.max_speed_mmps} must be a finite speed > 0 mm/s")

    def check_target(self, *, x_mm: float | None = None, y_mm: float | None = None,
                     theta_deg: float | None = None, source: str = "the bench") -> None:
        """Raise LimitError naming the axis, the value and the limit when a target lies outside the
        limits (None: that axis does not move). Called before any motion."""
        for axis, value, key, unit in (("x", x_mm, "x_limits_mm", "mm"), ("y", y_mm, "y_limits_mm", "mm"),
                                       ("theta", theta_deg, "theta_limits_deg", "deg")):
            if value is None:
                continue
            lo, hi = getattr(self, key)
            if not (math.isfinite(value) and lo <= value <= hi):
                raise LimitError(f"{axis} = {value:g} {unit} is outside [{self.name}] {key} = [{lo:g}, {hi:g}] "
                                 f"{unit} of {source}; nothing was moved", device=self.name)

    def connect(self, ctx: ConnectContext) -> Any:
        return Jig(self.port, baudrate=self.baud, x_range_mm=self.x_limits_mm, y_range_mm=self.y_limits_mm,
                   theta_range_deg=self.theta_limits_deg, device=self.name)


@dataclass
class CameraConfig(DeviceConfig):
    """Fingertip camera and the tactile sensor it images (mm/px in x and y, of the frames the driver
    gives: the vendor SDK's view when the camera has one).

    ``model`` names the camera (``c310``, ``gelsight-mini``, ``digit``: :data:`CAMERA_MODELS`); it gives
    the stream when ``fourcc``/``width``/``height``/``fps`` are not set (its default one), checks them
    when they are (a mode the camera does not offer is a problem naming the ones it does), chooses the
    controls the photometric lock holds (the ones the camera has, at its own defaults:
    :func:`~tactile_rig.devices.camera.photometric_lock`) and the SDK view the perception expects
    (``sdk_view``: one of the model's, default its first; ``"none"`` for the raw frame). ``mains_hz``
    (50 or 60) locks the power line frequency. Without a model: MJPG 320x240 at 25 fps and the C310's lock.
    """

    baud: int = 0  # cameras have no baud; kept so every device has the same fields
    sensor: str = "gelsight"
    mm_per_px_x: float = 0.0634
    mm_per_px_y: float = 0.0634
    width: int = 0  # 0: the model's default stream (320 without a model)
    height: int = 0  # 0: as width (240 without a model)
    fps: float = 0.0  # 0: as width (25 without a model)
    fourcc: str = ""  # "": as width ("MJPG" without a model)
    model: str | None = None
    mains_hz: float | None = None
    sdk_view: str | None = None
    force_map: Path | None = None  # marker forces → newtons (tactile-rig calibrate force-map)
    substance_model: Path | None = None  # stirring features → substance (tactile-rig calibrate substance)

    kind: ClassVar[str] = "camera"
    example_port: ClassVar[str] = "/dev/video0"
    serial: ClassVar[bool] = False

    def __post_init__(self) -> None:
        m = self.camera_model
        if m is not None:
            fmt = m.formats[0]
            frame = fmt.frames[fmt.default_frame]
            defaults = (fmt.fourcc, frame.width_px, frame.height_px,
                        m.modes()[(fmt.fourcc, frame.width_px, frame.height_px)])
        else:
            defaults = ("MJPG", 320, 240, 25.0)
        self.fourcc = self.fourcc or defaults[0]
        self.width = self.width or defaults[1]
        self.height = self.height or defaults[2]
        if not self.fps:  # the mode's fastest rate, where the model offers the mode
            self.fps = (m.modes().get((self.fourcc, self.width, self.height)) if m is not None else None) or defaults[3]

    @property
    def camera_model(self) -> CameraModel | None:
        """The :class:`CameraModel` named by ``model`` (None without one, or for an unknown name)."""
        return CAMERA_MODELS.get(self.model) if isinstance(self.model, str) else None

    @property
    def view(self) -> SdkView | None:
        """The SDK view applied to the frames (None: the raw frame)."""
        m = self.camera_model
        if m is None or self.sdk_view == "none" or not m.sdk_views:
            return None
        if self.sdk_view is None:
            return m.sdk_views[0]
        return next((v for v in m.sdk_views if v.name == self.sdk_view), None)

    def locked_controls(self) -> dict[str, float]:
        """The controls the driver locks and verifies on this camera."""
        mains = self.mains_hz if self.mains_hz in POWER_LINE_INDEX else None
        return photometric_lock(self.camera_model, mains)

    @property
    def calibration_kind(self) -> str:
        return self.sensor

    def check(self, problem: Problem) -> None:
        super().check(problem)
        if self.sensor not in SENSOR_TYPES:
            close = difflib.get_close_matches(self.sensor, SENSOR_TYPES, n=1, cutoff=0.4)
            hint = f"; did you mean '{close[0]}'?" if close else ""
            problem("sensor", f"= {self.sensor!r} must be one of {', '.join(SENSOR_TYPES)}{hint}")
        for key in ("mm_per_px_x", "mm_per_px_y"):
            v = getattr(self, key)
            if not 0 < v < 10:
                problem(key, f"= {v} must be in (0, 10) mm/px (GelSight Mini: 0.0634 at 320x240)")
        for key in ("width", "height"):
            v = getattr(self, key)
            if not 0 < v <= MAX_FRAME_SIDE_PX:
                problem(key, f"= {v} must be a frame size in 1..{MAX_FRAME_SIDE_PX} px")
        if not (math.isfinite(self.fps) and 0 < self.fps <= 1000):
            problem("fps", f"= {self.fps} must be in (0, 1000] frames per second")
        if len(self.fourcc) != 4 or not self.fourcc.isascii():
            problem("fourcc", f"= {self.fourcc!r} must be four ASCII characters such as \"MJPG\" or \"YUYV\"")
        if self.mains_hz is not None and self.mains_hz not in POWER_LINE_INDEX:
            problem("mains_hz", f"= {self.mains_hz!r} must be 50 or 60 (the lab's mains frequency, Hz)")
        if self.model is not None:
            self._check_model(problem)
        elif self.sdk_view is not None:
            problem("sdk_view", "needs a model (the vendor SDK views are the camera model's)")

    def _check_model(self, problem: Problem) -> None:
        m = self.camera_model
        if m is None:
            close = difflib.get_close_matches(str(self.model), list(CAMERA_MODELS), n=1, cutoff=0.4)
            hint = f"; did you mean '{close[0]}'?" if close else ""
            problem("model", f"= {self.model!r} must be one of {', '.join(CAMERA_MODELS)}{hint}")
            return
        modes = m.modes()
        key = (self.fourcc, int(self.width), int(self.height))
        if key not in modes:
            offered = ", ".join(f"{f} {w}x{h}" for f, w, h in modes)
            problem("width", f"= {self.width}, height = {self.height}, fourcc = {self.fourcc!r}: the {m.title} offers "
                             f"{offered}")
        else:
            frame = next(fr for f in m.formats if f.fourcc == self.fourcc for fr in f.frames
                         if (fr.width_px, fr.height_px) == key[1:])
            rates = sorted({fps_of_interval(i) for i in frame.intervals_100ns}, reverse=True)
            if not any(abs(self.fps - r) < 0.01 for r in rates):
                problem("fps", f"= {self.fps:g}: the {m.title} offers {', '.join(f'{r:g}' for r in rates)} fps at "
                               f"{self.fourcc} {self.width}x{self.height}")
        names = [v.name for v in m.sdk_views]
        if self.sdk_view is not None and self.sdk_view != "none" and self.sdk_view not in names:
            problem("sdk_view", f"= {self.sdk_view!r} must be one of {', '.join(names + ['none'])} for the {m.title}")

    def connect(self, ctx: ConnectContext) -> Any:
        """A V4L2 camera (or an ``http://`` MJPEG stream) configured from the bench and its model; a
        recording ``run.mcap[#/topic]`` served as the camera; or for ``rigsim://camera?model=NAME`` a
        camera rendering the bench's world, with the model's modes and controls."""
        fmt: dict[str, Any] = dict(fourcc=self.fourcc, width=self.width, height=self.height, fps=self.fps)
        path, _, topic = self.port.partition("#")
        if path.endswith(".mcap"):
            src = RecordedFrameSource(path, topic=topic or None, clock=ctx.clock)
            return FingertipCamera(src, clock=ctx.clock, name=self.name, **fmt).open()
        lock = self.locked_controls()
        if self.port.startswith("rigsim://"):
            m = self.camera_model
            extra: dict[str, Any] = {} if m is None else {"modes": m.modes(), "controls": m.controls}
            sim = SimulatedCamera(self.port, clock=ctx.clock, name=self.name, world=ctx.world, seed=ctx.bench.seed,
                                  **fmt, **extra)
            return FingertipCamera(sim, clock=ctx.clock, name=self.name, controls=lock, view=self.view, **fmt).open()
        return FingertipCamera(self.port, name=self.name, controls=lock, view=self.view, **fmt).open()


DEVICE_CLASSES = DeviceConfig.KINDS
