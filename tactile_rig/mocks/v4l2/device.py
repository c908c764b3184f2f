"""One registered capture node of an emulated UVC camera: its ioctls, file handles, buffers and stream.

The ioctls are answered as the V4L2 core (drivers/media/v4l2-core/v4l2-ioctl.c) and uvcvideo
(drivers/media/usb/uvc/uvc_v4l2.c) answer them for a UVC camera's capture node:

* the core first: ENOTTY for what uvcvideo does not implement (``G_STD``, ``ENUMSTD``, ``S_STD``,
  ``QUERYSTD``, ``PREPARE_BUF``, ``S_SELECTION``, ``S_CROP``, the tuner, audio, output and DV-timings
  ioctls, ``LOG_STATUS``); EBUSY from the priority check (``VIDIOC_S_PRIORITY``) for the ioctls that
  change state; EINVAL for a buffer type the node does not have; the input fields each ioctl
  zeroes (INFO_FL_CLEAR); the extended-pixel-format handling of ``S_FMT``/``TRY_FMT``.
* then who may use the stream, which depends on the uvcvideo generation (``kernel``):

  - before Linux 6.17, uvcvideo's file-handle privileges (uvc_acquire_privileges): the first
    handle that sets a format, a frame rate, the input or allocates buffers owns the stream;
    another gets EBUSY for those and for every buffer ioctl (QUERYBUF included, STREAMON without
    buffers too) until the owner frees its buffers (``REQBUFS`` 0) or closes. This is why
    v4l2-compliance's streaming tests fail on those kernels (a freed queue's STREAMON gives EBUSY,
    not EINVAL).
  - from Linux 6.17 (commit c93d73c9c2cf "media: uvcvideo: Use vb2 ioctl and fop helpers"),
    videobuf2's queue ownership (vb2_ioctl_*, vb2_queue_is_busy): the handle that allocates
    buffers owns the queue; another gets EBUSY for REQBUFS, CREATE_BUFS, QBUF, DQBUF, EXPBUF,
    STREAMON and STREAMOFF while it does; QUERYBUF is anyone's; S_FMT fails with EBUSY while
    buffers exist, S_PARM while streaming, whoever asks.
* formats (:mod:`.formats`), controls and control events (:mod:`.controls`), buffers (:mod:`.queue`).

Frames are made by a thread at the negotiated interval: a frame starts (its timestamp, on
CLOCK_MONOTONIC, is taken then, ``V4L2_BUF_FLAG_TSTAMP_SRC_SOE``), the sequence number advances
whether or not a buffer is queued (a host that does not requeue sees a gap, as on uvcvideo:
uvc_video.c counts frames regardless of buffer state), the first queued buffer receives the
image the simulated sensor forms, encoded in the negotiated format; the buffer is done when the
frame is made (the time a camera takes to send it). Frames start on the grid of the interval; when
the machine cannot render and encode a frame within one interval the slots it overran are not made
(their timestamps are missing from the stream, the sequence does not count them: the camera did
not send them).

After an unplug (:meth:`UvcNode.disconnect`) every ioctl, mmap and read fails with ENODEV and poll
reports POLLERR | POLLHUP | POLLPRI, as the V4L2 core does once the device is unregistered.
"""

from __future__ import annotations

import ctypes as C
import errno
import logging
import os
import select
import threading
import time
from collections import deque
from dataclasses import dataclass, field
from typing import Callable, TypeVar

import numpy as np

from tactile_rig.devices.camera_models import CameraModel
from tactile_rig.mocks.camera import SimulatedCamera
import tactile_rig.mocks.v4l2.abi as abi
import tactile_rig.mocks.v4l2.formats as formats
from tactile_rig.mocks.v4l2.controls import ControlChange, ControlSet, check_ext_ctrls
from tactile_rig.mocks.v4l2.formats import StreamFormat
from tactile_rig.mocks.v4l2.frames import encode_frame
from tactile_rig.mocks.v4l2.queue import Buffer, BufferQueue
from tactile_rig.mocks.v4l2.sysfs import NodeIdentity

log = logging.getLogger("tactile_rig.mocks.v4l2")

# State-changing ioctls the core checks the handle's priority for (INFO_FL_PRIO).
_PRIO_IOCTLS = {abi.VIDIOC_S_FMT, abi.VIDIOC_REQBUFS, abi.VIDIOC_STREAMON, abi.VIDIOC_STREAMOFF, abi.VIDIOC_S_PARM,
                abi.VIDIOC_S_CTRL, abi.VIDIOC_S_EXT_CTRLS, abi.VIDIOC_S_INPUT, abi.VIDIOC_S_PRIORITY,
                abi.VIDIOC_CREATE_BUFS}
EXT_CTRLS_IOCTLS = (abi.VIDIOC_G_EXT_CTRLS, abi.VIDIOC_S_EXT_CTRLS, abi.VIDIOC_TRY_EXT_CTRLS)
JPEG_QUALITY = 90


def running_kernel() -> tuple[int, int, int]:
    """(major, minor, patch) of the running kernel."""
    parts = [int(p) for p in os.uname().release.split("-")[0].split(".")[:3] if p.isdigit()] + [0, 0, 0]
    return parts[0], parts[1], parts[2]


def kernel_version_code(kernel: tuple[int, ...] | None = None) -> int:
    """LINUX_VERSION_CODE of ``kernel`` (default: the running one), what QUERYCAP's ``version`` holds."""
    major, minor, patch = (tuple(kernel) + (0, 0, 0))[:3] if kernel else running_kernel()
    return (major << 16) | (minor << 8) | min(patch, 255)


# Linux 6.3 made uvcvideo refuse writes to inactive controls itself, with EACCES; before, the
# camera's stall came back through uvc_query_ctrl's error mapping (see :mod:`.controls`).
EACCES_FOR_INACTIVE_SINCE = (6, 3)
# Linux 6.17 replaced uvcvideo's privileges with videobuf2's queue ownership.
VB2_OWNERSHIP_SINCE = (6, 17)


