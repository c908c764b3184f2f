"""The V4L2 user-space ABI (``linux/videodev2.h``) the emulated device speaks: ioctl numbers, the
structures they carry (as :mod:`ctypes` structures with the 64-bit Linux layout), and the
constants the device uses.

Only what a UVC capture device needs is here. The layouts are checked against the system's own
header by the test suite (a small C program compiled with ``cc`` prints each ``sizeof`` and ioctl
number), so a mismatch is caught rather than served.
"""

from __future__ import annotations

import ctypes as C
from typing import TypeVar

# -- ioctl encoding (asm-generic/ioctl.h) -------------------------------------------------------------
_IOC_NRBITS, _IOC_TYPEBITS, _IOC_SIZEBITS = 8, 8, 14
_IOC_NRSHIFT = 0
_IOC_TYPESHIFT = _IOC_NRSHIFT + _IOC_NRBITS
_IOC_SIZESHIFT = _IOC_TYPESHIFT + _IOC_TYPEBITS
_IOC_DIRSHIFT = _IOC_SIZESHIFT + _IOC_SIZEBITS
IOC_NONE, IOC_WRITE, IOC_READ = 0, 1, 2


def _ioc(direction: int, nr: int, size: int) -> int:
    return (direction << _IOC_DIRSHIFT) | (ord("V") << _IOC_TYPESHIFT) | (nr << _IOC_NRSHIFT) | (size << _IOC_SIZESHIFT)


def ioc_dir(cmd: int) -> int:
    return (cmd >> _IOC_DIRSHIFT) & 3


def ioc_size(cmd: int) -> int:
    return (cmd >> _IOC_SIZESHIFT) & ((1 << _IOC_SIZEBITS) - 1)


def ioc_type(cmd: int) -> int:
    return (cmd >> _IOC_TYPESHIFT) & 0xFF


def ioc_nr(cmd: int) -> int:
    return cmd & 0xFF


# -- structures -----------------------------------------------------------------------------------------

class v4l2_capability(C.Structure):
    _fields_ = [("driver", C.c_char * 16), ("card", C.c_char * 32), ("bus_info", C.c_char * 32),
                ("version", C.c_uint32), ("capabilities", C.c_uint32), ("device_caps", C.c_uint32),
                ("reserved", C.c_uint32 * 3)]


class v4l2_fmtdesc(C.Structure):
    _fields_ = [("index", C.c_uint32), ("type", C.c_uint32), ("flags", C.c_uint32), ("description", C.c_char * 32),
                ("pixelformat", C.c_uint32), ("mbus_code", C.c_uint32), ("reserved", C.c_uint32 * 3)]


class v4l2_pix_format(C.Structure):
    _fields_ = [("width", C.c_uint32), ("height", C.c_uint32), ("pixelformat", C.c_uint32), ("field", C.c_uint32),
                ("bytesperline", C.c_uint32), ("sizeimage", C.c_uint32), ("colorspace", C.c_uint32),
                ("priv", C.c_uint32), ("flags", C.c_uint32), ("ycbcr_enc", C.c_uint32),
                ("quantization", C.c_uint32), ("xfer_func", C.c_uint32)]


class _v4l2_format_union(C.Union):
    # The union holds struct v4l2_window (with pointers), hence its 8-byte alignment.
    _fields_ = [("pix", v4l2_pix_format), ("raw_data", C.c_uint8 * 200), ("_align", C.c_void_p)]


class v4l2_format(C.Structure):
    _fields_ = [("type", C.c_uint32), ("fmt", _v4l2_format_union)]


class v4l2_frmsize_discrete(C.Structure):
    _fields_ = [("width", C.c_uint32), ("height", C.c_uint32)]


class v4l2_frmsize_stepwise(C.Structure):
    _fields_ = [("min_width", C.c_uint32), ("max_width", C.c_uint32), ("step_width", C.c_uint32),
                ("min_height", C.c_uint32), ("max_height", C.c_uint32), ("step_height", C.c_uint32)]


class _frmsize_union(C.Union):
    _fields_ = [("discrete", v4l2_frmsize_discrete), ("stepwise", v4l2_frmsize_stepwise)]


class v4l2_frmsizeenum(C.Structure):
    _fields_ = [("index", C.c_uint32), ("pixel_format", C.c_uint32), ("type", C.c_uint32), ("u", _frmsize_union),
                ("reserved", C.c_uint32 * 2)]


