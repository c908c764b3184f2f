"""``tactile-rig gelsight``: calibrate from ball presses, height maps, registration, tactile maps.

Exit codes: 0 done; 1 a failed verdict (``register``/``localize`` refused the touch, ``map`` rejected
at least one touch; the JSON says why); 2 bad input (a missing file, a frame the calibration cannot read:
saturated, colours beyond its range, heights no gel shows, one line naming the reason).
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path
from typing import Any, Callable

import numpy as np

from tactile_rig.cli import bench_live
from tactile_rig.cli.args import float_in, int_in, output_dir, output_file
from tactile_rig.cli.common import EXIT_FAILED, add_command_group, add_json_flag, print_json
from tactile_rig.core.memory import keep_freed_memory
from tactile_rig.rig.loaders import (
    load_gelsight_calibration,
    load_height_mm,
    load_press_folder,
    load_tactile_map,
    read_frame,
)
from tactile_rig.perception.gelsight import (
    ACCEPT_CONFIDENCE,
    GelSightCalibration,
    IntegrationParams,
    Reconstructor,
    RegistrationParams,
    TactileMap,
    calibrate_from_presses,
    cross_validate,
)
from tactile_rig.perception.gelsight import register as register_heights


def _load_height(path: str) -> np.ndarray:
    return load_height_mm(path)


def _read_image(path: str) -> np.ndarray:
    return read_frame(path)


def _reconstructor(calib: str, background: str | None, solver: str | None = None, downsample: int | None = None,
                   lookup: str | None = None):

    cal = load_gelsight_calibration(calib)
    if background:
        bg = _read_image(background)
        cal = GelSightCalibration(cal.model, bg, cal.mm_per_px_x, cal.mm_per_px_y, cal.ball_radius_mm,
                                  cal.sensor, cal.date, cal.bake_bins, cal.bake_cells, cal.colour_range, cal.extra)
    knobs: dict[str, object] = {}
    if solver:
        knobs["solver"] = solver
    if downsample:
        knobs["downsample"] = downsample
    if lookup:
        knobs["lookup"] = lookup
    return Reconstructor(cal, IntegrationParams(**knobs) if knobs else None)  # type: ignore[arg-type]


def _height_or_image(path: str, calib: str | None, background: str | None) -> np.ndarray:
    if path.endswith(".npy"):
        return _load_height(path)
    if not calib:
        raise ValueError(f"{path} is an image: pass --calib CALIB to turn it into a height map")
    return _reconstructor(calib, background).height_mm(_read_image(path))


def _cmd_calibrate(args: argparse.Namespace) -> int:

    presses = load_press_folder(args.press_dir)
    hyper = {"bins": args.bins} if args.method == "lut" else {}
    cal = calibrate_from_presses(presses, args.mm_per_px, args.ball_radius_mm, args.method,
                                 sensor=args.sensor, **hyper)
    path = cal.save(args.output)
    out: dict = {"calibration": str(path), "method": args.method, "presses": len(presses.frames),
                 "mm_per_px_x": cal.mm_per_px_x, "mm_per_px_y": cal.mm_per_px_y}
    if args.report:
        rep = cross_validate(presses, args.mm_per_px, args.ball_radius_mm, args.method, folds=args.folds, **hyper)
        out.update({"held_out_normal_deg": rep.mean_normal_deg, "held_out_height_rms_mm": rep.mean_height_rms_mm,
                    "colour_coverage": rep.colour_coverage, "protocol": rep.protocol})
    if args.json:
        print_json(out)
    else:
        for k, v in out.items():
            print(f"{k}: {v}")
    return 0


def _npy_writer(shape: tuple[int, ...], dtype: type[np.generic] | np.dtype) -> Callable[[Path | str, np.ndarray], None]:
    """A writer of .npy files for arrays of one shape and dtype: the header (np.save's format) is
    built once, then each file is the header plus the array's bytes (no per-file formatting).

    An existing file is overwritten in place, then cut to length: truncating it first frees its
    blocks only for the write to allocate them again (0.5-2 ms a file on ext4 here, 0.1 ms in place).
    """
    import io

    buf = io.BytesIO()
    np.lib.format.write_array_header_1_0(buf, {"descr": np.lib.format.dtype_to_descr(np.dtype(dtype)),
                                               "fortran_order": False, "shape": tuple(shape)})
    header = buf.getvalue()
    flags = os.O_WRONLY | os.O_CREAT | getattr(os, "O_BINARY", 0)
    writev = getattr(os, "writev", None)

    def write(path: Path | str, arr: np.ndarray) -> None:
        data = np.ascontiguousarray(arr, dtype).reshape(-1).view(np.uint8).data
        total = len(header) + len(data)
        fd = os.open(path, flags, 0o666)
        try:
            done = writev(fd, (header, data)) if writev is not None else os.write(fd, header)
            while done < total:  # a short write: the rest, from where it stopped
                done += os.write(fd, data[done - len(header):] if done >= len(header) else header[done:])
            if os.fstat(fd).st_size != total:
                os.ftruncate(fd, total)
        finally:
            os.close(fd)

    return write


def _cmd_height(args: argparse.Namespace) -> int:
    if bench_live.wants_bench(args, "calib", "images"):
        return bench_live.height(args)
    bench_live.need_files(args, "calib", "images", "output")
    keep_freed_memory()
    rec = _reconstructor(args.calib, args.background, args.solver, args.downsample, args.lookup)
    out = Path(args.output)
    written: list[str] = []
    write = _npy_writer(rec.calibration.shape, np.float32)
    if len(args.images) == 1:
        target = out if out.suffix == ".npy" else out.with_suffix(".npy")
        write(target, rec.height_mm(_read_image(args.images[0])))
        written.append(str(target))
    else:
        out.mkdir(exist_ok=True)  # the parent exists (output_path): only the leaf is made
        folder = str(out)
        for img in args.images:
            stem = os.path.splitext(os.path.basename(img))[0]  # Path(img).stem, without the objects
            path = os.path.join(folder, stem + ".npy")
            write(path, rec.height_mm(_read_image(img)))
            written.append(path)
    if args.json:
        print_json({"written": written})
    else:
        print("\n".join(written))
    return 0


def _print_result(res, as_json: bool) -> int:
    d = res.as_dict()
    if as_json:
        print_json(d)
    elif res.ok:
        print(f"rotation_deg: {res.rotation_deg:.4f}\ntranslation_mm: {np.round(res.translation_mm, 4).tolist()}\n"
              f"confidence: {res.confidence:.4f}\ninliers: {res.inliers}\nmethod: {res.method}")
    else:
        print(f"refused: {res.reason} (confidence {res.confidence:.3f}, inliers {res.inliers})")
    return 0 if res.ok else EXIT_FAILED


# Every registration threshold and its flag; defaults and meanings come from RegistrationParams.
_REG_FLAGS: tuple[tuple[str, Callable[[str], Any], str], ...] = (
    ("ransac_iters", int_in(1, 100_000), "two-pair RANSAC samples"),
    ("inlier_px", float_in(0.0, 100.0, "px", low_open=True), "RANSAC residual threshold in px"),
    ("min_inliers", int_in(2, 100_000), "fewer RANSAC inliers refuse the keypoint answer"),
    ("min_confidence", float_in(0.0, 1.0), "Li's confidence c = 1 - |1 - det R| below this is refused"),
    ("min_ncc", float_in(-1.0, 1.0), "normalised correlation of the aligned heights below this is refused"),
    ("min_overlap", float_in(0.0, 1.0), "overlap (fraction of A's steep pixels) below this is refused"),
    ("max_sigma_rot_deg", float_in(0.0, 180.0, "deg", low_open=True),
     "refuse when the dense fit pins rotation worse than this (1 sigma, deg)"),
    ("max_sigma_px", float_in(0.0, 10_000.0, "px", low_open=True),
     "refuse when the dense fit pins translation worse than this (1 sigma, px)"),
    ("search_max_sigma_px", float_in(0.0, 10_000.0, "px", low_open=True),
     "dense search: refuse a pose pinning translation worse than this (1 sigma, px); the pose must also "
     "win the patch count and the uniqueness ratio"),
    ("min_rotation_pinning", float_in(0.0, 100.0),
     "refuse rotation-symmetric content (rotation vs translation information)"),
    ("detect_short_px", int_in(16, 8192, "px"), "keypoints are found on the map resized to this short side (px)"),
    ("orb_features", int_in(10, 100_000), "ORB keypoints per touch-sized image"),
    ("search_min_explained", float_in(0.0, 1.0),
     "dense search: refuse a pose explaining less of the map's relief (NCC^2 x overlap) than this"),
    ("search_min_ratio", float_in(1.0, 1000.0),
     "dense search: refuse unless the pose agrees on this many times more patches than any other pose"),
    ("search_min_support", int_in(0, 100_000), "dense search: keypoint matches that must agree with the pose"),
    ("search_min_patches", int_in(0, 1_000_000),
     "dense search and a thin keypoint consensus: patches of the overlap (search_patch_px square) "
     "carrying relief that must agree with the pose"),
)


def _params(args: argparse.Namespace) -> RegistrationParams:
    knobs = {name: getattr(args, name) for name, _, _ in _REG_FLAGS}
    return RegistrationParams(detector=args.detector, dense_fallback=not args.no_dense_fallback, **knobs)


def _cmd_register(args: argparse.Namespace) -> int:

    res = register_heights(_load_height(args.a), _load_height(args.b), args.mm_per_px, _params(args))
    return _print_result(res, args.json)


def _cmd_map(args: argparse.Namespace) -> int:
    keep_freed_memory()  # many touches: their buffers are reused, not faulted in afresh
    tmap = TactileMap(args.mm_per_px, canvas_factor=args.canvas_factor, params=_params(args),
                      accept_confidence=args.accept_confidence)
    rows = []
    for path in args.heights:
        rec = tmap.add_touch(_height_or_image(path, args.calib, args.background))
        rows.append({"touch": path, "accepted": rec.accepted, "reason": rec.result.reason,
                     "confidence": rec.result.confidence,
                     "g_T_m": None if rec.g_T_m is None else rec.g_T_m.tolist()})
    saved = tmap.save(args.output)
    rejected = sum(not r["accepted"] for r in rows)
    if args.json:
        print_json({"map": str(saved), "touches": rows, "rejected": rejected})
    else:
        for r in rows:
            print(f"{r['touch']}: {'accepted' if r['accepted'] else 'rejected (' + str(r['reason']) + ')'}")
        print(f"map: {saved}" + (f" ({rejected} of {len(rows)} touches rejected)" if rejected else ""))
    return EXIT_FAILED if rejected else 0


def _cmd_localize(args: argparse.Namespace) -> int:
    keep_freed_memory()  # --bench localizes frame after frame
    tmap = load_tactile_map(args.map, params=_params(args))
    if bench_live.wants_bench(args, "touch"):
        return bench_live.localize(args, tmap)
    bench_live.need_files(args, "touch")
    res = tmap.localize(_height_or_image(args.touch, args.calib, args.background))
    return _print_result(res, args.json)


def _add_reg_knobs(p: argparse.ArgumentParser) -> None:
    d = RegistrationParams()
    p.add_argument("--detector", default=d.detector, choices=["orb", "brisk", "both"],
                   help=f"keypoints (default {d.detector})")
    for name, kind, text in _REG_FLAGS:
        p.add_argument("--" + name.replace("_", "-"), type=kind, default=getattr(d, name),
                       help=f"{text} (default {getattr(d, name)})")
    p.add_argument("--no-dense-fallback", action="store_true",
                   help="no dense search when keypoints fail (default: search)")
    add_json_flag(p)


MM_PER_PX = float_in(1e-4, 10.0, "mm/px")  # 0.1 µm .. 10 mm a pixel: beyond either, a typo


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the ``gelsight`` command group."""
    _, sub = add_command_group(subparsers, "gelsight", metavar="SUBCOMMAND",
                               help="GelSight calibration, height maps, registration, tactile maps",
                               description="Exit codes: 0 done, 1 a failed verdict: the touch refused (register/localize) or "
                               "a touch rejected (map), 2 bad input (file, frame or map the pipeline cannot read; "
                               "one line).")

    p = sub.add_parser("calibrate", help="fit a colour->gradient calibration from ball presses")
    p.add_argument("press_dir", help="folder with background.png, press images and labels.csv")
    p.add_argument("--mm-per-px", type=MM_PER_PX, required=True, help="pixel pitch in mm")
    p.add_argument("--ball-radius-mm", type=float_in(0.0, 100.0, "mm", low_open=True), required=True, help="calibration ball radius in mm")
    p.add_argument("--method", default="mlp", choices=["lut", "poly", "mlp"], help="model (default mlp)")
    p.add_argument("--bins", type=int_in(2, 256), default=32, help="LUT bins per channel (method lut)")
    p.add_argument("--sensor", default="gelsight", help="sensor name stored in the metadata")
    p.add_argument("--report", action="store_true", help="also cross-validate on held-out presses")
    p.add_argument("--folds", type=int_in(2, 1000), default=5, help="folds of the report (default 5)")
    p.add_argument("-o", "--output", type=output_file(), required=True,
                   help="output base path (writes .npz and .json); its folder must exist")
    add_json_flag(p)
    p.set_defaults(func=_cmd_calibrate)

    p = sub.add_parser("height", help="height maps (mm, .npy) from frames")
    p.add_argument("calib", nargs="?", help="calibration (.npz/.json base path; --bench: default the camera's)")
    p.add_argument("images", nargs="*", help="BGR frames (or --bench: live from the bench's GelSight camera)")
    p.add_argument("--background", help="a fresh no-contact frame replacing the calibration's")
    p.add_argument("--solver", choices=["dst", "dct", "fc"], help="Poisson solver (default: the pipeline's)")
    p.add_argument("--downsample", type=int_in(1, 8), default=None,
                   help="slopes area-reduced by this factor before the solve (default: the largest keeping the "
                   "reduced pixel within 0.13 mm, 2 on a GelSight Mini; 1 keeps the finest detail at ~1.6x the compute)")
    p.add_argument("--lookup", choices=["full", "reduced"], default=None,
                   help="with a downsample > 1: 'full' (default) looks every pixel's colour up, 'reduced' looks up "
                   "the area-reduced frame: ~40%% less compute a frame, heights within 1%% of the press depth RMS, normals ~0.1 deg "
                   "worse on unseen presses (docs/speed_and_accuracy.md)")
    p.add_argument("-o", "--output", type=output_dir,
                   help="OUT.npy for one image, a folder for several (its parent must exist; required with "
                   "files; --bench: the last map)")
    add_json_flag(p)
    bench_live.add_bench_camera_arguments(p)
    p.set_defaults(func=_cmd_height)

    p = sub.add_parser("register", help="rigid transform taking height map B into A (exit 1 when refused)")
    p.add_argument("a", help="reference height map A (.npy, mm)")
    p.add_argument("b", help="height map B (.npy, mm)")
    p.add_argument("--mm-per-px", type=MM_PER_PX, required=True, help="pixel pitch in mm")
    _add_reg_knobs(p)
    p.set_defaults(func=_cmd_register)

    p = sub.add_parser("map", help="mosaic touches (height maps or frames) into a tactile map (.npz); "
                       "exit 1 when a touch is rejected")
    p.add_argument("heights", nargs="+", help="touches: .npy height maps, or frames with --calib")
    p.add_argument("--mm-per-px", type=MM_PER_PX, required=True, help="pixel pitch in mm")
    p.add_argument("--canvas-factor", type=float_in(1.0, 20.0), default=3.0, help="map size / touch size (default 3)")
    p.add_argument("--accept-confidence", type=float_in(0.0, 1.0), default=ACCEPT_CONFIDENCE,
                   help=f"a touch joins the map above this confidence c (default {ACCEPT_CONFIDENCE}, Li 2014)")
    p.add_argument("--calib", help="calibration for frames given as images")
    p.add_argument("--background", help="no-contact frame for --calib")
    p.add_argument("-o", "--output", type=output_file(".npz"), required=True,
                   help="output map .npz (its folder must exist)")
    _add_reg_knobs(p)
    p.set_defaults(func=_cmd_map)

    p = sub.add_parser("localize", help="where a touch lies in a tactile map (exit 1 when refused)")
    p.add_argument("map", help="tactile map .npz from 'gelsight map'")
    p.add_argument("touch", nargs="?", help="touch: .npy height map, or a frame with --calib "
                   "(or --bench: each live frame of the bench's GelSight camera)")
    p.add_argument("--calib", help="calibration for a frame given as an image (--bench: default the camera's)")
    p.add_argument("--background", help="no-contact frame for --calib")
    _add_reg_knobs(p)
    bench_live.add_bench_camera_arguments(p)
    p.set_defaults(func=_cmd_localize)
