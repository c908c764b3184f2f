"""``tactile-rig fingervision track FRAMES_OR_VIDEO``: run the FingerVision processor over recorded frames.

FRAMES may be a folder of images, a glob pattern or a video file. The first ``n_calib_frames`` frames
(no contact) build the marker baseline. With ``--json`` one JSON object per frame is printed.
"""

from __future__ import annotations

import argparse
import glob
import json
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from tactile_rig.cli import bench_live
from tactile_rig.cli.common import add_json_flag, print_json
from tactile_rig.perception.fingervision import FingerVision, FingerVisionParams

_IMAGE_EXT = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".ppm", ".pgm")


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("fingervision", help="FingerVision perception over recorded frames")
    fsub = p.add_subparsers(dest="fv_command", metavar="ACTION")
    t = fsub.add_parser("track", help="track markers, force/torque, object and slip, frame by frame")
    t.add_argument("frames", nargs="?", help="folder of images, glob pattern (quote it) or video file "
                   "(or --bench: live from the bench's camera)")
    t.add_argument("--config", help="TOML or JSON file of FingerVisionParams (sections detector, tracker, force, proximity)")
    t.add_argument("--calib-frames", type=int, help="no-contact frames for the baseline (overrides the config)")
    t.add_argument("--fps", type=float, help="frame rate, for timestamps t_s = index / fps (Kalman time step)")
    t.add_argument("--object-rect", type=int, nargs=4, metavar=("X", "Y", "W", "H"),
                   help="learn the object's colours from this rectangle (px) of the first frame after calibration")
    t.add_argument("--limit", type=int, help="stop after this many frames")
    add_json_flag(t)
    bench_live.add_bench_camera_arguments(t)
    t.set_defaults(func=_track)
    p.set_defaults(func=lambda args: (p.print_help(), 2)[1])


def load_params(path: str | None, calib_frames: int | None = None):
    """FingerVisionParams from a TOML/JSON file (or the defaults)."""

    data: dict[str, Any] = {}
    if path:
        file = Path(path)
        if not file.is_file():
            raise FileNotFoundError(f"--config: no such file {path!r}")
        text = file.read_text(encoding="utf-8")
        if file.suffix.lower() == ".json":
            data = json.loads(text)
        else:
            import tomllib

            try:
                data = tomllib.loads(text)
            except tomllib.TOMLDecodeError as exc:
                raise ValueError(f"--config {path}: not valid TOML ({exc})") from exc
    if calib_frames is not None:
        data = {**data, "n_calib_frames": calib_frames}
    return FingerVisionParams.from_mapping(data)


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
        cap = cv2.VideoCapture(str(path))
        if not cap.isOpened():
            raise ValueError(f"{source}: not an image and OpenCV cannot open it as a video")
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
        frame = cv2.imread(str(f), cv2.IMREAD_COLOR)
        if frame is None:
            raise ValueError(f"{f}: cannot decode the image")
        yield f.name, frame


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
        return bench_live.track(args, load_params(args.config, args.calib_frames))
    bench_live.need_files(args, "frames")

    if args.fps is not None and not args.fps > 0:
        raise ValueError(f"--fps: expected > 0 frames/s, got {args.fps}")
    fv = FingerVision(load_params(args.config, args.calib_frames))
    learnt = args.object_rect is None
    n = 0
    for i, (name, frame) in enumerate(iter_frames(args.frames)):
        if args.limit is not None and i >= args.limit:
            break
        if not learnt and fv.tracker is not None:
            fv.learn_object(frame, rects=[tuple(args.object_rect)])
            learnt = True
        r = fv.process(frame, None if args.fps is None else i / args.fps)
        rec = _record(i, name, r)
        n += 1
        if args.json:
            print_json(rec)
        else:
            state = "calibrating" if r.calibrating else f"{r.n_markers:3d} markers"
            f = r.force_px
            obj = "no object" if r.object_centroid_px is None else (
                f"object {r.object_area_px:.0f} px2 at ({r.object_centroid_px[0]:.1f}, {r.object_centroid_px[1]:.1f})"
                + ("" if r.object_orientation_deg is None else f" {r.object_orientation_deg:+.1f} deg"))
            print(f"{i:5d} {name:<24} {state}  force ({f[0]:+.2f}, {f[1]:+.2f}, {f[2]:+.2f}) px  "
                  f"torque_z {r.torque_px2[2]:+.1f} px2  {'SLIP' if r.slip else 'still'}  {obj}")
    if n == 0:
        raise ValueError(f"{args.frames}: no frames")
    return 0
