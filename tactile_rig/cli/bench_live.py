"""Live perception from a bench camera for ``fingervision track --bench`` and ``gelsight height --bench``,
and the ``--live`` arguments every live-capable command shares.

    tactile-rig fingervision track --bench bench.toml [--camera NAME] [--duration S] [--live] [--record OUT.mcap]
    tactile-rig gelsight height --bench bench.toml [CALIB] [--camera NAME] [--duration S] [--live] [-o OUT.npy]

``--live`` serves and ``--record`` records the same typed messages (the frame, the step's result and
its views: markers, arrows and wrench; the height map as a point cloud; the localized pose).

Each frame prints one line (or one JSON object with --json) with the measured frame rate and the
processing time; a summary follows.
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from tactile_rig.cli.args import COUNT, DURATION_S, float_in, int_in, output_file
from tactile_rig.cli.bench_args import add_bench_arguments, bench_from_args
from tactile_rig.cli.common import print_json
from tactile_rig.perception.gelsight import IntegrationParams
from tactile_rig.rig.bench_camera import camera_name
from tactile_rig.rig.camera_calibrations import camera_calibrations, describe_files
from tactile_rig.rig.live import DEFAULT_LIVE_PORT, LiveServer, Tee
from tactile_rig.rig.recording import Recorder, camera_topic
from tactile_rig.rig.live_perception import (
    FingerVisionStep,
    GelSightHeightStep,
    GelSightLocalizeStep,
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
    parser.add_argument("--live-port", type=int_in(0, 65535), default=DEFAULT_LIVE_PORT, metavar="PORT",
                        help=f"port of the live view (default {DEFAULT_LIVE_PORT}; 0: any free port, printed)")
    parser.add_argument("--live-wait", type=float_in(0.0, 3600.0, "s"), default=0.0, metavar="S",
                        help="with --live: wait up to S s for a viewer to subscribe before starting (default 0)")


# What a jig accuracy run publishes (the camera's topics depend on its name).
JIG_ACCURACY_TOPICS = {"/perception/jig_accuracy_point": "tactile_rig.Perception",
                       "/perception/tactile_map_touch": "tactile_rig.Perception",
                       "/jig/pose": "tactile_rig.JigPose", "/tf": "foxglove.FrameTransforms",
                       "/command/jig": "tactile_rig.Command", "/log": "foxglove.Log"}


def step_topics(camera: str, step: str) -> dict[str, str]:
    """The topics (-> schema) a live perception step publishes for ``camera``."""
    topics = {camera_topic(camera, compressed=True): "foxglove.CompressedImage",
              f"/perception/{camera}/{step}": "tactile_rig.Perception"}
    if step == "fingervision":
        topics.update({f"/{camera}/markers": "foxglove.ImageAnnotations",
                       f"/{camera}/marker_arrows": "foxglove.SceneUpdate", f"/{camera}/wrench": "tactile_rig.Wrench"})
    elif step == "height":
        topics[f"/{camera}/height/points"] = "foxglove.PointCloud"
    elif step == "localize":
        topics[f"/{camera}/localize/pose"] = "foxglove.PoseInFrame"
    return topics

SESSION_TOPIC = "/session"  # advertised at once so a viewer can subscribe before the session's own topics exist


def live_from_args(args: argparse.Namespace, clock: Any = None,
                   topics: Mapping[str, str] | tuple[str, ...] | None = None) -> LiveServer | None:
    """The live server ``--live`` asks for (its URL printed on stderr), or None.

    ``topics`` (topic → schema; a tuple means ``tactile_rig.Perception``) are advertised at once, so a
    viewer can subscribe before the session publishes on them; with ``--live-wait S`` the session
    waits up to S s for a viewer subscribed to all of them (or, without ``topics``, to anything)."""
    if not getattr(args, "live", False):
        return None
    live = LiveServer(port=args.live_port, clock=clock)
    print(f"live view: {live.url} (Foxglove: Open connection -> Foxglove WebSocket)", file=sys.stderr, flush=True)
    if isinstance(topics, tuple):
        topics = dict.fromkeys(topics, "tactile_rig.Perception")
    wanted = dict(topics or {SESSION_TOPIC: "tactile_rig.Json"})
    for topic, schema in wanted.items():
        live.advertise(topic, schema)
    if args.live_wait > 0:
        live.wait_for_subscriber(args.live_wait, set(wanted) if topics else None)
    return live


def add_bench_camera_arguments(parser: argparse.ArgumentParser) -> None:
    """What a perception command needs to run live from a bench camera."""
    add_bench_arguments(parser)
    parser.add_argument("--camera", metavar="NAME", help="which camera of the bench (default: the first of the sensor)")
    parser.add_argument("--duration", type=DURATION_S, metavar="S", help="stop after S seconds (default: at Ctrl-C)")
    parser.add_argument("--frames-max", dest="frames_max", type=COUNT, metavar="N", help="stop after N frames")
    parser.add_argument("--record", metavar="OUT.mcap", type=output_file(".mcap"),
                        help="also record what the live view shows (frames, results, markers, point clouds) to an MCAP")
    add_live_arguments(parser)


def wants_bench(args: argparse.Namespace, *files: str) -> bool:
    """True when the command runs live from a bench: ``--bench``/``--mock`` given, or none of its file
    arguments ``files`` given and ``$TACTILE_RIG_BENCH`` set."""
    if getattr(args, "bench", None) or getattr(args, "mock", False):
        return True
    return bool(os.environ.get("TACTILE_RIG_BENCH")) and not any(getattr(args, f, None) for f in files)


def _run(args: argparse.Namespace, step: Any, sensor: str, line: Any) -> int:
    bench = bench_from_args(args)
    cam = camera_name(bench, args.camera, sensor)
    live = live_from_args(args, topics=step_topics(cam, step.name))
    out = getattr(args, "record", None)
    recorder = None
    if out:
        try:
            recorder = Recorder(out)
            recorder.add_bench(bench)
        except BaseException:
            if live is not None:
                live.close()
            raise
    sink = Tee(recorder, live) if recorder is not None else live
    as_json = bool(getattr(args, "json", False))

    def on_frame(row: dict[str, Any]) -> None:
        text = line(row)
        if as_json:
            print_json(row)
        else:
            print(f"{row['frame']:5d} {row['fps']:6.2f} fps {row['work_ms']:6.1f} ms  {text}", flush=True)

    try:
        s = run_live(bench, cam, step, sensor=sensor, duration_s=args.duration, max_frames=args.frames_max,
                     live=sink, on_frame=on_frame,
                     publish_image=(lambda img: None if step.last is None else height_image(step.last))
                     if isinstance(step, GelSightHeightStep)
                     else None)
    finally:
        if recorder is not None:
            recorder.close()
        if live is not None:
            live.close()
    if recorder is not None and not as_json:
        print(f"recorded to {recorder.path}", file=sys.stderr)
    if as_json:
        print_json({"summary": True, **vars(s), **({"recording": str(recorder.path)} if recorder is not None else {})})
    else:
        print(f"{s.camera}: {s.frames} frames in {s.duration_s:.2f} s, {s.fps:.2f} fps, {s.step} {s.work_ms:.1f} ms/frame")
    return 0 if s.frames else 1


def track(args: argparse.Namespace, params: Any) -> int:
    """``fingervision track --bench``: live tracking from the bench's FingerVision camera, from the
    camera's stored baseline and in newtons through its force map when the bench names them."""

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
    knobs = {k: v for k in ("solver", "downsample", "lookup") if (v := getattr(args, k, None))}
    step = GelSightHeightStep(gelsight_calibration_for(bench, cam, args.calib),
                              integration=IntegrationParams(**knobs) if knobs else None)
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