class v4l2_fract(C.Structure):
    _fields_ = [("numerator", C.c_uint32), ("denominator", C.c_uint32)]


class v4l2_frmival_stepwise(C.Structure):
    _fields_ = [("min", v4l2_fract), ("max", v4l2_fract), ("step", v4l2_fract)]


class _frmival_union(C.Union):
    _fields_ = [("discrete", v4l2_fract), ("stepwise", v4l2_frmival_stepwise)]


class v4l2_frmivalenum(C.Structure):
    _fields_ = [("index", C.c_uint32), ("pixel_format", C.c_uint32), ("width", C.c_uint32), ("height", C.c_uint32),
                ("type", C.c_uint32), ("u", _frmival_union), ("reserved", C.c_uint32 * 2)]


class v4l2_captureparm(C.Structure):
    _fields_ = [("capability", C.c_uint32), ("capturemode", C.c_uint32), ("timeperframe", v4l2_fract),
                ("extendedmode", C.c_uint32), ("readbuffers", C.c_uint32), ("reserved", C.c_uint32 * 4)]


class _streamparm_union(C.Union):
    _fields_ = [("capture", v4l2_captureparm), ("raw_data", C.c_uint8 * 200)]


class v4l2_streamparm(C.Structure):
    _fields_ = [("type", C.c_uint32), ("parm", _streamparm_union)]


class v4l2_input(C.Structure):
    _fields_ = [("index", C.c_uint32), ("name", C.c_char * 32), ("type", C.c_uint32), ("audioset", C.c_uint32),
                ("tuner", C.c_uint32), ("std", C.c_uint64), ("status", C.c_uint32), ("capabilities", C.c_uint32),
                ("reserved", C.c_uint32 * 3)]


class v4l2_requestbuffers(C.Structure):
    _fields_ = [("count", C.c_uint32), ("type", C.c_uint32), ("memory", C.c_uint32), ("capabilities", C.c_uint32),
                ("flags", C.c_uint8), ("reserved", C.c_uint8 * 3)]


class timeval(C.Structure):
    _fields_ = [("tv_sec", C.c_long), ("tv_usec", C.c_long)]


class timespec(C.Structure):
    _fields_ = [("tv_sec", C.c_long), ("tv_nsec", C.c_long)]


class v4l2_timecode(C.Structure):
    _fields_ = [("type", C.c_uint32), ("flags", C.c_uint32), ("frames", C.c_uint8), ("seconds", C.c_uint8),
                ("minutes", C.c_uint8), ("hours", C.c_uint8), ("userbits", C.c_uint8 * 4)]


class _buffer_m(C.Union):
    _fields_ = [("offset", C.c_uint32), ("userptr", C.c_ulong), ("planes", C.c_void_p), ("fd", C.c_int32)]


class v4l2_buffer(C.Structure):
    _fields_ = [("index", C.c_uint32), ("type", C.c_uint32), ("bytesused", C.c_uint32), ("flags", C.c_uint32),
                ("field", C.c_uint32), ("timestamp", timeval), ("timecode", v4l2_timecode),
                ("sequence", C.c_uint32), ("memory", C.c_uint32), ("m", _buffer_m), ("length", C.c_uint32),
                ("reserved2", C.c_uint32), ("request_fd", C.c_int32)]


class v4l2_exportbuffer(C.Structure):
    _fields_ = [("type", C.c_uint32), ("index", C.c_uint32), ("plane", C.c_uint32), ("flags", C.c_uint32),
                ("fd", C.c_int32), ("reserved", C.c_uint32 * 11)]


class v4l2_create_buffers(C.Structure):
    _fields_ = [("index", C.c_uint32), ("count", C.c_uint32), ("memory", C.c_uint32), ("format", v4l2_format),
                ("capabilities", C.c_uint32), ("flags", C.c_uint32), ("reserved", C.c_uint32 * 6)]


class v4l2_queryctrl(C.Structure):
    _fields_ = [("id", C.c_uint32), ("type", C.c_uint32), ("name", C.c_char * 32), ("minimum", C.c_int32),
                ("maximum", C.c_int32), ("step", C.c_int32), ("default_value", C.c_int32), ("flags", C.c_uint32),
                ("reserved", C.c_uint32 * 2)]


