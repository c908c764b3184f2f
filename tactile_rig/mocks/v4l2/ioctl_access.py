"""Who may use an emulated capture node's stream, which depends on the uvcvideo generation, and the
state every ioctl handler reads (:class:`NodeState`, the base of the handler mixins).

* before Linux 6.17, uvcvideo's file-handle privileges (uvc_acquire_privileges): the first handle
  that sets a format, a frame rate, the input or allocates buffers owns the stream; another gets
  EBUSY for those and for every buffer ioctl (QUERYBUF included, STREAMON without buffers too)
  until the owner frees its buffers (``REQBUFS`` 0) or closes. This is why v4l2-compliance's
  streaming tests fail on those kernels (a freed queue's STREAMON gives EBUSY, not EINVAL).
* from Linux 6.17 (commit c93d73c9c2cf "media: uvcvideo: Use vb2 ioctl and fop helpers"),
  videobuf2's queue ownership (vb2_ioctl_*, vb2_queue_is_busy): the handle that allocates buffers
  owns the queue; another gets EBUSY for REQBUFS, CREATE_BUFS, QBUF, DQBUF, EXPBUF, STREAMON and
  STREAMOFF while it does; QUERYBUF is anyone's; S_FMT fails with EBUSY while buffers exist, S_PARM
  while streaming, whoever asks.
"""

from __future__ import annotations

import errno

import tactile_rig.mocks.v4l2.abi as abi
from tactile_rig.devices.camera_models import CameraModel
from tactile_rig.mocks.camera import SimulatedCamera
from tactile_rig.mocks.v4l2.controls import ControlSet
from tactile_rig.mocks.v4l2.formats import StreamFormat
from tactile_rig.mocks.v4l2.handle import FileHandle
from tactile_rig.mocks.v4l2.queue import BufferQueue
from tactile_rig.mocks.v4l2.sysfs import NodeIdentity

#: what a handler returns: (result or -errno, argument out, control array out, descriptors to send)
Result = tuple[int, bytes, bytes, list[int]]

# Linux 6.3 made uvcvideo refuse writes to inactive controls itself, with EACCES; before, the
# camera's stall came back through uvc_query_ctrl's error mapping (see :mod:`.controls`).
EACCES_FOR_INACTIVE_SINCE = (6, 3)
# Linux 6.17 replaced uvcvideo's privileges with videobuf2's queue ownership.
VB2_OWNERSHIP_SINCE = (6, 17)


class NodeState:
    """The node state the handlers read and change (held by :class:`~.device.UvcNode`), and the
    access rules above."""

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
