"""Benchmark: the jig accuracy run on the rehearsal bench, its cameras over V4L2 and over HTTP, beside
the same run on the mocks in process.

Side by side in one run, on one GelSight calibration (made once by the ball-press session), each
rehearsal run being the lab's command, ``tactile-rig run jig-accuracy --bench rehearsal/bench.toml``,
in a process of its own:

* ``mock`` — baseline: the drivers on ``rigsim://`` mocks in process, virtual time;
* ``v4l2_mjpg_q95`` — ``tactile-rig bench rehearse`` (default): the GRBL mock in its own process on a
  pty, the GelSight camera rendering its stage as an emulated C310 (``/dev/video42``), MJPG at JPEG
  quality 95 decoded by OpenCV's V4L2 backend, real time;
* ``v4l2_mjpg_q100`` — the same at quality 100 (how much the camera's compression costs);
* ``v4l2_yuyv`` — ``--gelsight-fourcc YUYV``: uncompressed 4:2:2, converted by OpenCV;
* ``http_mjpg_q95``, ``http_mjpg_q100`` — ``--camera-transport http``: the same camera as MJPEG
  over HTTP, read by ``HttpCameraSource``.

Each variant runs ``--repeats`` times (default 3), each run on a rehearsal of its own (a jig without
homing takes its position at connection as zero, so a second run on one rehearsal would start where the
first left the stage), the variants taking turns so that the machine's load falls on all alike; the rows
give each run and their mean. Also each variant's delivered frame rate (``tactile-rig camera fps``, 3 s), and what the console
script's re-execution costs (``tactile-rig camera list --bench`` on a V4L2 rehearsal, median of 8,
against the same command started with the cameras' environment).

    python benchmarks/bench_rehearsal.py [--quick] [--repeats N] [--save | --out PATH]

Prints a table; ``--save`` writes ``benchmarks/results/rehearsal.json`` (full runs only). ``--quick``
runs a reduced sweep (rotations −90..90 in 30° steps, shifts −6..6 in 3 mm steps) once. Real time: a
full run takes about ten minutes; timings depend on the machine's load (printed).
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from _output import add_save_args, parse_args, save_json  # noqa: E402  (benchmarks/ is the script's folder)

from tactile_rig.rig.jig_accuracy import JigAccuracyConfig, execute_jig_accuracy, mock_gelsight_calibration
from tactile_rig.rig.rehearsal import RehearsalBench, RehearsalOptions

KEYS = ("n_points", "n_refused", "extra_touches", "rotation_mae_deg", "rotation_std_deg", "translation_mae_mm",
        "translation_std_mm")
VARIANTS: dict[str, dict[str, Any]] = {
    "v4l2_mjpg_q95": {},
    "v4l2_mjpg_q100": {"gelsight_jpeg_quality": 100},
    "v4l2_yuyv": {"gelsight_fourcc": "YUYV"},
    "http_mjpg_q95": {"camera_transport": "http"},
    "http_mjpg_q100": {"camera_transport": "http", "gelsight_jpeg_quality": 100},
}
QUICK = {"rotations_deg": (-90.0, 90.0, 30.0), "shifts_mm": (-6.0, 6.0, 3.0)}


def _tactile_rig(*argv: str, verdict: bool = False) -> dict[str, Any]:
    """The console script's last JSON line (the command a lab runs, re-executing with the cameras' library);
    with ``verdict`` a failed verdict (exit 1, e.g. ``camera fps`` below its bar) still gives its line."""
    script = shutil.which("tactile-rig", path=os.path.dirname(sys.executable)) or "tactile-rig"
    done = subprocess.run([script, *argv], capture_output=True, text=True, timeout=900)
    if done.returncode != 0 and not (verdict and done.returncode == 1 and done.stdout.strip()):
        raise RuntimeError(f"tactile-rig {' '.join(argv)} exited with {done.returncode}: {done.stderr[-2000:]}")
    return json.loads(done.stdout.splitlines()[-1])


def _reexec_cost(bench: str, env: dict[str, str], n: int = 8) -> dict[str, float]:
    """Median wall time of ``tactile-rig camera list --bench`` that re-executes itself with the cameras'
    library, and of one started with it already (the difference is what the re-execution costs)."""
    script = shutil.which("tactile-rig", path=os.path.dirname(sys.executable)) or "tactile-rig"
    plain = {k: v for k, v in os.environ.items() if k not in env}

    def median_s(environ: dict[str, str]) -> float:
        times = []
        for _ in range(n):
            t0 = time.perf_counter()
            subprocess.run([script, "camera", "list", "--bench", bench, "--json"], env=environ, capture_output=True,
                           check=True, timeout=120)
            times.append(time.perf_counter() - t0)
        return statistics.median(times)

    reexec, started = median_s(plain), median_s({**plain, **env})
    return {"reexec_s": round(reexec, 3), "started_with_env_s": round(started, 3),
            "difference_s": round(reexec - started, 3)}


def _refused(points: Path) -> list[dict[str, Any]]:
    """The points of a run that were not localized: index, commanded pose, touches and the reason."""
    out = []
    for line in points.read_text(encoding="utf-8").splitlines():
        r = json.loads(line)
        if r.get("type") == "point" and not r.get("ok"):
            out.append({"index": r["index"], "commanded": r["commanded"], "touches": r["touches"],
                        "reason": r["reason"]})
    return out


def _sweep_args(cfg: JigAccuracyConfig) -> list[str]:
    return ["--rotations", *map(str, cfg.rotations_deg), "--shifts", *map(str, cfg.shifts_mm), "--seed", str(cfg.seed)]


def _mean_row(variant: str, runs: list[dict[str, Any]]) -> dict[str, Any]:
    row: dict[str, Any] = {"variant": variant, "runs": len(runs)}
    for k in KEYS + ("wall_s",):
        row[k] = statistics.fmean(r[k] for r in runs)
    for k in ("rotation_mae_deg", "translation_mae_mm", "n_refused"):
        row[f"{k}_runs"] = [r[k] for r in runs]
    row["refused_runs"] = [r["refused"] for r in runs]
    return row


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="reduced sweep, one run per variant")
    ap.add_argument("--repeats", type=int, default=3, help="runs per rehearsal variant (default 3)")
    add_save_args(ap, "rehearsal.json")
    args = parse_args(ap)
    repeats = 1 if args.quick else max(1, args.repeats)
    cfg = JigAccuracyConfig(seed=0, **(QUICK if args.quick else {}))
    rows: list[dict[str, Any]] = []
    cameras: dict[str, dict[str, Any]] = {}
    reexec: dict[str, float] = {}
    loads: list[float] = []  # the 1-minute load average after each rehearsal run
    with tempfile.TemporaryDirectory(prefix="br-") as tmp:
        cal = mock_gelsight_calibration(Path(tmp) / "cal" / "gelsight", seed=0)
        t0 = time.perf_counter()
        s = execute_jig_accuracy(cfg, Path(tmp) / "mock", calibration=cal, record=False, report=False).summary
        rows.append({"variant": "mock", "runs": 1, **{k: s[k] for k in KEYS},
                     "wall_s": round(time.perf_counter() - t0, 2)})
        # The variants take turns (variant after variant, repeat after repeat), so a change in the
        # machine's load falls on all alike. Each run has a rehearsal of its own: a GRBL jig without
        # homing takes the stage's position as its zero when its port opens, and a run ends at its last
        # point (x = +6 mm), so a second run on one rehearsal would start 6 mm off the first.
        runs: dict[str, list[dict[str, Any]]] = {v: [] for v in VARIANTS}
        failed: dict[str, list[str]] = {v: [] for v in VARIANTS}
        for k in range(repeats):
            for variant, extra in VARIANTS.items():
                opts = RehearsalOptions(seed=0, calibration=False, **extra)
                with RehearsalBench(Path(tmp) / f"{variant}-{k}", opts) as rb:
                    bench = str(rb.bench_path)
                    if k == 0:
                        cameras[variant] = _tactile_rig("camera", "fps", "--bench", bench, "--camera",
                                                        "camera_gelsight", "--duration", "3", "--json", verdict=True)
                        if variant == "v4l2_mjpg_q95":
                            reexec = _reexec_cost(bench, rb.env)
                    t0 = time.perf_counter()
                    try:
                        s = _tactile_rig("run", "jig-accuracy", "--bench", bench, *_sweep_args(cfg), "--calibration",
                                         str(cal), "--out", str(Path(tmp) / f"run-{variant}-{k}"), "--overwrite",
                                         "--no-record", "--no-report", "--json")
                    except RuntimeError as exc:  # reported in the row and the table, not averaged
                        failed[variant].append(str(exc).splitlines()[-1][-300:])
                        print(f"{variant} run {k + 1}/{repeats} FAILED: {failed[variant][-1]}", flush=True)
                        continue
                    runs[variant].append({**{key: s[key] for key in KEYS},
                                          "wall_s": round(time.perf_counter() - t0, 2),
                                          "refused": _refused(Path(s["out"]) / "points.jsonl")})
                    loads.append(os.getloadavg()[0])
                    print(f"{variant} run {k + 1}/{repeats}: rotation MAE {s['rotation_mae_deg']:.3f} deg, "
                          f"translation MAE {s['translation_mae_mm']:.4f} mm, {s['n_refused']} refused", flush=True)
        for variant in VARIANTS:
            if runs[variant]:
                rows.append({**_mean_row(variant, runs[variant]), "failed": failed[variant]})
    load = round(statistics.fmean(loads), 2) if loads else None
    save_json(args, {"quick": args.quick, "repeats": repeats, "load_average_1min": load,
                     "load_average_range": [min(loads), max(loads)] if loads else None, "rows": rows,
                     "cameras": cameras, "reexec": reexec}, indent=2)
    print(f"load average {load:.1f} ({min(loads):.1f}..{max(loads):.1f}) over the rehearsal runs"
          if load is not None else "load average unknown")
    print(f"{'variant':<16} {'runs':>4} {'pts':>4} {'ref':>4} {'+tch':>5} {'rot MAE°':>9} {'rot std°':>9} "
          f"{'tra MAE mm':>10} {'tra std mm':>10} {'wall s':>7}  rotation MAE per run")
    for r in rows:
        per_run = ", ".join(f"{v:.3f}" for v in r.get("rotation_mae_deg_runs", []))
        print(f"{r['variant']:<16} {r['runs']:>4} {r['n_points']:>4.0f} {r['n_refused']:>4.0f} "
              f"{r['extra_touches']:>5.1f} {r['rotation_mae_deg']:>9.3f} {r['rotation_std_deg']:>9.3f} "
              f"{r['translation_mae_mm']:>10.4f} {r['translation_std_mm']:>10.4f} {r['wall_s']:>7.2f}  {per_run}")
        for f in r.get("failed", []):
            print(f"{'':<16} failed run: {f}")
    print(f"tactile-rig camera list --bench: {reexec['reexec_s']} s re-executing itself, "
          f"{reexec['started_with_env_s']} s started with the cameras' environment")
    for variant, m in cameras.items():
        print(f"{variant:<16} camera: {m['host_fps']} fps delivered ({m['configured_fps']} configured), "
              f"{m['duplicates']} duplicates, longest gap {m['max_gap_s'] * 1000:.0f} ms")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
