"""Benchmark: the mock jig accuracy run (Li 2014 Fig. 7), accuracy and wall time.

Side by side in one run, on the same GelSight calibration (made once by the ball-press session):

* ``tactile_map`` — the default run: a tactile map of three touches (0, 0), (0, ±2) mm;
* ``no_retouch`` — baseline: one touch per point unless refused (the paper's protocol), no re-touch
  when the confidence is below 0.99;
* ``single_touch_map`` — baseline: the map is the first touch only (no mosaicking);
* ``paper`` — Li et al. 2014's real-bench figures, for reference (not measured here).

    python benchmarks/bench_jig_accuracy.py [--quick] [--seeds N] [--save | --out PATH]

Prints a table; ``--save`` writes ``benchmarks/results/jig_accuracy.json`` (full runs only). ``--quick`` runs a reduced
sweep (rotations −90..90 in 30° steps, shifts −6..6 in 3 mm steps) with one seed.
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

from _output import add_save_args, parse_args, save_json  # noqa: E402  (benchmarks/ is the script's folder)

from tactile_rig.rig.jig_accuracy import (
    PAPER_FIGURES,
    JigAccuracyConfig,
    execute_jig_accuracy,
    mock_gelsight_calibration,
)

def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="reduced sweeps, one seed")
    ap.add_argument("--seeds", type=int, default=3, help="world seeds per variant (default 3)")
    add_save_args(ap, "jig_accuracy.json")
    args = parse_args(ap)
    seeds = range(1 if args.quick else args.seeds)
    sweep = dict(rotations_deg=(-90.0, 90.0, 30.0), shifts_mm=(-6.0, 6.0, 3.0)) if args.quick else {}
    variants = {
        "tactile_map": {},
        "no_retouch": {"retouch_below_confidence": 0.0},
        "single_touch_map": {"map_touches_mm": ((0.0, 0.0),)},
    }
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        cal = mock_gelsight_calibration(Path(tmp) / "cal" / "gelsight", seed=0)
        cal_s = time.perf_counter() - t0
        for name, extra in variants.items():
            for seed in seeds:
                cfg = JigAccuracyConfig(seed=seed, **sweep, **extra)
                t0 = time.perf_counter()
                out = execute_jig_accuracy(cfg, Path(tmp) / f"{name}-{seed}", calibration=cal, record=True,
                                           report=False)
                wall = time.perf_counter() - t0
                s = out.summary
                rows.append({"variant": name, "seed": seed, "points": s["n_points"], "refused": s["n_refused"],
                             "extra_touches": s["extra_touches"],
                             "rotation_mae_deg": s["rotation_mae_deg"], "rotation_std_deg": s["rotation_std_deg"],
                             "translation_mae_mm": s["translation_mae_mm"],
                             "translation_std_mm": s["translation_std_mm"], "wall_s": round(wall, 3)})
    rows.append({"variant": "paper (Li 2014, real bench)", "seed": None, "points": None, "refused": None,
                 "extra_touches": None,
                 **{k: v for k, v in PAPER_FIGURES.items()}, "wall_s": None})
    save_json(args, {"quick": args.quick, "calibration_wall_s": round(cal_s, 3), "rows": rows}, indent=2)

    def f(v, fmt):
        return "—" if v is None else format(v, fmt)

    print(f"calibration session (20 ball presses + 4-fold report): {cal_s:.2f} s")
    print(f"{'variant':<28} {'seed':>4} {'pts':>4} {'ref':>4} {'+tch':>4} {'rot MAE°':>9} {'rot std°':>9} "
          f"{'tra MAE mm':>10} {'tra std mm':>10} {'wall s':>7}")
    for r in rows:
        print(f"{r['variant']:<28} {f(r['seed'], 'd'):>4} {f(r['points'], 'd'):>4} {f(r['refused'], 'd'):>4} "
              f"{f(r['extra_touches'], 'd'):>4} "
              f"{f(r['rotation_mae_deg'], '.3f'):>9} {f(r['rotation_std_deg'], '.3f'):>9} "
              f"{f(r['translation_mae_mm'], '.4f'):>10} {f(r['translation_std_mm'], '.4f'):>10} "
              f"{f(r['wall_s'], '.2f'):>7}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
