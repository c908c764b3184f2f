"""End-to-end ``tactile-rig gelsight height`` on a folder of 320x240 PNG frames against a gs_sdk-style loop.

Run: ``python benchmarks/bench_gelsight_height.py [--frames N] [--rounds R] [--save]``. One thread
(OpenCV, BLAS and FFT). Both sides do the same job in the same process, alternating rounds: read
every PNG, reconstruct a height map in mm, write one ``.npy`` per frame. Ours goes through the CLI
entry point (``main(["gelsight", "height", CALIB, *PNGS, "-o", DIR])``, so argument parsing and loading
the calibration count); the baseline is a per-pixel MLP on (BGR, x, y) plus a DCT set up per frame
(gs_sdk's organisation, re-implemented). Frames: rendered GelSight Mini ball presses (real background,
240x320). Prints frames/s of each, the ratio by wall clock and by CPU time (steadier on a shared machine); writes ``benchmarks/results/gelsight_height.json``
only with ``--save``.
"""

from __future__ import annotations

import os

for _v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import argparse  # noqa: E402
import contextlib  # noqa: E402
import io  # noqa: E402
import json  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import cv2  # noqa: E402
import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from _output import add_save_args, parse_args, save_json  # noqa: E402  (benchmarks/ is the script's folder)

from tactile_rig.cli import main as cli_main  # noqa: E402
from tactile_rig.perception.gelsight import load_presses  # noqa: E402
from tactile_rig.rig.trade.gelsight import gs_sdk_style_height  # noqa: E402
from tactile_rig.rig.trade.registration_data import MINI_MM_PER_PX, MINI_SHAPE, mini_calibration  # noqa: E402
from tactile_rig.sim.render import gelsight as render  # noqa: E402


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=200, help="PNG frames in the folder (default 200)")
    ap.add_argument("--rounds", type=int, default=3, help="alternating rounds; the best of each side counts")
    add_save_args(ap, "gelsight_height.json")
    args = parse_args(ap)
    cv2.setNumThreads(1)
    load0 = os.getloadavg()
    with tempfile.TemporaryDirectory() as tmp:
        t = Path(tmp)
        render.render_ball_press_dataset(t / "presses", n_presses=min(args.frames, 40), shape_px=MINI_SHAPE,
                                         mm_per_px=MINI_MM_PER_PX, background="gsmini", seed=5)
        presses = load_presses(t / "presses")
        cal = mini_calibration()
        cal.save(t / "cal")
        pngs = []
        (t / "frames").mkdir()
        for i in range(args.frames):
            p = t / "frames" / f"f{i:05d}.png"
            cv2.imwrite(str(p), presses.frames[i % len(presses.frames)])
            pngs.append(str(p))

        def ours() -> None:
            with contextlib.redirect_stdout(io.StringIO()):
                assert cli_main(["gelsight", "height", str(t / "cal"), *pngs, "-o", str(t / "ours")]) == 0

        def baseline() -> None:
            out = t / "base"
            out.mkdir(exist_ok=True)
            for p in pngs:
                frame = cv2.imread(p, cv2.IMREAD_COLOR)
                z = gs_sdk_style_height(cal.model, cal.background, MINI_MM_PER_PX, frame).astype(np.float32)
                np.save(out / (Path(p).stem + ".npy"), z)

        best = {"ours": float("inf"), "baseline": float("inf")}
        cpu = {"ours": float("inf"), "baseline": float("inf")}
        for _ in range(max(1, args.rounds)):
            for name, fn in (("ours", ours), ("baseline", baseline)):
                t0, c0 = time.perf_counter(), time.process_time()
                fn()
                best[name] = min(best[name], time.perf_counter() - t0)
                cpu[name] = min(cpu[name], time.process_time() - c0)
        z = np.load(t / "ours" / "f00000.npy")
        assert z.shape == MINI_SHAPE and np.isfinite(z).all()
    n = args.frames
    res = {"frames": n, "shape": list(MINI_SHAPE),
           "ours_frames_per_s": n / best["ours"], "ours_ms_per_frame": 1e3 * best["ours"] / n,
           "baseline_frames_per_s": n / best["baseline"], "baseline_ms_per_frame": 1e3 * best["baseline"] / n,
           "ratio": best["baseline"] / best["ours"], "rounds": args.rounds,
           "ours_cpu_ms_per_frame": 1e3 * cpu["ours"] / n, "baseline_cpu_ms_per_frame": 1e3 * cpu["baseline"] / n,
           "cpu_ratio": cpu["baseline"] / cpu["ours"],
           "load_average_start": load0, "load_average_end": os.getloadavg(), "opencv": cv2.__version__}
    print(f"gelsight height, {n} PNG frames 320x240 -> .npy, one thread (load {load0[0]:.1f} -> "
          f"{res['load_average_end'][0]:.1f}):")
    print(f"  ours (CLI):          {res['ours_frames_per_s']:8.1f} frames/s  {res['ours_ms_per_frame']:.2f} ms/frame")
    print(f"  baseline gs_sdk-style: {res['baseline_frames_per_s']:6.1f} frames/s  {res['baseline_ms_per_frame']:.2f} ms/frame")
    print(f"  ratio: {res['ratio']:.1f}x wall clock; {res['cpu_ratio']:.1f}x in CPU time "
          f"({res['ours_cpu_ms_per_frame']:.2f} vs {res['baseline_cpu_ms_per_frame']:.2f} ms/frame: on a shared "
          "machine the CPU time is the steadier figure)")
    save_json(args, res)
    return 0


if __name__ == "__main__":
    sys.exit(main())
