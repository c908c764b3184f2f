"""Camera models as data: uvcvideo's naming, clamping and fraction rules on them, and their facts."""

from __future__ import annotations

import errno
import struct
from fractions import Fraction

import pytest
from hypothesis import given
from hypothesis import strategies as st

from tactile_rig.devices.camera_models import (C310, CAMERA_MODELS, DIGIT, GELSIGHT_MINI, UvcControl, camera_model,
                                               fps_of_interval, udev_sanitize, uvc_simplify_fraction)
from tactile_rig.mocks.camera import C310_CONTROLS, C310_MODES
from tactile_rig.mocks.usb.descriptors import Configuration
from tactile_rig.mocks.usb.models import load_model


def test_card_names_follow_uvc_probe() -> None:
    assert C310.card == "UVC Camera (046d:081b)"  # no product string
    assert GELSIGHT_MINI.card == "GelSight Mini R0B 28F5-K4RR: Ge"  # product ": " function, 31 characters
    assert DIGIT.card == "DIGIT: DIGIT"
    assert len(GELSIGHT_MINI.card) == 31


def test_models_by_key_and_the_historical_names() -> None:
    assert set(CAMERA_MODELS) == {"c310", "gelsight-mini", "digit"}
    assert camera_model("digit") is DIGIT
    with pytest.raises(ValueError, match="unknown camera model 'nope'"):
        camera_model("nope")
    assert C310_CONTROLS == C310.controls
    assert C310_MODES[("MJPG", 640, 480)] == 30.0 and C310_MODES[("YUYV", 1280, 960)] == 7.5
    assert (DIGIT.vendor_id, DIGIT.product_id) == (0x2833, 0x0209)
    assert DIGIT.modes() == {("YUYV", 640, 480): 30.0, ("YUYV", 320, 240): 60.0}


@pytest.mark.parametrize(("interval", "fraction"), [(333333, Fraction(1, 30)), (400000, Fraction(1, 25)),
                                                    (666666, Fraction(1, 15)), (1333333, Fraction(2, 15)),
                                                    (166666, Fraction(1, 60)), (2000000, Fraction(1, 5))])
def test_uvc_simplify_fraction_gives_the_rates_v4l2_ctl_prints(interval: int, fraction: Fraction) -> None:
    assert uvc_simplify_fraction(interval, 10_000_000) == fraction


@given(st.integers(1, 0xFFFFFFFF), st.integers(1, 0xFFFFFFFF))
def test_uvc_simplify_fraction_is_close_and_finite(num: int, den: int) -> None:
    f = uvc_simplify_fraction(num, den)
    assert f.denominator > 0
    if num / den < 333 and den / num < 1e6:  # the continued fraction ran its course or hit a large term
        assert abs(float(f) - num / den) <= 0.01 * num / den + 1 / 333


def test_fps_of_interval() -> None:
    assert fps_of_interval(333333) == 30.0 and fps_of_interval(1333333) == 7.5


@given(st.integers(-(2 ** 31), 2 ** 31 - 1))
def test_clamp_as_uvcvideo_signed_and_unsigned(value: int) -> None:
    brightness = UvcControl("b", 1, "int", -64, 64, 0, signed=True)
    gain = UvcControl("g", 2, "int", 0, 255, 64)
    wb = UvcControl("w", 3, "int", 2800, 6500, 4600, step=10)
    for c in (brightness, gain, wb):
        v = c.clamp(value)
        assert c.minimum <= v <= c.maximum
        assert (v - c.minimum) % c.step == 0 or v == c.maximum
    if value < 0:
        assert gain.clamp(value) == 255  # u32 arithmetic: a negative write is huge
        assert brightness.clamp(value) == max(-64, brightness.minimum + round((value + 64) / 1) * 1)
    if 2800 <= value <= 6500:
        assert abs(wb.clamp(value) - value) <= 5


def test_menu_errors() -> None:
    ae = C310.control("auto_exposure")
    assert ae is not None
    assert [ae.menu_errno(i) for i in (-1, 0, 1, 2, 3, 4)] == [errno.ERANGE, errno.EINVAL, 0, errno.EINVAL, 0,
                                                              errno.ERANGE]


def test_udev_sanitize_and_by_id_serial() -> None:
    assert udev_sanitize("Arducam Technology Co., Ltd.") == "Arducam_Technology_Co.__Ltd."
    assert udev_sanitize(" GelSight Mini R0B 28F5-K4RR ") == "GelSight_Mini_R0B_28F5-K4RR"


