"""Closing an OpenCV camera while its capture thread reads: ``cv2.VideoCapture`` is not thread-safe
(``release()`` during another thread's ``read()`` frees the buffers that read fills: a SIGSEGV of the
whole process, seen on the emulated C310 on every few dozen opens), so the source releases the
capture only after a read in progress has returned, and the driver's capture thread then ends
without reporting the camera lost."""

from __future__ import annotations

import logging
import threading
import time

import cv2
import numpy as np

from tactile_rig.drivers.camera import FingertipCamera, OpenCVSource


class SlowCapture:
    """A capture whose ``read()`` takes ``read_s`` (a frame interval, or a stalled camera's select())
    and which records any call made while a read is in progress."""

    def __init__(self, read_s: float) -> None:
        self.read_s = read_s
        self.reading = False
        self.released = False
        self.overlaps: list[str] = []
        self.props: dict[int, float] = {cv2.CAP_PROP_FOURCC: float(cv2.VideoWriter.fourcc(*"MJPG")),
                                        cv2.CAP_PROP_FRAME_WIDTH: 64, cv2.CAP_PROP_FRAME_HEIGHT: 48,
                                        cv2.CAP_PROP_FPS: 10.0}

    def _enter(self, what: str) -> None:
        if self.reading:
            self.overlaps.append(what)

    def isOpened(self) -> bool:  # noqa: N802  (cv2 API)
        return not self.released

    def read(self) -> tuple[bool, np.ndarray | None]:
        self._enter("read")
        self.reading = True
        time.sleep(self.read_s)
        self.reading = False
        if self.released:
            return False, None
        return True, np.full((48, 64, 3), int(time.monotonic() * 1000) % 251, np.uint8)

    def release(self) -> None:
        self._enter("release")
        self.released = True

    def set(self, prop: int, value: float) -> bool:
        self._enter("set")
        if prop in self.props:
            self.props[prop] = float(value)
        return True

    def get(self, prop: int) -> float:
        self._enter("get")
        return self.props.get(prop, 0.0)


def test_close_waits_for_the_read_in_progress() -> None:
    cap = SlowCapture(0.3)
    src = OpenCVSource("/dev/video9", capture_factory=lambda device, api: cap)
    src.open()
    reader = threading.Thread(target=src.read)
    reader.start()
    time.sleep(0.05)  # the read is under way
    src.close()
    reader.join(2.0)
    assert cap.released and cap.overlaps == []


def test_a_threaded_camera_closes_without_calling_its_source_lost(caplog) -> None:
    cap = SlowCapture(0.1)
    cam = FingertipCamera(OpenCVSource("/dev/video9", capture_factory=lambda device, api: cap), name="cam",
                          fourcc="MJPG", width=64, height=48, fps=10.0, controls={})
    with caplog.at_level(logging.WARNING, logger="tactile_rig.camera"):
        cam.open()
        cam.read(2.0)
        cam.close()
    assert cap.released and cap.overlaps == []
    assert not [r for r in caplog.records if "lost" in r.getMessage()]
