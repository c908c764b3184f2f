"""The messages between the preload library (``preload.c``) and the device server.

One connection per open file (``SOCK_SEQPACKET``, so each message keeps its boundaries): the
library sends one request and waits for one reply. Descriptors travel with ``SCM_RIGHTS``.

Request ``<IiQQQII``: ``op``, ``arg0``, ``cmd``, ``arg1``, ``arg2``, ``len``, ``len2``, then ``len`` bytes
(the ioctl argument as the caller's memory holds it) and ``len2`` bytes (the control array of an
``*_EXT_CTRLS`` ioctl). Reply ``<iIIIQ``: ``result`` (>= 0, or -errno), ``len``, ``len2``, ``nfds``,
``aux``, then the argument and the array as the caller's memory is to hold them.

==========  =======================================================================================
op          meaning
==========  =======================================================================================
OPEN        a new open file; ``arg0`` the open flags; reply ``aux`` = file handle id, descriptors:
            the caller's descriptor (readable while a POLLIN-class answer is due), the event
            descriptor (readable while an event is pending), the wait descriptor (readable while a
            blocking DQBUF would return)
ATTACH      a forked child joins file handle ``arg1`` (the descriptors it inherited stay valid)
IOCTL       ``cmd`` with its argument; never blocks (the library waits on the descriptors)
MMAP        ``arg1`` offset, ``arg2`` length, ``arg0`` prot, ``cmd`` flags; reply: the buffer's memfd
MUNMAP      the mapping of the buffer at offset ``arg1`` is gone
POLL        ``arg0`` requested events; reply ``result`` = the events to report
READ        read() on the node (uvcvideo has none)
==========  =======================================================================================
"""

from __future__ import annotations

import array
import socket
import struct
from dataclasses import dataclass, field

OP_OPEN, OP_ATTACH, OP_IOCTL, OP_MMAP, OP_MUNMAP, OP_POLL, OP_READ = 1, 2, 3, 4, 5, 6, 7
OP_NAMES = {OP_OPEN: "OPEN", OP_ATTACH: "ATTACH", OP_IOCTL: "IOCTL", OP_MMAP: "MMAP", OP_MUNMAP: "MUNMAP",
            OP_POLL: "POLL", OP_READ: "READ"}

REQUEST = struct.Struct("<IiQQQII")
REPLY = struct.Struct("<iIIIQ")
MAX_ARG = (1 << 14) - 1  # _IOC_SIZE's 14 bits
MAX_ARRAY = 1024 * 20  # V4L2_CID_MAX_CTRLS controls of 20 bytes
MAX_MESSAGE = REQUEST.size + MAX_ARG + MAX_ARRAY


class ProtocolError(ValueError):
    """A message that does not parse (a client that is not the preload library, or a bug)."""


@dataclass
class Request:
    op: int
    arg0: int = 0
    cmd: int = 0
    arg1: int = 0
    arg2: int = 0
    payload: bytes = b""
    payload2: bytes = b""

    @classmethod
    def parse(cls, data: bytes) -> "Request":
        if len(data) < REQUEST.size:
            raise ProtocolError(f"request of {len(data)} bytes; at least {REQUEST.size} expected")
        op, arg0, cmd, arg1, arg2, n1, n2 = REQUEST.unpack_from(data)
        if op not in OP_NAMES:
            raise ProtocolError(f"unknown request op {op}")
        if REQUEST.size + n1 + n2 != len(data) or n1 > MAX_ARG or n2 > MAX_ARRAY:
            raise ProtocolError(f"request says {n1}+{n2} payload bytes, carries {len(data) - REQUEST.size}")
        p1 = data[REQUEST.size:REQUEST.size + n1]
        return cls(op, arg0, cmd, arg1, arg2, p1, data[REQUEST.size + n1:])

    def pack(self) -> bytes:
        return REQUEST.pack(self.op, self.arg0, self.cmd, self.arg1, self.arg2, len(self.payload),
                            len(self.payload2)) + self.payload + self.payload2


@dataclass
class Reply:
    result: int
    payload: bytes = b""
    payload2: bytes = b""
    aux: int = 0
    fds: list[int] = field(default_factory=list)

    def pack(self) -> bytes:
        return REPLY.pack(self.result, len(self.payload), len(self.payload2), len(self.fds), self.aux) \
            + self.payload + self.payload2

    @classmethod
    def parse(cls, data: bytes, fds: list[int]) -> "Reply":
        if len(data) < REPLY.size:
            raise ProtocolError(f"reply of {len(data)} bytes; at least {REPLY.size} expected")
        result, n1, n2, _nfds, aux = REPLY.unpack_from(data)
        p1 = data[REPLY.size:REPLY.size + n1]
        return cls(result, p1, data[REPLY.size + n1:REPLY.size + n1 + n2], aux, fds)


def send_reply(sock: socket.socket, reply: Reply) -> None:
    """Send ``reply``; its descriptors go along (the caller still owns and closes its own copies)."""
    anc = [(socket.SOL_SOCKET, socket.SCM_RIGHTS, array.array("i", reply.fds).tobytes())] if reply.fds else []
    sock.sendmsg([reply.pack()], anc)


def receive(sock: socket.socket, maxfds: int = 4) -> tuple[bytes, list[int]]:
    """One message and the descriptors that came with it; ``b""`` when the peer closed."""
    data, anc, flags, _addr = sock.recvmsg(MAX_MESSAGE + 64, socket.CMSG_SPACE(maxfds * 4))
    fds: list[int] = []
    for level, kind, blob in anc:
        if level == socket.SOL_SOCKET and kind == socket.SCM_RIGHTS:
            a = array.array("i")
            a.frombytes(blob[: len(blob) - len(blob) % a.itemsize])
            fds.extend(a)
    if flags & socket.MSG_TRUNC:
        raise ProtocolError("message truncated")
    return data, fds