def test_sdk_crops() -> None:
    gs_sdk = {v.name: v for v in GELSIGHT_MINI.sdk_views}["gs_sdk"]
    x0, y0, x1, y1 = gs_sdk.crop_box(3280, 2464)
    assert (x1 - x0) / (y1 - y0) == pytest.approx(4 / 3, rel=0.01)
    assert x0 == pytest.approx(3280 / 7, abs=2)
    gsr = {v.name: v for v in GELSIGHT_MINI.sdk_views}["gsrobotics"]
    # crop_and_resize: int(2464 * 0.15) = 369 rows and int(3280 * 0.15) = 492 columns off each side.
    assert gsr.crop_box(3280, 2464) == (492, 369, 2788, 2095)


def _uvc_streaming_formats(config: Configuration) -> list[tuple[str, list[tuple[int, int, tuple[int, ...], int, int]]]]:
    """(format, [(width, height, intervals, default interval, max frame bytes)]) from the class-specific
    VideoStreaming descriptors (UVC 1.1 3.9.2): formats 0x04 (uncompressed) and 0x06 (MJPEG), frames
    0x05 and 0x07."""
    out: list[tuple[str, list[tuple[int, int, tuple[int, ...], int, int]]]] = []
    streaming = [alts[0] for alts in config.interfaces if alts[0].bInterfaceClass == 0x0E
                 and alts[0].bInterfaceSubClass == 0x02]
    assert len(streaming) == 1
    extra, descriptors = streaming[0].extra, []
    while extra:
        descriptors.append(extra[:extra[0]])
        extra = extra[extra[0]:]
    for d in descriptors:
        if len(d) < 3 or d[1] != 0x24:
            continue
        if d[2] in (0x04, 0x06):
            out.append(("YUYV" if d[2] == 0x04 else "MJPG", []))
        elif d[2] in (0x05, 0x07) and out:
            w, h = struct.unpack_from("<HH", d, 5)
            max_bytes, default = struct.unpack_from("<II", d, 17)
            n = d[25]
            intervals = struct.unpack_from(f"<{n}I", d, 26)
            out[-1][1].append((w, h, intervals, default, max_bytes))
    return out


def _class_descriptors(extra: bytes) -> list[bytes]:
    out = []
    while extra:
        out.append(extra[:extra[0]])
        extra = extra[extra[0]:]
    return [d for d in out if len(d) >= 3 and d[1] == 0x24]


def test_the_c310_models_format_and_uvc_facts_are_the_descriptors() -> None:
    """The rest of what the model says about the C310 against the same descriptors: the UVC version of
    the VideoControl header, the formats in order with their compressed flag and default frame, and the
    device's USB identity."""
    usb = load_model("logitech_c310")
    config = usb.parsed_configuration()
    (control,) = [alts[0] for alts in config.interfaces if (alts[0].bInterfaceClass, alts[0].bInterfaceSubClass)
                  == (0x0E, 0x01)]
    header = next(d for d in _class_descriptors(control.extra) if d[2] == 0x01)
    assert struct.unpack_from("<H", header, 3)[0] == C310.uvc_version
    (streaming,) = [alts[0] for alts in config.interfaces if (alts[0].bInterfaceClass, alts[0].bInterfaceSubClass)
                    == (0x0E, 0x02)]
    formats = [d for d in _class_descriptors(streaming.extra) if d[2] in (0x04, 0x06)]
    # uncompressed (0x04): bDefaultFrameIndex at byte 22; MJPEG (0x06): at byte 6 (UVC 1.1 3.9.2.x)
    seen = [("YUYV" if d[2] == 0x04 else "MJPG", d[2] == 0x06, d[22 if d[2] == 0x04 else 6] - 1, d[4])
            for d in formats]
    assert seen == [(f.fourcc, f.compressed, f.default_frame, len(f.frames)) for f in C310.formats]
    assert (usb.vid, usb.pid, usb.device.bcdDevice) == (C310.vendor_id, C310.product_id, C310.bcd_device)
    assert (usb.manufacturer, usb.product) == (None, None) == (C310.manufacturer, C310.product)


def test_the_c310_model_is_the_c310s_usb_descriptors() -> None:
    """Two transcriptions of one real C310 (its frame descriptors, as the USB testbed holds them)
    agree with the model: sizes in order, intervals, default intervals, frame buffer sizes."""
    config = load_model("logitech_c310").parsed_configuration()
    usb = _uvc_streaming_formats(config)
    model = [(f.fourcc, [(fr.width_px, fr.height_px, fr.intervals_100ns, fr.default_interval_100ns, fr.max_frame_bytes)
                         for fr in f.frames]) for f in C310.formats]
    assert usb == model
