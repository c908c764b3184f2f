"""Benchmark: the jig accuracy run on the rehearsal bench against the same run on the mocks in process.

Side by side in one run, on one GelSight calibration (made once by the ball-press session):

* ``mock`` — baseline: the drivers on ``rigsim://`` mocks in process, virtual time;
* ``rehearsal_q95`` — ``tactile-rig bench rehearse`` (default): the GRBL mock in its own process on a
  pty, the GelSight camera rendering its stage served as MJPEG over HTTP at JPEG quality 95, real time;
* ``rehearsal_q100`` — the same at JPEG quality 100 (how much the camera's compression costs).

Also the rehearsal camera's delivered frame rate (``camera fps``) over 3 s.

    python benchmarks/bench_rehearsal.py [--quick] [--save | --out PATH]

Prints a table; ``--save`` writes ``benchmarks/results/rehearsal.json`` (full runs only). ``--quick``
runs a reduced sweep (rotations −90..90 in 30° steps, shifts −6..6 in 3 mm steps). Real time: a
full run takes about two minutes; timings depend on the machine's load (printed).
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

from _output import add_save_args, parse_args, save_json  # noqa: E402  (benchmarks/ is the script's folder)

from tactile_rig.rig.bench import load_bench
from tactile_rig.rig.bench_camera import measure_fps, open_camera
from tactile_rig.rig.jig_accuracy import JigAccuracyConfig, execute_jig_accuracy, mock_gelsight_calibration
from tactile_rig.rig.rehearsal import RehearsalBench, RehearsalOptions

KEYS = ("n_points", "n_refused", "extra_touches", "rotation_mae_deg", "rotation_std_deg", "translation_mae_mm",
        "translation_std_mm")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="reduced sweeps")
    add_save_args(ap, "rehearsal.json")
    args = parse_args(ap)
    sweep = dict(rotations_deg=(-90.0, 90.0, 30.0), shifts_mm=(-6.0, 6.0, 3.0)) if args.quick else {}
    cfg = JigAccuracyConfig(seed=0, **sweep)
    rows = []
    fps = None
    with tempfile.TemporaryDirectory() as tmp:
        cal = mock_gelsight_calibration(Path(tmp) / "cal" / "gelsight", seed=0)
        t0 = time.perf_counter()
        s = execute_jig_accuracy(cfg, Path(tmp) / "mock", calibration=cal, record=False, report=False).summary
        rows.append({"variant": "mock", **{k: s[k] for k in KEYS}, "wall_s": round(time.perf_counter() - t0, 2)})
        for q in (95, 100):
            opts = RehearsalOptions(seed=0, gelsight_jpeg_quality=q, calibration=False)
            with RehearsalBench(Path(tmp) / f"rehearsal-{q}", opts) as rb:
                bench = load_bench(rb.bench_path)
                if fps is None:
                    with open_camera(bench, "camera_gelsight") as rig:
                        m = measure_fps(rig["camera_gelsight"], 3.0, name="camera_gelsight")
                    fps = {"configured_fps": m.configured_fps, "host_fps": m.host_fps, "device_fps": m.device_fps,
                           "frames": m.frames, "duplicates": m.duplicates, "dropped": m.dropped,
                           "max_gap_s": m.max_gap_s}
                t0 = time.perf_counter()
                s = execute_jig_accuracy(cfg, Path(tmp) / f"bench-{q}", bench=bench, calibration=cal, record=False,
                                         report=False).summary
                rows.append({"variant": f"rehearsal_q{q}", **{k: s[k] for k in KEYS},
                             "wall_s": round(time.perf_counter() - t0, 2)})
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else None
    save_json(args, {"quick": args.quick, "load_average_1min": load, "rows": rows, "camera": fps}, indent=2)
    print(f"load average {load:.1f}" if load is not None else "load average unknown")
    print(f"{'variant':<16} {'pts':>4} {'ref':>4} {'+tch':>4} {'rot MAE°':>9} {'rot std°':>9} {'tra MAE mm':>10} "
          f"{'tra std mm':>10} {'wall s':>7}")
    for r in rows:
        print(f"{r['variant']:<16} {r['n_points']:>4} {r['n_refused']:>4} {r['extra_touches']:>4} "
              f"{r['rotation_mae_deg']:>9.3f} {r['rotation_std_deg']:>9.3f} {r['translation_mae_mm']:>10.4f} "
              f"{r['translation_std_mm']:>10.4f} {r['wall_s']:>7.2f}")
    print(f"rehearsal GelSight camera: {fps['host_fps']} fps delivered ({fps['configured_fps']} configured), "
          f"{fps['duplicates']} duplicates, {fps['dropped']} dropped, longest gap {fps['max_gap_s'] * 1000:.0f} ms")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
