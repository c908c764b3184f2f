"""UVC camera facts shared by the camera driver and the simulated camera: control names, the order
controls must be written in, the locked photometric set, and FOURCC codes."""

from __future__ import annotations

import math

from tactile_rig.devices.camera_models import CameraModel

# Kernels ≥ 5.x renamed several UVC controls; accept both spellings, store the new one.
CONTROL_ALIASES = {
    "exposure_auto": "auto_exposure",
    "exposure_absolute": "exposure_time_absolute",
    "white_balance_temperature_auto": "white_balance_automatic",
    "exposure_auto_priority": "exposure_dynamic_framerate",
}
# Written first: a manual value is refused (inactive) while its auto switch is on, and with
# exposure_dynamic_framerate on the camera may lengthen the exposure past the frame period.
AUTO_SWITCHES = ("auto_exposure", "white_balance_automatic", "exposure_dynamic_framerate")

PHOTOMETRIC_CONTROLS: dict[str, float] = {
    "auto_exposure": 1,  # V4L2 menu: 1 = manual, 3 = aperture priority
    "exposure_time_absolute": 166,  # 100 µs units
    "white_balance_automatic": 0,
    "white_balance_temperature": 4000,
    "gain": 64,
    "exposure_dynamic_framerate": 0,  # the frame rate stays the configured one whatever the light
}
"""Locked controls for photometric (GelSight) work: no auto exposure, no auto white balance, no
frame-rate drop in dim light (the Logitech C310's values; :func:`photometric_lock` gives any
model's). The power line frequency joins the lock when the mains frequency is known
(:func:`power_line_control`)."""

# The auto switches' manual settings; the other locked controls hold a value of the camera's own.
_MANUAL_SETTINGS = {"auto_exposure": 1, "white_balance_automatic": 0, "exposure_dynamic_framerate": 0}

# V4L2_CID_POWER_LINE_FREQUENCY's menu (uvcvideo): 0 disabled, 1 50 Hz, 2 60 Hz, 3 auto.
POWER_LINE_INDEX = {50.0: 1, 60.0: 2}


def power_line_control(mains_hz: float) -> dict[str, float]:
    """``{"power_line_frequency": index}`` for the lab's mains (50 or 60 Hz): the camera's
    anti-flicker filter matched to the lights (a wrong one leaves bands that move across the gel)."""
    if not (isinstance(mains_hz, (int, float)) and math.isfinite(mains_hz) and float(mains_hz) in POWER_LINE_INDEX):
        raise ValueError(f"mains_hz={mains_hz!r} must be 50 or 60 (the lab's mains frequency, Hz)")
    return {"power_line_frequency": POWER_LINE_INDEX[float(mains_hz)]}


def photometric_lock(model: CameraModel | None = None, mains_hz: float | None = None) -> dict[str, float]:
    """The controls to lock for photometric work, in the order to write them.

    Without a model: :data:`PHOTOMETRIC_CONTROLS`. With one: the controls of that set the camera
    has, the auto switches at their manual settings and the manual values at the camera's own
    defaults, and the controls driving the sensor's LEDs (the DIGIT's) at their defaults. With
    ``mains_hz`` (and, with a model, a power line control on the camera): the power line frequency."""
    if model is None:
        lock = dict(PHOTOMETRIC_CONTROLS)
    else:
        lock = {}
        for name in PHOTOMETRIC_CONTROLS:
            c = model.control(name)
            if c is not None:
                lock[name] = float(_MANUAL_SETTINGS.get(name, c.default))
        for name in model.led_controls:
            c = model.control(name)
            assert c is not None  # CameraModel checks its led_controls
            lock[name] = float(c.default)
    if mains_hz is not None and (model is None or model.control("power_line_frequency") is not None):
        lock.update(power_line_control(mains_hz))
    return lock


def canonical_control(name: str) -> str:
    """The current kernel name of a UVC control (old names accepted)."""
    return CONTROL_ALIASES.get(name, name)


def fourcc_text(code: float) -> str:
    """The four characters of a FOURCC code as OpenCV reports it (a float holding 4 bytes, little end first)."""
    c = int(code)
    return "".join(chr((c >> (8 * i)) & 0xFF) for i in range(4))
