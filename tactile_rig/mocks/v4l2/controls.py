"""The control ioctls as uvcvideo answers them, over a :class:`~tactile_rig.mocks.camera.UvcControlTable`.

Where each rule comes from (Linux 6.x):

* ``VIDIOC_QUERYCTRL`` / ``QUERY_EXT_CTRL`` with ``V4L2_CTRL_FLAG_NEXT_CTRL`` walk the controls in id
  order with the class pseudo-controls ("User Controls", "Camera Controls") inserted before the first
  control of each class (uvc_ctrl.c, uvc_query_v4l2_ctrl / __uvc_query_v4l2_class); a manual control
  whose auto switch is not at its manual value has ``V4L2_CTRL_FLAG_INACTIVE``; a menu reports the
  index range of uvcvideo's mapping (0..3 for auto exposure) and ``QUERYMENU`` refuses (EINVAL) the
  indices the camera's GET_RES bitmap does not offer.
* ``G/S/TRY_EXT_CTRLS`` (and ``G/S_CTRL``, which the V4L2 core turns into them: v4l2-ioctl.c,
  v4l_g_ctrl / v4l_s_ctrl) check the whole request first (uvc_ctrl_check_access): a class id or an
  unknown id fails (EACCES / EINVAL) with ``error_idx`` = count (= the index for TRY); a write to an
  inactive control fails with EACCES unless its auto switch is set to manual in the same request
  (uvc_ctrl_is_accessible, Linux >= 6.3). Before 6.3 uvcvideo sent the write to the camera, which
  stalls it; uvc_query_ctrl maps the camera's error code (EIO for Invalid control/request, EILSEQ
  for Wrong state, which 6.3 maps to EACCES too): TRY succeeded and S failed at commit,
  ``error_idx`` = count. A :class:`ControlSet` made with ``legacy_wrong_state=True`` answers that
  way, with the model's ``inactive_write_errno_legacy``. Values are then rounded and clamped
  (:meth:`~tactile_rig.devices.camera_models.UvcControl.clamp`), menu indices checked (ERANGE, EINVAL),
  and committed (S) or only returned (TRY).
* A committed write sends ``V4L2_EVENT_CTRL`` to every other file handle subscribed to that control
  (to the writer too with ``V4L2_EVENT_SUB_FL_ALLOW_FEEDBACK``), and a flags-changed event for the
  manual control an auto switch governs (uvc_ctrl_send_events, uvc_ctrl_send_slave_event).
"""

from __future__ import annotations

import ctypes as C
import errno
from dataclasses import dataclass
from typing import Callable, Iterable

from tactile_rig.devices.camera_models import UvcControl
from tactile_rig.mocks.camera import UvcControlTable
import tactile_rig.mocks.v4l2.abi as abi

_TYPES = {"int": abi.V4L2_CTRL_TYPE_INTEGER, "bool": abi.V4L2_CTRL_TYPE_BOOLEAN, "menu": abi.V4L2_CTRL_TYPE_MENU}
_CLASS_NAMES = {abi.V4L2_CID_CAMERA_CLASS: b"Camera Controls", abi.V4L2_CID_USER_CLASS: b"User Controls"}
# uvcvideo's order of the class table (uvc_control_classes).
_CLASS_ORDER = (abi.V4L2_CID_CAMERA_CLASS, abi.V4L2_CID_USER_CLASS)


@dataclass(frozen=True)
class ControlChange:
    """A committed control: ``changes`` is V4L2_EVENT_CTRL_CH_* bits; ``origin`` the writer's handle id."""

    control: UvcControl
    changes: int
    origin: int


