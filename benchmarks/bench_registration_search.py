"""Registration of independent re-touches with and without the dense search: accuracy and speed.

Run: ``python benchmarks/bench_registration_search.py [--quick] [--seeds 0,1,2] [--save]``. One core.
For each part (usb, plate) and seed, the re-touch set of
:mod:`tactile_rig.rig.trade.registration_data` (Li's jig protocol, 95 independent re-touches) is
registered as fresh pairs with the defaults and, side by side in the same run, with
``dense_fallback=False`` (keypoints only): right / wrong / refused, the MAEs, how many pairs reached
the search, and ms per pair (each pair's best of ``--repeats`` calls, the two settings interleaved
pair by pair, so machine load hits both alike). ``--save`` writes
``benchmarks/results/registration_search.json``; ``--quick`` registers every third re-touch.

``--must-refuse [N]`` also registers pairs that must be refused, with every setting: N pairs of
unrelated real ball-press tiles (default 480,
:func:`~tactile_rig.rig.trade.registration_data.unrelated_tile_pairs`), each part's re-touches
against the other part's map, and the re-touches of two other plates of the same kind (their own
seeded features) against the plate's map; it prints how many each setting placed, by method (0 is
the only right answer).

``--margin`` (with ``--must-refuse``) measures the dense search's evidence on every pair, whatever
the keypoints did (and that of every thin keypoint consensus, the patch count turned off): every
candidate pose polished, its agreeing patches counted
(:func:`~tactile_rig.perception.gelsight.dense_search.agreeing_patches`); it prints the worst right
pose of the re-touches (fewest agreeing patches, and the smallest ratio to a wrong candidate of the
same pair) against the best wrong pose anywhere (the re-touches' wrong candidates and every
candidate of the pairs that must be refused): the margin the defaults
(``search_min_patches``, ``search_min_ratio``) sit in. ``--held-out`` swaps the pairs that must be
refused for ones the defaults were not chosen on (run it with ``--seeds 3,4,5``).
"""

from __future__ import annotations

import os

import _single_core  # noqa: E402,F401  (first: one BLAS/OpenMP thread before numpy loads)

import argparse  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

from _output import add_save_args, parse_args, save_json  # noqa: E402  (benchmarks/ is the script's folder)

import cv2  # noqa: E402
import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from tactile_rig.perception.gelsight import RegistrationParams, register  # noqa: E402
from tactile_rig.perception.gelsight.dense_search import agreeing_patches, rotation_search  # noqa: E402
from tactile_rig.perception.gelsight.registration import (  # noqa: E402
    WEAK_CONSENSUS_INLIERS,
    WEAK_CONSENSUS_NCC,
    dense_refine,
    detect_scale,
    extract_features,
)
from tactile_rig.rig.trade.registration_data import (  # noqa: E402
    TAXIM_MM_PER_PX,
    Score,
    is_right,
    pose_error,
    retouch_set,
    unrelated_tile_pairs,
)

SETTINGS = {"defaults": RegistrationParams(), "keypoints only": RegistrationParams(dense_fallback=False)}
# Looser settings measured on the must-refuse pairs beside the defaults (trade rows ahead of the default).
LOOSER = {"inlier_px=6": RegistrationParams(inlier_px=6.0),
          "search bars loosened": RegistrationParams(search_min_patches=15, search_min_ratio=1.0),
          "orb_features=150": RegistrationParams(orb_features=150),
          "max_sigma=0.5": RegistrationParams(max_sigma_px=0.5, max_sigma_rot_deg=0.5)}
# A candidate this close to the truth is neither right nor wrong for the margin (deg, mm).
NEAR_ROT_DEG, NEAR_TRANS_MM = 2.0, 0.2