def _clear_after(s: C.Structure, name: str) -> None:
    """Zero every byte after field ``name`` (the core's INFO_FL_CLEAR / memset_after)."""
    f = getattr(type(s), name)
    end = f.offset + f.size
    C.memset(C.addressof(s) + end, 0, C.sizeof(s) - end)


_S = TypeVar("_S", bound=C.Structure)


def _parse(cls: type[_S], payload: bytes) -> _S:
    size = C.sizeof(cls)
    return cls.from_buffer_copy(payload[:size].ljust(size, b"\0"))


@dataclass(eq=False)
class FileHandle:
    """One open file of the node (shared by dup()ed descriptors and forked children)."""

    id: int
    efd_in: int
    efd_pri: int
    efd_wait: int
    prio: int = abi.V4L2_PRIORITY_INTERACTIVE
    connections: int = 1
    subscriptions: dict[tuple[int, int], int] = field(default_factory=dict)
    events: deque[tuple[tuple[int, int], bytes]] = field(default_factory=deque)
    sequence: int = 0
    signalled: dict[int, bool] = field(default_factory=dict)

    def signal(self, efd: int, on: bool) -> None:
        """Make ``efd`` readable (on) or not, changing it only when its state changes."""
        if self.signalled.get(efd, False) == on:
            return
        try:
            if on:
                os.eventfd_write(efd, 1)
            elif select.select([efd], [], [], 0)[0]:  # the client may have made the file blocking
                os.eventfd_read(efd)
        except OSError:
            pass
        self.signalled[efd] = on

    def close(self) -> None:
        for fd in (self.efd_in, self.efd_pri, self.efd_wait):
            try:
                os.close(fd)
            except OSError:
                pass


@dataclass
class RenderedFrame:
    """A frame the node delivered: what the sensor formed (BGR) and what went into the buffer."""

    sequence: int
    timestamp_ns: int
    fourcc: str
    image: np.ndarray
    payload_bytes: int


