"""The format, frame-rate, input and cropping ioctls of an emulated UVC capture node, as the V4L2
core (v4l2-ioctl.c: the input fields each ioctl zeroes, the extended-pixel-format handling of
``S_FMT``/``TRY_FMT``, a multi-planar type handed to the selection ioctls as its single-planar twin)
and uvcvideo (uvc_v4l2.c: the closest size, the closest interval) answer them; the rules of
sizes and intervals are :mod:`.formats`.
"""

from __future__ import annotations

import ctypes as C
import errno

import tactile_rig.mocks.v4l2.abi as abi
import tactile_rig.mocks.v4l2.formats as formats
from tactile_rig.mocks.v4l2.formats import StreamFormat
from tactile_rig.mocks.v4l2.handle import FileHandle
from tactile_rig.mocks.v4l2.ioctl_access import NodeState, Result


def sanitize_format(f: abi.v4l2_format) -> None:
    """v4l_sanitize_format, then CLEAR_AFTER_FIELD(fmt.pix)."""
    p = f.fmt.pix
    if p.priv != abi.V4L2_PIX_FMT_PRIV_MAGIC:
        p.priv = abi.V4L2_PIX_FMT_PRIV_MAGIC
        p.flags = p.ycbcr_enc = p.quantization = p.xfer_func = 0
    start = abi.v4l2_format.fmt.offset + C.sizeof(abi.v4l2_pix_format)
    C.memset(C.addressof(f) + start, 0, C.sizeof(f) - start)


class FormatIoctls(NodeState):
    """ENUM_FMT, G/S/TRY_FMT, G/S_PARM, ENUM_FRAMESIZES, ENUM_FRAMEINTERVALS, ENUMINPUT, G/S_INPUT,
    G_SELECTION, CROPCAP, G_CROP."""

    def _enum_fmt(self, fh: FileHandle, payload: bytes, array: bytes) -> Result:
        f = abi.parse_struct(abi.v4l2_fmtdesc, payload)
        if f.type != abi.V4L2_BUF_TYPE_VIDEO_CAPTURE:
            return -errno.EINVAL, b"", b"", []
        abi.clear_after(f, "type")
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

    def _g_fmt(self, fh: FileHandle, payload: bytes, array: bytes) -> Result:
        f = abi.parse_struct(abi.v4l2_format, payload)
        if f.type != abi.V4L2_BUF_TYPE_VIDEO_CAPTURE:
            return -errno.EINVAL, b"", b"", []
        C.memset(C.addressof(f) + abi.v4l2_format.fmt.offset, 0, C.sizeof(f) - abi.v4l2_format.fmt.offset)
        self._fill_pix(f, self.stream)
        return 0, bytes(f), b"", []

    def _try_or_set_fmt(self, fh: FileHandle, payload: bytes, set_: bool) -> Result:
        f = abi.parse_struct(abi.v4l2_format, payload)
        if set_:  # uvc_ioctl_s_fmt acquires privileges before it looks at the type
            err = self._acquire(fh)
            if err:
                return err, b"", b"", []
        if f.type != abi.V4L2_BUF_TYPE_VIDEO_CAPTURE:
            return -errno.EINVAL, b"", b"", []
        sanitize_format(f)
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

    def _s_fmt(self, fh: FileHandle, payload: bytes, array: bytes) -> Result:
        return self._try_or_set_fmt(fh, payload, True)

    def _try_fmt(self, fh: FileHandle, payload: bytes, array: bytes) -> Result:
        return self._try_or_set_fmt(fh, payload, False)

    def _fill_parm(self, p: abi.v4l2_streamparm) -> None:
        frac = formats.interval_fraction(self.stream.interval_100ns)
        p.parm.capture.capability = abi.V4L2_CAP_TIMEPERFRAME
        p.parm.capture.timeperframe.numerator = frac.numerator
        p.parm.capture.timeperframe.denominator = frac.denominator

    def _g_parm(self, fh: FileHandle, payload: bytes, array: bytes) -> Result:
        p = abi.parse_struct(abi.v4l2_streamparm, payload)
        if p.type != abi.V4L2_BUF_TYPE_VIDEO_CAPTURE:
            return -errno.EINVAL, b"", b"", []
        abi.clear_after(p, "type")
        self._fill_parm(p)
        return 0, bytes(p), b"", []

    def _s_parm(self, fh: FileHandle, payload: bytes, array: bytes) -> Result:
        p = abi.parse_struct(abi.v4l2_streamparm, payload)
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

    def _enum_framesizes(self, fh: FileHandle, payload: bytes, array: bytes) -> Result:
        f = abi.parse_struct(abi.v4l2_frmsizeenum, payload)
        abi.clear_after(f, "pixel_format")
        fmt = next((m for m in self.model.formats if abi.fourcc(m.fourcc) == f.pixel_format), None)
        if fmt is None:
            return -errno.EINVAL, b"", b"", []
        sizes = formats.frame_sizes(fmt)
        if f.index >= len(sizes):
            return -errno.EINVAL, b"", b"", []
        f.type = abi.V4L2_FRMSIZE_TYPE_DISCRETE
        f.u.discrete.width, f.u.discrete.height = sizes[f.index].width_px, sizes[f.index].height_px
        return 0, bytes(f), b"", []

    def _enum_frameintervals(self, fh: FileHandle, payload: bytes, array: bytes) -> Result:
        f = abi.parse_struct(abi.v4l2_frmivalenum, payload)
        abi.clear_after(f, "height")
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

    def _enuminput(self, fh: FileHandle, payload: bytes, array: bytes) -> Result:
        i = abi.parse_struct(abi.v4l2_input, payload)
        abi.clear_after(i, "index")
        if i.index != 0:
            return -errno.EINVAL, b"", b"", []
        i.name = b"Camera 1"  # uvcvideo names a camera terminal "Camera <bTerminalID>"
        i.type = abi.V4L2_INPUT_TYPE_CAMERA
        return 0, bytes(i), b"", []

    def _g_input(self, fh: FileHandle, payload: bytes, array: bytes) -> Result:
        return 0, (0).to_bytes(4, "little"), b"", []

    def _s_input(self, fh: FileHandle, payload: bytes, array: bytes) -> Result:
        err = self._acquire(fh)
        if err:
            return err, b"", b"", []
        value = int.from_bytes(payload[:4].ljust(4, b"\0"), "little")
        return (-errno.EINVAL if value != 0 else 0), payload[:4].ljust(4, b"\0"), b"", []

    def _g_selection(self, fh: FileHandle, payload: bytes, array: bytes) -> Result:
        s = abi.parse_struct(abi.v4l2_selection, payload)
        abi.clear_after(s, "r")
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

    def _cropcap(self, fh: FileHandle, payload: bytes, array: bytes) -> Result:
        c = abi.parse_struct(abi.v4l2_cropcap, payload)
        abi.clear_after(c, "type")
        c.pixelaspect.numerator = c.pixelaspect.denominator = 1
        for target, attr in ((abi.V4L2_SEL_TGT_CROP_BOUNDS, "bounds"), (abi.V4L2_SEL_TGT_CROP_DEFAULT, "defrect")):
            r = self._selection(c.type, target)
            if isinstance(r, int):
                return r, b"", b"", []
            setattr(c, attr, r)
        return 0, bytes(c), b"", []

    def _g_crop(self, fh: FileHandle, payload: bytes, array: bytes) -> Result:
        c = abi.parse_struct(abi.v4l2_crop, payload)
        r = self._selection(c.type, abi.V4L2_SEL_TGT_CROP)
        return (r if isinstance(r, int) else 0), b"", b"", []
