"""UVC camera models as data: USB identity, the formats, sizes and frame intervals their UVC
descriptors offer, their control tables, and the crop and resize their vendors' SDKs apply.

One home per fact: the simulated camera (:mod:`tactile_rig.mocks.camera`), the V4L2 emulation
(:mod:`tactile_rig.mocks.v4l2`) and discovery read these; nothing else restates them. Each model's
docstring (and ``docs/emulated_cameras.md``) says where every fact comes from and which are
modelled rather than read from a published capture of the device.

The module is a little over 500 lines because it is one table: three models' descriptors and
controls, each with its source, beside the few helpers that read them the way uvcvideo does.

Units: frame intervals in 100 ns (the UVC descriptors' own unit, ``dwFrameInterval``), sizes in
pixels, exposure in 100 µs (the UVC/V4L2 ``exposure_time_absolute`` unit).
"""

from __future__ import annotations

import errno
import re
from dataclasses import dataclass, field
from fractions import Fraction

__all__ = [
    "UvcControl", "UvcFrame", "UvcFormat", "SdkView", "CameraModel", "CAMERA_MODELS", "camera_model",
    "C310", "GELSIGHT_MINI", "DIGIT", "C310_CONTROLS", "C310_MODES", "V4L2_CID",
    "fps_of_interval", "interval_of_fps", "udev_sanitize", "uvc_simplify_fraction", "camera_model_by_usb_kind",
]

# V4L2 control ids (linux/v4l2-controls.h) of the controls these cameras expose.
V4L2_CID: dict[str, int] = {
    "brightness": 0x00980900, "contrast": 0x00980901, "saturation": 0x00980902, "hue": 0x00980903,
    "white_balance_automatic": 0x0098090C, "gamma": 0x00980910, "gain": 0x00980913,
    "power_line_frequency": 0x00980918, "white_balance_temperature": 0x0098091A, "sharpness": 0x0098091B,
    "backlight_compensation": 0x0098091C, "auto_exposure": 0x009A0901, "exposure_time_absolute": 0x009A0902,
    "exposure_dynamic_framerate": 0x009A0903, "zoom_absolute": 0x009A090D,
}

# uvcvideo's menu entries for the two standard menu controls (drivers/media/usb/uvc/uvc_ctrl.c, the
# mapping table): index -> name; a camera offers the subset its GET_RES bitmap allows.
EXPOSURE_AUTO_MENU = ("Auto Mode", "Manual Mode", "Shutter Priority Mode", "Aperture Priority Mode")
POWER_LINE_MENU = ("Disabled", "50 Hz", "60 Hz", "Auto")