class v4l2_query_ext_ctrl(C.Structure):
    _fields_ = [("id", C.c_uint32), ("type", C.c_uint32), ("name", C.c_char * 32), ("minimum", C.c_int64),
                ("maximum", C.c_int64), ("step", C.c_uint64), ("default_value", C.c_int64), ("flags", C.c_uint32),
                ("elem_size", C.c_uint32), ("elems", C.c_uint32), ("nr_of_dims", C.c_uint32), ("dims", C.c_uint32 * 4),
                ("reserved", C.c_uint32 * 32)]


class _querymenu_union(C.Union):
    _pack_ = 1
    _fields_ = [("name", C.c_char * 32), ("value", C.c_int64)]


class v4l2_querymenu(C.Structure):
    _pack_ = 1
    _fields_ = [("id", C.c_uint32), ("index", C.c_uint32), ("u", _querymenu_union), ("reserved", C.c_uint32)]


class v4l2_control(C.Structure):
    _fields_ = [("id", C.c_uint32), ("value", C.c_int32)]


class _ext_control_union(C.Union):
    _pack_ = 1
    _fields_ = [("value", C.c_int32), ("value64", C.c_int64), ("ptr", C.c_void_p)]


class v4l2_ext_control(C.Structure):
    _pack_ = 1
    _fields_ = [("id", C.c_uint32), ("size", C.c_uint32), ("reserved2", C.c_uint32), ("u", _ext_control_union)]


class v4l2_ext_controls(C.Structure):
    _fields_ = [("which", C.c_uint32), ("count", C.c_uint32), ("error_idx", C.c_uint32), ("request_fd", C.c_int32),
                ("reserved", C.c_uint32), ("controls", C.c_void_p)]


class v4l2_event_subscription(C.Structure):
    _fields_ = [("type", C.c_uint32), ("id", C.c_uint32), ("flags", C.c_uint32), ("reserved", C.c_uint32 * 5)]


class _event_ctrl_value(C.Union):
    _fields_ = [("value", C.c_int32), ("value64", C.c_int64)]


class v4l2_event_ctrl(C.Structure):
    _fields_ = [("changes", C.c_uint32), ("type", C.c_uint32), ("v", _event_ctrl_value), ("flags", C.c_uint32),
                ("minimum", C.c_int32), ("maximum", C.c_int32), ("step", C.c_int32), ("default_value", C.c_int32)]


class _event_union(C.Union):
    _fields_ = [("ctrl", v4l2_event_ctrl), ("data", C.c_uint8 * 64), ("_align", C.c_int64)]


class v4l2_event(C.Structure):
    _fields_ = [("type", C.c_uint32), ("u", _event_union), ("pending", C.c_uint32), ("sequence", C.c_uint32),
                ("timestamp", timespec), ("id", C.c_uint32), ("reserved", C.c_uint32 * 8)]


class v4l2_rect(C.Structure):
    _fields_ = [("left", C.c_int32), ("top", C.c_int32), ("width", C.c_uint32), ("height", C.c_uint32)]


class v4l2_selection(C.Structure):
    _fields_ = [("type", C.c_uint32), ("target", C.c_uint32), ("flags", C.c_uint32), ("r", v4l2_rect),
                ("reserved", C.c_uint32 * 9)]


class v4l2_cropcap(C.Structure):
    _fields_ = [("type", C.c_uint32), ("bounds", v4l2_rect), ("defrect", v4l2_rect), ("pixelaspect", v4l2_fract)]


class v4l2_crop(C.Structure):
    _fields_ = [("type", C.c_uint32), ("c", v4l2_rect)]


STRUCTS: dict[str, type[C.Structure]] = {cls.__name__: cls for cls in (
    v4l2_capability, v4l2_fmtdesc, v4l2_pix_format, v4l2_format, v4l2_frmsizeenum, v4l2_frmivalenum,
    v4l2_streamparm, v4l2_input, v4l2_requestbuffers, v4l2_buffer, v4l2_exportbuffer, v4l2_create_buffers,
    v4l2_queryctrl, v4l2_query_ext_ctrl, v4l2_querymenu, v4l2_control, v4l2_ext_control, v4l2_ext_controls,
    v4l2_event_subscription, v4l2_event, v4l2_selection, v4l2_cropcap, v4l2_crop)}

