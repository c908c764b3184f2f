"""The buffer queue of the capture node, as videobuf2 runs it for uvcvideo.

Where the rules come from (Linux 6.x, drivers/media/common/videobuf2/videobuf2-core.c and -v4l2.c,
drivers/media/usb/uvc/uvc_queue.c):

* ``REQBUFS``: EBUSY while streaming; a count of 0 (or a new count, or another memory type) frees
  the buffers (still-mapped ones are orphaned, V4L2_BUF_CAP_SUPPORTS_ORPHANED_BUFS), then at most 32
  buffers of the format's ``sizeimage`` are allocated. ``CREATE_BUFS`` appends buffers of the asked
  ``sizeimage`` (EINVAL below the format's own size, ENOBUFS past 32), also while streaming.
* ``QBUF``: EINVAL for a wrong type, index, memory or a buffer not dequeued; EIO after a queue
  error; ``DQBUF``: EINVAL when not streaming, EAGAIN (non-blocking) when no buffer is done; the
  dequeued buffer reports MONOTONIC | TSTAMP_SRC_SOE timestamps (uvc_queue_init), never DONE.
* ``STREAMOFF`` returns every buffer to the dequeued state; ``poll`` reports POLLERR when not
  streaming or before the first QBUF after REQBUFS (vb2's quirk_poll_must_check_waiting_for_buffers),
  POLLIN | POLLRDNORM while a buffer is done.
* ``mmap``: MAP_SHARED and PROT_READ required, the offset must be a buffer's and the length within it.

Buffers are memfds: the server renders into its own mapping, the client maps the same pages at
the offset ``QUERYBUF`` gave, and ``EXPBUF`` hands out a descriptor of the same memory.
"""

from __future__ import annotations

import ctypes as C
import errno
import mmap
import os
from collections import deque
from dataclasses import dataclass

import tactile_rig.mocks.v4l2.abi as abi

MAX_BUFFERS = 32  # VB2_MAX_FRAME
PAGE = mmap.PAGESIZE
CAPS = abi.V4L2_BUF_CAP_SUPPORTS_MMAP | abi.V4L2_BUF_CAP_SUPPORTS_ORPHANED_BUFS
TIMESTAMP_FLAGS = abi.V4L2_BUF_FLAG_TIMESTAMP_MONOTONIC | abi.V4L2_BUF_FLAG_TSTAMP_SRC_SOE

DEQUEUED, QUEUED, ACTIVE, DONE, ERROR = "dequeued", "queued", "active", "done", "error"


def page_align(n: int) -> int:
    return (n + PAGE - 1) // PAGE * PAGE


class Buffer:
    """One buffer: its memory (a memfd, mapped here too), state and the frame it last carried."""

    def __init__(self, index: int, length: int, offset: int) -> None:
        self.index, self.length, self.offset = index, length, offset
        self.memfd = os.memfd_create(f"tactile-rig-v4l2-buf{index}", os.MFD_CLOEXEC)
        os.ftruncate(self.memfd, page_align(length))
        self.mem = mmap.mmap(self.memfd, page_align(length))
        self.state = DEQUEUED
        self.bytesused = 0
        self.timestamp_ns = 0
        self.sequence = 0
        self.mapped = 0

    def reset_frame(self) -> None:
        self.bytesused, self.timestamp_ns, self.sequence = 0, 0, 0

    def release(self) -> None:
        """Drop the server's hold; a client mapping keeps the pages (an orphaned buffer)."""
        try:
            self.mem.close()
        except BufferError:  # a memoryview of a frame being written; the writer holds the lock
            pass
        os.close(self.memfd)


@dataclass
class Memory:
    """What a file descriptor request asks of the queue (``VIDIOC_EXPBUF``'s answer)."""

    fd: int


