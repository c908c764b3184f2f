"""Live perception from a bench camera for ``fingervision track --bench`` and ``gelsight height --bench``,
and the ``--live`` arguments every live-capable command shares.

    tactile-rig fingervision track --bench bench.toml [--camera NAME] [--duration S] [--live]
    tactile-rig gelsight height --bench bench.toml [CALIB] [--camera NAME] [--duration S] [--live] [-o OUT.npy]

Each frame prints one line (or one JSON object with --json) with the measured frame rate and the
processing time; a summary follows.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

import numpy as np

from tactile_rig.cli.bench_args import add_bench_arguments, bench_from_args
from tactile_rig.cli.common import print_json
from tactile_rig.rig.camera_calibrations import camera_calibrations, describe_files
from tactile_rig.rig.live import DEFAULT_LIVE_PORT, LiveServer
from tactile_rig.rig.live_perception import (
    FingerVisionStep,
    GelSightHeightStep,
    gelsight_calibration_for,
    height_image,
    run_live,
)
from tactile_rig.rig.scene_runner import run_episode, summarize
from tactile_rig.sim.scenes import resolve_scene_path


def add_live_arguments(parser: argparse.ArgumentParser) -> None:
    """``--live`` / ``--live-port`` (the Foxglove WebSocket live view on 127.0.0.1)."""
    parser.add_argument("--live", action="store_true",
                        help=f"serve the session live over the Foxglove WebSocket protocol on 127.0.0.1 "
                             f"(ws://127.0.0.1:{DEFAULT_LIVE_PORT} in Foxglove; needs tactile-rig[live])")
    parser.add_argument("--live-port", type=int, default=DEFAULT_LIVE_PORT, metavar="PORT",
                        help=f"port of the live view (default {DEFAULT_LIVE_PORT}; 0: any free port, printed)")
    parser.add_argument("--live-wait", type=float, default=0.0, metavar="S",
                        help="with --live: wait up to S s for a viewer to subscribe before starting (default 0)")


SESSION_TOPIC = "/session"  # advertised at once so a viewer can subscribe before the session's own topics exist


def live_from_args(args: argparse.Namespace, clock: Any = None,
                   topics: tuple[str, ...] | dict[str, str] = ()) -> LiveServer | None:
    """The live server ``--live`` asks for (its URL printed on stderr), or None. With ``--live-wait``
    it waits for a viewer to subscribe to ``topics`` (advertised first: a dict gives each topic's schema,
    a tuple means ``tactile_rig.Perception``), or to anything."""
    if not getattr(args, "live", False):
        return None
    if args.live_wait < 0:
        raise ValueError(f"--live-wait {args.live_wait} must be >= 0 s")
    live = LiveServer(port=args.live_port, clock=clock)
    print(f"live view: {live.url} (Foxglove: Open connection -> Foxglove WebSocket)", file=sys.stderr, flush=True)
    if args.live_wait > 0 and not topics:
        live.advertise(SESSION_TOPIC)
        live.wait_for_subscriber(args.live_wait)
    elif args.live_wait > 0:
        schemas = topics if isinstance(topics, dict) else dict.fromkeys(topics, "tactile_rig.Perception")
        for t, schema in schemas.items():
            live.advertise(t, schema)
        live.wait_for_subscriber(args.live_wait, set(topics))
    return live


def add_bench_camera_arguments(parser: argparse.ArgumentParser) -> None:
    """What a perception command needs to run live from a bench camera."""
    add_bench_arguments(parser)
    parser.add_argument("--camera", metavar="NAME", help="which camera of the bench (default: the first of the sensor)")
    parser.add_argument("--duration", type=float, metavar="S", help="stop after S seconds (default: at Ctrl-C)")
    parser.add_argument("--frames-max", dest="frames_max", type=int, metavar="N", help="stop after N frames")
    add_live_arguments(parser)


def wants_bench(args: argparse.Namespace) -> bool:
    """True when the command was given a bench (``--bench``/``--mock``) and runs live."""
    return bool(getattr(args, "bench", None) or getattr(args, "mock", False))


def _run(args: argparse.Namespace, step: Any, sensor: str, line: Any) -> int:
    bench = bench_from_args(args)
    live = live_from_args(args)
    as_json = bool(getattr(args, "json", False))

    def on_frame(row: dict[str, Any]) -> None:
        if as_json:
            print_json(row)
        else:
            print(f"{row['frame']:5d} {row['fps']:6.2f} fps {row['work_ms']:6.1f} ms  {line(row)}", flush=True)

    try:
        s = run_live(bench, args.camera, step, sensor=sensor, duration_s=args.duration, max_frames=args.frames_max,
                     live=live, on_frame=on_frame,
                     publish_image=(lambda img: height_image(step.last)) if isinstance(step, GelSightHeightStep)
                     else None)
    finally:
        if live is not None:
            live.close()
    if as_json:
        print_json({"summary": True, **vars(s)})
    else:
        print(f"{s.camera}: {s.frames} frames in {s.duration_s:.2f} s, {s.fps:.2f} fps, {s.step} {s.work_ms:.1f} ms/frame")
    return 0 if s.frames else 1


def track(args: argparse.Namespace, params: Any) -> int:
    """``fingervision track --bench``: live tracking from the bench's FingerVision camera."""

    def line(r: dict[str, Any]) -> str:
        if r["calibrating"]:
            return f"calibrating ({r['marker_count']} markers)"
        f, unit = (r["force_n"], "N") if "force_n" in r else (r["force_px"], "px")
        return (f"{r['marker_count']:3d} markers  force ({f[0]:+.3f}, {f[1]:+.3f}, {f[2]:+.3f}) {unit}  "
                f"{'contact' if r['contact'] else 'free'}  {'SLIP' if r['slip'] else 'still'}")

    bench = bench_from_args(args)
    stored = not getattr(args, "no_calibration", False)
    cal = camera_calibrations(bench, args.camera, calibration=getattr(args, "calibration", None) if stored else None,
                              force_map=getattr(args, "force_map", None) if stored else None, defaults=False,
                              load=("calibration", "force_map") if stored else ())
    cfg = bench.cameras.get(cal.camera)
    step = FingerVisionStep(params, cal, mm_per_px=float(cfg.mm_per_px_x) if cfg is not None else None)
    if not getattr(args, "json", False):
        print(f"calibration: {describe_files(cal)}", flush=True)
    return _run(args, step, "fingervision", line)


