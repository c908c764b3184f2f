"""v4l2-compliance (v4l-utils 1.22.1, Debian 12's) judges the emulated cameras.

What the tool says of a real uvcvideo camera depends on the kernel: the emulation answers as the
uvcvideo generation it is given, and each run below is compared with what that generation gives
(docs/emulated_cameras.md has the table beside a real Logitech camera's logs).
"""

from __future__ import annotations

import re

from tests._v4l2 import KERNEL_6_1, KERNEL_CURRENT, emulated, require, run


def _compliance(model: str, kernel: tuple[int, int], *args: str) -> str:
    require("v4l2-compliance")
    with emulated(model, kernel=kernel) as cam:
        done = run(cam, "v4l2-compliance", "-d", cam.port, *args, timeout_s=240, check=False)
    return done.stdout + done.stderr


def _total(out: str) -> tuple[int, int, int, int]:
    m = re.search(r"Total for uvcvideo device /dev/video\d+: (\d+), Succeeded: (\d+), Failed: (\d+), Warnings: (\d+)",
                  out)
    assert m, out[-3000:]
    total, ok, failed, warnings = (int(g) for g in m.groups())
    return total, ok, failed, warnings


def _failures(out: str) -> list[str]:
    return re.findall(r"^\s*fail: (.*)$", out, re.M)


def _warnings(out: str) -> list[str]:
    return re.findall(r"^\s*warn: (.*)$", out, re.M)


def _load_warnings_only(out: str) -> bool:
    """Streaming on a loaded machine may lose a frame the tool did not requeue in time (it warns of
    the sequence gap, as it does on hardware); no other warning is expected."""
    return all(re.fullmatch(r"v4l2-test-buffers\.cpp\(\d+\): got sequence number \d+, expected \d+", w)
               for w in _warnings(out))


def test_digit_passes_every_test_with_streaming() -> None:
    """No auto/manual control pair, a current uvcvideo: all 54 tests pass, streaming included
    (MMAP with no poll, select and epoll; 60 frames each)."""
    out = _compliance("digit", KERNEL_CURRENT, "-s")
    assert _total(out)[:3] == (54, 54, 0), "\n".join(_failures(out))
    assert _load_warnings_only(out), _warnings(out)
    for test in ("MMAP (no poll)", "MMAP (select)", "MMAP (epoll)", "blocking wait", "VIDIOC_EXPBUF",
                 "VIDIOC_REQBUFS/CREATE_BUFS/QUERYBUF", "VIDIOC_(UN)SUBSCRIBE_EVENT/DQEVENT"):
        assert re.search(rf"test {re.escape(test)}: OK$", out, re.M), test


def test_c310_on_a_current_kernel_fails_only_where_the_tool_predates_uvcvideos_eacces() -> None:
    """Streaming passes; the two control tests fail on EACCES for the inactive manual controls,
    exactly as a real Logitech camera does with this tool on Linux >= 6.3 (v4l-utils 1.24 learnt it)."""
    out = _compliance("c310", KERNEL_CURRENT, "-s")
    assert _total(out)[:3] == (54, 52, 2)
    assert _load_warnings_only(out), _warnings(out)
    assert _failures(out) == ["v4l2-test-controls.cpp(489): s_ctrl returned an error (13)",
                              "v4l2-test-controls.cpp(736): s_ext_ctrls returned an error (13)"]
    assert re.search(r"test MMAP \(select\): OK$", out, re.M)


def test_c310_on_linux_6_1_matches_a_real_logitech_cameras_log() -> None:
    """Without streaming (the real log's run): no failure; the camera's EIO for inactive controls and
    the second format that cannot be set are warnings, as in the C525's log on 5.15 (whose 46 tests
    include the media controller's, which is not emulated)."""
    out = _compliance("c310", KERNEL_6_1)
    total, ok, failed, _ = _total(out)
    assert (total, ok, failed) == (45, 45, 0), "\n".join(_failures(out))
    assert "test MC information" not in out
    assert _warnings(out) == ["v4l2-test-controls.cpp(483): s_ctrl returned EIO"] * 2 + \
        ["v4l2-test-controls.cpp(729): s_ext_ctrls returned EIO"] * 2 + \
        ["v4l2-test-controls.cpp(805): s_ext_ctrls returned EIO", "v4l2-test-formats.cpp(1036): Could not set fmt2"]


def test_c310_on_linux_6_1_fails_streaming_on_uvcvideos_privileges() -> None:
    """Before 6.17 a handle that freed its buffers loses the stream's privileges and STREAMON gives
    EBUSY where the tool expects EINVAL: the reason uvcvideo's developers gave for moving to vb2's
    ownership ("with Hans' patch we can also pass v4l2-compliance -s", linux-media, 2021)."""
    out = _compliance("c310", KERNEL_6_1, "-s")
    assert _failures(out) == ["v4l2-test-buffers.cpp(1345): node->streamon(q.g_type()) != EINVAL"] * 3
    assert re.findall(r"test (MMAP \(\w+ ?\w*\)): FAIL", out) == ["MMAP (no poll)", "MMAP (select)", "MMAP (epoll)"]