@dataclass(frozen=True)
class UvcControl:
    """One control as uvcvideo presents it.

    ``kind`` is ``int``, ``bool`` or ``menu``; ``minimum``/``maximum`` are what ``VIDIOC_QUERYCTRL``
    reports (for a menu uvcvideo reports the index range of its mapping, e.g. 0..3 for
    ``auto_exposure``); ``menu`` are the indices this camera accepts (its GET_RES bitmap);
    ``menu_names`` the names by index. ``active_when=(switch, value)``: the control is inactive
    (``V4L2_CTRL_FLAG_INACTIVE``, writes refused with EACCES) unless ``switch`` has that value.
    ``signed``: the UVC data type is signed (uvcvideo clamps unsigned controls as u32, so a negative
    write to an unsigned control lands on the maximum). ``power_on``: the value the camera starts
    with when it differs from its GET_DEF default (a camera quirk). ``label``: the name QUERYCTRL
    returns.
    """

    name: str
    cid: int
    kind: str
    minimum: int
    maximum: int
    default: int
    step: int = 1
    menu: tuple[int, ...] = ()
    active_when: tuple[str, int] | None = None
    label: str = ""
    menu_names: tuple[str, ...] = ()
    signed: bool = False
    power_on: int | None = None

    def __post_init__(self) -> None:
        if self.kind not in ("int", "bool", "menu"):
            raise ValueError(f"control {self.name}: kind={self.kind!r}; expected int, bool or menu")
        if not self.minimum <= self.default <= self.maximum:
            raise ValueError(f"control {self.name}: default {self.default} outside {self.minimum}..{self.maximum}")
        if self.kind == "menu" and (not self.menu or self.default not in self.menu):
            raise ValueError(f"control {self.name}: a menu needs its valid indices, the default among them")
        if self.step < 1:
            raise ValueError(f"control {self.name}: step={self.step} must be >= 1")

    @property
    def initial(self) -> int:
        """The value after power-on (the default unless the camera starts elsewhere)."""
        return self.default if self.power_on is None else self.power_on

    def clamp(self, value: int) -> int:
        """What uvcvideo stores when ``value`` (a V4L2 s32) is written to an int or bool control.

        uvc_ctrl.c rounds to the nearest step in u32 arithmetic, ``min + DIV_ROUND_CLOSEST((u32)(v - min),
        step) * step``, then clamps as s32 for a signed UVC control and as u32 for an unsigned one, so a
        negative write to an unsigned control lands on the maximum."""
        if self.kind == "bool":
            return min(max(int(value), 0), 1)
        m32 = 0xFFFFFFFF
        x = (int(value) - self.minimum) & m32
        q = ((x + self.step // 2) & m32) // self.step
        v = (self.minimum + q * self.step) & m32
        if self.signed:
            s = v - (1 << 32) if v & 0x80000000 else v
            return min(max(s, self.minimum), self.maximum)
        return min(max(v, self.minimum & m32), self.maximum & m32)

    def menu_errno(self, index: int) -> int:
        """0 if uvcvideo accepts menu ``index``; ERANGE outside the mapping's range, EINVAL for an index the
        mapping or the camera's GET_RES bitmap does not offer (uvc_ctrl.c, uvc_ctrl_clamp)."""
        if not self.minimum <= index <= self.maximum:
            return errno.ERANGE
        return 0 if index in self.menu else errno.EINVAL


@dataclass(frozen=True)
class UvcFrame:
    """A frame descriptor: size and discrete frame intervals (100 ns units, fastest first as the
    descriptors list them); ``max_frame_bytes`` is dwMaxVideoFrameBufferSize (VIDIOC_G_FMT's sizeimage)."""

    width_px: int
    height_px: int
    intervals_100ns: tuple[int, ...]
    max_frame_bytes: int = 0
    default_100ns: int = 0

    def __post_init__(self) -> None:
        if not self.intervals_100ns or any(i <= 0 for i in self.intervals_100ns):
            raise ValueError(f"frame {self.width_px}x{self.height_px}: intervals must be positive")
        if self.max_frame_bytes == 0:
            object.__setattr__(self, "max_frame_bytes", self.width_px * self.height_px * 2)
        if self.default_100ns and self.default_100ns not in self.intervals_100ns:
            raise ValueError(f"frame {self.width_px}x{self.height_px}: default interval {self.default_100ns} "
                             f"is not one of {self.intervals_100ns}")

    @property
    def default_interval_100ns(self) -> int:
        """dwDefaultFrameInterval (``default_100ns``; when not given, the fastest rate)."""
        return self.default_100ns or self.intervals_100ns[0]


@dataclass(frozen=True)
class UvcFormat:
    """A format descriptor: FOURCC, its frames in descriptor order, which is the default frame."""

    fourcc: str
    frames: tuple[UvcFrame, ...]
    default_frame: int = 0
    compressed: bool = False

    def frame(self, width_px: int, height_px: int) -> UvcFrame | None:
        return next((f for f in self.frames if (f.width_px, f.height_px) == (width_px, height_px)), None)


@dataclass(frozen=True)
class SdkView:
    """The crop and resize a vendor SDK applies to the camera's raw frame before its users see it.

    ``border_rows``/``border_cols``: fraction of the raw height/width cut off each side; then, if
    ``keep_aspect``, more rows or columns (from the top or left, as the SDK does) until the aspect
    ratio is the output's; then a resize to ``output_px`` = (width, height). ``transpose_flip``: the
    SDK transposes the frame and flips it vertically (the DIGIT's portrait view). ``source`` names the
    project and file it was read from.
    """

    name: str
    source: str
    border_rows: float = 0.0
    border_cols: float = 0.0
    keep_aspect: bool = False
    output_px: tuple[int, int] | None = None
    transpose_flip: bool = False

    def crop_box(self, width_px: int, height_px: int) -> tuple[int, int, int, int]:
        """(x0, y0, x1, y1) of the raw frame the SDK keeps, for a raw frame of that size."""
        by = int(height_px * self.border_rows)
        bx = int(width_px * self.border_cols)
        h, w = height_px - 2 * by, width_px - 2 * bx
        extra_h = extra_w = 0
        if self.keep_aspect and self.output_px is not None:
            ow, oh = self.output_px
            if h * ow / oh > w + 1e-8:
                extra_h = int(h - w * oh / ow)
            elif h * ow / oh < w - 1e-8:
                extra_w = int(w - h * ow / oh)
        return bx + extra_w, by + extra_h, width_px - bx, height_px - by


@dataclass(frozen=True)
class CameraModel:
    """A UVC camera as the host sees it (see the module doc for units and sources).

    ``manufacturer``/``product``/``function``: the USB strings (None: the device has none);
    uvcvideo's card name (:attr:`card`) is built from them. ``formats`` are in descriptor order
    (the first is the default). ``format_change_resets``: controls a format change puts back to
    their defaults. ``background``: the real no-contact frame its renderer composites on (a name of
    :data:`tactile_rig.sim.render.gelsight.BACKGROUNDS`); ``mm_per_px`` the scale of that frame.
    ``sdk_views``: what the vendor SDKs do to a raw frame. ``inactive_write_errno_legacy``: what a
    write to an inactive manual control returned before Linux 6.3, when uvcvideo passed it to the
    camera: the camera stalls the request and uvc_query_ctrl maps its error code (Invalid
    control/request: EIO; Wrong state: EILSEQ). A Logitech HD Webcam C525 on Linux 5.15 gave EIO
    for exposure and white balance temperature (its v4l2-compliance 1.22.1 log on linux-media,
    "Re: [PATCH 0/4] Follow-up patches for uvc v4l2-compliance", November 2021).
    """

    key: str
    title: str
    vendor_id: int | None
    product_id: int | None
    manufacturer: str | None
    product: str | None
    serial: str
    formats: tuple[UvcFormat, ...]
    controls: tuple[UvcControl, ...]
    function: str | None = None
    bcd_device: int | None = None
    uvc_version: int = 0x0100
    format_change_resets: tuple[str, ...] = ()
    background: str = "gsmini"
    sdk_views: tuple[SdkView, ...] = ()
    inactive_write_errno_legacy: int = errno.EIO
    sources: tuple[str, ...] = ()
    notes: tuple[str, ...] = field(default=())
    has_serial_number: bool = True
    product_prefix: str | None = None
    led_controls: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        names = [c.name for c in self.controls]
        if len(set(names)) != len(names):
            raise ValueError(f"camera model {self.key}: duplicate control names")
        for c in self.controls:
            if c.active_when is not None and c.active_when[0] not in names:
                raise ValueError(f"camera model {self.key}: {c.name} depends on unknown {c.active_when[0]}")
        for n in (*self.format_change_resets, *self.led_controls):
            if n not in names:
                raise ValueError(f"camera model {self.key}: {n} is not one of its controls")
        if self.product_prefix is not None and not (self.product or "").startswith(self.product_prefix):
            raise ValueError(f"camera model {self.key}: product {self.product!r} does not start with "
                             f"product_prefix {self.product_prefix!r}")

    @property
    def usb_kind(self) -> str:
        """The kind discovery reports for this camera (``camera_c310``, ``camera_gelsight_mini``)."""
        return "camera_" + self.key.replace("-", "_")

    @property
    def card(self) -> str:
        """The name uvcvideo gives the device (VIDIOC_QUERYCAP ``card``, sysfs ``name``): the product
        string, or ``UVC Camera (vvvv:pppp)`` without one; ``": <function>"`` appended when the
        device has both; at most 31 characters (drivers/media/usb/uvc/uvc_driver.c, uvc_probe)."""
        if self.product:
            name = self.product
            if self.function:
                name = f"{name}: {self.function}"
        else:
            name = f"UVC Camera ({self.vendor_id or 0:04x}:{self.product_id or 0:04x})"
        return name[:31]

    def format(self, fourcc: str) -> UvcFormat | None:
        return next((f for f in self.formats if f.fourcc == fourcc), None)

    def control(self, name: str) -> UvcControl | None:
        return next((c for c in self.controls if c.name == name), None)

    def modes(self) -> dict[tuple[str, int, int], float]:
        """(fourcc, width, height) -> fastest frame rate in frames per second."""
        return {(f.fourcc, fr.width_px, fr.height_px): fps_of_interval(fr.intervals_100ns[0])
                for f in self.formats for fr in f.frames}

    def udev_serial(self, serial: str | None = None) -> str:
        """udev's ID_SERIAL: ``<manufacturer>_<product>_<serial>``, the USB ids in hex where a string
        is missing (systemd's ``usb_id`` builtin); the ``/dev/v4l/by-id`` link names are built on it."""
        vendor = udev_sanitize(self.manufacturer) if self.manufacturer else f"{self.vendor_id or 0:04x}"
        model = udev_sanitize(self.product) if self.product else f"{self.product_id or 0:04x}"
        s = udev_sanitize(serial if serial is not None else self.serial)
        return f"{vendor}_{model}_{s}" if s else f"{vendor}_{model}"


def udev_sanitize(text: str) -> str:
    """udev's replacement of unsafe characters in an ID_* string: whitespace and anything but
    ``0-9A-Za-z#+-.:=@_`` become ``_`` (systemd ``udev_replace_chars``)."""
    return re.sub(r"[^0-9A-Za-z#+\-.:=@_]", "_", text.strip())


def uvc_simplify_fraction(numerator: int, denominator: int, n_terms: int = 8, threshold: int = 333) -> Fraction:
    """The fraction uvcvideo reports for ``numerator/denominator`` (uvc_driver.c, uvc_simplify_fraction):
    the simple continued fraction, stopped after ``n_terms`` terms or before the first term >= ``threshold``
    (kept if it is one of the first two), expanded back; e.g. 333333/10000000 -> 1/30. Inputs are u32."""
    terms: list[int] = []
    x, y = numerator & 0xFFFFFFFF, denominator & 0xFFFFFFFF
    while len(terms) < n_terms and y != 0:
        a = x // y
        if a >= threshold:
            if len(terms) < 2:
                terms.append(a)
            break
        terms.append(a)
        x, y = y, x - a * y
    num, den = 1, 0
    for a in reversed(terms):
        num, den = (a * num + den) & 0xFFFFFFFF, num
    return Fraction(num, den) if den else Fraction(num, 1)


def uvc_size_distance(width: int, height: int, want_width: int, want_height: int) -> int:
    """uvcvideo's distance between a frame size and a requested one (uvc_v4l2.c, uvc_v4l2_try_format):
    the area of the two rectangles that does not overlap. The first frame of the format at the
    smallest distance is chosen."""
    overlap = min(width, want_width) * min(height, want_height)
    return width * height + want_width * want_height - 2 * overlap


def fps_of_interval(interval_100ns: int) -> float:
    """Frames per second of a UVC frame interval (100 ns units), from the fraction uvcvideo reports."""
    period = uvc_simplify_fraction(int(interval_100ns), 10_000_000)
    return float(1 / period)


def interval_of_fps(fps: float) -> int:
    """The UVC frame interval (100 ns units) of a rate, as the descriptors write it (333333 for 30)."""
    return int(Fraction(10_000_000) / Fraction(fps).limit_denominator(1000))


# -- Logitech C310 ----------------------------------------------------------------------------------

C310_CONTROLS: tuple[UvcControl, ...] = (
    UvcControl("brightness", V4L2_CID["brightness"], "int", 0, 255, 128, label="Brightness", signed=True),
    UvcControl("contrast", V4L2_CID["contrast"], "int", 0, 255, 32, label="Contrast"),
    UvcControl("saturation", V4L2_CID["saturation"], "int", 0, 255, 32, label="Saturation"),
    UvcControl("white_balance_automatic", V4L2_CID["white_balance_automatic"], "bool", 0, 1, 1,
               label="White Balance, Automatic"),
    UvcControl("gain", V4L2_CID["gain"], "int", 0, 255, 64, label="Gain"),
    UvcControl("power_line_frequency", V4L2_CID["power_line_frequency"], "menu", 0, 2, 2, menu=(0, 1, 2),
               label="Power Line Frequency", menu_names=POWER_LINE_MENU[:3]),
    UvcControl("white_balance_temperature", V4L2_CID["white_balance_temperature"], "int", 0, 10000, 4000, step=10,
               active_when=("white_balance_automatic", 0), label="White Balance Temperature"),
    UvcControl("sharpness", V4L2_CID["sharpness"], "int", 0, 255, 24, label="Sharpness"),
    UvcControl("backlight_compensation", V4L2_CID["backlight_compensation"], "int", 0, 1, 0,
               label="Backlight Compensation"),
    UvcControl("auto_exposure", V4L2_CID["auto_exposure"], "menu", 0, 3, 3, menu=(1, 3), label="Auto Exposure",
               menu_names=EXPOSURE_AUTO_MENU),
    UvcControl("exposure_time_absolute", V4L2_CID["exposure_time_absolute"], "int", 1, 10000, 166,
               active_when=("auto_exposure", 1), label="Exposure Time, Absolute"),
    UvcControl("exposure_dynamic_framerate", V4L2_CID["exposure_dynamic_framerate"], "bool", 0, 1, 0,
               label="Exposure, Dynamic Framerate", power_on=1),
)

# A real C310's frame descriptors (lsusb -v of a C310 in AristoChen/usb-proxy/issues/30; the same
# Logitech UVC 1.00 design as the C270 whose complete dump fills the fields that one omits; transcribed
# in tactile_rig/mocks/usb/models/logitech_c310.toml): size, intervals (100 ns), dwDefaultFrameInterval.
_C310_30_TO_5 = (333333, 400000, 500000, 666666, 1000000, 2000000)
_C310_YUYV = (
    ((640, 480), _C310_30_TO_5, 333333), ((160, 120), _C310_30_TO_5, 333333), ((176, 144), _C310_30_TO_5, 333333),
    ((320, 176), _C310_30_TO_5, 333333), ((320, 240), _C310_30_TO_5, 333333), ((352, 288), _C310_30_TO_5, 333333),
    ((432, 240), _C310_30_TO_5, 333333), ((544, 288), _C310_30_TO_5, 333333), ((640, 360), _C310_30_TO_5, 333333),
    ((752, 416), _C310_30_TO_5[1:], 400000), ((800, 448), _C310_30_TO_5[1:], 400000),
    ((800, 600), _C310_30_TO_5[2:], 500000), ((864, 480), _C310_30_TO_5[2:], 500000),
    ((960, 544), _C310_30_TO_5[3:], 666666), ((960, 720), _C310_30_TO_5[4:], 1000000),
    ((1024, 576), _C310_30_TO_5[4:], 1000000), ((1184, 656), _C310_30_TO_5[4:], 1000000),
    ((1280, 720), _C310_30_TO_5[4:], 1000000), ((1280, 960), (1333333, 2000000), 2000000),
)
_C310_SIZES = tuple(size for size, _, _ in _C310_YUYV)


C310 = CameraModel(
    key="c310",
    title="Logitech HD Webcam C310",
    vendor_id=0x046D,
    product_id=0x081B,
    manufacturer=None,
    product=None,
    serial="A1C3F310",
    formats=(
        UvcFormat("YUYV", tuple(UvcFrame(w, h, iv, default_100ns=d) for (w, h), iv, d in _C310_YUYV)),
        UvcFormat("MJPG", tuple(UvcFrame(w, h, _C310_30_TO_5, default_100ns=333333) for w, h in _C310_SIZES),
                  compressed=True),
    ),
    controls=C310_CONTROLS,
    bcd_device=0x0010,
    background="gsmini",
    sources=(
        "USB ids 046d:081b and card 'UVC Camera (046d:081b)' (no product string: dmesg 'Found UVC 1.00 device "
        "<unnamed> (046d:081b)'): public dmesg and v4l2-ctl --list-devices captures of C310s",
        "frame sizes, intervals and default intervals: the frame descriptors of a real C310 (lsusb -v in "
        "AristoChen/usb-proxy/issues/30), as the USB testbed (tactile_rig/mocks/usb/models/logitech_c310.toml) "
        "transcribes them: MJPG 30, 25, 20, 15, 10, 5 fps at every size; YUYV from 30 fps at 640x480 down to "
        "7.5 and 5 at 1280x960",
        "control table (ids, ranges, steps, defaults, inactive flags, exposure_dynamic_framerate powering up at 1 "
        "with GET_DEF 0): public v4l2-ctl --all / --list-ctrls captures of C310s",
    ),
    notes=(
        "no control is known to reset on a format change: uvcvideo keeps the values (it writes them back only "
        "after a USB reset or resume, uvc_ctrl_restore_values) and no public C310 capture shows the firmware "
        "resetting any; format_change_resets is empty",
        "serial is an example; a real C310 reports its own 8-character serial",
    ),
)

# The historical names the simulated camera and its tests use.
C310_MODES: dict[tuple[str, int, int], float] = C310.modes()


# -- GelSight Mini --------------------------------------------------------------------------------

# Ranges and defaults: a public v4l2-ctl --list-ctrls capture of an Arducam-class UVC camera whose defaults
# are exactly the values gsrobotics' config/mini_set_cam_params.sh writes to a Mini (brightness 0, contrast
# 32, saturation 64, hue 0, sharpness 3); not a capture of a Mini itself.
GELSIGHT_MINI_CONTROLS: tuple[UvcControl, ...] = (
    UvcControl("brightness", V4L2_CID["brightness"], "int", -64, 64, 0, label="Brightness", signed=True),
    UvcControl("contrast", V4L2_CID["contrast"], "int", 0, 64, 32, label="Contrast"),
    UvcControl("saturation", V4L2_CID["saturation"], "int", 0, 128, 64, label="Saturation"),
    UvcControl("hue", V4L2_CID["hue"], "int", -40, 40, 0, label="Hue", signed=True),
    UvcControl("white_balance_automatic", V4L2_CID["white_balance_automatic"], "bool", 0, 1, 1,
               label="White Balance, Automatic"),
    UvcControl("gamma", V4L2_CID["gamma"], "int", 72, 500, 100, label="Gamma"),
    UvcControl("gain", V4L2_CID["gain"], "int", 0, 100, 0, label="Gain"),
    UvcControl("power_line_frequency", V4L2_CID["power_line_frequency"], "menu", 0, 2, 1, menu=(0, 1, 2),
               label="Power Line Frequency", menu_names=POWER_LINE_MENU[:3]),
    UvcControl("white_balance_temperature", V4L2_CID["white_balance_temperature"], "int", 2800, 6500, 4600,
               active_when=("white_balance_automatic", 0), label="White Balance Temperature"),
    UvcControl("sharpness", V4L2_CID["sharpness"], "int", 0, 6, 3, label="Sharpness"),
    UvcControl("backlight_compensation", V4L2_CID["backlight_compensation"], "int", 0, 2, 1,
               label="Backlight Compensation"),
    UvcControl("auto_exposure", V4L2_CID["auto_exposure"], "menu", 0, 3, 3, menu=(1, 3), label="Auto Exposure",
               menu_names=EXPOSURE_AUTO_MENU),
    UvcControl("exposure_time_absolute", V4L2_CID["exposure_time_absolute"], "int", 1, 5000, 157,
               active_when=("auto_exposure", 1), label="Exposure Time, Absolute"),
    UvcControl("exposure_dynamic_framerate", V4L2_CID["exposure_dynamic_framerate"], "bool", 0, 1, 0,
               label="Exposure, Dynamic Framerate", power_on=1),
)

GELSIGHT_MINI = CameraModel(
    key="gelsight-mini",
    title="GelSight Mini",
    vendor_id=0x0C45,
    product_id=0x636D,
    manufacturer="Arducam Technology Co., Ltd.",
    product="GelSight Mini R0B 28F5-K4RR",
    function="GelSight Mini R0B 28F5-K4RR",
    serial="28F5K4RR",
    bcd_device=0x0100,
    formats=(UvcFormat("MJPG", (UvcFrame(3280, 2464, (400000,)),), compressed=True),),
    controls=GELSIGHT_MINI_CONTROLS,
    background="gsmini",
    product_prefix="GelSight Mini",
    sdk_views=(
        SdkView("gs_sdk", "joehjhuang/gs_sdk gs_sdk/gs_device.py resize_crop (examples/configs/gsmini.yaml)",
                border_rows=1 / 7, border_cols=1 / 7, keep_aspect=True, output_px=(320, 240)),
        SdkView("gsrobotics", "gelsightinc/gsrobotics utilities/image_processing.py crop_and_resize "
                "(default_config.json border_fraction 0.15)", border_rows=0.15, border_cols=0.15,
                output_px=(320, 240)),
    ),
    sources=(
        "USB strings: /dev/v4l/by-id/usb-Arducam_Technology_Co.__Ltd._GelSight_Mini_R0B_28F5-K4RR_28F5K4RR-video-index0 "
        "(public lab code) -> manufacturer 'Arducam Technology Co., Ltd.', product 'GelSight Mini R0B <ID>', serial "
        "'<ID without dash>'; uvcvideo names it 'GelSight Mini R0B <ID>: Ge' (31 characters, seen in public code)",
        "USB ids 0c45:636d (the Sonix/Microdia id of Arducam's UVC module), bcdDevice 1.00, 480 Mb/s, 500 mA: "
        "lsusb and macOS system_profiler listings of a Mini in xiaoxiaoxh/reactive_diffusion_policy/issues/13",
        "two nodes per Mini, capture and metadata: gelsightinc/gsrobotics/issues/5",
        "MJPG 3280x2464 at 25 fps: joehjhuang/gs_sdk examples/configs/gsmini.yaml (raw_imgw/raw_imgh/framerate) "
        "and a public V4L2 mode capture (MJPEG 3280x2464, 25 fps advertised, ~18.8 Hz delivered)",
        "control names: gelsightinc/gsrobotics config/mini_set_cam_params.sh",
    ),
    notes=(
        "0c45:636d is a generic Arducam/Sonix id other cameras share: discovery matches the product string too",
        "only the documented 3280x2464 MJPG mode is modelled (both SDKs ask OpenCV for 320x240 and crop and "
        "resize the raw frame themselves)",
        "control ranges are modelled (see GELSIGHT_MINI_CONTROLS)",
    ),
)


# -- DIGIT ------------------------------------------------------------------------------------------

DIGIT_CONTROLS: tuple[UvcControl, ...] = (
    # The LED drive: digit-interface writes (r << 8) | (g << 4) | b, each 0..15, through CAP_PROP_ZOOM.
    UvcControl("zoom_absolute", V4L2_CID["zoom_absolute"], "int", 0, 0xFFF, 0xFFF, label="Zoom, Absolute"),
)

DIGIT = CameraModel(
    key="digit",
    title="DIGIT (Meta / GelSight)",
    vendor_id=0x2833,
    product_id=0x0209,
    manufacturer="Facebook",
    product="DIGIT",
    function="DIGIT",
    serial="D20001",
    bcd_device=0x0200,
    formats=(UvcFormat("YUYV", (UvcFrame(640, 480, (333333, 666666)), UvcFrame(320, 240, (166666, 333333)))),),
    controls=DIGIT_CONTROLS,
    led_controls=("zoom_absolute",),
    background="digit",
    sdk_views=(
        SdkView("digit-interface", "facebookresearch/digit-interface digit_interface/digit.py Digit.get_frame",
                transpose_flip=True),
        SdkView("gs_sdk", "joehjhuang/gs_sdk gs_sdk/gs_device.py resize_crop (examples/configs/digit.yaml)",
                border_rows=1 / 7, border_cols=1 / 7, keep_aspect=True, output_px=(320, 240)),
    ),
    sources=(
        "USB device descriptor 2833:0209, bcdDevice 2.00, strings 'Facebook' / 'DIGIT': the firmware image "
        "facebookresearch/digit-design DIGIT/firmware/digit-2021-2a.bin; udev rule udev/50-DIGIT.rules",
        "card 'DIGIT: DIGIT' (product and function strings): public lab configuration files",
        "modes: the firmware's stream table (UNCOMPRESSED 320x240 at 60 and 30 fps, 640x480 at 30 and 15 fps) and "
        "digit-interface digit_interface/digit.py DigitDefaults.STREAMS; VGA 30 fps is the power-on stream (README)",
        "LED control through zoom_absolute: digit_interface/digit.py set_intensity_rgb (CAP_PROP_ZOOM)",
    ),
    notes=(
        "the uncompressed format is YUYV (the firmware names it UNCOMPRESSED; its bridge builds the descriptors)",
        "the control set beyond the LED (zoom_absolute) is not published; the model has only that control",
        "serial is an example; digit-interface finds a DIGIT by its serial (ID_SERIAL_SHORT), e.g. D20001",
    ),
)

CAMERA_MODELS: dict[str, CameraModel] = {m.key: m for m in (C310, GELSIGHT_MINI, DIGIT)}


def camera_model_by_usb_kind(kind: str) -> CameraModel | None:
    """The model discovery reports as ``kind`` (``camera_digit``), or None."""
    return next((m for m in CAMERA_MODELS.values() if m.usb_kind == kind), None)


def camera_model(key: str) -> CameraModel:
    """A model by key (``c310``, ``gelsight-mini``, ``digit``); ValueError naming the known ones."""
    try:
        return CAMERA_MODELS[key]
    except KeyError:
        raise ValueError(f"unknown camera model {key!r}; known: {', '.join(CAMERA_MODELS)}") from None