# -- ioctl numbers ----------------------------------------------------------------------------------------
_u32 = C.sizeof(C.c_uint32)
VIDIOC_QUERYCAP = _ioc(IOC_READ, 0, C.sizeof(v4l2_capability))
VIDIOC_ENUM_FMT = _ioc(IOC_READ | IOC_WRITE, 2, C.sizeof(v4l2_fmtdesc))
VIDIOC_G_FMT = _ioc(IOC_READ | IOC_WRITE, 4, C.sizeof(v4l2_format))
VIDIOC_S_FMT = _ioc(IOC_READ | IOC_WRITE, 5, C.sizeof(v4l2_format))
VIDIOC_REQBUFS = _ioc(IOC_READ | IOC_WRITE, 8, C.sizeof(v4l2_requestbuffers))
VIDIOC_QUERYBUF = _ioc(IOC_READ | IOC_WRITE, 9, C.sizeof(v4l2_buffer))
VIDIOC_G_FBUF = _ioc(IOC_READ, 10, 48)
VIDIOC_S_FBUF = _ioc(IOC_WRITE, 11, 48)
VIDIOC_OVERLAY = _ioc(IOC_WRITE, 14, _u32)
VIDIOC_QBUF = _ioc(IOC_READ | IOC_WRITE, 15, C.sizeof(v4l2_buffer))
VIDIOC_EXPBUF = _ioc(IOC_READ | IOC_WRITE, 16, C.sizeof(v4l2_exportbuffer))
VIDIOC_DQBUF = _ioc(IOC_READ | IOC_WRITE, 17, C.sizeof(v4l2_buffer))
VIDIOC_STREAMON = _ioc(IOC_WRITE, 18, _u32)
VIDIOC_STREAMOFF = _ioc(IOC_WRITE, 19, _u32)
VIDIOC_G_PARM = _ioc(IOC_READ | IOC_WRITE, 21, C.sizeof(v4l2_streamparm))
VIDIOC_S_PARM = _ioc(IOC_READ | IOC_WRITE, 22, C.sizeof(v4l2_streamparm))
VIDIOC_G_STD = _ioc(IOC_READ, 23, 8)
VIDIOC_S_STD = _ioc(IOC_WRITE, 24, 8)
VIDIOC_ENUMSTD = _ioc(IOC_READ | IOC_WRITE, 25, 72)
VIDIOC_ENUMINPUT = _ioc(IOC_READ | IOC_WRITE, 26, C.sizeof(v4l2_input))
VIDIOC_G_CTRL = _ioc(IOC_READ | IOC_WRITE, 27, C.sizeof(v4l2_control))
VIDIOC_S_CTRL = _ioc(IOC_READ | IOC_WRITE, 28, C.sizeof(v4l2_control))
VIDIOC_QUERYCTRL = _ioc(IOC_READ | IOC_WRITE, 36, C.sizeof(v4l2_queryctrl))
VIDIOC_QUERYMENU = _ioc(IOC_READ | IOC_WRITE, 37, C.sizeof(v4l2_querymenu))
VIDIOC_G_INPUT = _ioc(IOC_READ, 38, _u32)
VIDIOC_S_INPUT = _ioc(IOC_READ | IOC_WRITE, 39, _u32)
VIDIOC_CROPCAP = _ioc(IOC_READ | IOC_WRITE, 58, C.sizeof(v4l2_cropcap))
VIDIOC_G_CROP = _ioc(IOC_READ | IOC_WRITE, 59, C.sizeof(v4l2_crop))
VIDIOC_S_CROP = _ioc(IOC_WRITE, 60, C.sizeof(v4l2_crop))
VIDIOC_TRY_FMT = _ioc(IOC_READ | IOC_WRITE, 64, C.sizeof(v4l2_format))
VIDIOC_G_PRIORITY = _ioc(IOC_READ, 67, _u32)
VIDIOC_S_PRIORITY = _ioc(IOC_WRITE, 68, _u32)
VIDIOC_LOG_STATUS = _ioc(IOC_NONE, 70, 0)
VIDIOC_G_EXT_CTRLS = _ioc(IOC_READ | IOC_WRITE, 71, C.sizeof(v4l2_ext_controls))
VIDIOC_S_EXT_CTRLS = _ioc(IOC_READ | IOC_WRITE, 72, C.sizeof(v4l2_ext_controls))
VIDIOC_TRY_EXT_CTRLS = _ioc(IOC_READ | IOC_WRITE, 73, C.sizeof(v4l2_ext_controls))
VIDIOC_ENUM_FRAMESIZES = _ioc(IOC_READ | IOC_WRITE, 74, C.sizeof(v4l2_frmsizeenum))
VIDIOC_ENUM_FRAMEINTERVALS = _ioc(IOC_READ | IOC_WRITE, 75, C.sizeof(v4l2_frmivalenum))
VIDIOC_DQEVENT = _ioc(IOC_READ, 89, C.sizeof(v4l2_event))
VIDIOC_SUBSCRIBE_EVENT = _ioc(IOC_WRITE, 90, C.sizeof(v4l2_event_subscription))
VIDIOC_UNSUBSCRIBE_EVENT = _ioc(IOC_WRITE, 91, C.sizeof(v4l2_event_subscription))
VIDIOC_CREATE_BUFS = _ioc(IOC_READ | IOC_WRITE, 92, C.sizeof(v4l2_create_buffers))
VIDIOC_PREPARE_BUF = _ioc(IOC_READ | IOC_WRITE, 93, C.sizeof(v4l2_buffer))
VIDIOC_G_SELECTION = _ioc(IOC_READ | IOC_WRITE, 94, C.sizeof(v4l2_selection))
VIDIOC_S_SELECTION = _ioc(IOC_READ | IOC_WRITE, 95, C.sizeof(v4l2_selection))
VIDIOC_QUERY_EXT_CTRL = _ioc(IOC_READ | IOC_WRITE, 103, C.sizeof(v4l2_query_ext_ctrl))

