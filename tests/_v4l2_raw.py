"""A raw V4L2 client (libc calls through ctypes, the kernel's structures from
:mod:`tactile_rig.mocks.v4l2.abi`) for bodies that run in a child process started with an emulated
camera's environment. Each body returns plain data the parent checks.
"""

from __future__ import annotations

import ctypes as C
import errno
import mmap
import os
import select
import stat
import time
from typing import Any

import tactile_rig.mocks.v4l2.abi as abi

_libc = C.CDLL(None, use_errno=True)
_libc.ioctl.argtypes = [C.c_int, C.c_ulong, C.c_void_p]
_libc.ioctl.restype = C.c_int


def ioctl(fd: int, req: int, arg: Any) -> int:
    """0, or the errno (the argument is a ctypes structure, None for NULL, or an int for a bad address)."""
    ptr = None if arg is None else (arg if isinstance(arg, int) else C.addressof(arg))
    if _libc.ioctl(fd, req, ptr) < 0:
        return C.get_errno()
    return 0


def _check(fd: int, req: int, arg: Any) -> None:
    err = ioctl(fd, req, arg)
    if err:
        raise OSError(err, f"{abi.IOCTL_NAMES.get(req, hex(req))}: {os.strerror(err)}")


def start_stream(fd: int, count: int, width: int = 320, height: int = 240) -> list[mmap.mmap]:
    f = abi.v4l2_format(type=abi.V4L2_BUF_TYPE_VIDEO_CAPTURE)
    f.fmt.pix.width, f.fmt.pix.height, f.fmt.pix.pixelformat = width, height, abi.fourcc("YUYV")
    _check(fd, abi.VIDIOC_S_FMT, f)
    r = abi.v4l2_requestbuffers(count=count, type=abi.V4L2_BUF_TYPE_VIDEO_CAPTURE, memory=abi.V4L2_MEMORY_MMAP)
    _check(fd, abi.VIDIOC_REQBUFS, r)
    maps = []
    for i in range(r.count):
        b = abi.v4l2_buffer(index=i, type=abi.V4L2_BUF_TYPE_VIDEO_CAPTURE, memory=abi.V4L2_MEMORY_MMAP)
        _check(fd, abi.VIDIOC_QUERYBUF, b)
        maps.append(mmap.mmap(fd, b.length, mmap.MAP_SHARED, mmap.PROT_READ, offset=b.m.offset))
        _check(fd, abi.VIDIOC_QBUF, b)
    _check(fd, abi.VIDIOC_STREAMON, C.c_int(abi.V4L2_BUF_TYPE_VIDEO_CAPTURE))
    return maps


def dqbuf(fd: int) -> abi.v4l2_buffer:
    b = abi.v4l2_buffer(type=abi.V4L2_BUF_TYPE_VIDEO_CAPTURE, memory=abi.V4L2_MEMORY_MMAP)
    _check(fd, abi.VIDIOC_DQBUF, b)
    return b


def qbuf(fd: int, index: int) -> None:
    _check(fd, abi.VIDIOC_QBUF, abi.v4l2_buffer(index=index, type=abi.V4L2_BUF_TYPE_VIDEO_CAPTURE,
                                                memory=abi.V4L2_MEMORY_MMAP))


# -- bodies ------------------------------------------------------------------------------------------
def sequence_with_a_late_host(port: str) -> list[tuple[int, int, int, int]]:
    """(index, sequence, timestamp in us, flags) of frames dequeued by a host that stops requeueing
    for 0.5 s with both buffers full (a blocking open: DQBUF waits)."""
    fd = os.open(port, os.O_RDWR)
    maps = start_stream(fd, 2)
    got = []
    for _ in range(4):
        b = dqbuf(fd)
        got.append((b.index, b.sequence, b.timestamp.tv_sec * 1_000_000 + b.timestamp.tv_usec, b.flags))
        qbuf(fd, b.index)
    time.sleep(0.5)  # both buffers fill, then frames find no buffer
    for _ in range(4):
        b = dqbuf(fd)
        got.append((b.index, b.sequence, b.timestamp.tv_sec * 1_000_000 + b.timestamp.tv_usec, b.flags))
        qbuf(fd, b.index)
    for m in maps:
        m.close()
    os.close(fd)
    return got