class UvcNode:
    """The capture node of ``model`` as registered now; a replug makes a new one."""

    def __init__(self, model: CameraModel, sim: SimulatedCamera, ident: NodeIdentity, *,
                 jpeg_quality: int = JPEG_QUALITY, stalled: Callable[[float], bool] | None = None,
                 frozen: Callable[[float], bool] | None = None, on_frame: Callable[[int], None] | None = None,
                 history: int = 64, kernel: tuple[int, ...] | None = None) -> None:
        self.model, self.sim, self.ident = model, sim, ident
        self.kernel = tuple(kernel) if kernel else running_kernel()
        self.jpeg_quality = int(jpeg_quality)
        self.stalled = stalled or (lambda t: False)
        self.frozen = frozen or (lambda t: False)
        self.on_frame = on_frame
        self.lock = threading.RLock()
        self.cond = threading.Condition(self.lock)
        self.stream: StreamFormat = formats.default_stream(model)
        self.controls = ControlSet(sim.table,
                                   legacy_wrong_state=self.kernel[:2] < EACCES_FOR_INACTIVE_SINCE,
                                   legacy_errno=model.inactive_write_errno_legacy)
        self.vb2_ownership = self.kernel[:2] >= VB2_OWNERSHIP_SINCE
        self.queue = BufferQueue()
        self.handles: dict[int, FileHandle] = {}
        self.owner: FileHandle | None = None
        self.gone = False
        self.sequence = -1
        self._next_fh = 1
        self._stream_gen = 0
        self._encoding = False
        self._thread: threading.Thread | None = None
        self._last_payload: tuple[str, int, int, bytes] | None = None
        self.history: deque[RenderedFrame] = deque(maxlen=history)
        self.frames_delivered = 0
        self.frames_lost = 0
        #: (file handle id, ioctl name, errno or 0) of every ioctl, when a list is set here.
        self.trace: deque[tuple[int, str, int]] | None = None

    # -- file handles ---------------------------------------------------------------------------
    def open(self) -> FileHandle:
        """A new open file with its three readiness descriptors (see :mod:`.protocol`)."""
        flags = os.EFD_CLOEXEC | os.EFD_NONBLOCK
        with self.lock:
            fh = FileHandle(self._next_fh, os.eventfd(0, flags), os.eventfd(0, flags), os.eventfd(0, flags))
            self._next_fh += 1
            self.handles[fh.id] = fh
            self._sync(fh)
            return fh

    def attach(self, fh_id: int) -> FileHandle | None:
        with self.lock:
            fh = self.handles.get(fh_id)
            if fh is not None:
                fh.connections += 1
            return fh

    def release(self, fh: FileHandle) -> None:
        """A connection of ``fh`` closed; the last one closes the file (uvc_v4l2_release)."""
        with self.lock:
            fh.connections -= 1
            if fh.connections > 0:
                return
            if self.owner is fh:
                self._stop_stream()
                self.queue.release()
                self.owner = None
            self.handles.pop(fh.id, None)
            fh.close()
            self._sync_all()

    # -- readiness ------------------------------------------------------------------------------
    def _sync(self, fh: FileHandle) -> None:
        fh.signal(fh.efd_in, self.gone or self.queue.poll(abi.POLLIN) != 0)
        fh.signal(fh.efd_pri, self.gone or bool(fh.events))
        fh.signal(fh.efd_wait, self.gone or self.queue.dqbuf_ready())

    def _sync_all(self) -> None:
        for fh in self.handles.values():
            self._sync(fh)

    def poll(self, fh: FileHandle, events: int) -> int:
        with self.lock:
            if self.gone:
                return abi.POLLERR | abi.POLLHUP | abi.POLLPRI
            return (abi.POLLPRI if fh.events else 0) | self.queue.poll(events)

    # -- mmap and read --------------------------------------------------------------------------
    def mmap(self, offset: int, length: int, prot: int, flags: int) -> tuple[int, int]:
        """(0, the buffer's memfd) or (-errno, -1)."""
        with self.lock:
            if self.gone:
                return -errno.ENODEV, -1
            buf = self.queue.mmap(offset, length, prot, flags)
            if isinstance(buf, int):
                return buf, -1
            return 0, buf.memfd

    def munmap(self, offset: int) -> None:
        with self.lock:
            self.queue.unmapped(offset)

    def read(self) -> int:
        return -errno.ENODEV if self.gone else -errno.EINVAL

    # -- unplug ---------------------------------------------------------------------------------
    def disconnect(self) -> None:
        """The camera is pulled: streaming stops, every handle sees ENODEV and POLLERR from now on."""
        with self.lock:
            if self.gone:
                return
            self.gone = True
            self._stop_stream()
            self.queue.error = True
            self._sync_all()

    def shutdown(self) -> None:
        """Free everything (the server is stopping)."""
        with self.lock:
            self.disconnect()
            self.queue.release()
            for fh in list(self.handles.values()):
                fh.close()
            self.handles.clear()

    # -- ioctl ----------------------------------------------------------------------------------
    def ioctl(self, fh: FileHandle, cmd: int, payload: bytes, array: bytes) -> tuple[int, bytes, bytes, list[int]]:
        """(result, argument out, control array out, descriptors to send)."""
        with self.lock:
            handler = self._HANDLERS.get(cmd)
            if self.gone:
                result: tuple[int, bytes, bytes, list[int]] = (-errno.ENODEV, b"", b"", [])
            elif handler is None:
                result = (-errno.ENOTTY, b"", b"", [])
            elif cmd in _PRIO_IOCTLS and fh.prio < self._max_prio():
                result = (-errno.EBUSY, b"", b"", [])
            else:
                result = handler(self, fh, payload, array)
                self._sync_all()
            if self.trace is not None:
                self.trace.append((fh.id, abi.IOCTL_NAMES.get(cmd, hex(cmd)), -result[0]))
            return result

    def _max_prio(self) -> int:
        return max((h.prio for h in self.handles.values()), default=abi.V4L2_PRIORITY_UNSET)

    def _acquire(self, fh: FileHandle) -> int:
        """uvc_acquire_privileges (before 6.17): S_FMT, S_PARM, S_INPUT, REQBUFS and CREATE_BUFS
        make the handle the stream's owner, or fail with EBUSY if another handle is."""
        if self.vb2_ownership or self.owner is fh:
            return 0
        if self.owner is not None:
            return -errno.EBUSY
        self.owner = fh
        return 0

    def _may_use_queue(self, fh: FileHandle, query: bool = False) -> bool:
        """May ``fh`` run a buffer ioctl: before 6.17 only the privileged handle may (uvc_has_privileges);
        from 6.17 anyone unless another handle owns the queue (vb2_queue_is_busy), QUERYBUF always."""
        if not self.vb2_ownership:
            return self.owner is fh
        return query or self.owner is None or self.owner is fh

    # Each handler: (node, fh, payload, array) -> (result, out, array_out, fds).
    def _querycap(self, fh: FileHandle, payload: bytes, array: bytes) -> tuple[int, bytes, bytes, list[int]]:
        cap = abi.v4l2_capability()
        cap.driver = b"uvcvideo"
        cap.card = self.model.card.encode()
        cap.bus_info = self.ident.bus_info.encode()
        cap.version = kernel_version_code(self.kernel)
        dev = abi.V4L2_CAP_VIDEO_CAPTURE | abi.V4L2_CAP_STREAMING | abi.V4L2_CAP_EXT_PIX_FORMAT
        cap.device_caps = dev
        cap.capabilities = dev | abi.V4L2_CAP_DEVICE_CAPS
        return 0, bytes(cap), b"", []

    def _enum_fmt(self, fh: FileHandle, payload: bytes, array: bytes) -> tuple[int, bytes, bytes, list[int]]:
        f = _parse(abi.v4l2_fmtdesc, payload)
        if f.type != abi.V4L2_BUF_TYPE_VIDEO_CAPTURE:
            return -errno.EINVAL, b"", b"", []
        _clear_after(f, "type")
        if f.index >= len(self.model.formats):
            return -errno.EINVAL, b"", b"", []
        fmt = self.model.formats[f.index]
        f.pixelformat = abi.fourcc(fmt.fourcc)
        f.flags = abi.V4L2_FMT_FLAG_COMPRESSED if fmt.compressed else 0
        f.description = abi.FORMAT_DESCRIPTIONS.get(fmt.fourcc, fmt.fourcc).encode()
        return 0, bytes(f), b"", []

    def _fill_pix(self, f: abi.v4l2_format, s: StreamFormat) -> None:
        p = f.fmt.pix
        p.width, p.height, p.pixelformat = s.width_px, s.height_px, abi.fourcc(s.fourcc)
        p.field = abi.V4L2_FIELD_NONE
        p.bytesperline, p.sizeimage = s.bytesperline, s.sizeimage
        p.colorspace, p.xfer_func, p.ycbcr_enc = abi.V4L2_COLORSPACE_SRGB, abi.V4L2_XFER_FUNC_709, abi.V4L2_YCBCR_ENC_601
        p.priv = abi.V4L2_PIX_FMT_PRIV_MAGIC

    @staticmethod
    def _sanitize(f: abi.v4l2_format) -> None:
        """v4l_sanitize_format, then CLEAR_AFTER_FIELD(fmt.pix)."""
        p = f.fmt.pix
        if p.priv != abi.V4L2_PIX_FMT_PRIV_MAGIC:
            p.priv = abi.V4L2_PIX_FMT_PRIV_MAGIC
            p.flags = p.ycbcr_enc = p.quantization = p.xfer_func = 0
        start = abi.v4l2_format.fmt.offset + C.sizeof(abi.v4l2_pix_format)
        C.memset(C.addressof(f) + start, 0, C.sizeof(f) - start)

    def _g_fmt(self, fh: FileHandle, payload: bytes, array: bytes) -> tuple[int, bytes, bytes, list[int]]:
        f = _parse(abi.v4l2_format, payload)
        if f.type != abi.V4L2_BUF_TYPE_VIDEO_CAPTURE:
            return -errno.EINVAL, b"", b"", []
        C.memset(C.addressof(f) + abi.v4l2_format.fmt.offset, 0, C.sizeof(f) - abi.v4l2_format.fmt.offset)
        self._fill_pix(f, self.stream)
        return 0, bytes(f), b"", []

    def _try_or_set_fmt(self, fh: FileHandle, payload: bytes, set_: bool) -> tuple[int, bytes, bytes, list[int]]:
        f = _parse(abi.v4l2_format, payload)
        if set_:  # uvc_ioctl_s_fmt acquires privileges before it looks at the type
            err = self._acquire(fh)
            if err:
                return err, b"", b"", []
        if f.type != abi.V4L2_BUF_TYPE_VIDEO_CAPTURE:
            return -errno.EINVAL, b"", b"", []
        self._sanitize(f)
        s = formats.try_format(self.model, f.fmt.pix.pixelformat, f.fmt.pix.width, f.fmt.pix.height)
        if set_:
            if self.queue.buffers:
                return -errno.EBUSY, b"", b"", []
            self._set_stream(s)
        self._fill_pix(f, s)
        return 0, bytes(f), b"", []

    def _set_stream(self, s: StreamFormat) -> None:
        changed = (s.fourcc, s.width_px, s.height_px) != (self.stream.fourcc, self.stream.width_px, self.stream.height_px)
        self.stream = s
        if changed:
            for name in self.model.format_change_resets:
                self.sim.table.values[name] = self.sim.table.controls[name].initial

    def _s_fmt(self, fh: FileHandle, payload: bytes, array: bytes) -> tuple[int, bytes, bytes, list[int]]:
        return self._try_or_set_fmt(fh, payload, True)

    def _try_fmt(self, fh: FileHandle, payload: bytes, array: bytes) -> tuple[int, bytes, bytes, list[int]]:
        return self._try_or_set_fmt(fh, payload, False)

    def _fill_parm(self, p: abi.v4l2_streamparm) -> None:
        frac = formats.interval_fraction(self.stream.interval_100ns)
        p.parm.capture.capability = abi.V4L2_CAP_TIMEPERFRAME
        p.parm.capture.timeperframe.numerator = frac.numerator
        p.parm.capture.timeperframe.denominator = frac.denominator

    def _g_parm(self, fh: FileHandle, payload: bytes, array: bytes) -> tuple[int, bytes, bytes, list[int]]:
        p = _parse(abi.v4l2_streamparm, payload)
        if p.type != abi.V4L2_BUF_TYPE_VIDEO_CAPTURE:
            return -errno.EINVAL, b"", b"", []
        _clear_after(p, "type")
        self._fill_parm(p)
        return 0, bytes(p), b"", []

    def _s_parm(self, fh: FileHandle, payload: bytes, array: bytes) -> tuple[int, bytes, bytes, list[int]]:
        p = _parse(abi.v4l2_streamparm, payload)
        err = self._acquire(fh)
        if err:
            return err, b"", b"", []
        if p.type != abi.V4L2_BUF_TYPE_VIDEO_CAPTURE:
            return -errno.EINVAL, b"", b"", []
        cp = p.parm.capture
        C.memset(C.addressof(cp.reserved), 0, C.sizeof(cp.reserved))
        cp.extendedmode = 0
        cp.capturemode &= abi.V4L2_MODE_HIGHQUALITY
        if self.queue.streaming:
            return -errno.EBUSY, b"", b"", []
        tpf = cp.timeperframe
        self.stream = formats.set_interval(self.model, self.stream, tpf.numerator, tpf.denominator)
        frac = formats.interval_fraction(self.stream.interval_100ns)
        cp.timeperframe.numerator, cp.timeperframe.denominator = frac.numerator, frac.denominator
        cp.capability = abi.V4L2_CAP_TIMEPERFRAME
        return 0, bytes(p), b"", []

    def _enum_framesizes(self, fh: FileHandle, payload: bytes, array: bytes) -> tuple[int, bytes, bytes, list[int]]:
        f = _parse(abi.v4l2_frmsizeenum, payload)
        _clear_after(f, "pixel_format")
        fmt = next((m for m in self.model.formats if abi.fourcc(m.fourcc) == f.pixel_format), None)
        if fmt is None:
            return -errno.EINVAL, b"", b"", []
        sizes = formats.frame_sizes(fmt)
        if f.index >= len(sizes):
            return -errno.EINVAL, b"", b"", []
        f.type = abi.V4L2_FRMSIZE_TYPE_DISCRETE
        f.u.discrete.width, f.u.discrete.height = sizes[f.index].width_px, sizes[f.index].height_px
        return 0, bytes(f), b"", []

    def _enum_frameintervals(self, fh: FileHandle, payload: bytes, array: bytes) -> tuple[int, bytes, bytes, list[int]]:
        f = _parse(abi.v4l2_frmivalenum, payload)
        _clear_after(f, "height")
        fmt = next((m for m in self.model.formats if abi.fourcc(m.fourcc) == f.pixel_format), None)
        if fmt is None:
            return -errno.EINVAL, b"", b"", []
        ivals = formats.frame_intervals(fmt, f.width, f.height)
        if f.index >= len(ivals):
            return -errno.EINVAL, b"", b"", []
        frac = formats.interval_fraction(ivals[f.index])
        f.type = abi.V4L2_FRMIVAL_TYPE_DISCRETE
        f.u.discrete.numerator, f.u.discrete.denominator = frac.numerator, frac.denominator
        return 0, bytes(f), b"", []

    def _enuminput(self, fh: FileHandle, payload: bytes, array: bytes) -> tuple[int, bytes, bytes, list[int]]:
        i = _parse(abi.v4l2_input, payload)
        _clear_after(i, "index")
        if i.index != 0:
            return -errno.EINVAL, b"", b"", []
        i.name = b"Camera 1"  # uvcvideo names a camera terminal "Camera <bTerminalID>"
        i.type = abi.V4L2_INPUT_TYPE_CAMERA
        return 0, bytes(i), b"", []

    def _g_input(self, fh: FileHandle, payload: bytes, array: bytes) -> tuple[int, bytes, bytes, list[int]]:
        return 0, (0).to_bytes(4, "little"), b"", []

    def _s_input(self, fh: FileHandle, payload: bytes, array: bytes) -> tuple[int, bytes, bytes, list[int]]:
        err = self._acquire(fh)
        if err:
            return err, b"", b"", []
        value = int.from_bytes(payload[:4].ljust(4, b"\0"), "little")
        return (-errno.EINVAL if value != 0 else 0), payload[:4].ljust(4, b"\0"), b"", []

    def _g_selection(self, fh: FileHandle, payload: bytes, array: bytes) -> tuple[int, bytes, bytes, list[int]]:
        s = _parse(abi.v4l2_selection, payload)
        _clear_after(s, "r")
        r = self._selection(s.type, s.target)
        if isinstance(r, int):
            return r, b"", b"", []
        s.r = r
        return 0, bytes(s), b"", []

    def _selection(self, buftype: int, target: int) -> abi.v4l2_rect | int:
        # The core hands a multi-planar type to the driver as its single-planar twin (v4l_g_selection,
        # v4l_g_crop, v4l_cropcap) and gives the caller its own type back.
        if buftype == abi.V4L2_BUF_TYPE_VIDEO_CAPTURE_MPLANE:
            buftype = abi.V4L2_BUF_TYPE_VIDEO_CAPTURE
        if buftype != abi.V4L2_BUF_TYPE_VIDEO_CAPTURE:
            return -errno.EINVAL
        if target not in (abi.V4L2_SEL_TGT_CROP_DEFAULT, abi.V4L2_SEL_TGT_CROP_BOUNDS):
            return -errno.EINVAL
        return abi.v4l2_rect(0, 0, self.stream.width_px, self.stream.height_px)

    def _cropcap(self, fh: FileHandle, payload: bytes, array: bytes) -> tuple[int, bytes, bytes, list[int]]:
        c = _parse(abi.v4l2_cropcap, payload)
        _clear_after(c, "type")
        c.pixelaspect.numerator = c.pixelaspect.denominator = 1
        for target, attr in ((abi.V4L2_SEL_TGT_CROP_BOUNDS, "bounds"), (abi.V4L2_SEL_TGT_CROP_DEFAULT, "defrect")):
            r = self._selection(c.type, target)
            if isinstance(r, int):
                return r, b"", b"", []
            setattr(c, attr, r)
        return 0, bytes(c), b"", []

    def _g_crop(self, fh: FileHandle, payload: bytes, array: bytes) -> tuple[int, bytes, bytes, list[int]]:
        c = _parse(abi.v4l2_crop, payload)
        r = self._selection(c.type, abi.V4L2_SEL_TGT_CROP)
        return (r if isinstance(r, int) else 0), b"", b"", []

    def _g_priority(self, fh: FileHandle, payload: bytes, array: bytes) -> tuple[int, bytes, bytes, list[int]]:
        return 0, self._max_prio().to_bytes(4, "little"), b"", []

    def _s_priority(self, fh: FileHandle, payload: bytes, array: bytes) -> tuple[int, bytes, bytes, list[int]]:
        value = int.from_bytes(payload[:4].ljust(4, b"\0"), "little")
        if value not in (abi.V4L2_PRIORITY_BACKGROUND, abi.V4L2_PRIORITY_INTERACTIVE, abi.V4L2_PRIORITY_RECORD):
            return -errno.EINVAL, b"", b"", []
        fh.prio = value
        return 0, b"", b"", []

    # -- controls ---------------------------------------------------------------------------------
    def _queryctrl(self, fh: FileHandle, payload: bytes, array: bytes) -> tuple[int, bytes, bytes, list[int]]:
        q = _parse(abi.v4l2_queryctrl, payload)
        ret = self.controls.queryctrl(q)
        return ret, bytes(q), b"", []

    def _query_ext_ctrl(self, fh: FileHandle, payload: bytes, array: bytes) -> tuple[int, bytes, bytes, list[int]]:
        q = _parse(abi.v4l2_query_ext_ctrl, payload)
        ret = self.controls.query_ext_ctrl(q)
        return ret, bytes(q), b"", []

    def _querymenu(self, fh: FileHandle, payload: bytes, array: bytes) -> tuple[int, bytes, bytes, list[int]]:
        m = _parse(abi.v4l2_querymenu, payload)
        ret = self.controls.querymenu(m)
        return ret, bytes(m), b"", []

    def _g_ctrl(self, fh: FileHandle, payload: bytes, array: bytes) -> tuple[int, bytes, bytes, list[int]]:
        c = _parse(abi.v4l2_control, payload)
        ok, _ = check_ext_ctrls(c.id & 0x0FFF0000, [c.id], "G_CTRL")
        if not ok:
            return -errno.EINVAL, b"", b"", []
        err, _idx, values = self.controls.get_ext(abi.V4L2_CTRL_WHICH_CUR_VAL, [c.id])
        if err:
            return err, b"", b"", []
        c.value = values[0]
        return 0, bytes(c), b"", []

    def _s_ctrl(self, fh: FileHandle, payload: bytes, array: bytes) -> tuple[int, bytes, bytes, list[int]]:
        c = _parse(abi.v4l2_control, payload)
        ok, _ = check_ext_ctrls(c.id & 0x0FFF0000, [c.id], "S_CTRL")
        if not ok:
            return -errno.EINVAL, b"", b"", []
        err, _idx, values = self.controls.set_ext([c.id], [c.value], try_=False)
        if err:
            return err, b"", b"", []
        c.value = values[0]
        self._send_events(self.controls.changes_for([c.id], fh.id))
        return 0, bytes(c), b"", []

    def _ext_ctrls(self, fh: FileHandle, payload: bytes, array: bytes, kind: str) -> tuple[int, bytes, bytes, list[int]]:
        x = _parse(abi.v4l2_ext_controls, payload)
        if x.count > abi.V4L2_CID_MAX_CTRLS:
            return -errno.EINVAL, bytes(x), b"", []
        n = x.count
        size = C.sizeof(abi.v4l2_ext_control)
        if len(array) < n * size:
            return -errno.EFAULT, bytes(x), array, []
        ctrls = (abi.v4l2_ext_control * n).from_buffer_copy(array[: n * size]) if n else []
        x.error_idx = n
        x.reserved = 0
        for c in ctrls:
            c.reserved2 = 0
        ids = [c.id for c in ctrls]
        ok, idx = check_ext_ctrls(x.which, ids, kind)

        def out(ret: int) -> tuple[int, bytes, bytes, list[int]]:
            return ret, bytes(x), (bytes(ctrls) if n else b""), []

        if not ok:
            if idx is not None:
                x.error_idx = idx
            return out(-errno.EINVAL)
        if kind == "G":
            err, x.error_idx, values = self.controls.get_ext(x.which, ids)
        else:
            err, x.error_idx, values = self.controls.set_ext(ids, [c.u.value for c in ctrls], try_=(kind == "TRY"))
        for c, v in zip(ctrls, values):
            c.u.value = v
        if not err and kind == "S":
            self._send_events(self.controls.changes_for(ids, fh.id))
        return out(err)

    def _g_ext_ctrls(self, fh: FileHandle, payload: bytes, array: bytes) -> tuple[int, bytes, bytes, list[int]]:
        return self._ext_ctrls(fh, payload, array, "G")

    def _s_ext_ctrls(self, fh: FileHandle, payload: bytes, array: bytes) -> tuple[int, bytes, bytes, list[int]]:
        return self._ext_ctrls(fh, payload, array, "S")

    def _try_ext_ctrls(self, fh: FileHandle, payload: bytes, array: bytes) -> tuple[int, bytes, bytes, list[int]]:
        return self._ext_ctrls(fh, payload, array, "TRY")

    # -- events -----------------------------------------------------------------------------------
    def _queue_event(self, fh: FileHandle, key: tuple[int, int], ev: abi.v4l2_event) -> None:
        """__v4l2_event_queue_fh with one slot per subscription: a newer event replaces a pending one
        (its change bits merged) and goes to the back of the queue."""
        if key not in fh.subscriptions:
            return
        fh.sequence += 1
        for i, (k, old) in enumerate(fh.events):
            if k == key:
                ev.u.ctrl.changes |= abi.v4l2_event.from_buffer_copy(old).u.ctrl.changes
                del fh.events[i]
                break
        ev.sequence = fh.sequence
        ns = time.monotonic_ns()
        ev.timestamp.tv_sec, ev.timestamp.tv_nsec = divmod(ns, 1_000_000_000)
        fh.events.append((key, bytes(ev)))

    def _send_events(self, changes: list[ControlChange]) -> None:
        for ch in changes:
            for fh in self.handles.values():
                key = (abi.V4L2_EVENT_CTRL, ch.control.cid)
                flags = fh.subscriptions.get(key)
                if flags is None:
                    continue
                if fh.id == ch.origin and not flags & abi.V4L2_EVENT_SUB_FL_ALLOW_FEEDBACK:
                    continue
                ev = abi.v4l2_event()
                self.controls.fill_event(ev, ch.control, ch.changes)
                self._queue_event(fh, key, ev)

    def _subscribe(self, fh: FileHandle, payload: bytes, array: bytes) -> tuple[int, bytes, bytes, list[int]]:
        s = _parse(abi.v4l2_event_subscription, payload)
        if s.type != abi.V4L2_EVENT_CTRL:
            return -errno.EINVAL, b"", b"", []
        key = (s.type, s.id)
        if key in fh.subscriptions:
            return 0, b"", b"", []
        if s.id in self.controls.classes:  # uvc_ctrl_add_event: a class subscribes and sends nothing
            fh.subscriptions[key] = s.flags
            return 0, b"", b"", []
        c = self.controls.by_id.get(s.id)
        if c is None:
            return -errno.EINVAL, b"", b"", []
        fh.subscriptions[key] = s.flags
        if s.flags & abi.V4L2_EVENT_SUB_FL_SEND_INITIAL:
            ev = abi.v4l2_event()
            self.controls.fill_event(ev, c, abi.V4L2_EVENT_CTRL_CH_FLAGS | abi.V4L2_EVENT_CTRL_CH_VALUE)
            self._queue_event(fh, key, ev)
        return 0, b"", b"", []

    def _unsubscribe(self, fh: FileHandle, payload: bytes, array: bytes) -> tuple[int, bytes, bytes, list[int]]:
        s = _parse(abi.v4l2_event_subscription, payload)
        if s.type == abi.V4L2_EVENT_ALL:
            fh.subscriptions.clear()
            fh.events.clear()
            return 0, b"", b"", []
        key = (s.type, s.id)
        fh.subscriptions.pop(key, None)
        fh.events = deque(e for e in fh.events if e[0] != key)
        return 0, b"", b"", []

    def _dqevent(self, fh: FileHandle, payload: bytes, array: bytes) -> tuple[int, bytes, bytes, list[int]]:
        if not fh.events:
            return -errno.ENOENT, b"", b"", []
        _key, data = fh.events.popleft()
        ev = abi.v4l2_event.from_buffer_copy(data)
        ev.pending = len(fh.events)
        return 0, bytes(ev), b"", []

    # -- buffers ----------------------------------------------------------------------------------
    def _reqbufs(self, fh: FileHandle, payload: bytes, array: bytes) -> tuple[int, bytes, bytes, list[int]]:
        r = _parse(abi.v4l2_requestbuffers, payload)
        if r.type != abi.V4L2_BUF_TYPE_VIDEO_CAPTURE:
            return -errno.EINVAL, b"", b"", []
        _clear_after(r, "flags")
        err = self._acquire(fh)
        if not err and not self._may_use_queue(fh):
            err = -errno.EBUSY
        if err:
            return err, b"", b"", []
        err = self.queue.reqbufs(r, self.stream.sizeimage)
        if err:
            return err, b"", b"", []
        if r.count == 0:
            self.owner = None  # uvc_dismiss_privileges / vb2_ioctl_reqbufs
        elif self.vb2_ownership:
            self.owner = fh
        return 0, bytes(r), b"", []

    def _create_bufs(self, fh: FileHandle, payload: bytes, array: bytes) -> tuple[int, bytes, bytes, list[int]]:
        cb = _parse(abi.v4l2_create_buffers, payload)
        if cb.format.type != abi.V4L2_BUF_TYPE_VIDEO_CAPTURE:
            return -errno.EINVAL, b"", b"", []
        _clear_after(cb, "flags")
        self._sanitize(cb.format)
        err = self._acquire(fh)
        if not err and cb.count and not self._may_use_queue(fh):
            err = -errno.EBUSY
        if err:
            return err, b"", b"", []
        err = self.queue.create_bufs(cb, self.stream.sizeimage)
        cb.format.fmt.pix.priv = abi.V4L2_PIX_FMT_PRIV_MAGIC
        if not err and cb.count and self.vb2_ownership:
            self.owner = fh
        return err, bytes(cb), b"", []

    def _buffer_ioctl(self, fh: FileHandle, payload: bytes, op: Callable[[abi.v4l2_buffer], int],
                      clear: str | None = None) -> tuple[int, bytes, bytes, list[int]]:
        b = _parse(abi.v4l2_buffer, payload)
        if b.type != abi.V4L2_BUF_TYPE_VIDEO_CAPTURE:
            return -errno.EINVAL, b"", b"", []
        if clear:
            _clear_after(b, clear)
        if not self._may_use_queue(fh, query=op == self.queue.querybuf):
            return -errno.EBUSY, b"", b"", []
        err = op(b)
        return err, (bytes(b) if not err else b""), b"", []

    def _querybuf(self, fh: FileHandle, payload: bytes, array: bytes) -> tuple[int, bytes, bytes, list[int]]:
        return self._buffer_ioctl(fh, payload, self.queue.querybuf, clear="length")

    def _qbuf(self, fh: FileHandle, payload: bytes, array: bytes) -> tuple[int, bytes, bytes, list[int]]:
        return self._buffer_ioctl(fh, payload, self.queue.qbuf)

    def _dqbuf(self, fh: FileHandle, payload: bytes, array: bytes) -> tuple[int, bytes, bytes, list[int]]:
        return self._buffer_ioctl(fh, payload, self.queue.dqbuf)

    def _expbuf(self, fh: FileHandle, payload: bytes, array: bytes) -> tuple[int, bytes, bytes, list[int]]:
        e = _parse(abi.v4l2_exportbuffer, payload)
        _clear_after(e, "flags")
        if not self._may_use_queue(fh):
            return -errno.EBUSY, b"", b"", []
        err, fd = self.queue.expbuf(e)
        if err:
            return err, b"", b"", []
        return 0, bytes(e), b"", [fd]

    def _streamon(self, fh: FileHandle, payload: bytes, array: bytes) -> tuple[int, bytes, bytes, list[int]]:
        if not self._may_use_queue(fh):
            return -errno.EBUSY, b"", b"", []
        was = self.queue.streaming
        err = self.queue.streamon(int.from_bytes(payload[:4].ljust(4, b"\0"), "little"))
        if not err and not was:
            self._start_stream()
        return err, b"", b"", []

    def _streamoff(self, fh: FileHandle, payload: bytes, array: bytes) -> tuple[int, bytes, bytes, list[int]]:
        if not self._may_use_queue(fh):
            return -errno.EBUSY, b"", b"", []
        buftype = int.from_bytes(payload[:4].ljust(4, b"\0"), "little")
        if buftype != self.queue.type:
            return -errno.EINVAL, b"", b"", []
        self._stop_stream()
        return self.queue.streamoff(buftype), b"", b"", []

    _HANDLERS: dict[int, Callable[..., tuple[int, bytes, bytes, list[int]]]] = {}

    # -- the stream ---------------------------------------------------------------------------------
    def _start_stream(self) -> None:
        self._stream_gen += 1
        self.sequence = -1  # uvc_video_start_streaming: the first frame is number 0
        t = threading.Thread(target=self._stream_loop, args=(self._stream_gen,), daemon=True,
                             name=f"v4l2-{self.ident.name}-stream")
        self._thread = t
        t.start()

    def _stop_stream(self) -> None:
        """Stop making frames and wait for one in flight (lock held; the wait releases it)."""
        self._stream_gen += 1
        self.cond.notify_all()
        while self._encoding:
            self.cond.wait(1.0)

    def _stream_loop(self, gen: int) -> None:
        period = self.stream.interval_100ns * 1e-7
        t_next = time.monotonic() + period
        while True:
            with self.lock:
                while True:
                    if gen != self._stream_gen or self.gone or not self.queue.streaming:
                        return
                    wait = t_next - time.monotonic()
                    if wait <= 0:
                        break
                    self.cond.wait(wait)
                t_frame = t_next
                now = time.monotonic()
                t_next += period
                while t_next < now:  # could not keep up: the frames of the missed slots are not made
                    t_next += period
                if self.stalled(t_frame):
                    continue
                self.sequence += 1
                buf = self.queue.take()
                if buf is None:
                    self.frames_lost += 1
                    continue
                self._encoding = True
                stream = self.stream
                seq = self.sequence
            try:
                n = self._make_frame(buf, stream, t_frame, seq)
            except Exception:  # noqa: BLE001  (a rendering bug must not hang the host: the buffer errs)
                log.exception("%s: frame %d failed", self.ident.name, seq)
                n = -1
            with self.lock:
                self._encoding = False
                self.cond.notify_all()
                if gen != self._stream_gen or buf.state != "active":
                    continue
                self.queue.complete(buf, max(n, 0), int(t_frame * 1e9), seq, error=n < 0)
                self.frames_delivered += 1
                self._sync_all()
            if self.on_frame is not None:
                self.on_frame(seq)

    def _make_frame(self, buf: Buffer, s: StreamFormat, t_frame: float, seq: int) -> int:
        key = (s.fourcc, s.width_px, s.height_px)
        if self.frozen(t_frame) and self._last_payload is not None and self._last_payload[:3] == key:
            data = self._last_payload[3]
            image = self.history[-1].image if self.history else None
        else:
            image = self.sim.render_frame(t_frame, s.width_px, s.height_px)
            data = encode_frame(image, s.fourcc, self.jpeg_quality).tobytes()
            self._last_payload = (*key, data)
        n = len(data)
        if n > buf.length:
            return -1
        buf.mem[:n] = data
        if image is not None:
            self.history.append(RenderedFrame(seq, int(t_frame * 1e9), s.fourcc, image, n))
        return n