IOCTLS: dict[str, int] = {k: v for k, v in globals().items() if k.startswith("VIDIOC_")}
IOCTL_NAMES: dict[int, str] = {v: k for k, v in IOCTLS.items()}

# -- constants ---------------------------------------------------------------------------------------------
V4L2_CAP_VIDEO_CAPTURE = 0x00000001
V4L2_CAP_META_CAPTURE = 0x00800000
V4L2_CAP_STREAMING = 0x04000000
V4L2_CAP_EXT_PIX_FORMAT = 0x00200000
V4L2_CAP_DEVICE_CAPS = 0x80000000

V4L2_BUF_TYPE_VIDEO_CAPTURE = 1
V4L2_BUF_TYPE_VIDEO_CAPTURE_MPLANE = 9
V4L2_BUF_TYPE_META_CAPTURE = 13
V4L2_MEMORY_MMAP, V4L2_MEMORY_USERPTR, V4L2_MEMORY_OVERLAY, V4L2_MEMORY_DMABUF = 1, 2, 3, 4
V4L2_FIELD_ANY, V4L2_FIELD_NONE = 0, 1
V4L2_COLORSPACE_SRGB = 8
V4L2_XFER_FUNC_709 = 1
V4L2_YCBCR_ENC_601 = 1
V4L2_PIX_FMT_PRIV_MAGIC = 0xFEEDCAFE
V4L2_FMT_FLAG_COMPRESSED = 0x0001
V4L2_FRMSIZE_TYPE_DISCRETE = 1
V4L2_FRMIVAL_TYPE_DISCRETE = 1
V4L2_CAP_TIMEPERFRAME = 0x1000
V4L2_MODE_HIGHQUALITY = 0x0001
V4L2_INPUT_TYPE_CAMERA = 2

V4L2_BUF_FLAG_MAPPED = 0x00000001
V4L2_BUF_FLAG_QUEUED = 0x00000002
V4L2_BUF_FLAG_DONE = 0x00000004
V4L2_BUF_FLAG_KEYFRAME = 0x00000008
V4L2_BUF_FLAG_PFRAME = 0x00000010
V4L2_BUF_FLAG_BFRAME = 0x00000020
V4L2_BUF_FLAG_ERROR = 0x00000040
V4L2_BUF_FLAG_IN_REQUEST = 0x00000080
V4L2_BUF_FLAG_TIMECODE = 0x00000100
V4L2_BUF_FLAG_M2M_HOLD_CAPTURE_BUF = 0x00000200
V4L2_BUF_FLAG_PREPARED = 0x00000400
V4L2_BUF_FLAG_NO_CACHE_INVALIDATE = 0x00000800
V4L2_BUF_FLAG_NO_CACHE_CLEAN = 0x00001000
V4L2_BUF_FLAG_TIMESTAMP_MONOTONIC = 0x00002000
V4L2_BUF_FLAG_TSTAMP_SRC_SOE = 0x00010000
V4L2_BUF_FLAG_LAST = 0x00100000
V4L2_BUF_FLAG_REQUEST_FD = 0x00800000

