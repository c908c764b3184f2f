"""The preload library at the system-call boundary: what a raw V4L2 client, stat, sysfs, fork and the
pass-through path see (each body runs in a child process started with the camera's environment)."""

from __future__ import annotations

import errno
import os
import shutil
import threading
import time
from pathlib import Path
from typing import Any

from tactile_rig.mocks.v4l2 import V4L2Camera, build, preload_env
from tactile_rig.mocks.v4l2.child import run_in_child
from tests import _v4l2_raw as raw
from tests._v4l2 import emulated, require

V4L2_BUF_FLAG_TIMESTAMP_MONOTONIC = 0x2000
V4L2_BUF_FLAG_TSTAMP_SRC_SOE = 0x10000


def test_a_host_that_does_not_requeue_sees_a_sequence_gap() -> None:
    with emulated("c310") as cam:
        rows = run_in_child(raw.sequence_with_a_late_host, cam.port, env=cam.env)
    seqs = [r[1] for r in rows]
    assert seqs[:4] == [0, 1, 2, 3]
    # Both buffers were done and waiting: the next two are consecutive, then the frames that found
    # no buffer during the 0.5 s are missing (about 15 at 30 fps).
    assert seqs[5] == seqs[4] + 1
    assert seqs[6] - seqs[5] >= 10
    for (_, s0, t0, _), (_, s1, t1, _) in zip(rows, rows[1:]):
        assert (t1 - t0) / 1e6 * 30 >= (s1 - s0) - 0.01, "timestamps advance at least one interval per sequence step"
    assert all(r[3] & V4L2_BUF_FLAG_TIMESTAMP_MONOTONIC and r[3] & V4L2_BUF_FLAG_TSTAMP_SRC_SOE for r in rows)


def test_null_and_unmapped_pointers_give_efault_as_the_kernel_does() -> None:
    with emulated("c310") as cam:
        got = run_in_child(raw.bad_pointers, cam.port, env=cam.env)
    assert got == {"QUERYCAP NULL": errno.EFAULT, "G_FMT unmapped": errno.EFAULT, "S_CTRL NULL": errno.EFAULT,
                   "G_EXT_CTRLS NULL array": errno.EFAULT, "not a V4L2 ioctl": errno.ENOTTY, "QUERYCAP": 0}


def test_the_node_is_a_character_device_with_its_sysfs_entries() -> None:
    with emulated("digit") as cam:
        got = run_in_child(raw.node_files, cam.port, cam.by_id, env=cam.env)
        node = int(cam.port.removeprefix("/dev/video"))
    assert got["is_chr"] and got["fstat_is_chr"] and got["fstat_rdev"]
    assert (got["major"], got["minor"]) == (81, node)
    assert got["by_id_is_link"] and got["by_id_real"] == cam.port
    assert got["uevent"] == f"MAJOR=81\nMINOR={node}\nDEVNAME=video{node}\n"
    assert got["card"] == "DIGIT: DIGIT\n"
    assert got["index"] == "0\n"
    assert got["access_rw"]
    assert f"video{node}" in got["class_listing"]
    assert got["missing"] == errno.ENOENT


def _in_thread(fn: Any, *args: Any, **kwargs: Any) -> tuple[threading.Thread, dict[str, Any]]:
    box: dict[str, Any] = {}

    def body() -> None:
        try:
            box["result"] = run_in_child(fn, *args, **kwargs)
        except BaseException as exc:  # noqa: BLE001  (handed to the test thread)
            box["error"] = exc

    t = threading.Thread(target=body, daemon=True)
    t.start()
    return t, box


def _joined(t: threading.Thread, box: dict[str, Any]) -> Any:
    t.join(60)
    assert not t.is_alive()
    if "error" in box:
        raise box["error"]
    return box["result"]


def test_an_unplugged_node_disappears_and_its_open_handle_errs() -> None:
    """After the unplug: stat and open fail with ENOENT; an open handle gets ENODEV from every ioctl,
    and poll/select report it ready with POLLERR | POLLHUP | POLLPRI (the V4L2 core after
    video_unregister_device)."""
    with emulated("c310") as cam:
        t, box = _in_thread(raw.gone_after_unplug, cam.port, True, env=cam.env)
        deadline = time.monotonic() + 30
        while cam.node is not None and not cam.node.handles and time.monotonic() < deadline:
            time.sleep(0.02)  # the child has the node open
        cam.unplug()
        got = _joined(t, box)
    assert got["stat"] == errno.ENOENT and got["open"] == errno.ENOENT
    assert got["querycap"] == errno.ENODEV
    assert got["poll"] == 0x8 | 0x10 | 0x2  # POLLERR | POLLHUP | POLLPRI
    assert got["select"] == (True, True)


def test_a_process_started_before_the_camera_sees_it() -> None:
    """The registry is read when a path is used: a long-lived process finds cameras started later."""
    require()
    registry = Path(os.environ.get("TMPDIR", "/tmp")) / f"trv-later-{os.getpid()}"
    env = preload_env(build.build(), registry)
    t, box = _in_thread(raw.waits_for_a_camera_started_later, "/dev/video77", env=env)
    time.sleep(1.0)
    try:
        with V4L2Camera("digit", registry=registry, node=77):
            card = _joined(t, box)
    finally:
        shutil.rmtree(registry, ignore_errors=True)
    assert card == "DIGIT: DIGIT"


def test_descriptors_survive_fork_and_dup() -> None:
    with emulated("c310") as cam:
        got = run_in_child(raw.forked_and_duplicated, cam.port, env=cam.env)
    assert got == {"forked": 0, "dup_after_close": 0, "closed": errno.EBADF}


def test_another_handle_gets_control_events() -> None:
    """uvcvideo sends V4L2_EVENT_CTRL to the other subscribed handles: a value change of exposure,
    and a flags change when auto exposure makes it active (uvc_ctrl_send_slave_event)."""
    with emulated("c310") as cam:
        got = run_in_child(raw.control_events, cam.port, env=cam.env)
    assert not got["pending_before"] and got["pending_after"]
    assert got["end"] == errno.ENOENT
    ch_value, ch_flags = 1, 2
    assert [(e[0], e[1], e[2], e[3], e[4]) for e in got["events"]] == [
        (3, 0x009A0902, ch_value | ch_flags, 321, 0)]  # the flags change merged into the value event
    assert got["events"][-1][5] == 0


def test_the_pass_through_path_leaves_other_files_alone(tmp_path: Path) -> None:
    with emulated("c310") as cam:
        with_preload = run_in_child(raw.ordinary_files, str(tmp_path), env=cam.env)
        without = run_in_child(raw.ordinary_files, str(tmp_path), env={"LD_PRELOAD": ""})
        node = cam.port.removeprefix("/dev/")
    assert with_preload.pop("dev_video_listing") == sorted(without.pop("dev_video_listing") + [node])
    assert with_preload == without
    assert without["first"] == b"0123456789" and without["size"] == 10000 and without["fionread"] == 3
