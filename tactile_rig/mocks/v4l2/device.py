"""One registered capture node of an emulated UVC camera: its state, open files, buffers and stream.

The ioctls are answered by :class:`~tactile_rig.mocks.v4l2.ioctls.UvcIoctls` (the V4L2 core's,
uvcvideo's and videobuf2's rules, per uvcvideo generation); this module holds the node's state, its
open files and their readiness, and the stream.

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

import errno
import logging
import os
import threading
import time
from collections import deque
from typing import Callable

from tactile_rig.devices.camera_models import CameraModel
from tactile_rig.mocks.camera import SimulatedCamera
import tactile_rig.mocks.v4l2.abi as abi
import tactile_rig.mocks.v4l2.formats as formats
from tactile_rig.mocks.v4l2.controls import ControlSet
from tactile_rig.mocks.v4l2.formats import StreamFormat
from tactile_rig.mocks.v4l2.frames import encode_frame
from tactile_rig.mocks.v4l2.handle import FileHandle, RenderedFrame
from tactile_rig.mocks.v4l2.ioctls import (PRIORITY_IOCTLS, EACCES_FOR_INACTIVE_SINCE, HANDLERS, VB2_OWNERSHIP_SINCE,
                                           UvcIoctls, kernel_version_code, running_kernel)
from tactile_rig.mocks.v4l2.queue import Buffer, BufferQueue
from tactile_rig.mocks.v4l2.sysfs import NodeIdentity

log = logging.getLogger("tactile_rig.mocks.v4l2")

JPEG_QUALITY = 90


class UvcNode(UvcIoctls):
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
            handler = HANDLERS.get(cmd)
            if self.gone:
                result: tuple[int, bytes, bytes, list[int]] = (-errno.ENODEV, b"", b"", [])
            elif handler is None:
                result = (-errno.ENOTTY, b"", b"", [])
            elif cmd in PRIORITY_IOCTLS and fh.prio < self._max_prio():
                result = (-errno.EBUSY, b"", b"", [])
            else:
                result = handler(self, fh, payload, array)
                self._sync_all()
            if self.trace is not None:
                self.trace.append((fh.id, abi.IOCTL_NAMES.get(cmd, hex(cmd)), -result[0]))
            return result

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


def rendered_image(node: UvcNode, timestamp_ns: int, tolerance_ns: int = 500_000) -> RenderedFrame | None:
    """The frame the node delivered with that buffer timestamp (within ``tolerance_ns``)."""
    with node.lock:
        for f in reversed(node.history):
            if abs(f.timestamp_ns - timestamp_ns) <= tolerance_ns:
                return f
    return None


__all__ = ["UvcNode", "FileHandle", "RenderedFrame", "rendered_image", "kernel_version_code", "running_kernel",
           "EACCES_FOR_INACTIVE_SINCE"]