UvcNode._HANDLERS = {
    abi.VIDIOC_QUERYCAP: UvcNode._querycap,
    abi.VIDIOC_ENUM_FMT: UvcNode._enum_fmt,
    abi.VIDIOC_G_FMT: UvcNode._g_fmt,
    abi.VIDIOC_S_FMT: UvcNode._s_fmt,
    abi.VIDIOC_TRY_FMT: UvcNode._try_fmt,
    abi.VIDIOC_G_PARM: UvcNode._g_parm,
    abi.VIDIOC_S_PARM: UvcNode._s_parm,
    abi.VIDIOC_ENUM_FRAMESIZES: UvcNode._enum_framesizes,
    abi.VIDIOC_ENUM_FRAMEINTERVALS: UvcNode._enum_frameintervals,
    abi.VIDIOC_ENUMINPUT: UvcNode._enuminput,
    abi.VIDIOC_G_INPUT: UvcNode._g_input,
    abi.VIDIOC_S_INPUT: UvcNode._s_input,
    abi.VIDIOC_G_SELECTION: UvcNode._g_selection,
    abi.VIDIOC_CROPCAP: UvcNode._cropcap,
    abi.VIDIOC_G_CROP: UvcNode._g_crop,
    abi.VIDIOC_G_PRIORITY: UvcNode._g_priority,
    abi.VIDIOC_S_PRIORITY: UvcNode._s_priority,
    abi.VIDIOC_QUERYCTRL: UvcNode._queryctrl,
    abi.VIDIOC_QUERY_EXT_CTRL: UvcNode._query_ext_ctrl,
    abi.VIDIOC_QUERYMENU: UvcNode._querymenu,
    abi.VIDIOC_G_CTRL: UvcNode._g_ctrl,
    abi.VIDIOC_S_CTRL: UvcNode._s_ctrl,
    abi.VIDIOC_G_EXT_CTRLS: UvcNode._g_ext_ctrls,
    abi.VIDIOC_S_EXT_CTRLS: UvcNode._s_ext_ctrls,
    abi.VIDIOC_TRY_EXT_CTRLS: UvcNode._try_ext_ctrls,
    abi.VIDIOC_SUBSCRIBE_EVENT: UvcNode._subscribe,
    abi.VIDIOC_UNSUBSCRIBE_EVENT: UvcNode._unsubscribe,
    abi.VIDIOC_DQEVENT: UvcNode._dqevent,
    abi.VIDIOC_REQBUFS: UvcNode._reqbufs,
    abi.VIDIOC_CREATE_BUFS: UvcNode._create_bufs,
    abi.VIDIOC_QUERYBUF: UvcNode._querybuf,
    abi.VIDIOC_QBUF: UvcNode._qbuf,
    abi.VIDIOC_DQBUF: UvcNode._dqbuf,
    abi.VIDIOC_EXPBUF: UvcNode._expbuf,
    abi.VIDIOC_STREAMON: UvcNode._streamon,
    abi.VIDIOC_STREAMOFF: UvcNode._streamoff,
}


def rendered_image(node: UvcNode, timestamp_ns: int, tolerance_ns: int = 500_000) -> RenderedFrame | None:
    """The frame the node delivered with that buffer timestamp (within ``tolerance_ns``)."""
    with node.lock:
        for f in reversed(node.history):
            if abs(f.timestamp_ns - timestamp_ns) <= tolerance_ns:
                return f
    return None


__all__ = ["UvcNode", "FileHandle", "RenderedFrame", "rendered_image", "kernel_version_code", "running_kernel",
           "EACCES_FOR_INACTIVE_SINCE"]
