"""The ioctls of an emulated UVC capture node, as the V4L2 core (drivers/media/v4l2-core/v4l2-ioctl.c),
uvcvideo (drivers/media/usb/uvc/uvc_v4l2.c) and videobuf2 answer them: :class:`UvcIoctls`, mixed into
:class:`~tactile_rig.mocks.v4l2.device.UvcNode`, which holds the state they read and change, and
:data:`HANDLERS`, the table :meth:`~tactile_rig.mocks.v4l2.device.UvcNode.ioctl` dispatches on.

The node answers first as the core does: ENOTTY for what uvcvideo does not implement (``G_STD``,
``ENUMSTD``, ``S_STD``, ``QUERYSTD``, ``PREPARE_BUF``, ``S_SELECTION``, ``S_CROP``, the tuner,
audio, output and DV-timings ioctls, ``LOG_STATUS``: they are not in the table), EBUSY from the
priority check (``VIDIOC_S_PRIORITY``) for the ioctls that change state (:data:`PRIORITY_IOCTLS`),
EINVAL for a buffer type the node does not have. The handlers, one module per job:

* capability and priority: here;
* formats, frame rates, inputs and cropping: :mod:`.ioctl_formats`;
* controls and control events: :mod:`.ioctl_controls`;
* buffers and streaming: :mod:`.ioctl_buffers`;
* who may use the stream (per uvcvideo generation) and the state they share: :mod:`.ioctl_access`.
"""

from __future__ import annotations

import errno
import os
from typing import Callable

import tactile_rig.mocks.v4l2.abi as abi
from tactile_rig.mocks.v4l2.handle import FileHandle
from tactile_rig.mocks.v4l2.ioctl_access import EACCES_FOR_INACTIVE_SINCE, VB2_OWNERSHIP_SINCE, Result
from tactile_rig.mocks.v4l2.ioctl_buffers import BufferIoctls
from tactile_rig.mocks.v4l2.ioctl_controls import ControlIoctls
from tactile_rig.mocks.v4l2.ioctl_formats import FormatIoctls

__all__ = ["HANDLERS", "PRIORITY_IOCTLS", "EXT_CTRLS_IOCTLS", "EACCES_FOR_INACTIVE_SINCE", "VB2_OWNERSHIP_SINCE",
           "UvcIoctls", "kernel_version_code", "running_kernel"]

# State-changing ioctls the core checks the handle's priority for (INFO_FL_PRIO).
PRIORITY_IOCTLS = {abi.VIDIOC_S_FMT, abi.VIDIOC_REQBUFS, abi.VIDIOC_STREAMON, abi.VIDIOC_STREAMOFF, abi.VIDIOC_S_PARM,
                abi.VIDIOC_S_CTRL, abi.VIDIOC_S_EXT_CTRLS, abi.VIDIOC_S_INPUT, abi.VIDIOC_S_PRIORITY,
                abi.VIDIOC_CREATE_BUFS}
EXT_CTRLS_IOCTLS = (abi.VIDIOC_G_EXT_CTRLS, abi.VIDIOC_S_EXT_CTRLS, abi.VIDIOC_TRY_EXT_CTRLS)


def running_kernel() -> tuple[int, int, int]:
    """(major, minor, patch) of the running kernel."""
    parts = [int(p) for p in os.uname().release.split("-")[0].split(".")[:3] if p.isdigit()] + [0, 0, 0]
    return parts[0], parts[1], parts[2]


def kernel_version_code(kernel: tuple[int, ...] | None = None) -> int:
    """LINUX_VERSION_CODE of ``kernel`` (default: the running one), what QUERYCAP's ``version`` holds."""
    major, minor, patch = (tuple(kernel) + (0, 0, 0))[:3] if kernel else running_kernel()
    return (major << 16) | (minor << 8) | min(patch, 255)


