"""Client bodies that run in a child process started with an emulated camera's environment
(:func:`tactile_rig.mocks.v4l2.child.run_in_child`): OpenCV's V4L2 backend as an application uses it.

Only OpenCV and the standard library are imported here, so a child starts in about half a second.
"""

from __future__ import annotations

import hashlib
import time
from typing import Any

import cv2

FOURCC_YUYV = cv2.VideoWriter_fourcc(*"YUYV")
FOURCC_MJPG = cv2.VideoWriter_fourcc(*"MJPG")

# The photometric controls a tactile bench sets, as OpenCV names them, with the V4L2 control each
# maps to and a value to write that differs from the C310's default.
PHOTOMETRIC = (
    ("CAP_PROP_AUTO_EXPOSURE", "auto_exposure", 1),
    ("CAP_PROP_EXPOSURE", "exposure_time_absolute", 250),
    ("CAP_PROP_AUTO_WB", "white_balance_automatic", 0),
    ("CAP_PROP_WB_TEMPERATURE", "white_balance_temperature", 5000),
    ("CAP_PROP_GAIN", "gain", 100),
    ("CAP_PROP_BRIGHTNESS", "brightness", 150),
    ("CAP_PROP_CONTRAST", "contrast", 40),
    ("CAP_PROP_SATURATION", "saturation", 50),
    ("CAP_PROP_SHARPNESS", "sharpness", 100),
    ("CAP_PROP_BACKLIGHT", "backlight_compensation", 1),
)


# -- the client bodies (run in the child) ----------------------------------------------------------------
def open_capture(port: str, fourcc: int | None = None, width: int | None = None, height: int | None = None,
          fps: float | None = None) -> Any:
    cap = cv2.VideoCapture(port, cv2.CAP_V4L2)
    if not cap.isOpened():
        raise RuntimeError(f"OpenCV could not open {port}")
    if fourcc is not None:
        cap.set(cv2.CAP_PROP_FOURCC, fourcc)
    if width is not None:
        cap.set(cv2.CAP_PROP_FRAME_WIDTH, width)
        cap.set(cv2.CAP_PROP_FRAME_HEIGHT, height)
    if fps is not None:
        cap.set(cv2.CAP_PROP_FPS, fps)
    return cap


def grab_frames(port: str, fourcc: int, width: int, height: int, fps: float, n: int) -> dict[str, Any]:
    cap = open_capture(port, fourcc, width, height, fps)
    got = {"backend": cap.getBackendName(), "fourcc": int(cap.get(cv2.CAP_PROP_FOURCC)),
           "size": (int(cap.get(cv2.CAP_PROP_FRAME_WIDTH)), int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT))),
           "fps": cap.get(cv2.CAP_PROP_FPS), "frames": []}
    for _ in range(n):
        ok, img = cap.read()
        if not ok:
            raise RuntimeError("read() failed on a healthy camera")
        got["frames"].append((cap.get(cv2.CAP_PROP_POS_MSEC), img))
    cap.release()
    return got


def defaults_then_writes(port: str, writes: list[tuple[str, float]]) -> dict[str, Any]:
    cap = open_capture(port)
    props = [p for p, _, _ in PHOTOMETRIC] + ["CAP_PROP_HUE", "CAP_PROP_FOCUS"]
    initial = {p: cap.get(getattr(cv2, p)) for p in props}
    results = []
    for prop, value in writes:
        ok = cap.set(getattr(cv2, prop), value)
        results.append((prop, value, ok, cap.get(getattr(cv2, prop))))
    cap.release()
    return {"initial": initial, "writes": results}


def read_log(port: str, n: int, sleep_before_last_s: float = 0.0) -> list[tuple[bool, float, float, str | None, bool]]:
    """(ok, seconds read() took, POS_MSEC, a hash of the image, isOpened) for ``n`` reads."""
    cap = open_capture(port, FOURCC_YUYV, 320, 240)
    rows = []
    for i in range(n):
        if i == n - 1 and sleep_before_last_s:
            time.sleep(sleep_before_last_s)
        t = time.monotonic()
        ok, img = cap.read()
        took = time.monotonic() - t
        digest = hashlib.sha256(img.tobytes()).hexdigest()[:12] if ok else None
        rows.append((bool(ok), took, cap.get(cv2.CAP_PROP_POS_MSEC), digest, bool(cap.isOpened())))
    cap.release()
    return rows


def opens_and_reads(port: str) -> tuple[bool, bool, float, float]:
    """(isOpened, read ok, the exposure and auto exposure it reads) on a fresh capture."""
    cap = cv2.VideoCapture(port, cv2.CAP_V4L2)
    opened = bool(cap.isOpened())
    ok = bool(cap.read()[0]) if opened else False
    out = (opened, ok, cap.get(cv2.CAP_PROP_EXPOSURE), cap.get(cv2.CAP_PROP_AUTO_EXPOSURE))
    cap.release()
    return out



def width_then_height(port: str) -> list[tuple[int, int]]:
    """(width, height) OpenCV reports after setting the width alone, then the height."""
    cap = open_capture(port)
    out = [(int(cap.get(cv2.CAP_PROP_FRAME_WIDTH)), int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT)))]
    cap.set(cv2.CAP_PROP_FRAME_WIDTH, 320)
    out.append((int(cap.get(cv2.CAP_PROP_FRAME_WIDTH)), int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT))))
    cap.set(cv2.CAP_PROP_FRAME_HEIGHT, 240)
    out.append((int(cap.get(cv2.CAP_PROP_FRAME_WIDTH)), int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT))))
    ok, img = cap.read()
    out.append(tuple(img.shape[:2][::-1]) if ok else (0, 0))
    cap.release()
    return out


def fourcc_change_keeps_controls(port: str) -> tuple[float, float, bool]:
    """Gain set, a frame read, FOURCC changed to MJPG: (gain before, gain after, read ok after)."""
    cap = open_capture(port)
    cap.set(cv2.CAP_PROP_GAIN, 100)
    cap.read()
    before = cap.get(cv2.CAP_PROP_GAIN)
    cap.set(cv2.CAP_PROP_FOURCC, FOURCC_MJPG)
    after = cap.get(cv2.CAP_PROP_GAIN)
    ok = bool(cap.read()[0])
    cap.release()
    return before, after, ok
