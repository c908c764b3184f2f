"""``tactile-rig fingervision track FRAMES_OR_VIDEO``: run the FingerVision processor over recorded frames.

FRAMES may be a folder of images, a glob pattern or a video file. Markers get their ids on the first
frame (a lattice fit); the first ``n_calib_frames`` frames (no contact) refine their rest positions.
With ``--json`` one JSON object per frame is printed.

Exit codes: 0 done; 2 bad input (a missing file, a bad option, an undecodable image, frames of
different sizes) or no marker lattice in the first ``n_calib_frames`` frames (black, white, flat,
out-of-focus frames: ``MarkersNotFound``), one line on stderr.
"""

from __future__ import annotations

import argparse
import glob
import os
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from tactile_rig.cli import bench_live
from tactile_rig.cli.args import float_in, int_in
from tactile_rig.cli.common import add_command_group, add_json_flag, print_json
from tactile_rig.core.errors import MarkersNotFound
from tactile_rig.rig.files import check_file, check_image_dims, quiet_opencv
from tactile_rig.perception.fingervision import FingerVision, FingerVisionParams
from tactile_rig.rig.loaders import load_fingervision_params, read_frame
from tactile_rig.rig.bench import load_bench
from tactile_rig.rig.camera_calibrations import camera_calibrations, describe_files

_IMAGE_EXT = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".ppm", ".pgm")


def register(sub: argparse._SubParsersAction) -> None:
    _, fsub = add_command_group(sub, "fingervision", help="FingerVision perception over recorded frames")
    t = fsub.add_parser("track", help="track markers, force/torque, object and slip, frame by frame")
    t.add_argument("frames", nargs="?", help="folder of images, glob pattern (quote it) or video file "
                   "(or --bench: live from the bench's camera)")
    t.add_argument("--config", help="TOML or JSON file of FingerVisionParams (sections detector, tracker, force, proximity)")
    t.add_argument("--calib-frames", type=int_in(1, 100_000),
                   help="no-contact frames refining the markers' rest positions (ids exist from the first frame); "
                        "with --init frames, the baseline frames (overrides the config; default 10)")
    t.add_argument("--init", choices=("lattice", "frames"),
                   help="lattice (default): marker ids from the first frame; frames: the reference's scheme, ids only "
                        "after --calib-frames baseline frames (overrides the config)")
    t.add_argument("--fps", type=float_in(0.0, 100_000.0, "frames/s", low_open=True), help="frame rate, for timestamps t_s = index / fps (Kalman time step)")
    t.add_argument("--object-rect", type=int_in(0, 65535, "px"), nargs=4, metavar=("X", "Y", "W", "H"),
                   help="learn the object's colours from this rectangle (px) of the first frame after calibration")
    t.add_argument("--limit", type=int_in(1, 10**9), help="stop after this many frames")
    t.add_argument("--calibration", help="marker baseline (calibrate fingervision) to start from; default: the "
                   "bench camera's, else calib/fingervision.json when present")
    t.add_argument("--force-map", help="force map for newtons (calibrate force-map); default: the bench camera's, "
                   "else calib/force_map when present")
    t.add_argument("--no-calibration", action="store_true",
                   help="load no stored file: build the baseline from the first frames, forces in px")
    add_json_flag(t)
    bench_live.add_bench_camera_arguments(t)
    t.set_defaults(func=_track)


def load_params(path: str | None, calib_frames: int | None = None, init: str | None = None) -> FingerVisionParams:
    """FingerVisionParams from a TOML/JSON file (or the defaults), with the command line's overrides."""

    return load_fingervision_params(path, calib_frames, init)


def iter_frames(source: str) -> Iterator[tuple[str, np.ndarray]]:
    """Yield ``(name, frame_bgr)`` from a folder, a glob pattern or a video file, in order."""
    import cv2

    path = Path(source)
    if path.is_dir():
        files = sorted(p for p in path.iterdir() if p.suffix.lower() in _IMAGE_EXT)
        if not files:
            raise ValueError(f"{source}: folder holds no images ({', '.join(_IMAGE_EXT)})")
    elif any(c in source for c in "*?["):
        files = sorted(Path(p) for p in glob.glob(source) if Path(p).suffix.lower() in _IMAGE_EXT)
        if not files:
            raise ValueError(f"{source}: the pattern matches no images")
    elif path.is_file() and path.suffix.lower() in _IMAGE_EXT:
        files = [path]
    elif path.is_file():
        check_file(path, "video")
        with quiet_opencv():
            cap = cv2.VideoCapture(str(path))
        if not cap.isOpened():
            raise ValueError(f"{source}: not an image and OpenCV cannot open it as a video")
        check_image_dims(path, "video frame", int(cap.get(cv2.CAP_PROP_FRAME_WIDTH)) or 1,
                         int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT)) or 1)
        try:
            i = 0
            while True:
                ok, frame = cap.read()
                if not ok:
                    break
                yield f"{path.name}#{i}", frame
                i += 1
            if i == 0:
                raise ValueError(f"{source}: video has no decodable frames")
        finally:
            cap.release()
        return
    else:
        raise FileNotFoundError(f"{source}: no such folder, video or matching files")
    for f in files:
        yield f.name, read_frame(f)


