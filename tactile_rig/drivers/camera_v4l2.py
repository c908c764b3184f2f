"""V4L2 controls by their ids, through linuxpy: what OpenCV's ``CAP_PROP_*`` mapping cannot reach.

OpenCV's V4L2 backend maps a fixed set of properties onto V4L2 controls (``capPropertyToV4L2`` in
``modules/videoio/src/cap_v4l.cpp``): brightness, contrast, saturation, hue, gain, exposure, auto
exposure, auto white balance, white balance temperature, sharpness, backlight, gamma, zoom, focus,
autofocus, pan, tilt, iris... It has no property for the power line frequency
(``V4L2_CID_POWER_LINE_FREQUENCY``) nor for ``exposure_dynamic_framerate``
(``V4L2_CID_EXPOSURE_AUTO_PRIORITY``), which a photometric lock needs. :class:`V4L2Controls` sets and
reads any control by its id (:data:`~tactile_rig.devices.camera_models.V4L2_CID`) on a file of its own
opened beside OpenCV's (controls belong to the device, not to a file handle, and uvcvideo lets any
handle change them while another streams), with ``VIDIOC_G_CTRL`` / ``VIDIOC_S_CTRL`` /
``VIDIOC_QUERYCTRL`` issued by linuxpy (pure Python: ``os.open`` and ``fcntl.ioctl``, so an emulated
camera's preload answers them as it answers OpenCV). The same file tells a vanished device from a
stalled one: once the camera is unplugged every ioctl on it fails with ENODEV (the V4L2 core refuses
them for an unregistered device), a stalled camera still answers.

linuxpy is the optional extra ``v4l2`` (``pip install 'tactile-rig[v4l2]'``; GPL-3.0-or-later, which is
why it is not a base dependency of this MIT package); it is imported when a :class:`V4L2Controls`
opens, and :func:`linuxpy_problem` says whether it can be.
"""

from __future__ import annotations

import errno
import importlib.util
import logging
from typing import Any

from tactile_rig.core.errors import NotConnected
from tactile_rig.devices.camera import canonical_control
from tactile_rig.devices.camera_models import V4L2_CID

__all__ = ["V4L2Controls", "linuxpy_problem", "EXTRA_HINT"]

log = logging.getLogger("tactile_rig.camera")

EXTRA_HINT = "pip install 'tactile-rig[v4l2]' (linuxpy)"
_FLAG_INACTIVE = 0x0010  # V4L2_CTRL_FLAG_INACTIVE


def linuxpy_problem() -> str | None:
    """Why controls by id are unavailable (one line naming the extra), or None."""
    if importlib.util.find_spec("linuxpy") is None:
        return f"linuxpy is not installed: {EXTRA_HINT}"
    return None


def _linuxpy() -> Any:
    # Imported here, not at module level: an optional extra (see the module doc).
    import linuxpy.ioctl
    import linuxpy.video.device
    import linuxpy.video.raw

    return linuxpy


class V4L2Controls:
    """Controls of the V4L2 device at ``path`` by name (their V4L2 ids); ``name`` is for messages."""

    def __init__(self, path: str, *, name: str | None = None) -> None:
        self.path = path
        self.name = name or path
        self._dev: Any = None

    @property
    def is_open(self) -> bool:
        return self._dev is not None

    def open(self) -> None:
        """Open the device file (NotConnected if it cannot be; ImportError without linuxpy)."""
        lp = _linuxpy()
        dev = lp.video.device.Device(self.path, read_write=True, blocking=False)
        try:
            dev.open()
        except OSError as exc:
            raise NotConnected(f"cannot open {self.path} for its controls: {exc}", device=self.name) from exc
        self._dev = dev

    def close(self) -> None:
        dev, self._dev = self._dev, None
        if dev is not None:
            try:
                dev.close()
            except OSError as exc:  # a vanished device may fail to close; the descriptor is gone either way
                log.debug("%s: closing the control file: %s", self.name, exc)

    @staticmethod
    def cid(name: str) -> int | None:
        """The V4L2 id of a control name (old kernel names accepted), or None for a name we do not know."""
        return V4L2_CID.get(canonical_control(name))

    def _need(self) -> Any:
        if self._dev is None:
            raise NotConnected("the control file is not open", device=self.name)
        return self._dev

    def set(self, name: str, value: float) -> int:
        """Write ``value`` (rounded to an integer) to control ``name``: 0, or the errno the driver gave
        (EINVAL: no such control or value; ERANGE: out of the menu's range; EACCES: inactive or
        read-only; ENODEV: the device is gone). A name without a known id gives EINVAL."""
        cid = self.cid(name)
        if cid is None:
            return errno.EINVAL
        lp = _linuxpy()
        try:
            lp.video.device.set_control(self._need(), cid, int(round(value)))
        except OSError as exc:
            return exc.errno or errno.EIO
        return 0

    def get(self, name: str) -> int | None:
        """The control's current value; None when the camera has no such control. ENODEV (the device
        is gone) raises NotConnected."""
        cid = self.cid(name)
        if cid is None:
            return None
        lp = _linuxpy()
        try:
            return int(lp.video.device.get_control(self._need(), cid))
        except OSError as exc:
            if exc.errno == errno.ENODEV:
                raise NotConnected(f"{self.path}: the device is gone (ENODEV)", device=self.name) from exc
            return None

    def inactive(self, name: str) -> bool | None:
        """Whether the control is inactive now (its auto switch is on), None if the camera lacks it."""
        cid = self.cid(name)
        if cid is None:
            return None
        lp = _linuxpy()
        q = lp.video.raw.v4l2_queryctrl()
        q.id = cid
        try:
            lp.ioctl.ioctl(self._need(), lp.video.raw.IOC.QUERYCTRL, q)
        except OSError:
            return None
        return bool(q.flags & _FLAG_INACTIVE)

    def alive(self) -> bool:
        """False once the device is gone (its file answers ENODEV); True while it answers, stalled or not."""
        lp = _linuxpy()
        cap = lp.video.raw.v4l2_capability()
        try:
            lp.ioctl.ioctl(self._need(), lp.video.raw.IOC.QUERYCAP, cap)
        except OSError as exc:
            return exc.errno != errno.ENODEV
        return True
