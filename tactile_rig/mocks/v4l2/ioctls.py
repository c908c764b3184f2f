"""The ioctls of an emulated UVC capture node, as the V4L2 core (drivers/media/v4l2-core/v4l2-ioctl.c),
uvcvideo (drivers/media/usb/uvc/uvc_v4l2.c) and videobuf2 answer them; :class:`UvcIoctls` is mixed
into :class:`~tactile_rig.mocks.v4l2.device.UvcNode`, which holds the state they read and change.

* the core first: ENOTTY for what uvcvideo does not implement (``G_STD``, ``ENUMSTD``, ``S_STD``,
  ``QUERYSTD``, ``PREPARE_BUF``, ``S_SELECTION``, ``S_CROP``, the tuner, audio, output and DV-timings
  ioctls, ``LOG_STATUS``); EBUSY from the priority check (``VIDIOC_S_PRIORITY``) for the ioctls that
  change state; EINVAL for a buffer type the node does not have; the input fields each ioctl
  zeroes (INFO_FL_CLEAR); the extended-pixel-format handling of ``S_FMT``/``TRY_FMT``; a
  multi-planar type handed to the selection ioctls as its single-planar twin.
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
"""

from __future__ import annotations

import ctypes as C
import errno
import os
import time
from collections import deque
from typing import Callable, TypeVar

import tactile_rig.mocks.v4l2.abi as abi
import tactile_rig.mocks.v4l2.formats as formats
from tactile_rig.devices.camera_models import CameraModel
from tactile_rig.mocks.camera import SimulatedCamera
from tactile_rig.mocks.v4l2.controls import ControlChange, ControlSet, check_ext_ctrls
from tactile_rig.mocks.v4l2.formats import StreamFormat
from tactile_rig.mocks.v4l2.handle import FileHandle
from tactile_rig.mocks.v4l2.queue import BufferQueue
from tactile_rig.mocks.v4l2.sysfs import NodeIdentity

Result = tuple[int, bytes, bytes, list[int]]

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


class UvcIoctls:
    """The ioctl handlers; each takes (file handle, argument bytes, control array bytes) and returns
    (result or -errno, argument out, control array out, descriptors to send)."""

    model: CameraModel
    sim: SimulatedCamera
    ident: NodeIdentity
    kernel: tuple[int, ...]
    stream: StreamFormat
    controls: ControlSet
    queue: BufferQueue
    handles: dict[int, FileHandle]
    owner: FileHandle | None
    vb2_ownership: bool

    def _start_stream(self) -> None:
        raise NotImplementedError

    def _stop_stream(self) -> None:
        raise NotImplementedError

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
