"""Bodies that run in a child process started with a rehearsal bench's camera emulation
(:func:`tactile_rig.mocks.v4l2.child.run_in_child` with ``RehearsalBench.env``): what a lab's own
program on the rehearsal does, through OpenCV's V4L2 backend."""

from __future__ import annotations

import os
import threading
import time
from typing import Any

from tactile_rig.rig.bench import connect_bench, load_bench
from tactile_rig.rig.camera_calibrations import camera_calibrations
from tactile_rig.rig.live_perception import FingerVisionStep, run_live


def bench_ports(bench_path: str) -> dict[str, str]:
    """The bench's device paths as the process sees them (the loader checks that each exists)."""
    bench = load_bench(bench_path)
    return {name: os.path.realpath(dev.port) for name, dev in bench.devices.items()}


def press_while_tracking(bench_path: str, force_map: str) -> tuple[list[dict[str, Any]], list[float]]:
    """Live FingerVision tracking of ``camera_fingervision`` with ``force_map`` for 100 frames while the
    gripper closes on the scale (after 20 frames at rest) and lets go (after 70): the tracked rows and
    the scale's readings in newtons during the press."""
    bench = load_bench(bench_path)
    cal = camera_calibrations(bench, "camera_fingervision", force_map=force_map, defaults=False, load=("force_map",))
    assert cal.force_map is not None
    rig = connect_bench(load_bench(text=f'[gripper]\nport = "{bench.devices["gripper"].port}"\nbaud = 57600\n'
                                        f'[scale]\nport = "{bench.devices["scale"].port}"\nrate_hz = 80.0\n'))
    rows: list[dict[str, Any]] = []
    scale_n: list[float] = []

    def press() -> None:  # close on the platform once tracking has started at rest, then let go
        deadline = time.monotonic() + 60.0
        while len(rows) < 20 and time.monotonic() < deadline:  # frames, not seconds: a loaded machine
            time.sleep(0.02)
        rig.gripper.activate(0.02)  # the collection's probe measured ~260 N per unit effort: ~5 N
        rig.gripper.gripper_go(0.0, 0.02, blocking=False)
        while len(rows) < 70 and time.monotonic() < deadline:
            scale_n.extend(r.newtons for r in rig.scale.poll())
            time.sleep(0.02)
        rig.gripper.gripper_go(0.06, 0.1, blocking=False)

    presser = threading.Thread(target=press)
    presser.start()
    try:
        run_live(bench, "camera_fingervision", FingerVisionStep(calibrations=cal), max_frames=100, on_frame=rows.append)
    finally:
        presser.join(30)
        rig.close()
    return rows, scale_n