def refuse_groups(n_tiles: int, held_out: bool = False) -> dict[str, list[tuple[np.ndarray, np.ndarray, float]]]:
    """The pairs that must be refused, by group: (A, B, mm per px); ``held_out``: other tile draws,
    other plates and other re-touch draws than the ones the defaults were chosen on."""
    tiles = unrelated_tile_pairs(n_tiles, seed=2 if held_out else 1)
    groups: dict[str, list[tuple[np.ndarray, np.ndarray, float]]] = {
        "unrelated ball-press tiles": [(a, b, TAXIM_MM_PER_PX) for a, b in tiles]}
    usb, plate = retouch_set("usb", seed=3 if held_out else 0), retouch_set("plate", seed=3 if held_out else 0)
    groups["other part's re-touches"] = ([(plate.a.height_mm, t.height_mm, plate.mm_per_px) for t in usb.touches]
                                         + [(usb.a.height_mm, t.height_mm, usb.mm_per_px) for t in plate.touches])
    groups["other plates' re-touches"] = [(plate.a.height_mm, t.height_mm, plate.mm_per_px)
                                          for other in (("other_plate_10", "other_plate_11") if held_out
                                                        else ("other_plate_8", "other_plate_9"))
                                          for t in retouch_set(other, seed=4 if held_out else 3).touches]
    return groups


def search_evidence(a: np.ndarray, b: np.ndarray, params: RegistrationParams) -> list[tuple[np.ndarray, int, float, bool]]:
    """Every dense-search candidate of the pair as register polishes it: (B->A matrix px, agreeing
    patches, 1-sigma translation px, passes the per-pose bars but the patch count), wandered
    polishes left out, 0 patches below min_overlap."""
    k = detect_scale(params, b.shape)
    fa = extract_features(a, params, scale=k)
    fb = extract_features(b, params, dense=False, scale=k)
    found = rotation_search(a, b, highpass_px=params.search_highpass_px, coarse_px=params.search_coarse_px,
                            step_deg=params.search_step_deg, max_candidates=params.search_candidates,
                            valid_a=fa.valid, valid_b=fb.valid)
    out = []
    for c in found.candidates:
        f = dense_refine(fa, fb.smooth, c.matrix_px, params.refine_iters, gain_fit=params.dense_gain,
                         valid_b=fb.valid, bias_order=params.dense_bias_order)
        if f.wandered or not np.isfinite(f.ncc):
            continue
        n = agreeing_patches(fa.smooth, fb.smooth, f.matrix_px, params.search_patch_px, fa.valid, fb.valid) \
            if f.overlap >= params.min_overlap else 0
        bars = (f.converged and f.overlap >= params.min_overlap and f.rotation_pinning >= params.min_rotation_pinning
                and f.sigma_rot_deg <= params.max_sigma_rot_deg and f.sigma_px <= params.search_max_sigma_px
                and max(f.ncc, 0.0) ** 2 * f.overlap >= params.search_min_explained)
        out.append((f.matrix_px, n, f.sigma_px, bool(bars)))
    return out


