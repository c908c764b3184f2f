"""The rehearsal bench: the real-bench path (``--bench bench.toml``) without hardware.

``tactile-rig bench rehearse`` starts every serial device's mock in its own process on its own pty
and serves each camera as an emulated V4L2 device (``/dev/videoN``, a UVC camera model whose
system calls a preload library answers, opened by the camera driver through OpenCV's V4L2 backend;
or, as an option, MJPEG over HTTP), then writes a ``bench.toml`` naming those paths: every bench
command then runs exactly as on a lab bench, with separate processes and real time, no
``rigsim://``.

Modules, one job each: :mod:`.bench` (start, write the bench file, stop), :mod:`.processes` (one
device process), :mod:`.bench_file` (the TOML and the device links), :mod:`.child` (the stage and
camera processes), :mod:`.cameras` (a camera model seeing a scene, served over V4L2 or HTTP),
:mod:`.camera_server` (a camera as MJPEG over HTTP), :mod:`.frames` (recorded footage at its
recorded rate).
"""

from tactile_rig.rig.rehearsal.bench import BENCH_FILE, RehearsalBench, RehearsalOptions
from tactile_rig.rig.rehearsal.camera_server import CameraServer
from tactile_rig.rig.rehearsal.frames import Footage, load_footage

__all__ = ["BENCH_FILE", "CameraServer", "Footage", "RehearsalBench", "RehearsalOptions", "load_footage"]
