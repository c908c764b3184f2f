"""An open file of an emulated node, and a frame the node delivered."""

from __future__ import annotations

import os
import select
from collections import deque
from dataclasses import dataclass, field

import numpy as np

import tactile_rig.mocks.v4l2.abi as abi

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
