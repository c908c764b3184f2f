"""``tactile-rig calibrate ...``: calibration and learning sessions, each writing a versioned file + report.

Subcommands live in one ``_register_<name>(csub)`` function each (add new sessions the same way):
``force-map`` (thesis 3.4.1) and ``substance`` (thesis 3.4.2) here; GelSight, FingerVision, scale
and gripper calibrations join them. Sessions never prompt when stdin is not a terminal.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any, Callable

from tactile_rig.cli.args import EFFORT, SEED, float_in, int_in, output_dir_or
from tactile_rig.cli.bench_args import add_bench_arguments, bench_from_args
from tactile_rig.cli.calibrate_sessions import connect_session_rig, register_sessions, session_guide
from tactile_rig.cli.common import add_command_group, add_json_flag, extras_as_errors, print_json
from tactile_rig.rig.camera_calibrations import camera_calibrations
from tactile_rig.rig.jig_accuracy import sim_camera_connector
from tactile_rig.rig.learning import DEFAULT_GAMMA, force_map_session, substance_session
from tactile_rig.rig.live_collection import PressPlan, collect_force_map, collect_stirring
from tactile_rig.sim.scenes import FORCE_MAP_PRESS_SCENE
from tactile_rig.sim.world.stick_press import increasing_peaks


def register(sub: argparse._SubParsersAction) -> None:
    _, csub = add_command_group(sub, "calibrate", metavar="SESSION",
                                help="calibration and learning sessions (force map, substance classifier, ...)")
    for reg in (_register_force_map, _register_substance):
        reg(csub)

    register_sessions(csub)


def _source_arguments(p: argparse.ArgumentParser) -> None:
    add_bench_arguments(p)
    p.add_argument("--from-recording", metavar="FILE.mcap",
                   help="learn from a recorded session instead of collecting one")
    p.add_argument("--camera", help="perception topic name in the recording (default: the only one)")
    p.add_argument("--seed", type=SEED, default=0, help="seed of the mock session (default 0)")
    p.add_argument("--no-figures", action="store_true", help="skip the PNG figures and Markdown page")
    p.add_argument("--force", action="store_true",
                   help="overwrite the newest model version instead of adding <name>-vN+1")
    p.add_argument("--live", action="store_true",
                   help="guided live collection (the default on a real bench; on --mock the simulated scene)")
    p.add_argument("--yes", action="store_true", help="never prompt, even on a terminal")
    add_json_flag(p)


def _check_source(args: argparse.Namespace, what: str) -> tuple[Any, bool]:
    """(the bench or None, whether to collect live). A real bench collects live unless it learns
    from ``--from-recording``; the mock simulates the trials unless ``--live``."""
    if not (getattr(args, "mock", False) or getattr(args, "bench", None)):
        if args.live:
            raise ValueError(f"{what} --live needs a bench: pass --bench FILE or --mock")
        return None, False
    bench = bench_from_args(args, check_files=False)
    if args.from_recording:
        if args.live:
            raise ValueError("--live and --from-recording exclude each other (collect, or learn from a file)")
        return bench, False
    return bench, bool(args.live or not bench.is_mock)


def _live_camera(args: argparse.Namespace, bench: Any) -> str:
    """The FingerVision camera of the bench that the live session reads (``--camera`` or the first)."""
    if bench.is_mock:
        return "camera"
    cams = [n for n, c in bench.cameras.items() if c.sensor == "fingervision"]
    name = args.camera or (cams[0] if cams else None)
    if name is None or name not in bench.cameras:
        raise ValueError(f"{bench.source}: no FingerVision camera for the live session (cameras: "
                         f"{', '.join(bench.cameras) or 'none'}); add one with sensor = \"fingervision\" or "
                         "pass --camera NAME (or learn from a recording with --from-recording FILE.mcap)")
    return name


# -- force map ---------------------------------------------------------------------------------
def _register_force_map(csub: argparse._SubParsersAction) -> None:
    p = csub.add_parser("force-map", help="learn marker forces → newtons on the scale (kernel ridge, thesis 3.4.1)",
                        description="Press a grasped stick on the scale through N trials of increasing force, "
                        "fit RBF kernel ridge regression on robust-scaled marker forces, report the MSE on a "
                        "held-out trial, save force_map.npz + force_map.json (no pickle).")
    _source_arguments(p)
    p.add_argument("--trials", type=int_in(2, 10_000), default=10, help="number of presses, one held out (default 10)")
    p.add_argument("--max-force", type=float_in(0.0, 10_000.0, "N", low_open=True), default=20.0, help="peak force of the last press in N (default 20)")
    p.add_argument("--holdout", type=int_in(0, 10_000), help="trial held out for the MSE (default: the middle one)")
    p.add_argument("--alpha", type=float_in(0.0, 1e6, low_open=True), default=0.02, help="ridge penalty λ (default 0.02, as the thesis)")
    p.add_argument("--gamma", type=float_in(0.0, 1e6, low_open=True), default=None, help="RBF gamma on robust-scaled features (default 0.05)")
    p.add_argument("--out", default="calib/force_map", type=output_dir_or("calib/force_map"), help="output folder (default calib/force_map)")
    p.add_argument("--max-effort", type=EFFORT, default=0.5,
                   help="live: effort cap, fraction of the current limit (default 0.5)")
    p.add_argument("--release-opening-m", type=float_in(0.0, 1.0, "m"), default=0.06,
                   help="live: opening between presses in m, clear of the platform (default 0.06)")
    p.add_argument("--ramp", type=float_in(0.0, 3600.0, "s", low_open=True), default=1.0, help="live: seconds to reach each press's peak (default 1)")
    p.add_argument("--hold", type=float_in(0.0, 3600.0, "s"), default=0.5, help="live: seconds at the peak (default 0.5)")
    p.set_defaults(func=_force_map)


@extras_as_errors
def _force_map(args: argparse.Namespace) -> int:
    bench, live = _check_source(args, "force-map")
    collect: Callable[[Path], Path] | None = None
    camera = args.camera
    if live:
        missing = [d for d in ("gripper", "scale") if d not in bench.devices]
        if missing:
            raise ValueError(f"force-map live collection: {bench.source} has no [{'], ['.join(missing)}]; add "
                             "them, or learn from a recorded session with --from-recording FILE.mcap")
        camera = _live_camera(args, bench)
        plan = PressPlan(peaks_n=tuple(float(v) for v in increasing_peaks(args.trials, args.max_force)),
                         max_effort=args.max_effort, release_opening_m=args.release_opening_m, ramp_s=args.ramp,
                         hold_s=args.hold)
        collect = _press_collector(args, bench, camera, plan)

    report = force_map_session(Path(args.out), n_trials=args.trials, max_force_n=args.max_force, seed=args.seed,
                               recording=args.from_recording, holdout=args.holdout, alpha=args.alpha,
                               gamma=DEFAULT_GAMMA if args.gamma is None else args.gamma, camera=camera,
                               bench=bench, figures=not args.no_figures, force=args.force, collect=collect)
    if args.json:
        print_json(report)
    else:
        noise = f" (scene noise {report['scene_noise_rms_n']:.3f} N rms)" if "scene_noise_rms_n" in report else ""
        print(f"force map: held-out trial {report['holdout_trial']}: MSE {report['mse_holdout_n2']:.4f} N², "
              f"RMSE {report['rmse_holdout_n']:.3f} N{noise}; {report['n_train']} training samples")
        print(f"model: {report['model']['npz']} + {report['model']['json']}")
    return 0


# -- substance classifier ----------------------------------------------------------------------
def _register_substance(csub: argparse._SubParsersAction) -> None:
    p = csub.add_parser("substance", help="learn the stirred substance from marker forces (MLP, thesis 3.4.2)",
                        description="Stirring trials → windows of marker-force statistics → MLPClassifier "
                        "(10, 10, 10), logistic, lbfgs; accuracy on held-out trials; saves substance.npz + .json.")
    _source_arguments(p)
    p.add_argument("--per-substance", type=int_in(2, 10_000), default=12, help="mock trials per substance (default 12)")
    p.add_argument("--window", type=float_in(0.0, 3600.0, "s", low_open=True), default=2.0, help="feature window in s (default 2)")
    p.add_argument("--test-fraction", type=float_in(0.0, 1.0, low_open=True), default=0.25, help="trials held out per substance (default 0.25)")
    p.add_argument("--out", default="calib/substance", type=output_dir_or("calib/substance"), help="output folder (default calib/substance)")
    p.add_argument("--substances", help="live: comma-separated substances to stir, e.g. water,oil,honey")
    p.add_argument("--trial-s", type=float_in(0.0, 3600.0, "s", low_open=True), default=10.0, help="live: seconds of stirring per trial (default 10)")
    p.add_argument("--grip-effort", type=EFFORT, default=0.3, help="live: effort holding the stick (default 0.3)")
    p.set_defaults(func=_substance)


@extras_as_errors
def _substance(args: argparse.Namespace) -> int:
    bench, live = _check_source(args, "substance")
    collect: Callable[[Path], Path] | None = None
    camera = args.camera
    if live:
        if bench.is_mock:
            raise ValueError("substance --live: the mock bench has no stirring scene to stir in; drop --live "
                             "(the mock simulates the stirring trials) or use a real or rehearsal bench")
        if not args.substances:
            raise ValueError("substance on a bench: name what will be stirred with --substances water,oil,honey")
        camera = _live_camera(args, bench)
        names = [s.strip() for s in args.substances.split(",") if s.strip()]
        collect = _stir_collector(args, bench, camera, names)

    report = substance_session(Path(args.out), per_substance=args.per_substance, seed=args.seed,
                               recording=args.from_recording, test_fraction=args.test_fraction,
                               window_s=args.window, camera=camera, figures=not args.no_figures,
                               force=args.force, collect=collect)
    if args.json:
        print_json(report)
    else:
        print(f"substance classifier: held-out accuracy {report['accuracy_holdout']:.3f} on "
              f"{report['n_test_windows']} windows of {report['n_test_trials']} trials; classes "
              f"{', '.join(report['classes'])}")
        print(f"model: {report['model']['npz']} + {report['model']['json']}")
    return 0


def _press_collector(args: argparse.Namespace, bench: Any, camera: str, plan: PressPlan) -> Callable[[Path], Path]:
    """``collect(path)`` for the force-map session: connect the devices, press, record, close."""

    def collect(path: Path) -> Path:
        rig = connect_session_rig(args, ["gripper", "scale", camera], scene=FORCE_MAP_PRESS_SCENE,
                                  connectors={"camera": sim_camera_connector("fingervision")})
        try:
            cal = camera_calibrations(rig.bench, camera, load=("calibration",), defaults=not bench.is_mock)
            return collect_force_map(rig, path, camera=camera, plan=plan, calibrations=cal,
                                     guide=session_guide(args))
        finally:
            rig.close()

    return collect


def _stir_collector(args: argparse.Namespace, bench: Any, camera: str, names: list[str]) -> Callable[[Path], Path]:
    """``collect(path)`` for the substance session: the operator stirs each named substance."""

    def collect(path: Path) -> Path:
        rig = connect_session_rig(args, [camera] + (["gripper"] if "gripper" in bench.devices else []))
        try:
            cal = camera_calibrations(rig.bench, camera, load=("calibration",))
            return collect_stirring(rig, path, camera=camera, substances=names, per_substance=args.per_substance,
                                    trial_s=args.trial_s, grip_effort=args.grip_effort, calibrations=cal,
                                    guide=session_guide(args))
        finally:
            rig.close()

    return collect
