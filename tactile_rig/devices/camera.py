"""UVC camera facts shared by the camera driver and the simulated camera: control names, the order
controls must be written in, the locked photometric set, and FOURCC codes."""

from __future__ import annotations

# Kernels ≥ 5.x renamed several UVC controls; accept both spellings, store the new one.
CONTROL_ALIASES = {
    "exposure_auto": "auto_exposure",
    "exposure_absolute": "exposure_time_absolute",
    "white_balance_temperature_auto": "white_balance_automatic",
    "exposure_auto_priority": "exposure_dynamic_framerate",
}
# Written first: a manual value is ignored (inactive) while its auto switch is on.
AUTO_SWITCHES = ("auto_exposure", "white_balance_automatic", "exposure_dynamic_framerate")

PHOTOMETRIC_CONTROLS: dict[str, float] = {
    "auto_exposure": 1,  # V4L2 menu: 1 = manual, 3 = aperture priority
    "exposure_time_absolute": 166,  # 100 µs units
    "white_balance_automatic": 0,
    "white_balance_temperature": 4000,
    "gain": 64,
}
"""Locked controls for photometric (GelSight) work: no auto exposure, no auto white balance."""


def canonical_control(name: str) -> str:
    """The current kernel name of a UVC control (old names accepted)."""
    return CONTROL_ALIASES.get(name, name)


def fourcc_text(code: float) -> str:
    """The four characters of a FOURCC code as OpenCV reports it (a float holding 4 bytes, little end first)."""
    c = int(code)
    return "".join(chr((c >> (8 * i)) & 0xFF) for i in range(4))