def _record(i: int, name: str, r) -> dict[str, Any]:
    markers = [
        {"id": int(k), "x_px": float(p[0]), "y_px": float(p[1]), "size_px": float(s), "valid": bool(v), "found": bool(f)}
        for k, p, s, v, f in zip(r.marker_ids, r.marker_positions_px, r.marker_sizes_px, r.marker_valid, r.marker_found)
    ]
    return {
        "frame": i,
        "source": name,
        "t_s": r.t_s,
        "calibrating": r.calibrating,
        "marker_count": r.n_markers,
        "markers": markers,
        "force_px": r.force_px,
        "torque_px2": r.torque_px2,
        "slip": r.slip,
        "slip_magnitude_px": r.slip_magnitude_px,
        "slip_direction_deg": r.slip_direction_deg,
        "contact": r.contact,
        "object": {
            "area_px": r.object_area_px,
            "centroid_px": r.object_centroid_px,
            "orientation_deg": r.object_orientation_deg,
        },
        "timings_ms": r.timings_ms,
    }


def _track(args: argparse.Namespace) -> int:
    if bench_live.wants_bench(args, "frames"):
        return bench_live.track(args, load_params(args.config, args.calib_frames, args.init))
    bench_live.need_files(args, "frames")

    if args.object_rect is not None and (args.object_rect[2] < 1 or args.object_rect[3] < 1):
        raise ValueError(f"--object-rect: expected a width and height >= 1 px, got {args.object_rect[2:]}")
    fv = FingerVision(load_params(args.config, args.calib_frames, args.init))
    cal, mm_per_px = _calibrations(args)
    if cal.calibration is not None:
        cal.calibration.apply(fv)  # the stored baseline: no frames spent rebuilding it
    fm = cal.force_map
    if not args.json and cal.files:  # say which stored files the numbers come from (none: as before)
        print(f"calibration: {describe_files(cal)}")
    learnt = args.object_rect is None
    n = 0
    for i, (name, frame) in enumerate(iter_frames(args.frames)):
        if args.limit is not None and i >= args.limit:
            break
        if i == 0 and cal.calibration is not None:
            cal.calibration.check_frame(frame)
        if not learnt and fv.tracker is not None:
            fv.learn_object(frame, rects=[tuple(args.object_rect)])
            learnt = True
        r = fv.process(frame, None if args.fps is None else i / args.fps)
        if fv.tracker is None and i + 1 >= fv.params.n_calib_frames and (
                fv.params.init == "lattice" or i + 1 > fv.params.n_calib_frames):
            raise MarkersNotFound(
                f"{args.frames}: no marker lattice in the first {i + 1} frame(s) (frame {name}); expected dark "
                f"dots on the skin: the frames are black, white, flat or out of focus", device="fingervision")
        if fv.tracker is not None and fv.baseline is not None and not np.any(fv.baseline.valid):
            raise MarkersNotFound(f"{args.frames}: the baseline frames hold no stable marker", device="fingervision")
        rec = _record(i, name, r)
        if fm is not None and not r.calibrating:
            f_n, tq, mag = fm.to_newtons(r.force_px, r.torque_px2)
            rec.update(force_n=f_n, force_map_n=mag)
            rec["torque_nmm" if mm_per_px else "torque_npx"] = tq * (mm_per_px or 1.0)
        n += 1
        if args.json:
            print_json(rec)
        else:
            n_ids = int(np.count_nonzero(r.marker_ids >= 0))
            state = (f"{r.n_markers:3d} markers" if not r.calibrating else
                     f"{r.n_markers:3d} markers, refining" if n_ids else "calibrating")
            f = r.force_px
            obj = "no object" if r.object_centroid_px is None else (
                f"object {r.object_area_px:.0f} px2 at ({r.object_centroid_px[0]:.1f}, {r.object_centroid_px[1]:.1f})"
                + ("" if r.object_orientation_deg is None else f" {r.object_orientation_deg:+.1f} deg"))
            newtons = f"  {rec['force_map_n']:6.2f} N" if "force_map_n" in rec else ""
            print(f"{i:5d} {name:<24} {state}  force ({f[0]:+.2f}, {f[1]:+.2f}, {f[2]:+.2f}) px{newtons}  "
                  f"torque_z {r.torque_px2[2]:+.1f} px2  {'SLIP' if r.slip else 'still'}  {obj}")
    if n == 0:
        raise ValueError(f"{args.frames}: no frames")
    if fv.tracker is None:
        raise MarkersNotFound(f"{args.frames}: no marker lattice in any of the {n} frame(s); expected dark dots "
                              f"on the skin: the frames are black, white, flat or out of focus", device="fingervision")
    return 0


def _calibrations(args: argparse.Namespace) -> tuple[Any, float | None]:
    """The marker baseline and force map ``track`` uses on files: named on the command line, else by
    ``$TACTILE_RIG_BENCH`` for ``--camera``, else the sessions' default files (``--bench`` runs live:
    :func:`tactile_rig.cli.bench_live.track` loads the bench camera's)."""
    env_bench = os.environ.get("TACTILE_RIG_BENCH")
    bench = load_bench(env_bench, check_ports=False) if env_bench and not args.no_calibration else None
    camera = getattr(args, "camera", None)
    cal = camera_calibrations(bench, camera, calibration=None if args.no_calibration else args.calibration,
                              force_map=None if args.no_calibration else args.force_map,
                              defaults=not args.no_calibration,
                              load=() if args.no_calibration else ("calibration", "force_map"))
    cfg = bench.cameras.get(cal.camera) if bench is not None else None
    return cal, (float(cfg.mm_per_px_x) if cfg is not None else None)