def bad_pointers(port: str) -> dict[str, int]:
    """The errno of ioctls given NULL or an unmapped address, as the kernel's copy_from_user fails."""
    fd = os.open(port, os.O_RDWR)
    out = {"QUERYCAP NULL": ioctl(fd, abi.VIDIOC_QUERYCAP, None),
           "G_FMT unmapped": ioctl(fd, abi.VIDIOC_G_FMT, 8),
           "S_CTRL NULL": ioctl(fd, abi.VIDIOC_S_CTRL, None)}
    x = abi.v4l2_ext_controls(which=abi.V4L2_CTRL_WHICH_CUR_VAL, count=1)  # controls = NULL
    out["G_EXT_CTRLS NULL array"] = ioctl(fd, abi.VIDIOC_G_EXT_CTRLS, x)
    out["not a V4L2 ioctl"] = ioctl(fd, 0x5401, abi.v4l2_capability())  # TCGETS
    cap = abi.v4l2_capability()
    out["QUERYCAP"] = ioctl(fd, abi.VIDIOC_QUERYCAP, cap)
    os.close(fd)
    return out


def node_files(port: str, by_id: str) -> dict[str, Any]:
    """What stat, readlink, sysfs and directory listings show of the node."""
    st = os.stat(port)
    fst_fd = os.open(port, os.O_RDWR)
    fst = os.fstat(fst_fd)
    os.close(fst_fd)
    name = os.path.basename(port)
    minor = os.minor(st.st_rdev)
    with open(f"/sys/dev/char/81:{minor}/uevent") as f:
        uevent = f.read()
    with open(f"/sys/class/video4linux/{name}/name") as f:
        card = f.read()
    return {
        "is_chr": stat.S_ISCHR(st.st_mode), "major": os.major(st.st_rdev), "minor": minor,
        "fstat_is_chr": stat.S_ISCHR(fst.st_mode), "fstat_rdev": fst.st_rdev == st.st_rdev,
        "by_id_is_link": stat.S_ISLNK(os.lstat(by_id).st_mode), "by_id_real": os.path.realpath(by_id),
        "uevent": uevent, "card": card, "access_rw": os.access(port, os.R_OK | os.W_OK),
        "class_listing": sorted(os.listdir("/sys/class/video4linux")),
        "index": open(f"/sys/class/video4linux/{name}/index").read(),
        "missing": _errno_of(lambda: os.stat("/dev/video999")),
    }


def _errno_of(fn: Any) -> int:
    try:
        fn()
    except OSError as exc:
        return exc.errno or 0
    return 0


def gone_after_unplug(port: str, open_fd_first: bool) -> dict[str, Any]:
    """Waits for the parent's unplug (the node disappears), then reports what the host sees."""
    fd = os.open(port, os.O_RDWR) if open_fd_first else -1
    deadline = time.monotonic() + 20
    while os.path.exists(port) and time.monotonic() < deadline:
        time.sleep(0.02)
    out: dict[str, Any] = {"stat": _errno_of(lambda: os.stat(port)), "open": _errno_of(lambda: os.open(port, os.O_RDWR))}
    if fd >= 0:
        p = select.poll()
        p.register(fd, select.POLLIN | select.POLLPRI)
        out["poll"] = p.poll(1000)[0][1] if p.poll(0) else 0
        out["querycap"] = ioctl(fd, abi.VIDIOC_QUERYCAP, abi.v4l2_capability())
        r, _, x = select.select([fd], [], [fd], 1.0)
        out["select"] = (bool(r), bool(x))
        os.close(fd)
    return out


def waits_for_a_camera_started_later(port: str) -> str:
    """A process started before the camera: the node appears in it when the camera starts."""
    deadline = time.monotonic() + 30
    while not os.path.exists(port):
        if time.monotonic() > deadline:
            raise TimeoutError(f"{port} never appeared")
        time.sleep(0.05)
    fd = os.open(port, os.O_RDWR)
    cap = abi.v4l2_capability()
    _check(fd, abi.VIDIOC_QUERYCAP, cap)
    os.close(fd)
    return bytes(cap.card).rstrip(b"\0").decode()