class BufferQueue:
    """The capture queue (one per device); every method returns 0 or -errno like the kernel."""

    def __init__(self) -> None:
        self.type = abi.V4L2_BUF_TYPE_VIDEO_CAPTURE
        self.memory = 0
        self.buffers: list[Buffer] = []
        self.queued: deque[Buffer] = deque()
        self.done: deque[Buffer] = deque()
        self.streaming = False
        self.error = False
        self.waiting_for_buffers = False

    # -- allocation ---------------------------------------------------------------------------
    def _verify_memory(self, memory: int, buftype: int) -> int:
        """vb2_verify_memory_type: only MMAP is offered here."""
        if memory not in (abi.V4L2_MEMORY_MMAP, abi.V4L2_MEMORY_USERPTR, abi.V4L2_MEMORY_DMABUF):
            return -errno.EINVAL
        if buftype != self.type:
            return -errno.EINVAL
        if memory != abi.V4L2_MEMORY_MMAP:
            return -errno.EINVAL
        return 0

    def _free_all(self) -> None:
        self.cancel()
        for b in self.buffers:
            b.release()
        self.buffers = []
        self.memory = 0

    def _alloc(self, count: int, length: int) -> int:
        n = 0
        for _ in range(count):
            index = len(self.buffers)
            prev = self.buffers[-1] if self.buffers else None
            offset = page_align(prev.offset + prev.length) if prev else 0
            self.buffers.append(Buffer(index, length, offset))
            n += 1
        return n

    def reqbufs(self, r: abi.v4l2_requestbuffers, sizeimage: int) -> int:
        err = self._verify_memory(r.memory, r.type)
        r.capabilities = CAPS
        r.flags = 0  # no cache hints on this queue (validate_memory_flags)
        if err:
            return err
        if self.streaming:
            return -errno.EBUSY
        if r.count == 0 or self.buffers or (self.memory and self.memory != r.memory):
            self._free_all()
            if r.count == 0:
                return 0
        count = min(r.count, MAX_BUFFERS)
        self.memory = r.memory
        r.count = self._alloc(count, sizeimage)
        self.waiting_for_buffers = True
        return 0

    def create_bufs(self, cb: abi.v4l2_create_buffers, sizeimage: int) -> int:
        err = self._verify_memory(cb.memory, cb.format.type)
        cb.capabilities = CAPS
        cb.flags = 0
        cb.index = len(self.buffers)
        if cb.count == 0:
            return err if err != -errno.EBUSY else 0
        if cb.format.type != abi.V4L2_BUF_TYPE_VIDEO_CAPTURE:
            return -errno.EINVAL
        want = cb.format.fmt.pix.sizeimage
        if want == 0:
            return -errno.EINVAL
        if err:
            return err
        if len(self.buffers) == MAX_BUFFERS:
            return -errno.ENOBUFS
        if self.buffers and self.memory != cb.memory:
            return -errno.EINVAL
        if want < sizeimage:  # uvc_queue_setup: a buffer must hold a whole frame
            return -errno.EINVAL
        if not self.buffers:
            self.memory = cb.memory
            self.waiting_for_buffers = True
        cb.count = self._alloc(min(cb.count, MAX_BUFFERS - len(self.buffers)), want)
        return 0

    # -- the buffer ioctls -------------------------------------------------------------------
    def fill(self, b: abi.v4l2_buffer, buf: Buffer, *, dequeued: bool = False) -> None:
        """__fill_v4l2_buffer: what QUERYBUF, QBUF and DQBUF return."""
        C.memset(C.addressof(b), 0, C.sizeof(b))
        b.index, b.type, b.memory = buf.index, self.type, self.memory
        b.bytesused, b.length, b.sequence = buf.bytesused, buf.length, buf.sequence
        b.m.offset = buf.offset
        b.field = abi.V4L2_FIELD_NONE
        b.timestamp.tv_sec, b.timestamp.tv_usec = divmod(buf.timestamp_ns // 1000, 1_000_000)
        flags = TIMESTAMP_FLAGS
        if buf.state in (QUEUED, ACTIVE):
            flags |= abi.V4L2_BUF_FLAG_QUEUED
        elif buf.state == ERROR:
            flags |= abi.V4L2_BUF_FLAG_ERROR | abi.V4L2_BUF_FLAG_DONE
        elif buf.state == DONE:
            flags |= abi.V4L2_BUF_FLAG_DONE
        if buf.mapped:
            flags |= abi.V4L2_BUF_FLAG_MAPPED
        if dequeued:
            flags &= ~abi.V4L2_BUF_FLAG_DONE  # vb2_dqbuf: DONE is cleared once dequeued
        b.flags = flags

    def _lookup(self, b: abi.v4l2_buffer) -> Buffer | int:
        if b.type != self.type or b.index >= len(self.buffers):
            return -errno.EINVAL
        return self.buffers[b.index]

    def querybuf(self, b: abi.v4l2_buffer) -> int:
        buf = self._lookup(b)
        if isinstance(buf, int):
            return buf
        self.fill(b, buf)
        return 0

    def qbuf(self, b: abi.v4l2_buffer, *, disconnected: bool = False) -> int:
        buf = self._lookup(b)
        if isinstance(buf, int):
            return buf
        if b.memory != self.memory:
            return -errno.EINVAL
        if b.flags & abi.V4L2_BUF_FLAG_REQUEST_FD:
            return -errno.EINVAL if buf.state != DEQUEUED else -errno.EBADR
        if self.error:
            return -errno.EIO
        if buf.state != DEQUEUED:
            return -errno.EINVAL
        if disconnected:  # uvc_buffer_prepare
            return -errno.ENODEV
        buf.reset_frame()
        buf.state = QUEUED
        self.queued.append(buf)
        self.waiting_for_buffers = False
        self.fill(b, buf)
        return 0

    def dqbuf(self, b: abi.v4l2_buffer) -> int:
        if b.type != self.type:
            return -errno.EINVAL
        if not self.streaming:
            return -errno.EINVAL
        if self.error:
            return -errno.EIO
        if not self.done:
            return -errno.EAGAIN
        buf = self.done.popleft()
        self.fill(b, buf, dequeued=True)
        buf.state = DEQUEUED
        return 0

    def expbuf(self, e: abi.v4l2_exportbuffer) -> tuple[int, int]:
        if self.memory != abi.V4L2_MEMORY_MMAP:
            return -errno.EINVAL, -1
        if e.flags & ~(os.O_CLOEXEC | os.O_ACCMODE):
            return -errno.EINVAL, -1
        if e.type != self.type or e.index >= len(self.buffers) or e.plane != 0:
            return -errno.EINVAL, -1
        buf = self.buffers[e.index]
        access = e.flags & os.O_ACCMODE
        # A descriptor of the same pages with the access asked for (dma_buf_fd).
        fd = os.open(f"/proc/self/fd/{buf.memfd}", (os.O_RDWR if access == os.O_RDWR else
                                                    os.O_WRONLY if access == os.O_WRONLY else os.O_RDONLY) | os.O_CLOEXEC)
        return 0, fd

    def streamon(self, buftype: int) -> int:
        if buftype != self.type:
            return -errno.EINVAL
        if self.streaming:
            return 0
        if not self.buffers:
            return -errno.EINVAL
        self.streaming = True
        return 0

    def streamoff(self, buftype: int) -> int:
        if buftype != self.type:
            return -errno.EINVAL
        self.cancel()
        return 0

    def cancel(self) -> None:
        """__vb2_queue_cancel: stop, and give every buffer back (dequeued, frame forgotten)."""
        self.streaming = False
        self.error = False
        self.queued.clear()
        self.done.clear()
        for b in self.buffers:
            b.state = DEQUEUED
            b.reset_frame()
        self.waiting_for_buffers = True

    # -- driver side ------------------------------------------------------------------------------
    def take(self) -> Buffer | None:
        """The next queued buffer for a frame (it becomes ACTIVE), or None: the frame is lost."""
        if not self.streaming or not self.queued:
            return None
        buf = self.queued.popleft()
        buf.state = ACTIVE
        return buf

    def complete(self, buf: Buffer, bytesused: int, timestamp_ns: int, sequence: int, error: bool = False) -> None:
        buf.bytesused, buf.timestamp_ns, buf.sequence = bytesused, timestamp_ns, sequence
        buf.state = ERROR if error else DONE
        self.done.append(buf)

    # -- poll and mmap -------------------------------------------------------------------------
    def poll(self, events: int) -> int:
        """vb2_core_poll's answer for a capture queue."""
        if not events & (abi.POLLIN | abi.POLLRDNORM):
            return 0
        if not self.streaming or self.error or self.waiting_for_buffers:
            return abi.POLLERR
        return abi.POLLIN | abi.POLLRDNORM if self.done else 0

    def dqbuf_ready(self) -> bool:
        """Would a blocking DQBUF return now (a buffer, or an error)?"""
        return not self.streaming or self.error or bool(self.done)

    def mmap(self, offset: int, length: int, prot: int, flags: int) -> Buffer | int:
        """vb2_mmap's checks; the buffer to map, or -errno."""
        if offset % PAGE or length == 0:
            return -errno.EINVAL  # mmap(2)'s own checks
        if self.memory != abi.V4L2_MEMORY_MMAP:
            return -errno.EINVAL
        if not flags & mmap.MAP_SHARED or not prot & mmap.PROT_READ:
            return -errno.EINVAL
        buf = next((b for b in self.buffers if b.offset == offset), None)
        if buf is None or page_align(length) > page_align(buf.length):
            return -errno.EINVAL
        buf.mapped += 1
        return buf

    def unmapped(self, offset: int) -> None:
        buf = next((b for b in self.buffers if b.offset == offset), None)
        if buf is not None and buf.mapped:
            buf.mapped -= 1

    def release(self) -> None:
        self._free_all()