class UvcIoctls(FormatIoctls, ControlIoctls, BufferIoctls):
    """Every ioctl handler; each takes (file handle, argument bytes, control array bytes) and returns
    a :data:`~.ioctl_access.Result` (result or -errno, argument out, control array out, descriptors)."""

    def _querycap(self, fh: FileHandle, payload: bytes, array: bytes) -> Result:
        cap = abi.v4l2_capability()
        cap.driver = b"uvcvideo"
        cap.card = self.model.card.encode()
        cap.bus_info = self.ident.bus_info.encode()
        cap.version = kernel_version_code(self.kernel)
        dev = abi.V4L2_CAP_VIDEO_CAPTURE | abi.V4L2_CAP_STREAMING | abi.V4L2_CAP_EXT_PIX_FORMAT
        cap.device_caps = dev
        cap.capabilities = dev | abi.V4L2_CAP_DEVICE_CAPS
        return 0, bytes(cap), b"", []

    def _g_priority(self, fh: FileHandle, payload: bytes, array: bytes) -> Result:
        return 0, self._max_prio().to_bytes(4, "little"), b"", []

    def _s_priority(self, fh: FileHandle, payload: bytes, array: bytes) -> Result:
        value = int.from_bytes(payload[:4].ljust(4, b"\0"), "little")
        if value not in (abi.V4L2_PRIORITY_BACKGROUND, abi.V4L2_PRIORITY_INTERACTIVE, abi.V4L2_PRIORITY_RECORD):
            return -errno.EINVAL, b"", b"", []
        fh.prio = value
        return 0, b"", b"", []


HANDLERS: dict[int, Callable[..., Result]] = {
    abi.VIDIOC_QUERYCAP: UvcIoctls._querycap,
    abi.VIDIOC_ENUM_FMT: UvcIoctls._enum_fmt,
    abi.VIDIOC_G_FMT: UvcIoctls._g_fmt,
    abi.VIDIOC_S_FMT: UvcIoctls._s_fmt,
    abi.VIDIOC_TRY_FMT: UvcIoctls._try_fmt,
    abi.VIDIOC_G_PARM: UvcIoctls._g_parm,
    abi.VIDIOC_S_PARM: UvcIoctls._s_parm,
    abi.VIDIOC_ENUM_FRAMESIZES: UvcIoctls._enum_framesizes,
    abi.VIDIOC_ENUM_FRAMEINTERVALS: UvcIoctls._enum_frameintervals,
    abi.VIDIOC_ENUMINPUT: UvcIoctls._enuminput,
    abi.VIDIOC_G_INPUT: UvcIoctls._g_input,
    abi.VIDIOC_S_INPUT: UvcIoctls._s_input,
    abi.VIDIOC_G_SELECTION: UvcIoctls._g_selection,
    abi.VIDIOC_CROPCAP: UvcIoctls._cropcap,
    abi.VIDIOC_G_CROP: UvcIoctls._g_crop,
    abi.VIDIOC_G_PRIORITY: UvcIoctls._g_priority,
    abi.VIDIOC_S_PRIORITY: UvcIoctls._s_priority,
    abi.VIDIOC_QUERYCTRL: UvcIoctls._queryctrl,
    abi.VIDIOC_QUERY_EXT_CTRL: UvcIoctls._query_ext_ctrl,
    abi.VIDIOC_QUERYMENU: UvcIoctls._querymenu,
    abi.VIDIOC_G_CTRL: UvcIoctls._g_ctrl,
    abi.VIDIOC_S_CTRL: UvcIoctls._s_ctrl,
    abi.VIDIOC_G_EXT_CTRLS: UvcIoctls._g_ext_ctrls,
    abi.VIDIOC_S_EXT_CTRLS: UvcIoctls._s_ext_ctrls,
    abi.VIDIOC_TRY_EXT_CTRLS: UvcIoctls._try_ext_ctrls,
    abi.VIDIOC_SUBSCRIBE_EVENT: UvcIoctls._subscribe,
    abi.VIDIOC_UNSUBSCRIBE_EVENT: UvcIoctls._unsubscribe,
    abi.VIDIOC_DQEVENT: UvcIoctls._dqevent,
    abi.VIDIOC_REQBUFS: UvcIoctls._reqbufs,
    abi.VIDIOC_CREATE_BUFS: UvcIoctls._create_bufs,
    abi.VIDIOC_QUERYBUF: UvcIoctls._querybuf,
    abi.VIDIOC_QBUF: UvcIoctls._qbuf,
    abi.VIDIOC_DQBUF: UvcIoctls._dqbuf,
    abi.VIDIOC_EXPBUF: UvcIoctls._expbuf,
    abi.VIDIOC_STREAMON: UvcIoctls._streamon,
    abi.VIDIOC_STREAMOFF: UvcIoctls._streamoff,
}
