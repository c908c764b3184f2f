"""The control and event ioctls of an emulated UVC capture node: QUERYCTRL, QUERY_EXT_CTRL, QUERYMENU,
G/S_CTRL, G/S/TRY_EXT_CTRLS (the rules are :mod:`.controls`), and SUBSCRIBE_EVENT /
UNSUBSCRIBE_EVENT / DQEVENT for ``V4L2_EVENT_CTRL`` as the V4L2 core queues them (one slot per
subscription, v4l2-event.c).
"""

from __future__ import annotations

import ctypes as C
import errno
import time
from collections import deque

import tactile_rig.mocks.v4l2.abi as abi
from tactile_rig.mocks.v4l2.controls import ControlChange, check_ext_ctrls
from tactile_rig.mocks.v4l2.handle import FileHandle
from tactile_rig.mocks.v4l2.ioctl_access import NodeState, Result


class ControlIoctls(NodeState):
    """The control ioctls and control events."""

    def _queryctrl(self, fh: FileHandle, payload: bytes, array: bytes) -> Result:
        q = abi.parse_struct(abi.v4l2_queryctrl, payload)
        ret = self.controls.queryctrl(q)
        return ret, bytes(q), b"", []

    def _query_ext_ctrl(self, fh: FileHandle, payload: bytes, array: bytes) -> Result:
        q = abi.parse_struct(abi.v4l2_query_ext_ctrl, payload)
        ret = self.controls.query_ext_ctrl(q)
        return ret, bytes(q), b"", []

    def _querymenu(self, fh: FileHandle, payload: bytes, array: bytes) -> Result:
        m = abi.parse_struct(abi.v4l2_querymenu, payload)
        ret = self.controls.querymenu(m)
        return ret, bytes(m), b"", []

    def _g_ctrl(self, fh: FileHandle, payload: bytes, array: bytes) -> Result:
        c = abi.parse_struct(abi.v4l2_control, payload)
        ok, _ = check_ext_ctrls(c.id & 0x0FFF0000, [c.id], "G_CTRL")
        if not ok:
            return -errno.EINVAL, b"", b"", []
        err, _idx, values = self.controls.get_ext(abi.V4L2_CTRL_WHICH_CUR_VAL, [c.id])
        if err:
            return err, b"", b"", []
        c.value = values[0]
        return 0, bytes(c), b"", []

    def _s_ctrl(self, fh: FileHandle, payload: bytes, array: bytes) -> Result:
        c = abi.parse_struct(abi.v4l2_control, payload)
        ok, _ = check_ext_ctrls(c.id & 0x0FFF0000, [c.id], "S_CTRL")
        if not ok:
            return -errno.EINVAL, b"", b"", []
        err, _idx, values = self.controls.set_ext([c.id], [c.value], try_=False)
        if err:
            return err, b"", b"", []
        c.value = values[0]
        self._send_events(self.controls.changes_for([c.id], fh.id))
        return 0, bytes(c), b"", []

    def _ext_ctrls(self, fh: FileHandle, payload: bytes, array: bytes, kind: str) -> Result:
        x = abi.parse_struct(abi.v4l2_ext_controls, payload)
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

        def out(ret: int) -> Result:
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

    def _g_ext_ctrls(self, fh: FileHandle, payload: bytes, array: bytes) -> Result:
        return self._ext_ctrls(fh, payload, array, "G")

    def _s_ext_ctrls(self, fh: FileHandle, payload: bytes, array: bytes) -> Result:
        return self._ext_ctrls(fh, payload, array, "S")

    def _try_ext_ctrls(self, fh: FileHandle, payload: bytes, array: bytes) -> Result:
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

    def _subscribe(self, fh: FileHandle, payload: bytes, array: bytes) -> Result:
        s = abi.parse_struct(abi.v4l2_event_subscription, payload)
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

    def _unsubscribe(self, fh: FileHandle, payload: bytes, array: bytes) -> Result:
        s = abi.parse_struct(abi.v4l2_event_subscription, payload)
        if s.type == abi.V4L2_EVENT_ALL:
            fh.subscriptions.clear()
            fh.events.clear()
            return 0, b"", b"", []
        key = (s.type, s.id)
        fh.subscriptions.pop(key, None)
        fh.events = deque(e for e in fh.events if e[0] != key)
        return 0, b"", b"", []

    def _dqevent(self, fh: FileHandle, payload: bytes, array: bytes) -> Result:
        if not fh.events:
            return -errno.ENOENT, b"", b"", []
        _key, data = fh.events.popleft()
        ev = abi.v4l2_event.from_buffer_copy(data)
        ev.pending = len(fh.events)
        return 0, bytes(ev), b"", []