def forked_and_duplicated(port: str) -> dict[str, Any]:
    """The descriptor works in a forked child and through dup(); closing a duplicate keeps the file."""
    fd = os.open(port, os.O_RDWR)
    dup = os.dup(fd)
    out: dict[str, Any] = {}
    pid = os.fork()
    if pid == 0:  # the forked child: QUERYCAP on the inherited descriptor
        code = ioctl(fd, abi.VIDIOC_QUERYCAP, abi.v4l2_capability())
        os._exit(100 + code)
    _, status = os.waitpid(pid, 0)
    out["forked"] = os.waitstatus_to_exitcode(status) - 100
    os.close(fd)
    out["dup_after_close"] = ioctl(dup, abi.VIDIOC_QUERYCAP, abi.v4l2_capability())
    os.close(dup)
    out["closed"] = ioctl(dup, abi.VIDIOC_QUERYCAP, abi.v4l2_capability())
    return out


def control_events(port: str) -> dict[str, Any]:
    """Handle A subscribes to exposure events; handle B switches to manual and sets exposure."""
    a = os.open(port, os.O_RDWR | os.O_NONBLOCK)
    b = os.open(port, os.O_RDWR)
    cid = 0x009A0902  # V4L2_CID_EXPOSURE_ABSOLUTE
    sub = abi.v4l2_event_subscription(type=abi.V4L2_EVENT_CTRL, id=cid)
    _check(a, abi.VIDIOC_SUBSCRIBE_EVENT, sub)
    out: dict[str, Any] = {"pending_before": select.select([], [], [a], 0)[2] != []}
    _check(b, abi.VIDIOC_S_CTRL, abi.v4l2_control(id=0x009A0901, value=1))  # auto exposure: manual
    _check(b, abi.VIDIOC_S_CTRL, abi.v4l2_control(id=cid, value=321))
    out["pending_after"] = select.select([], [], [a], 1.0)[2] != []
    events = []
    while True:
        ev = abi.v4l2_event()
        err = ioctl(a, abi.VIDIOC_DQEVENT, ev)
        if err:
            out["end"] = err
            break
        events.append((ev.type, ev.id, ev.u.ctrl.changes, ev.u.ctrl.v.value, ev.u.ctrl.flags, ev.pending))
    out["events"] = events
    os.close(a)
    os.close(b)
    return out


def ordinary_files(directory: str) -> dict[str, Any]:
    """Files, pipes and polls that have nothing to do with a camera (the pass-through path)."""
    path = os.path.join(directory, "plain.bin")
    fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_TRUNC, 0o600)
    os.write(fd, b"0123456789" * 1000)
    os.lseek(fd, 0, os.SEEK_SET)
    first = os.read(fd, 10)
    st = os.fstat(fd)
    m = mmap.mmap(fd, 4096)
    mapped = bytes(m[10:20])
    m.close()
    os.close(fd)
    r, w = os.pipe()
    os.write(w, b"abc")
    p = select.poll()
    p.register(r, select.POLLIN)
    polled = p.poll(100)
    sel = select.select([r], [], [], 0.1)[0] == [r]
    n = C.c_int()
    _libc.ioctl(r, 0x541B, C.addressof(n))  # FIONREAD
    data = os.read(r, 3)
    os.close(r)
    os.close(w)
    with open(path, "rb") as f:
        via_fopen = f.read(5)
    return {"first": first, "size": st.st_size, "is_reg": stat.S_ISREG(os.stat(path).st_mode), "mapped": mapped,
            "polled": [(e & select.POLLIN) != 0 for _, e in polled], "select": sel, "fionread": n.value,
            "pipe": data, "fopen": via_fopen, "devnull": stat.S_ISCHR(os.stat("/dev/null").st_mode),
            "no_such": _errno_of(lambda: os.open(os.path.join(directory, "nope"), os.O_RDONLY)),
            "dev_video_listing": sorted(e for e in os.listdir("/dev") if e.startswith("video")),
            "enoent_errno": errno.ENOENT}
