"""Randomised episodes of every controller scene: property pass counts, simulated seconds per wall
second, and the collision-stop speed cap derived at measured sensing rates.

Side by side in one run:

* ``virtual``: each scene's episodes on a VirtualClock (the property runs; the counts in
  docs/controllers.md come from here);
* ``baseline real-time``: one episode of the jig collision scene on a RealClock over a pty (what a
  bench run costs: simulated time ≈ wall time), to show the speed-up virtual time buys;
* ``cap``: the collision cap from rates and latencies measured off the model sensor (8-240 Hz) and
  off the real-time pty run.

Usage: ``python benchmarks/bench_scenes.py [--quick] [--only SCENE ...] [--save | --out PATH]``; prints a
table; ``--save`` writes ``benchmarks/results/scenes.json``.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from _output import add_save_args, parse_args, save_json  # noqa: E402  (benchmarks/ is the script's folder)

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from tactile_rig.core.clock import RealClock, VirtualClock  # noqa: E402
from tactile_rig.control.protocols import TouchReading  # noqa: E402
from tactile_rig.control.safety import collision_speed_cap_mps, measure_sensing  # noqa: E402
from tactile_rig.sim.fakes.sensors import ModelSensor  # noqa: E402
from tactile_rig.rig.scene_runner import list_scenes, run_episodes  # noqa: E402

# Full-run episode counts (the "hundreds of episodes"); --quick runs a handful of each.
FULL = {
    "collision_stop": 300, "collision_stop_jig": 50, "handover": 200, "handover_no_release": 50,
    "handover_pass_by": 50, "handover_dynamixel": 30, "inhand_rotation_slip": 200, "inhand_rotation_torque": 50,
    "inhand_rotation_dynamixel": 20, "lift_effort": 100, "lift_effort_dynamixel": 20, "insertion": 108,
    "following_force": 50, "following_proximity": 50, "following_jig": 20, "torque_rotation": 200,
    "torque_rotation_jig": 20, "stick_assembly": 50, "stick_assembly_hx711": 10,
    "following_proximity_rendered": 10,
}
FAULTS_FULL = 30


def cap_table() -> list[dict]:
    rows = []
    for rate in (8.0, 16.0, 30.0, 60.0, 120.0, 240.0):
        for latency in (0.0, 0.03):
            clock = VirtualClock()
            sensor = ModelSensor(clock, lambda t: TouchReading(t), rate_hz=rate, latency_s=latency)
            m = measure_sensing(sensor, clock, n_frames=10)
            rows.append({"rate_hz": rate, "latency_s": latency, "measured_rate_hz": round(m.rate_hz, 3),
                         "measured_latency_s": round(m.latency_s, 4),
                         "cap_mps": round(collision_speed_cap_mps(1.0, m.rate_hz, m.latency_s), 5)})
    return rows


def baseline_real_time() -> dict:
    from tactile_rig.rig.scene_runner import run_episode

    t0 = time.perf_counter()
    r = run_episode("collision_stop_jig", 3, clock=RealClock(),
                    overrides={"controller": {"transport": "pty"}, "wall": {"point_mm": [3.0, 0.0, 0.0]}})
    wall = time.perf_counter() - t0
    return {"scene": "collision_stop_jig (pty, RealClock)", "ok": r.ok, "sim_s": round(r.sim_s, 3),
            "wall_s": round(wall, 3), "sim_per_wall": round(r.sim_s / wall, 3),
            "measured_rate_hz": r.figures["sensing_rate_hz"], "measured_latency_s": r.figures["latency_s"],
            "cap_mps_at_measured": r.figures["cap_mps"], "overtravel_mm": r.figures["overtravel_mm"]}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="a few episodes per scene")
    ap.add_argument("--only", nargs="*", help="run only these scenes")
    add_save_args(ap, "scenes.json")
    args = parse_args(ap)
    if args.only and args.save:
        ap.error("--save with --only would replace the full run's scenes.json with some scenes; use --out PATH")
    scenes = [s["name"] for s in list_scenes()]
    if args.only:
        scenes = [s for s in scenes if s in args.only]
    rows = []
    for name in scenes:
        n = 3 if args.quick else FULL.get(name, FAULTS_FULL)
        s = run_episodes(name, 0, n)
        rows.append(s)
        print(f"{name:<30} {s['ok']:>4}/{s['episodes']:<4} ok  {s['sim_s']:>9.1f} s sim  {s['wall_s']:>7.2f} s wall"
              f"  {s['sim_per_wall']:>7.1f}x  {s['outcomes']}", flush=True)
    caps = cap_table()
    print("\ncollision cap (1 mm allowed overtravel) at measured sensing:")
    for c in caps:
        print(f"  {c['rate_hz']:>6.0f} Hz  latency {c['latency_s'] * 1000:>4.0f} ms  ->  {c['cap_mps']:.4f} m/s")
    base = baseline_real_time()
    print(f"\nbaseline (real time over a pty): {base['sim_s']} s simulated in {base['wall_s']} s wall "
          f"({base['sim_per_wall']}x), measured {base['measured_rate_hz']:.1f} Hz / "
          f"{base['measured_latency_s'] * 1000:.1f} ms -> cap {base['cap_mps_at_measured']:.4f} m/s")
    slowest = min((r["sim_per_wall"] or 0) for r in rows) if rows else None
    out = {"quick": args.quick, "scenes": rows, "collision_cap": caps, "baseline_real_time": base,
           "min_sim_per_wall": slowest}
    print(f"\nslowest scene: {slowest}x real time")
    save_json(args, out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