def height(args: argparse.Namespace) -> int:
    """``gelsight height --bench``: live height maps from the bench's GelSight camera (the last one is
    saved to ``-o`` when given)."""
    bench = bench_from_args(args)
    cam = args.camera or next((k for k, c in bench.cameras.items() if c.sensor == "gelsight"), None)
    if cam is None:
        raise ValueError(f"{bench.source}: no camera with sensor = \"gelsight\"")
    step = GelSightHeightStep(gelsight_calibration_for(bench, cam, args.calib))
    args.camera = cam

    def line(r: dict[str, Any]) -> str:
        return f"max {r['max_height_mm']:.3f} mm at {tuple(r['peak_px'])}  contact {r['contact_area_mm2']:.2f} mm2"

    rc = _run(args, step, "gelsight", line)
    out = getattr(args, "output", None)
    if out and step.last is not None:
        target = Path(out) if Path(out).suffix == ".npy" else Path(out).with_suffix(".npy")
        target.parent.mkdir(parents=True, exist_ok=True)
        np.save(target, step.last)
        print(f"last height map: {target}", file=sys.stderr)
    return rc


def need_files(args: argparse.Namespace, *names: str) -> None:
    """Without a bench, the file arguments are required: a one-line error naming the first missing."""
    for n in names:
        if not getattr(args, n, None):
            raise ValueError(f"{n.replace('_', '-')} is required (or pass --bench FILE to run live from a camera)")


def scene_live(args: argparse.Namespace, show: Any) -> dict[str, Any]:
    """``scene run --live``: each episode's report on ``/perception/<scene>/episode`` and its controller
    trace on ``/perception/<scene>/trace``, one message per sample, episodes one after the other in
    simulated time. Returns the summary ``run_episodes`` would."""
    stem = resolve_scene_path(args.name).stem
    live = live_from_args(args, topics=(f"/perception/{stem}/trace", f"/perception/{stem}/episode"))
    assert live is not None
    reports = []
    t0 = 0.0
    try:
        for i in range(args.episodes):
            r = run_episode(args.name, args.seed + i, episode=i, speed_mps=args.speed_mps)
            name = r.scene
            if r.result is not None:
                live.write_trace(f"{name}/trace", r.result.trace, t0_s=t0)
            live.write_perception(f"{name}/episode", r.to_json(), t_s=t0 + r.sim_s)
            t0 += r.sim_s
            r.result = None
            reports.append(r)
            show(r)
    finally:
        live.close()
    return summarize(args.name, reports)
