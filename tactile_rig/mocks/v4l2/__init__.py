"""UVC cameras emulated at the system-call boundary: OpenCV's V4L2 backend, ``v4l2-ctl``,
``v4l2-compliance`` and any program reaching ``/dev/videoN`` through the C library stream from them.

Two halves:

* a preload library (``preload.c``, compiled on demand by :mod:`.build`) that a client process
  loads with ``LD_PRELOAD``: for the device paths of emulated cameras, and nothing else, it
  answers ``open``, ``stat``, ``ioctl``, ``mmap``, ``poll``/``select``, ``read``, ``close`` (and their
  variants, ``syscall()`` included) and the node's ``/sys`` and ``/dev/v4l`` entries;
* a device server (:class:`V4L2Camera`, Python) that is the camera as uvcvideo presents it
  (:mod:`.device`): formats, frame intervals, controls and control events, videobuf2 buffers in
  shared memory, frames rendered by a :class:`~tactile_rig.mocks.camera.SimulatedCamera` and
  paced at the negotiated interval, faults (stall, freeze, unplug, replug).

How a process learns the cameras: a registry directory (``$TACTILE_RIG_V4L2_DIR``; default
``<tmp>/tactile-rig-v4l2-<uid>``) holds, under ``root/``, each node's socket and its ``/dev`` and
``/sys`` entries. The library looks a path up there when it is used, not when the process starts,
so a process started with the preload sees cameras served after it started (a long-lived bench
process, a CLI that re-executes itself), and an unplugged camera's node is simply gone. A client's
environment needs ``LD_PRELOAD`` and that variable: :attr:`V4L2Camera.env`.

    with V4L2Camera("c310") as cam:           # serves /dev/video42 (the first free node from 42)
        subprocess.run(["v4l2-ctl", "-d", cam.port, "--all"], env={**os.environ, **cam.env})
"""

from __future__ import annotations

from tactile_rig.mocks.v4l2.build import PreloadBuildError, PreloadUnavailable, toolchain_problem
from tactile_rig.mocks.v4l2.faults import CameraFaults
from tactile_rig.mocks.v4l2.server import V4L2Camera, default_registry, preload_env

__all__ = ["V4L2Camera", "CameraFaults", "PreloadUnavailable", "PreloadBuildError", "toolchain_problem",
           "default_registry", "preload_env"]
