"""The buffer and streaming ioctls of an emulated UVC capture node, as videobuf2 answers them
(REQBUFS, CREATE_BUFS, QUERYBUF, QBUF, DQBUF, EXPBUF, STREAMON, STREAMOFF on MMAP buffers; the queue
itself is :mod:`.queue`), behind the access rules of :mod:`.ioctl_access`.
"""

from __future__ import annotations

import errno
from typing import Callable

import tactile_rig.mocks.v4l2.abi as abi
from tactile_rig.mocks.v4l2.handle import FileHandle
from tactile_rig.mocks.v4l2.ioctl_access import NodeState, Result
from tactile_rig.mocks.v4l2.ioctl_formats import sanitize_format


class BufferIoctls(NodeState):
    """The buffer and streaming ioctls."""

    def _reqbufs(self, fh: FileHandle, payload: bytes, array: bytes) -> Result:
        r = abi.parse_struct(abi.v4l2_requestbuffers, payload)
        if r.type != abi.V4L2_BUF_TYPE_VIDEO_CAPTURE:
            return -errno.EINVAL, b"", b"", []
        abi.clear_after(r, "flags")
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

    def _create_bufs(self, fh: FileHandle, payload: bytes, array: bytes) -> Result:
        cb = abi.parse_struct(abi.v4l2_create_buffers, payload)
        if cb.format.type != abi.V4L2_BUF_TYPE_VIDEO_CAPTURE:
            return -errno.EINVAL, b"", b"", []
        abi.clear_after(cb, "flags")
        sanitize_format(cb.format)
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
                      clear: str | None = None) -> Result:
        b = abi.parse_struct(abi.v4l2_buffer, payload)
        if b.type != abi.V4L2_BUF_TYPE_VIDEO_CAPTURE:
            return -errno.EINVAL, b"", b"", []
        if clear:
            abi.clear_after(b, clear)
        if not self._may_use_queue(fh, query=op == self.queue.querybuf):
            return -errno.EBUSY, b"", b"", []
        err = op(b)
        return err, (bytes(b) if not err else b""), b"", []

    def _querybuf(self, fh: FileHandle, payload: bytes, array: bytes) -> Result:
        return self._buffer_ioctl(fh, payload, self.queue.querybuf, clear="length")

    def _qbuf(self, fh: FileHandle, payload: bytes, array: bytes) -> Result:
        return self._buffer_ioctl(fh, payload, self.queue.qbuf)

    def _dqbuf(self, fh: FileHandle, payload: bytes, array: bytes) -> Result:
        return self._buffer_ioctl(fh, payload, self.queue.dqbuf)

    def _expbuf(self, fh: FileHandle, payload: bytes, array: bytes) -> Result:
        e = abi.parse_struct(abi.v4l2_exportbuffer, payload)
        abi.clear_after(e, "flags")
        if not self._may_use_queue(fh):
            return -errno.EBUSY, b"", b"", []
        err, fd = self.queue.expbuf(e)
        if err:
            return err, b"", b"", []
        return 0, bytes(e), b"", [fd]

    def _streamon(self, fh: FileHandle, payload: bytes, array: bytes) -> Result:
        if not self._may_use_queue(fh):
            return -errno.EBUSY, b"", b"", []
        was = self.queue.streaming
        err = self.queue.streamon(int.from_bytes(payload[:4].ljust(4, b"\0"), "little"))
        if not err and not was:
            self._start_stream()
        return err, b"", b"", []

    def _streamoff(self, fh: FileHandle, payload: bytes, array: bytes) -> Result:
        if not self._may_use_queue(fh):
            return -errno.EBUSY, b"", b"", []
        buftype = int.from_bytes(payload[:4].ljust(4, b"\0"), "little")
        if buftype != self.queue.type:
            return -errno.EINVAL, b"", b"", []
        self._stop_stream()
        return self.queue.streamoff(buftype), b"", b"", []
