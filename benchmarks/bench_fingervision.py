"""FingerVision benchmark: detection and tracking on real frames, rendered scenes, Kalman vs none, speed.

    python benchmarks/bench_fingervision.py [--quick] [--speed-only | --real-only] [--save]

Side by side in the same run: the reference setting (fv_2_r.yaml thresholds through plain
SimpleBlobDetector), our per-frame detector, tracking with ids from the first frame (the default,
``init="lattice"``) and the reference's scheme whose first ``n_calib_frames`` frames only build a baseline
(``init="frames"``). Prints tables; writes ``benchmarks/results/fingervision.json`` only with
``--save``. Real frames are read in place from ../shared/data/real/fingervision_demo_gpl3 (GPL;
skipped if absent) and scored against ``tests/data/fingervision_labels``. Speed is measured on one
core (``cv2.setNumThreads(1)``) at 320x240: rendered frames and the real frames.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time
from pathlib import Path

import cv2
import numpy as np

from _output import add_save_args, parse_args, save_json  # noqa: E402  (benchmarks/ is the script's folder)

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from tactile_rig.perception.fingervision import (  # noqa: E402
    FingerVision,
    FingerVisionParams,
    MarkerBaseline,
    MarkerTracker,
    ProximityVision,
    TrackerParams,
    contrast_map,
    detect_markers,
    detect_markers_reference,
)
from tactile_rig.perception.fingervision.lattice import fit_lattice  # noqa: E402
from tactile_rig.rig.trade.fingervision import labelled_real_frames, score_real  # noqa: E402
from tests._data import SHARED_REAL  # noqa: E402
from tests._fingervision_real import load_gt, score, track_real  # noqa: E402
from tests._fingervision_synth import Ellipse, lattice, render  # noqa: E402


def _mask(e: Ellipse) -> np.ndarray:
    m = np.zeros((240, 320), np.uint8)
    cv2.ellipse(m, (int(round(e.cx)), int(round(e.cy))), (int(e.a), int(e.b)), e.angle_deg, 0, 360, 255, -1)
    return m


def bench_real() -> dict | None:
    if SHARED_REAL is None or not (SHARED_REAL / "fingervision_demo_gpl3").is_dir():
        return None
    folder = SHARED_REAL / "fingervision_demo_gpl3"
    gt = load_gt(folder)
    out: dict = {"per_frame": {}}
    tot = {"ours": [0, 0, 0], "reference": [0, 0, 0], "tracked": [0, 0, 0]}
    errs: dict[str, list[float]] = {"ours": [], "reference": [], "tracked": []}
    tracked = track_real(folder)
    id_map: dict[int, int] = {}
    id_changes = 0
    for name, truth in gt.items():
        img = cv2.imread(str(folder / "frames" / name))
        r = tracked[name]
        use = r.marker_valid & r.marker_found
        rows = {
            "ours": score(detect_markers(img).positions_px, truth),
            "reference": score(detect_markers_reference(img).positions_px, truth),
            "tracked": score(r.marker_positions_px[use], truth),
        }
        for det_i, lat in rows["tracked"].hit_ids.items():
            mid = int(r.marker_ids[use][det_i])
            if id_map.setdefault(mid, lat) != lat:
                id_changes += 1
        out["per_frame"][name] = {k: {"tp": s.tp, "fp": s.fp, "n_true": s.n_true} for k, s in rows.items()}
        for k, s in rows.items():
            tot[k][0] += s.tp
            tot[k][1] += s.fp
            tot[k][2] += s.n_true
            errs[k] += s.errors_px
    for k, (tp, fp, n) in tot.items():
        out[k] = {"tp": tp, "fp": fp, "n_true": n, "precision": tp / max(1, tp + fp), "recall": tp / max(1, n),
                  "mean_error_px_vs_hand_label": float(np.mean(errs[k])) if errs[k] else None}
    out["light_gain_sweep"] = {}
    for gain in (0.5, 0.7, 1.0, 1.3, 1.6):
        row = {}
        for label, fn in (("ours", detect_markers), ("reference", detect_markers_reference)):
            tp = fp = n = 0
            for name, truth in gt.items():
                img = cv2.imread(str(folder / "frames" / name)).astype(np.float32) * gain
                s = score(fn(np.clip(img, 0, 255).astype(np.uint8)).positions_px, truth)
                tp, fp, n = tp + s.tp, fp + s.fp, n + s.n_true
            row[label] = {"tp": tp, "fp": fp, "recall": tp / n, "precision": tp / max(1, tp + fp)}
        out["light_gain_sweep"][str(gain)] = row
    out["tracked"]["identity_changes"] = id_changes
    out["tracked"]["markers_with_identity"] = len(id_map)
    # the measurement noise a tracker sees: each marker's scatter about its mean over the ten frames,
    # unfiltered (an upper bound: the skin's own motion between the frames is included)
    raw = track_real(folder, FingerVisionParams(tracker=TrackerParams(use_kalman=False)))
    pos = np.array([r.marker_positions_px for r in raw.values()])
    scatter = pos.std(axis=0).ravel()
    out["tracked"]["centre_scatter_px"] = {"median": float(np.median(scatter)), "mean": float(np.mean(scatter))}
    # every labelled frame (10), three orders, each from a fresh processor: every frame scored
    data = labelled_real_frames()
    out["labelled_sequences"] = {}
    for label, params in (("lattice_default", FingerVisionParams()),
                          ("frames_baseline_10", FingerVisionParams(init="frames")),
                          ("frames_baseline_1", FingerVisionParams(init="frames", n_calib_frames=1))):
        sc = score_real(params, data)
        out["labelled_sequences"][label] = None if sc is None else sc.to_dict()
    return out


def bench_synthetic(quick: bool) -> dict:
    rest = lattice()
    out: dict = {}
    # marker position error (plain background + object; and with QR-like print behind)
    e_plain, e_print, fp_print = [], [], 0
    for seed in range(3 if quick else 10):
        truth = lattice(jitter_seed=seed)
        for dark, acc in ((False, e_plain), (True, e_print)):
            det = detect_markers(render(truth, obj=Ellipse(200, 150, 45, 22, 20), seed=seed, dark_print=dark,
                                        gain=0.7 + 0.06 * seed))
            d = np.hypot(det.positions_px[:, None, 0] - truth[None, :, 0], det.positions_px[:, None, 1] - truth[None, :, 1])
            acc.extend(d.min(axis=0).tolist())
            if dark:
                fp_print += int((d.min(axis=1) > 1.0).sum())  # off every marker by > 1 px
    out["marker_error_px"] = {"plain_mean": float(np.mean(e_plain)), "plain_max": float(np.max(e_plain)),
                              "print_mean": float(np.mean(e_print)), "print_max": float(np.max(e_print)),
                              "detections_off_by_over_1px_with_print": fp_print}
    # force direction error
    dir_err = []
    for ang in range(0, 360, 45 if quick else 15):
        fv = FingerVision(FingerVisionParams(n_calib_frames=3))
        fv.calibrate([render(rest, seed=s) for s in range(3)])
        u = np.array([math.cos(math.radians(ang)), math.sin(math.radians(ang))])
        for k in range(1, 7):
            r = fv.process(render(rest + u * 0.3 * k, seed=10 + k, gain=1 + 0.1 * (-1) ** k))
        got = math.degrees(math.atan2(r.force_px[1], r.force_px[0]))
        dir_err.append(abs((got - ang + 180) % 360 - 180))
    out["force_direction_error_deg"] = {"mean": float(np.mean(dir_err)), "max": float(np.max(dir_err))}
    # orientation over 0..180
    pv = ProximityVision()
    pv.set_background([render(rest, seed=s) for s in range(3)])
    e0 = Ellipse(170, 120, 60, 30, 25)
    pv.learn_object(render(rest, obj=e0, seed=9), mask=_mask(e0))
    o_err = []
    for ang in np.arange(0.0, 180.0, 10.0 if quick else 2.5):
        r = pv.process(render(rest, obj=Ellipse(165, 118, 55, 22, ang), seed=int(ang) % 5, gain=1 + 0.1 * math.sin(ang)))
        o_err.append(abs((r.moments.orientation_deg - ang + 90) % 180 - 90))
    out["orientation_error_deg"] = {"mean": float(np.mean(o_err)), "max": float(np.max(o_err)), "n": len(o_err)}
    # slip latency and false alarms
    still_frames, alarms, latencies = 0, 0, []
    for trial in range(2 if quick else 6):
        pv = ProximityVision()
        pv.set_background([render(rest, seed=s) for s in range(3)])
        e0 = Ellipse(150, 120, 50, 28, 10 + 30 * trial)
        pv.learn_object(render(rest, obj=e0, seed=3), mask=_mask(e0))
        ang = 50.0 * trial
        u = np.array([math.cos(math.radians(ang)), math.sin(math.radians(ang))])
        start = 20
        first = None
        for k in range(start + 4):
            off = u * 0.8 * max(0, k - start + 1)
            e = Ellipse(e0.cx + off[0], e0.cy + off[1], e0.a, e0.b, e0.angle_deg)
            r = pv.process(render(rest, obj=e, obj_texture_offset_px=tuple(off), seed=k,
                                  gain=1 + 0.12 * math.sin(1.7 * k)), rest)
            if k < start and k > 0:
                still_frames += 1
                alarms += int(r.slip)
            if k >= start and r.slip and first is None:
                first = k - start
        latencies.append(first if first is not None else 99)
    out["slip"] = {"speed_px_per_frame": 0.8, "latency_frames": latencies, "false_alarms": alarms,
                   "still_frames": still_frames, "false_alarm_rate": alarms / max(1, still_frames)}
    return out


def bench_kalman(quick: bool) -> dict:
    """Jitter of the mean displacement on still frames with light flicker; lag on a ramp and a step."""
    rest = lattice()
    base = MarkerBaseline(rest.copy(), np.full(len(rest), 8.0), np.ones(len(rest), bool))
    n_still = 20 if quick else 60
    n_ramp = 15
    frames = []
    truth = []
    for k in range(n_still + n_ramp + 15):
        if k < n_still:
            s = 0.0
        elif k < n_still + n_ramp:
            s = 0.3 * (k - n_still + 1)  # ramp 0.3 px/frame
        else:
            s = 0.3 * n_ramp
        truth.append(s)
        gain = 1.0 + 0.2 * math.sin(2.3 * k) + 0.1 * ((k * 7) % 3 - 1)
        frames.append(contrast_map(render(rest + [s, 0.0], seed=k % 9, gain=gain))[2])
    truth = np.array(truth)
    out = {}
    for use_kalman in (False, True):
        tr = MarkerTracker(base, TrackerParams(use_kalman=use_kalman))
        xs = np.array([(tr.update(c).positions_px - rest)[:, 0] for c in frames])
        est = xs.mean(axis=1)
        jitter = float(np.std(est[5:n_still]))
        marker_jitter = float(np.mean(np.std(xs[5:n_still], axis=0)))
        ramp = slice(n_still + 5, n_still + n_ramp)
        lag_px = float(np.mean(truth[ramp] - est[ramp]))
        settle = next((i for i in range(n_still + n_ramp, len(est)) if abs(est[i] - truth[i]) <= 0.1), None)
        out["kalman" if use_kalman else "none"] = {
            "jitter_px": jitter, "per_marker_jitter_px": marker_jitter, "ramp_lag_px": lag_px, "ramp_lag_frames": lag_px / 0.3,
            "settle_frames_after_ramp_end": None if settle is None else settle - (n_still + n_ramp - 1),
            **_steady_speeds(use_kalman, quick)}
    return out


def _steady_speeds(use_kalman: bool, quick: bool) -> dict:
    """Fastest steady speed (from rest, 16 frames, 4 directions, a 3 x 3 patch of markers) at which
    every marker is measured in every frame, and the largest position error up to that speed."""
    rest = lattice(nx=3, ny=3, x0=110.0, y0=80.0, dx=50.0, dy=40.0)
    base = MarkerBaseline(rest.copy(), np.full(len(rest), 8.0), np.ones(len(rest), bool))
    kept, worst = 0.0, 0.0
    for speed in np.arange(0.5, 6.01, 1.0 if quick else 0.25):
        errs = []
        for ang in (0.0, 35.0, 90.0, 200.0):
            u = np.array([math.cos(math.radians(ang)), math.sin(math.radians(ang))])
            tr = MarkerTracker(base, TrackerParams(use_kalman=use_kalman))
            for k in range(1, 17):
                truth = rest + u * speed * k
                st_ = tr.update(contrast_map(render(truth, seed=k))[2])
                errs.append(np.inf if not st_.found.all() else float(np.hypot(*(st_.positions_px - truth).T).max()))
        if not np.isfinite(errs).all():
            break
        kept, worst = float(speed), max(worst, max(errs))
    return {"fastest_steady_speed_kept_px_per_frame": kept, "max_error_up_to_it_px": worst}


def _cycle(fn, frames: list[np.ndarray]):
    """A zero-argument callable applying ``fn`` to the next frame of ``frames`` each call."""
    k = [0]

    def run() -> object:
        k[0] = (k[0] + 1) % len(frames)
        return fn(frames[k[0]])

    return run


def bench_speed(quick: bool) -> dict:
    """Interleaved rounds (every method once per round): the best round is each method's figure, so
    other processes on the machine penalise all methods alike.

    Rendered 320x240 frames (30 markers, an object): the full processor with and without Kalman, and
    the per-frame detectors (reference = plain SimpleBlobDetector). The real 320x240 frames (when present):
    tracking with ids from the first frame (default), the frames-baseline scheme after its
    baseline, the first frame's one-off cost (our detector + the lattice fit) and the reference
    detector, all in the same rounds.
    """
    cv2.setNumThreads(1)
    rest = lattice()
    rounds, batch = (3, 60) if quick else (8, 120)
    obj = Ellipse(190, 140, 50, 25, 30)
    frames = [render(rest + [0.02 * (k % 50), 0.01 * (k % 50)], obj=obj, seed=k % 10,
                     gain=1 + 0.1 * math.sin(k)) for k in range(60)]
    methods: dict[str, object] = {}
    last: dict[str, tuple[FingerVision, np.ndarray]] = {}
    for label, kalman in (("ours_full_kalman", True), ("ours_full_no_kalman", False)):
        fv = FingerVision(FingerVisionParams(n_calib_frames=3, tracker=TrackerParams(use_kalman=kalman)))
        fv.calibrate([render(rest, seed=s) for s in range(3)])
        fv.learn_object(render(rest, obj=obj, seed=5), mask=_mask(obj))
        methods[label] = _cycle(fv.process, frames)
        last[label] = (fv, frames[1])
    methods["reference_blob_detector_only"] = _cycle(detect_markers_reference, frames)
    methods["ours_full_frame_detector_only"] = _cycle(detect_markers, frames)
    real = [img for _, img in labelled_real_frames()]
    if real:
        for label, params in (("real_track_lattice_default", FingerVisionParams()),
                              ("real_track_frames_baseline", FingerVisionParams(init="frames"))):
            fv = FingerVision(params)
            for f in real:
                fv.process(f)
            methods[label] = _cycle(fv.process, real)
            last[label] = (fv, real[1])

        def first_frame(f: np.ndarray) -> object:
            value, _bg, contrast = contrast_map(f)
            return fit_lattice(detect_markers(f), contrast, value)

        methods["real_first_frame_detector_plus_lattice"] = _cycle(first_frame, real)
        methods["real_reference_blob_detector_only"] = _cycle(detect_markers_reference, real)
    times: dict[str, list[float]] = {k: [] for k in methods}
    cpu: dict[str, list[float]] = {k: [] for k in methods}
    for _ in range(rounds):
        for label, fn in methods.items():
            fn()
            t0, c0 = time.perf_counter(), time.process_time()
            for _k in range(batch):
                fn()
            times[label].append((time.perf_counter() - t0) / batch)
            cpu[label].append((time.process_time() - c0) / batch)
    out: dict = {"load_average_1min": os.getloadavg()[0], "rounds": rounds, "frames_per_round": batch}
    for label, ts in times.items():
        best = min(ts)
        # CPU time of this process (one OpenCV thread): holds still on a shared machine, wall time does not
        best_cpu = max(min(cpu[label]), 1e-9)
        out[label] = {"ms": best * 1e3, "fps": 1.0 / best, "median_round_fps": 1.0 / float(np.median(ts)),
                      "cpu_ms": best_cpu * 1e3, "cpu_fps": 1.0 / best_cpu}
        if label in last:
            fv, f = last[label]
            out[label]["stages_ms"] = fv.process(f).timings_ms
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="fewer frames and angles")
    ap.add_argument("--speed-only", action="store_true",
                    help="re-measure speed only (e.g. on an idle machine); with --save, update the saved results")
    ap.add_argument("--real-only", action="store_true",
                    help="re-measure the real-frame tables only (seconds); with --save, update the saved results")
    add_save_args(ap, "fingervision.json")
    args = parse_args(ap)
    saved = ROOT / "benchmarks" / "results" / "fingervision.json"
    if args.real_only:
        real = bench_real()
        if saved.is_file():  # update the real-frame figures of the saved full run, keep the rest
            res = json.loads(saved.read_text())
            res["real"] = real
            save_json(args, res, default=float)
        _print_real(real)
        return 0
    if args.speed_only:
        speed = bench_speed(args.quick)
        if saved.is_file():  # update the speed figures of the saved full run, keep its accuracy figures
            res = json.loads(saved.read_text())
            res["speed_320x240_one_core"] = speed
            save_json(args, res, default=float)
        _print_speed(speed)
        return 0
    res = {"opencv": cv2.__version__, "quick": args.quick}
    res["real"] = bench_real()
    res["synthetic"] = bench_synthetic(args.quick)
    res["kalman_vs_none"] = bench_kalman(args.quick)
    res["speed_320x240_one_core"] = bench_speed(args.quick)
    try:
        res["mock_renderer"] = bench_mock_renderer()
    except Exception as exc:  # the renderer belongs to another module; report, do not fail
        res["mock_renderer"] = {"error": repr(exc)}
    save_json(args, res, default=float)
    _print(res)
    return 0


def bench_mock_renderer() -> dict:
    from tactile_rig.sim.render.fingervision import FingerVisionRenderer, FvObject

    rdr = FingerVisionRenderer(seed=1)
    errs, fps_ = [], 0
    for gain in (0.7, 1.0, 1.3):
        img, truth = rdr.render(light_gain=gain)
        det = detect_markers(img)
        gt, rad = np.asarray(truth["markers_px"]), np.asarray(truth["marker_radius_px"])
        d = np.hypot(det.positions_px[:, None, 0] - gt[None, :, 0], det.positions_px[:, None, 1] - gt[None, :, 1])
        clear = (gt[:, 0] - rad >= 1) & (gt[:, 0] + rad <= 318) & (gt[:, 1] - rad >= 1) & (gt[:, 1] + rad <= 238)
        errs.extend(d.min(axis=0)[clear].tolist())
        fps_ += int((d.min(axis=1) > 1.0).sum())
    o_err, f_err = [], []
    for ang in range(0, 180, 30):
        fv = FingerVision(FingerVisionParams(n_calib_frames=3))
        fv.calibrate([rdr.render()[0] for _ in range(3)])
        obj = FvObject((170.0, 120.0), (60.0, 25.0), float(ang))
        img, truth = rdr.render(object=obj)
        m = np.zeros(img.shape[:2], np.uint8)
        FingerVisionRenderer._draw_object(m, obj)
        fv.learn_object(img, mask=m)
        u = np.array([math.cos(math.radians(2 * ang)), math.sin(math.radians(2 * ang))])
        for k in range(1, 7):
            img, truth = rdr.render(markers_shift_px=np.tile(u * 0.3 * k, (len(rdr.rest_px), 1)), object=obj,
                                    light_gain=1 + 0.1 * (-1) ** k)
            r = fv.process(img)
        o_err.append(abs((r.object_orientation_deg - truth["object_orientation_deg"] + 90) % 180 - 90))
        f_err.append(abs((math.degrees(math.atan2(r.force_px[1], r.force_px[0])) - 2 * ang + 180) % 360 - 180))
    return {"marker_error_px_mean": float(np.mean(errs)), "marker_error_px_max": float(np.max(errs)),
            "n_markers": len(errs), "false_positives": fps_,
            "orientation_error_deg_max": float(np.max(o_err)), "force_direction_error_deg_max": float(np.max(f_err))}


def _print(res: dict) -> None:
    _print_real(res["real"])
    _print_rest(res)


def _print_real(real: dict | None) -> None:
    if real:
        print("Real frames (3 hand-labelled frames, 28 sure markers each)")
        print(f"{'method':<34}{'TP':>5}{'FP':>5}{'prec':>7}{'recall':>8}{'err px':>8}")
        for k, label in (("reference", "reference (fv_2_r + plain SBD)"), ("ours", "ours, detector per frame"),
                         ("tracked", "ours, tracked (valid & found)")):
            s = real[k]
            err = s["mean_error_px_vs_hand_label"]
            print(f"{label:<34}{s['tp']:>5}{s['fp']:>5}{s['precision']:>7.3f}{s['recall']:>8.3f}{err if err is None else round(err, 2):>8}")
        print(f"identity changes over the labelled frames: {real['tracked']['identity_changes']}")
        sc = real["tracked"].get("centre_scatter_px")
        if sc:
            print(f"scatter of a marker's measured centre over the frames (x and y, no Kalman): median {sc['median']:.3f} px,"
                  f" mean {sc['mean']:.3f} px")
        print("Tracking, every labelled frame (10 frames x 3 orders, every frame scored, valid markers):")
        for k, v in real["labelled_sequences"].items():
            if v:
                print(f"  {k:<22} precision {v['precision']:.3f}  recall {v['recall']:.3f}  id switches {v['id_switches']}"
                      f"  centre error {v['mean_error_px']:.2f} px")
        print("light gain sweep (frames x gain):  gain  ours TP/FP   reference TP/FP")
        for g, row in real["light_gain_sweep"].items():
            print(f"  {g:>5}  {row['ours']['tp']:>4}/{row['ours']['fp']:<4}  {row['reference']['tp']:>4}/{row['reference']['fp']:<4}")


def _print_rest(res: dict) -> None:
    syn = res["synthetic"]
    print("\nRendered scenes (own synthetic maker)")
    for k, v in syn.items():
        print(f"  {k}: {json.dumps(v, default=float)}")
    print("\nKalman vs none (flickering light, 30 markers)")
    for k, v in res["kalman_vs_none"].items():
        print(f"  {k:<7} jitter of mean {v['jitter_px']:.4f} px, per marker {v['per_marker_jitter_px']:.4f} px  ramp lag {v['ramp_lag_px']:.3f} px "
              f"({v['ramp_lag_frames']:.2f} frames)  settle {v['settle_frames_after_ramp_end']} frames  "
              f"steady speeds kept up to {v['fastest_steady_speed_kept_px_per_frame']} px/frame "
              f"(error <= {v['max_error_up_to_it_px']:.2f} px)")
    _print_speed(res["speed_320x240_one_core"])
    print(f"\nMock renderer: {json.dumps(res['mock_renderer'], default=float)}")


def _print_speed(sp: dict) -> None:
    print(f"\nSpeed, 320x240, one core (best of {sp['rounds']} interleaved rounds; load {sp['load_average_1min']:.1f})")
    for k, v in sp.items():
        if isinstance(v, dict):
            print(f"  {k:<40} {v['ms']:7.3f} ms  {v['fps']:8.1f} frames/s  (median round {v['median_round_fps']:.0f})"
                  + (f"  CPU {v['cpu_ms']:7.3f} ms  {v['cpu_fps']:8.1f} frames/CPU-s" if "cpu_ms" in v else ""))


if __name__ == "__main__":
    sys.exit(main())