V4L2_BUF_CAP_SUPPORTS_MMAP = 1 << 0
V4L2_BUF_CAP_SUPPORTS_USERPTR = 1 << 1
V4L2_BUF_CAP_SUPPORTS_DMABUF = 1 << 2
V4L2_BUF_CAP_SUPPORTS_REQUESTS = 1 << 3
V4L2_BUF_CAP_SUPPORTS_ORPHANED_BUFS = 1 << 4

V4L2_CTRL_TYPE_INTEGER, V4L2_CTRL_TYPE_BOOLEAN, V4L2_CTRL_TYPE_MENU = 1, 2, 3
V4L2_CTRL_TYPE_CTRL_CLASS = 6
V4L2_CTRL_FLAG_DISABLED = 0x0001
V4L2_CTRL_FLAG_GRABBED = 0x0002
V4L2_CTRL_FLAG_READ_ONLY = 0x0004
V4L2_CTRL_FLAG_UPDATE = 0x0008
V4L2_CTRL_FLAG_INACTIVE = 0x0010
V4L2_CTRL_FLAG_WRITE_ONLY = 0x0040
V4L2_CTRL_FLAG_NEXT_CTRL = 0x80000000
V4L2_CTRL_FLAG_NEXT_COMPOUND = 0x40000000
V4L2_CTRL_ID_MASK = 0x0FFFFFFF
V4L2_CTRL_WHICH_CUR_VAL = 0
V4L2_CTRL_WHICH_DEF_VAL = 0x0F000000
V4L2_CTRL_WHICH_REQUEST_VAL = 0x0F010000
V4L2_CTRL_CLASS_USER = 0x00980000
V4L2_CTRL_CLASS_CAMERA = 0x009A0000
V4L2_CID_USER_CLASS = V4L2_CTRL_CLASS_USER | 1
V4L2_CID_CAMERA_CLASS = V4L2_CTRL_CLASS_CAMERA | 1
V4L2_CID_PRIVATE_BASE = 0x08000000
V4L2_CID_MAX_CTRLS = 1024

V4L2_EVENT_ALL = 0
V4L2_EVENT_CTRL = 3
V4L2_EVENT_SUB_FL_SEND_INITIAL = 1 << 0
V4L2_EVENT_SUB_FL_ALLOW_FEEDBACK = 1 << 1
V4L2_EVENT_CTRL_CH_VALUE = 1 << 0
V4L2_EVENT_CTRL_CH_FLAGS = 1 << 1
V4L2_EVENT_CTRL_CH_RANGE = 1 << 2

V4L2_SEL_TGT_CROP = 0x0000
V4L2_SEL_TGT_CROP_DEFAULT = 0x0001
V4L2_SEL_TGT_CROP_BOUNDS = 0x0002

V4L2_PRIORITY_UNSET, V4L2_PRIORITY_BACKGROUND, V4L2_PRIORITY_INTERACTIVE, V4L2_PRIORITY_RECORD = 0, 1, 2, 3

POLLIN, POLLPRI, POLLOUT, POLLERR, POLLHUP, POLLRDNORM, POLLWRNORM = 0x1, 0x2, 0x4, 0x8, 0x10, 0x40, 0x100


def fourcc(code: str) -> int:
    """The V4L2 pixel format code of a 4-character FOURCC (``v4l2_fourcc``)."""
    if len(code) != 4:
        raise ValueError(f"FOURCC {code!r} must be 4 characters")
    b = code.encode("ascii")
    return b[0] | (b[1] << 8) | (b[2] << 16) | (b[3] << 24)


def fourcc_str(code: int) -> str:
    return "".join(chr((code >> (8 * i)) & 0xFF) for i in range(4))


# Format descriptions the V4L2 core fills in for ENUM_FMT (v4l2-ioctl.c, v4l_fill_fmtdesc).
FORMAT_DESCRIPTIONS = {"YUYV": "YUYV 4:2:2", "MJPG": "Motion-JPEG"}



_S = TypeVar("_S", bound=C.Structure)


def parse_struct(cls: type[_S], payload: bytes) -> _S:
    """An ioctl argument of type ``cls`` from the bytes the client sent (short input zero-padded)."""
    size = C.sizeof(cls)
    return cls.from_buffer_copy(payload[:size].ljust(size, b"\0"))


def clear_after(s: C.Structure, name: str) -> None:
    """Zero every byte after field ``name`` (the V4L2 core's INFO_FL_CLEAR / memset_after)."""
    f = getattr(type(s), name)
    end = f.offset + f.size
    C.memset(C.addressof(s) + end, 0, C.sizeof(s) - end)