def margin(seeds: list[int], n_tiles: int, held_out: bool = False) -> dict:
    """The worst right pose of the re-touches against the best wrong poses (agreeing patches; the
    wrong poses agreeing on search_min_patches or more, by their 1-sigma translation)."""
    params = RegistrationParams()
    right_min = (10**9, "")
    ratio_min = (float("inf"), "")
    wrong_max = {}  # group -> (agreeing patches, where)
    many = (float("inf"), "")  # smallest sigma px of a wrong pose agreeing on search_min_patches or more
    right_sigma = (0.0, "")  # largest sigma px of a right pose
    passing = 0  # wrong poses passing every per-pose bar

    thin: dict[str, list[int]] = {"right": [], "wrong": []}  # agreeing patches of thin keypoint answers

    def thin_answer(a: np.ndarray, b: np.ndarray, mm: float, truth: np.ndarray | None) -> None:
        # A keypoint answer with a thin consensus, the patch count off: its agreeing patches.
        res = register(a, b, mm, RegistrationParams(search_min_patches=0, dense_fallback=False))
        if not res.ok or res.inliers >= WEAK_CONSENSUS_INLIERS or res.ncc >= WEAK_CONSENSUS_NCC:
            return
        k = detect_scale(params, b.shape)
        fa, fb = extract_features(a, params, scale=k), extract_features(b, params, dense=False, scale=k)
        n = agreeing_patches(fa.smooth, fb.smooth, res.matrix_px, params.search_patch_px, fa.valid, fb.valid)
        ok = truth is not None and is_right(*pose_error(res.matrix_px, truth, b.shape, mm))
        thin["right" if ok else "wrong"].append(n)

    def wrong(group: str, n: int, sigma: float, bars: bool, where: str) -> None:
        nonlocal many, passing
        wrong_max[group] = max(wrong_max.get(group, (-1, "")), (n, where))
        if n >= params.search_min_patches:
            many = min(many, (sigma, where))
            passing += bars

    for seed in seeds:
        for part in ("usb", "plate"):
            data = retouch_set(part, seed=seed)
            for i, (t, truth) in enumerate(zip(data.touches, data.truth_px)):
                right, other = [], []
                where = f"{part} seed {seed} re-touch {i}"
                for m, n, sigma, bars in search_evidence(data.a.height_mm, t.height_mm, params):
                    err = pose_error(m, truth, t.height_mm.shape, data.mm_per_px)
                    if is_right(*err):
                        right.append(n)
                        right_sigma = max(right_sigma, (sigma, where))
                    elif err[0] > NEAR_ROT_DEG or err[1] > NEAR_TRANS_MM:
                        other.append(n)
                        wrong(f"{part} re-touches' wrong candidates", n, sigma, bars, where)
                thin_answer(data.a.height_mm, t.height_mm, data.mm_per_px, truth)
                if right:
                    right_min = min(right_min, (max(right), where))
                    ratio_min = min(ratio_min, (max(right) / max(max(other, default=0), 1), where))
    for group, pairs in refuse_groups(n_tiles, held_out).items():
        for i, (a, b, mm) in enumerate(pairs):
            thin_answer(a, b, mm, None)
            for _m, n, sigma, bars in search_evidence(a, b, params):
                wrong(group, n, sigma, bars, f"pair {i}")
    print(f"margin: right poses agree on >= {right_min[0]} patches ({right_min[1]}) and on >= {ratio_min[0]:.2f}x "
          f"their pair's best wrong candidate ({ratio_min[1]}); defaults search_min_patches="
          f"{params.search_min_patches}, search_min_ratio={params.search_min_ratio}")
    for group, (n, where) in wrong_max.items():
        print(f"margin: best wrong pose, {group}: {n} agreeing patches ({where})")
    print(f"margin: wrong poses agreeing on >= {params.search_min_patches} patches pin translation to "
          f">= {many[0]:.3f} px 1-sigma ({many[1]}), right poses to <= {right_sigma[0]:.3f} px ({right_sigma[1]}); "
          f"search_max_sigma_px {params.search_max_sigma_px}; wrong poses passing every "
          f"per-pose bar: {passing}")
    print(f"margin: thin keypoint answers (< {WEAK_CONSENSUS_INLIERS} inliers, NCC < {WEAK_CONSENSUS_NCC}, patch count "
          f"off): {len(thin['right'])} right agree on >= {min(thin['right'], default=0)} patches, {len(thin['wrong'])} "
          f"wrong on <= {max(thin['wrong'], default=0)} (search_min_patches={params.search_min_patches})")
    return {"thin_keypoint_right": thin["right"], "thin_keypoint_wrong": thin["wrong"], "right_min_agreeing": right_min, "right_min_ratio": ratio_min, "wrong_max_agreeing": wrong_max,
            "wrong_agreeing_min_sigma_px": many, "right_max_sigma_px": right_sigma, "wrong_passing_pose_bars": passing}


def must_refuse(n_tiles: int, held_out: bool = False) -> dict:
    """Placements (by method) of every setting on pairs with nothing to register."""
    groups = refuse_groups(n_tiles, held_out)
    out: dict = {}
    for group, pairs in groups.items():
        out[group] = {"pairs": len(pairs)}
        for name, params in {**SETTINGS, **LOOSER}.items():
            placed: dict[str, int] = {}
            for a, b, mm in pairs:
                res = register(a, b, mm, params)
                if res.ok:
                    placed[res.method] = placed.get(res.method, 0) + 1
            out[group][name] = placed
            print(f"must refuse: {group} ({len(pairs)} pairs), {name}: placed {sum(placed.values())} {placed or ''}")
    return out


