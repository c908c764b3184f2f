"""Format negotiation as uvcvideo does it (drivers/media/usb/uvc/uvc_v4l2.c): the closest frame size
of the asked format (or of the default format), the frame's default interval, and the closest
discrete interval for ``S_PARM``; fractions reported as uvcvideo simplifies them.
"""

from __future__ import annotations

from dataclasses import dataclass
from fractions import Fraction

from tactile_rig.devices.camera_models import CameraModel, UvcFormat, UvcFrame, uvc_simplify_fraction
import tactile_rig.mocks.v4l2.abi as abi


@dataclass(frozen=True)
class StreamFormat:
    """What the stream is set to: format, frame, interval (100 ns)."""

    format: UvcFormat
    frame: UvcFrame
    interval_100ns: int

    @property
    def fourcc(self) -> str:
        return self.format.fourcc

    @property
    def width_px(self) -> int:
        return self.frame.width_px

    @property
    def height_px(self) -> int:
        return self.frame.height_px

    @property
    def fps(self) -> float:
        return float(1 / interval_fraction(self.interval_100ns))

    @property
    def bytesperline(self) -> int:
        # uvc_v4l2_get_bytesperline: bits per pixel x width / 8; MJPG has no bits per pixel.
        return 0 if self.format.compressed else 2 * self.frame.width_px

    @property
    def sizeimage(self) -> int:
        return self.frame.max_frame_bytes


def interval_fraction(interval_100ns: int) -> Fraction:
    """The frame period in seconds as uvcvideo reports it (``timeperframe``)."""
    return uvc_simplify_fraction(interval_100ns, 10_000_000)


def default_stream(model: CameraModel) -> StreamFormat:
    """The power-on format: the first format's default frame at its default interval."""
    fmt = model.formats[0]
    frame = fmt.frames[fmt.default_frame]
    return StreamFormat(fmt, frame, frame.default_interval_100ns)


def closest_frame(fmt: UvcFormat, width: int, height: int) -> UvcFrame:
    """uvc_v4l2_try_format: the frame whose size differs least (area not shared with the request)."""
    best, best_d = fmt.frames[0], None
    for fr in fmt.frames:
        shared = min(fr.width_px, width) * min(fr.height_px, height)
        d = fr.width_px * fr.height_px + width * height - 2 * shared
        if best_d is None or d < best_d:
            best, best_d = fr, d
        if d == 0:
            break
    return best


def try_format(model: CameraModel, pixelformat: int, width: int, height: int) -> StreamFormat:
    """What S_FMT/TRY_FMT settles on: an unknown pixel format falls back to the default format."""
    fmt = next((f for f in model.formats if abi.fourcc(f.fourcc) == pixelformat), model.formats[0])
    frame = closest_frame(fmt, width & 0xFFFF, height & 0xFFFF)  # uvcvideo keeps them in u16
    return StreamFormat(fmt, frame, closest_interval(frame, frame.default_interval_100ns))


def closest_interval(frame: UvcFrame, interval_100ns: int) -> int:
    """uvc_try_frame_interval for discrete intervals: walk the list while the distance shrinks."""
    best = None
    chosen = frame.intervals_100ns[0]
    for i in frame.intervals_100ns:
        d = abs(interval_100ns - i)
        if best is not None and d > best:
            break
        best, chosen = d, i
    return chosen


def fraction_to_interval(numerator: int, denominator: int) -> int:
    """uvc_fraction_to_interval: seconds as a fraction -> 100 ns units, saturating at u32."""
    u32 = 0xFFFFFFFF
    if denominator == 0 or numerator // denominator >= u32 // 10_000_000:
        return u32
    multiplier = 10_000_000
    while numerator > u32 // multiplier:
        multiplier //= 2
        denominator //= 2
    return (numerator * multiplier) // denominator if denominator else 0


def set_interval(model: CameraModel, cur: StreamFormat, numerator: int, denominator: int) -> StreamFormat:
    """uvc_v4l2_set_streamparm: the closest interval of the current frame, or of another frame of the
    same size in the same format when it comes closer."""
    want = fraction_to_interval(numerator, denominator)
    frame = cur.frame
    ival = closest_interval(frame, want)
    maxd = abs(ival - want)
    for fr in cur.format.frames:
        if maxd == 0:
            break
        if fr is cur.frame or (fr.width_px, fr.height_px) != (cur.frame.width_px, cur.frame.height_px):
            continue
        iv = closest_interval(fr, want)
        d = abs(iv - want)
        if d < maxd:
            frame, ival, maxd = fr, iv, d
    return StreamFormat(cur.format, frame, ival)


def frame_sizes(fmt: UvcFormat) -> list[UvcFrame]:
    """The frames ENUM_FRAMESIZES lists, duplicate sizes skipped as uvcvideo does."""
    out: list[UvcFrame] = []
    for fr in fmt.frames:
        if out and (out[-1].width_px, out[-1].height_px) == (fr.width_px, fr.height_px):
            continue
        out.append(fr)
    return out


def frame_intervals(fmt: UvcFormat, width: int, height: int) -> list[int]:
    """Every interval of every frame of that size (uvc_ioctl_enum_frameintervals)."""
    return [i for fr in fmt.frames if (fr.width_px, fr.height_px) == (width, height) for i in fr.intervals_100ns]