class ControlSet:
    """The controls of one camera; ``table`` holds the values the image formation reads."""

    def __init__(self, table: UvcControlTable, *, legacy_wrong_state: bool = False,
                 legacy_errno: int = errno.EIO) -> None:
        self.table = table
        self.legacy_wrong_state = legacy_wrong_state
        self.legacy_errno = legacy_errno
        self.by_id = {c.cid: c for c in table.controls.values()}
        self.ordered = sorted(self.by_id)
        self.classes = [k for k in _CLASS_ORDER if any((cid & 0x0FFF0000) | 1 == k for cid in self.ordered)]

    # -- queries ------------------------------------------------------------------------------------
    def _class_between(self, req_id: int, found_id: int | None, find_next: bool) -> int | None:
        for k in self.classes:
            if not find_next:
                if k == req_id:
                    return k
                continue
            if k > req_id and (found_id is None or k < found_id):
                return k
        return None

    def is_active(self, c: UvcControl, pending: dict[int, int] | None = None) -> bool:
        if c.active_when is None:
            return True
        master = self.table.controls[c.active_when[0]]
        value = pending.get(master.cid, self.table.values[master.name]) if pending else self.table.values[master.name]
        return value == c.active_when[1]

    def flags(self, c: UvcControl) -> int:
        return 0 if self.is_active(c) else abi.V4L2_CTRL_FLAG_INACTIVE

    def find(self, qid: int) -> tuple[int | None, UvcControl | None]:
        """(class id, None) or (None, control) for a QUERYCTRL id; (None, None) if there is none."""
        find_next = bool(qid & abi.V4L2_CTRL_FLAG_NEXT_CTRL)
        next_compound = bool(qid & abi.V4L2_CTRL_FLAG_NEXT_COMPOUND)
        cid = qid & abi.V4L2_CTRL_ID_MASK
        if not find_next:
            if next_compound:
                return None, None  # no compound controls here
            cls = self._class_between(cid, None, False)
            if cls is not None:
                return cls, None
            return None, self.by_id.get(cid)
        found = next((i for i in self.ordered if i > cid), None)
        if found is None:
            return None, None
        cls = self._class_between(cid, found, True)
        if cls is not None:
            return cls, None
        return None, self.by_id[found]

    def queryctrl(self, q: abi.v4l2_queryctrl) -> int:
        cls, c = self.find(q.id)
        C.memset(C.addressof(q), 0, C.sizeof(q))
        if cls is not None:
            q.id, q.type, q.name = cls, abi.V4L2_CTRL_TYPE_CTRL_CLASS, _CLASS_NAMES[cls]
            q.flags = abi.V4L2_CTRL_FLAG_WRITE_ONLY | abi.V4L2_CTRL_FLAG_READ_ONLY
            return 0
        if c is None:
            return -errno.EINVAL
        q.id, q.type, q.name = c.cid, _TYPES[c.kind], c.label.encode()
        q.minimum, q.maximum, q.step, q.default_value = c.minimum, c.maximum, c.step, c.default
        q.flags = self.flags(c)
        return 0

    def query_ext_ctrl(self, q: abi.v4l2_query_ext_ctrl) -> int:
        b = abi.v4l2_queryctrl(id=q.id)
        ret = self.queryctrl(b)
        if ret:
            return ret
        C.memset(C.addressof(q), 0, C.sizeof(q))
        q.id, q.type, q.name = b.id, b.type, b.name
        q.minimum, q.maximum, q.step, q.default_value, q.flags = b.minimum, b.maximum, b.step, b.default_value, b.flags
        q.elem_size, q.elems, q.nr_of_dims = 4, 1, 0
        return 0

    def querymenu(self, m: abi.v4l2_querymenu) -> int:
        cid, index = m.id, m.index
        C.memset(C.addressof(m), 0, C.sizeof(m))
        m.id, m.index = cid, index
        c = self.by_id.get(cid)
        if c is None or c.kind != "menu" or index >= 32 or index not in c.menu:
            return -errno.EINVAL
        m.u.name = c.menu_names[index].encode()
        return 0

    # -- values -------------------------------------------------------------------------------------
    def _check_access(self, ids: list[int], values: list[int], write: bool, try_: bool) -> tuple[int, int]:
        """(errno or 0, index of the failing control) over the whole request (uvc_ctrl_check_access)."""
        pending = {}
        for i, cid in enumerate(ids):
            if self._class_between(cid, None, False) is not None:
                return -errno.EACCES, i
            c = self.by_id.get(cid)
            if c is None:
                return -errno.EINVAL, i
            if write and not try_ and not self.legacy_wrong_state and c.active_when is not None:
                master = self.table.controls[c.active_when[0]]
                # The last write of the master in this request counts, else its current value.
                pending = {m: values[j] for j, m in enumerate(ids) if m == master.cid}
                if not self.is_active(c, pending):
                    return -errno.EACCES, i
        return 0, len(ids)

    def get_ext(self, which: int, ids: list[int]) -> tuple[int, int, list[int]]:
        """G_EXT_CTRLS: (errno or 0, error_idx, values)."""
        err, _ = self._check_access(ids, [0] * len(ids), write=False, try_=False)
        if err:
            return err, len(ids), [0] * len(ids)
        if which == abi.V4L2_CTRL_WHICH_DEF_VAL:
            return 0, 0, [self.by_id[i].default for i in ids]
        return 0, 0, [self.table.values[self.by_id[i].name] for i in ids]

    def set_ext(self, ids: list[int], values: list[int], try_: bool) -> tuple[int, int, list[int]]:
        """S/TRY_EXT_CTRLS: (errno or 0, error_idx, the values as clamped). Commits on S."""
        err, i = self._check_access(ids, values, write=True, try_=try_)
        if err:
            return err, (i if try_ else len(ids)), list(values)
        out = list(values)
        for i, (cid, v) in enumerate(zip(ids, values)):
            c = self.by_id[cid]
            if c.kind == "menu":
                e = c.menu_errno(v)
                if e:
                    return -e, (i if try_ else len(ids)), out
            else:
                out[i] = c.clamp(v)
        if not try_ and self.legacy_wrong_state:
            pending = {cid: v for cid, v in zip(ids, out)}
            if any(not self.is_active(self.by_id[cid], pending) for cid in ids):
                return -self.legacy_errno, len(ids), out
        if not try_:
            for cid, v in zip(ids, out):
                self.table.values[self.by_id[cid].name] = v
        return 0, 0, out

    def changes_for(self, ids: Iterable[int], origin: int) -> list[ControlChange]:
        """The events a committed write of ``ids`` sends (uvc_ctrl_send_events)."""
        ids = list(ids)
        out: list[ControlChange] = []
        for cid in ids:
            c = self.by_id[cid]
            for slave in self.table.controls.values():
                if slave.active_when is not None and slave.active_when[0] == c.name and slave.cid not in ids:
                    out.append(ControlChange(slave, abi.V4L2_EVENT_CTRL_CH_FLAGS | abi.V4L2_EVENT_CTRL_CH_VALUE, origin))
            changes = abi.V4L2_EVENT_CTRL_CH_VALUE
            if c.active_when is not None and self.table.controls[c.active_when[0]].cid in ids:
                changes |= abi.V4L2_EVENT_CTRL_CH_FLAGS
            out.append(ControlChange(c, changes, origin))
        return out

    def fill_event(self, ev: abi.v4l2_event, c: UvcControl, changes: int) -> None:
        """An event's payload as uvc_ctrl_fill_event writes it (value and flags as of now)."""
        q = abi.v4l2_queryctrl(id=c.cid)
        self.queryctrl(q)
        ev.type = abi.V4L2_EVENT_CTRL
        ev.id = c.cid
        ev.u.ctrl.changes = changes
        ev.u.ctrl.type = q.type
        ev.u.ctrl.v.value = self.table.values[c.name]
        ev.u.ctrl.flags = q.flags
        ev.u.ctrl.minimum, ev.u.ctrl.maximum = q.minimum, q.maximum
        ev.u.ctrl.step, ev.u.ctrl.default_value = q.step, q.default_value


def check_ext_ctrls(which: int, ids: list[int], ioctl: str) -> tuple[bool, int | None]:
    """The V4L2 core's check_ext_ctrls (v4l2-ioctl.c): is the request well formed, and the error_idx
    it sets when not (None: leave it)."""
    count = len(ids)
    if which == abi.V4L2_CID_PRIVATE_BASE:
        return ioctl not in ("G_CTRL", "S_CTRL"), None
    if which == abi.V4L2_CTRL_WHICH_DEF_VAL:
        if ioctl in ("S", "TRY"):
            return False, count
        return True, None
    if which == abi.V4L2_CTRL_WHICH_CUR_VAL:
        return True, None
    if which == abi.V4L2_CTRL_WHICH_REQUEST_VAL:
        return False, count
    for i, cid in enumerate(ids):
        if cid & 0x0FFF0000 != which:
            return False, (i if ioctl == "TRY" else count)
    return True, None


ControlSink = Callable[[list[ControlChange]], None]
