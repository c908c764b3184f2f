"""``tactile-rig substance predict``: which substance is being stirred, from the learned classifier.

The model is the one the bench names for the camera (``substance_model``), else ``--model``, else
``calib/substance`` (what ``tactile-rig calibrate substance`` writes; the stable name reads the
newest version). The marker series comes from a recording (``--from-recording``: every trial in it)
or from frames (a folder, glob or video, tracked with the stored marker baseline at ``--fps``).

    tactile-rig substance predict --from-recording stir.mcap --json
    tactile-rig substance predict frames/ --fps 30 --model calib/substance
"""

from __future__ import annotations

import argparse
import os
from typing import Any

import numpy as np

from tactile_rig.cli.args import float_in
from tactile_rig.cli.common import add_command_group, add_json_flag, extras_as_errors, print_json
from tactile_rig.cli.fingervision import iter_frames
from tactile_rig.perception.fingervision import FingerVision
from tactile_rig.rig.bench import load_bench
from tactile_rig.rig.camera_calibrations import camera_calibrations
from tactile_rig.rig.learning import predict_substance, stirring_series_from_recording


def register(sub: argparse._SubParsersAction) -> None:
    _, ssub = add_command_group(sub, "substance", help="predict the stirred substance with the learned classifier")
    pr = ssub.add_parser("predict", help="classify a stirring recording or frames, window by window")
    pr.add_argument("frames", nargs="?", help="folder of images, glob pattern or video (else --from-recording)")
    pr.add_argument("--from-recording", metavar="FILE.mcap", help="marker forces recorded on /perception/<camera>")
    pr.add_argument("--camera", help="camera (bench table / perception topic) to use")
    pr.add_argument("--bench", help="bench.toml naming the camera's substance_model (default: $TACTILE_RIG_BENCH)")
    pr.add_argument("--model", help="substance model (.json, .npz or folder); default: the bench's, else "
                                    "calib/substance")
    pr.add_argument("--fps", type=float_in(0.0, 100_000.0, "frames/s", low_open=True), help="frame rate of FRAMES in frames/s (required with FRAMES)")
    pr.add_argument("--window", type=float_in(0.0, 3600.0, "s", low_open=True), help="feature window in s (default: the model's)")
    add_json_flag(pr)
    pr.set_defaults(func=_predict)


@extras_as_errors
def _predict(args: argparse.Namespace) -> int:
    if (args.frames is None) == (args.from_recording is None):
        raise ValueError("substance predict needs FRAMES or --from-recording FILE.mcap (one of them)")
    bench_path = args.bench or os.environ.get("TACTILE_RIG_BENCH")
    bench = load_bench(bench_path, check_ports=False) if bench_path else None
    cal = camera_calibrations(bench, args.camera, substance_model=args.model,
                              load=("substance_model",) if args.from_recording else ("calibration", "substance_model"))
    if cal.substance is None:
        raise ValueError("no substance model: pass --model, name substance_model in the bench's camera table, "
                         "or make calib/substance with: tactile-rig calibrate substance")
    if args.from_recording:
        series = stirring_series_from_recording(args.from_recording, camera=args.camera)
    else:
        if args.fps is None:
            raise ValueError("--fps is required with FRAMES (their frame rate in frames/s)")
        series = [{"trial": None, "label": None, "series": _series_from_frames(args, cal), "rate_hz": args.fps}]
    results = []
    for item in series:
        res = predict_substance(cal.substance, item["series"], item["rate_hz"], window_s=args.window)
        results.append({"trial": item["trial"], "true_label": item["label"], **res})
    if args.json:
        print_json({"model": cal.files.get("substance_model"), "classes": cal.substance.classes, "trials": results})
    else:
        print(f"model: {cal.files.get('substance_model')} (classes {', '.join(cal.substance.classes)})")
        for r in results:
            who = "series" if r["trial"] is None else f"trial {r['trial']}"
            truth = f" (recorded as {r['true_label']})" if r["true_label"] else ""
            print(f"{who}: {r['substance']}  {r['agreement']:.0%} of {r['windows']} windows{truth}")
    return 0


def _series_from_frames(args: argparse.Namespace, cal: Any) -> np.ndarray:
    """Track the frames with the stored baseline (or the first frames') → (fx, fy, tz) px per frame."""
    fv = FingerVision()
    if cal.calibration is not None:
        cal.calibration.apply(fv)
    rows = []
    for i, (_, frame) in enumerate(iter_frames(args.frames)):
        r = fv.process(frame, i / args.fps)
        if not r.calibrating:
            rows.append([r.force_px[0], r.force_px[1], r.torque_px2[2]])
    if not rows:
        raise ValueError(f"{args.frames}: no tracked frames (all used to build the marker baseline)")
    return np.asarray(rows, float)