def localize(args: argparse.Namespace, tactile_map: Any) -> int:
    """``gelsight localize MAP --bench``: each live frame of the bench's GelSight camera localized in
    ``tactile_map``; exit 1 when the last frame was refused."""
    bench = bench_from_args(args)
    cam = args.camera or next((k for k, c in bench.cameras.items() if c.sensor == "gelsight"), None)
    if cam is None:
        raise ValueError(f"{bench.source}: no camera with sensor = \"gelsight\"")
    step = GelSightLocalizeStep(gelsight_calibration_for(bench, cam, args.calib), tactile_map)
    args.camera = cam
    last: dict[str, Any] = {}

    def line(r: dict[str, Any]) -> str:
        last.update(r)
        if not r["ok"]:
            return f"refused: {r['reason']} (confidence {r['confidence']:.3f})"
        t = r["translation_mm"]
        return (f"rotation {r['rotation_deg']:+.3f} deg  translation ({t[0]:+.4f}, {t[1]:+.4f}) mm  "
                f"confidence {r['confidence']:.4f}  {r['method']}")

    rc = _run(args, step, "gelsight", line)
    return rc if rc else (0 if last.get("ok") else 1)


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
    live = live_from_args(args, topics={f"/perception/{stem}/trace": "tactile_rig.Perception",
                                        f"/perception/{stem}/episode": "tactile_rig.Perception"})
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