def run_set(part: str, seed: int, step: int, repeats: int) -> dict:
    """Score and time both settings on one re-touch set."""
    data = retouch_set(part, seed=seed)
    a = data.a.height_mm
    pairs = list(zip(data.touches, data.truth_px))[::step]
    scores = {k: Score() for k in SETTINGS}
    best = {k: [float("inf")] * len(pairs) for k in SETTINGS}
    searched = 0
    register(a, pairs[0][0].height_mm, data.mm_per_px)  # warm-up (detector construction)
    for rep in range(repeats):
        for i, (t, truth) in enumerate(pairs):
            for name, params in SETTINGS.items():
                t0 = time.perf_counter()
                res = register(a, t.height_mm, data.mm_per_px, params)
                best[name][i] = min(best[name][i], time.perf_counter() - t0)
                if rep == 0:
                    scores[name].add(res, truth, t.height_mm.shape, data.mm_per_px)
                    searched += name == "defaults" and res.method in ("dense_search", f"{params.detector}+dense")
    out = {"part": part, "seed": seed, "pairs": len(pairs), "pairs_searched": int(searched)}
    for name in SETTINGS:
        out[name] = {**scores[name].as_dict(), "ms_per_pair_mean": 1e3 * float(np.mean(best[name])),
                     "ms_per_pair_median": 1e3 * float(np.median(best[name]))}
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="every third re-touch")
    ap.add_argument("--seeds", default="0", help="comma-separated re-touch set seeds (default 0)")
    ap.add_argument("--repeats", type=int, default=3, help="timed calls per pair and setting (best kept)")
    ap.add_argument("--must-refuse", type=int, nargs="?", const=480, default=0, metavar="N",
                    help="also count placements on N unrelated tile pairs (default 480), the other part's "
                    "re-touches and two other plates' re-touches")
    ap.add_argument("--margin", action="store_true",
                    help="with --must-refuse: the dense search's agreeing patches, worst right pose against the "
                    "best wrong pose on every pair")
    ap.add_argument("--held-out", action="store_true",
                    help="with --must-refuse: the held-out pairs (tile draw seed 2, plates seeded 10 and 11, "
                    "re-touch draws seeds 3-4) instead of the ones the defaults were chosen on")
    add_save_args(ap, "registration_search.json")
    args = parse_args(ap)
    if args.must_refuse < 0 or args.repeats < 1:
        ap.error(f"--must-refuse N must be >= 1 (got {args.must_refuse}) and --repeats >= 1 (got {args.repeats})")
    cv2.setNumThreads(1)
    seeds = [int(s) for s in args.seeds.split(",")]
    rows = []
    load0 = os.getloadavg()
    print(f"{'part':6} {'seed':>4} {'setting':15} {'right':>5} {'wrong':>5} {'refused':>7} {'rot MAE':>8} "
          f"{'trans MAE':>9} {'ms/pair':>8} {'searched':>8}")
    for seed in seeds:
        for part in ("usb", "plate"):
            row = run_set(part, seed, 3 if args.quick else 1, max(1, args.repeats))
            rows.append(row)
            for name in SETTINGS:
                r = row[name]
                print(f"{part:6} {seed:>4} {name:15} {r['right']:>5} {r['wrong']:>5} {r['refused']:>7} "
                      f"{r['rot_mae_deg']:>7.3f}° {r['trans_mae_mm']:>6.4f} mm {r['ms_per_pair_mean']:>8.2f} "
                      f"{row['pairs_searched'] if name == 'defaults' else '':>8}")
    refuse = must_refuse(args.must_refuse, args.held_out) if args.must_refuse else None
    gap = margin(seeds, args.must_refuse, args.held_out) if args.margin and args.must_refuse else None
    save_json(args, {"opencv": cv2.__version__, "numpy": np.__version__, "quick": args.quick,
                     "load_average_start": load0, "load_average_end": os.getloadavg(), "rows": rows,
                     "must_refuse": refuse, "margin": gap})
    return 0


if __name__ == "__main__":
    sys.exit(main())
