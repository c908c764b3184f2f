"""Rendering speed of the simulated fingertips, against the 30 fps camera they replace.

    python benchmarks/bench_render.py [--quick]

For 320x240 and 640x480, side by side in the same run:

- ``gelsight``: the full per-frame path of a jig touch (sample the textured part at a stage pose,
  press, clip, smooth, shade, composite, noise, clip to 8 bit);
- ``gelsight_naive``: the same physics written the straightforward way (``np.gradient``,
  ``scipy.ndimage.gaussian_filter``, fresh Gaussian noise per frame): the baseline;
- ``fingervision``: markers displaced by a contact shear field, grown by load, an object behind
  the skin;
- ``camera_pipeline``: a FingertipCamera reading the GelSight scene through the SimulatedCamera
  (UVC exposure/white balance, read noise, duplicate detection) on a virtual clock.

Single core (``cv2.setNumThreads(1)``); reports wall-clock fps and CPU-time fps (the second is the
renderer's own cost when other jobs share the machine; the load average is recorded). Prints a table; ``--save`` writes ``benchmarks/results/render.json``.
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
import time
from pathlib import Path

from _output import add_save_args, parse_args, save_json  # noqa: E402  (benchmarks/ is the script's folder)

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from tactile_rig.core.clock import VirtualClock  # noqa: E402
from tactile_rig.drivers.camera import CameraConfig, FingertipCamera  # noqa: E402
from tactile_rig.mocks.camera import SimulatedCamera  # noqa: E402
from tactile_rig.sim import World  # noqa: E402
from tactile_rig.sim.render.fingervision import FingerVisionRenderer, FvObject, contact_shear_field  # noqa: E402
from tactile_rig.sim.render.gelsight import TAXIM_LIGHTING, GelSightRenderer  # noqa: E402
from tactile_rig.sim.world.objects import pressed_indentation_mm, usb_connector_part, view_in_sensor  # noqa: E402

CAMERA_FPS = 30.0
GSMINI_MM_PER_PX_320 = 0.0634


def timed(fn, n: int) -> dict[str, float]:
    """Frames per second of ``fn(i)`` over ``n`` calls (after 3 warm-up calls): wall clock, and CPU time
    of this process (what the renderer costs when other jobs share the machine)."""
    for i in range(3):
        fn(i)
    t0, c0 = time.perf_counter(), time.process_time()
    for i in range(n):
        fn(i)
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    return {"wall_fps": n / wall, "cpu_fps": n / max(cpu, 1e-9)}


def naive_gelsight(bg: np.ndarray, mm_per_px: float, rng: np.random.Generator):
    from scipy.ndimage import gaussian_filter

    bgf = bg.astype(np.float64)

    def render(h: np.ndarray) -> np.ndarray:
        s = gaussian_filter(np.clip(h, 0, 1.0), 0.6 / mm_per_px)
        gy, gx = np.gradient(s, mm_per_px)
        nz1 = 1 / np.sqrt(1 + gx**2 + gy**2) - 1
        img = bgf + np.stack([gx, gy, nz1], -1) @ TAXIM_LIGHTING.matrix.astype(np.float64)
        img += rng.normal(0, 1.0, img.shape)
        return np.clip(img + 0.5, 0, 255).astype(np.uint8)

    return render


def bench_size(rows: int, cols: int, n: int) -> dict[str, float]:
    mm_per_px = GSMINI_MM_PER_PX_320 * 320 / cols
    part = usb_connector_part(mm_per_px=0.05)
    gs = GelSightRenderer("gsmini", mm_per_px, shape_px=(rows, cols), seed=0)
    poses = [(6 * np.sin(i), 6 * np.cos(1.3 * i), (i * 17) % 180 - 90) for i in range(64)]

    def gelsight(i: int) -> None:
        x, y, th = poses[i % 64]
        gs.render_object(part, 0.5, x, y, th)

    naive = naive_gelsight(gs.background_bgr, mm_per_px, np.random.default_rng(0))

    def gelsight_naive(i: int) -> None:
        x, y, th = poses[i % 64]
        view = view_in_sensor(part, (rows, cols), mm_per_px, x, y, th)
        naive(pressed_indentation_mm(view, 0.5, part.max_height_mm))

    fv = FingerVisionRenderer((rows, cols), seed=0)
    centre = (cols / 2, rows / 2)

    def fingervision(i: int) -> None:
        field = lambda p: contact_shear_field(p, centre, shift_px=(3 * np.sin(i), 2.0), twist_deg=2.0,  # noqa: E731
                                              radius_px=0.35 * cols)
        fv.render(field, normal_load=0.5, object=FvObject((centre[0] + 10 * np.sin(i), centre[1]),
                                                          (cols / 5, rows / 8), 10.0 * i), light_gain=0.9)

    clock = VirtualClock()
    world = World(clock)
    world.build("object", "height_field_object", shape="usb_connector", mm_per_px=0.05, press_depth_mm=0.5)
    world.build("gelsight", "gelsight_renderer", background="gsmini", shape_px=(rows, cols), mm_per_px=mm_per_px)
    sim = SimulatedCamera(world.get("gelsight"), clock=clock, width=cols, height=rows, fps=30)
    cam = FingertipCamera(sim, CameraConfig(width=cols, height=rows, fps=30), clock=clock).open()
    obj = world.get("object")

    def camera_pipeline(i: int) -> None:
        obj.x_mm = poses[i % 64][0]
        cam.read()

    out = {name: timed(fn, n) for name, fn in (("gelsight", gelsight), ("gelsight_naive", gelsight_naive),
                                               ("fingervision", fingervision), ("camera_pipeline", camera_pipeline))}
    cam.close()
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="fewer frames")
    add_save_args(ap, "render.json")
    args = parse_args(ap)
    cv2.setNumThreads(1)
    n = 20 if args.quick else 150
    results: dict = {"opencv": cv2.__version__, "numpy": np.__version__, "python": platform.python_version(),
                     "machine": platform.machine(), "quick": args.quick, "frames": n, "camera_fps": CAMERA_FPS,
                     "fps": {}}
    for rows, cols in ((240, 320), (480, 640)):
        results["fps"][f"{cols}x{rows}"] = bench_size(rows, cols, n)
    try:
        results["load_average"] = list(__import__("os").getloadavg())
    except OSError:
        pass
    print(f"{'size':9s} {'renderer':16s} {'wall fps':>9s} {'cpu fps':>9s} {'cpu x 30 fps':>13s}")
    for size, by in results["fps"].items():
        for name, r in by.items():
            print(f"{size:9s} {name:16s} {r['wall_fps']:9.1f} {r['cpu_fps']:9.1f} {r['cpu_fps'] / CAMERA_FPS:13.1f}")
    save_json(args, results)
    return 0


if __name__ == "__main__":
    sys.exit(main())
