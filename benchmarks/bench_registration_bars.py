"""The figures behind the registration's fixed bars: rotation pinning, the squash test, thin consensus.

Run: ``python benchmarks/bench_registration_bars.py [--tiles N] [--save]`` (``--out PATH`` anywhere;
``--save`` writes ``benchmarks/results/registration_bars.json``). One thread. Three measurements, each
the number a constant or default of :mod:`tactile_rig.perception.gelsight` rests on:

* **rotation pinning** (``min_rotation_pinning`` 0.05): the polish's rotation information over its
  translation information x radius² (:class:`~tactile_rig.perception.gelsight.dense_refinement.DenseFit`),
  at the true pose, for a lone smooth dome (a 2 mm ball's spherical cap), each real Taxim ball press (a dome
  with the gel's own texture) and the textured re-touch maps (usb panel, plate);
* **squash test** (``SQUASH_ANISOTROPY_FACTOR`` 4): the ratio of the gradient anisotropy (of the
  high-passed heights the test reads) of 20 tiled real press maps and of the same maps moved rigidly
  (rotations -80..90 deg) or squashed by ``s`` along one axis;
* **thin consensus** (``WEAK_CONSENSUS_INLIERS`` 20, ``WEAK_CONSENSUS_NCC`` 0.98): the keypoint answers
  with the patch count off on ``--tiles`` unrelated tile pairs (all wrong) and on the re-touch sets of
  seed 0 (inliers and polished NCC of each).
"""

from __future__ import annotations

import os

import _single_core  # noqa: E402,F401  (first: one BLAS/OpenMP thread before numpy loads)

import argparse  # noqa: E402
import sys  # noqa: E402
from pathlib import Path  # noqa: E402

import cv2  # noqa: E402
import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from _output import add_save_args, parse_args, save_json  # noqa: E402  (benchmarks/ is the script's folder)

from tactile_rig.perception.gelsight.calibration import sphere_cap  # noqa: E402
from tactile_rig.perception.gelsight.dense_refinement import dense_refine  # noqa: E402
from tactile_rig.perception.gelsight.features import extract_features  # noqa: E402
from tactile_rig.perception.gelsight.registration import RegistrationParams, register  # noqa: E402
from tactile_rig.perception.gelsight.rigid_fit import _anisotropy  # noqa: E402
from tactile_rig.perception.gelsight.synthetic import jig_move, tile  # noqa: E402
from tactile_rig.rig.trade.registration_data import (  # noqa: E402
    TAXIM_MM_PER_PX,
    retouch_set,
    taxim_heights,
    unrelated_tile_pairs,
)

PARAMS = RegistrationParams()


def pinning_at_identity(height_mm: np.ndarray) -> float:
    """The rotation pinning of a map against itself at the true pose (the polish's own reading)."""
    fa = extract_features(height_mm, PARAMS)
    fb = extract_features(height_mm, PARAMS, dense=False)
    fit = dense_refine(fa, fb.smooth, np.array([[1.0, 0, 0], [0, 1.0, 0]]), PARAMS.refine_iters,  # type: ignore[arg-type]
                       gain_fit=PARAMS.dense_gain, valid_b=fb.valid, bias_order=PARAMS.dense_bias_order)
    return float(fit.rotation_pinning)


def rotation_pinning() -> dict[str, list[float]]:
    dome = sphere_cap((120, 160), (70.0, 55.0), 15.0, 2.0, TAXIM_MM_PER_PX)[0].astype(np.float32)
    out = {"lone smooth dome (a 2 mm ball's cap)": [pinning_at_identity(dome)],
           "real ball press (dome + gel texture)": [pinning_at_identity(h) for h in taxim_heights()]}
    for part in ("usb", "plate"):
        out[f"{part} map touch"] = [pinning_at_identity(retouch_set(part, seed=0).a.height_mm)]
    return out


def _squash(z: np.ndarray, s: float) -> np.ndarray:
    """``z`` squashed by ``s`` along y about its centre (det R = s), in a frame of the same size."""
    h, w = z.shape
    return cv2.warpAffine(z, np.array([[1.0, 0, 0], [0, s, (1 - s) * (h - 1) / 2.0]]), (w, h))


def _smooth_anisotropy(z: np.ndarray) -> float:
    """The anisotropy the squash test reads: of the map's high-passed, smoothed heights."""
    return _anisotropy(extract_features(np.nan_to_num(z), PARAMS, dense=False).smooth)  # type: ignore[arg-type]


def squash() -> dict[str, list[float]]:
    hs = taxim_heights()
    rng = np.random.default_rng(0)
    rigid: list[float] = []
    squashed: dict[float, list[float]] = {s: [] for s in (0.7, 0.45, 0.4, 0.2)}
    for _ in range(20):
        idx = rng.permutation(len(hs))[:4]
        a = tile([hs[i] for i in idx])
        ra = _smooth_anisotropy(a)
        for rot in (-80.0, -40.0, 10.0, 50.0, 90.0):
            rb = _smooth_anisotropy(jig_move(a, rot, (0.5, -0.5), TAXIM_MM_PER_PX)[0])
            rigid.append(min(ra, rb) / max(ra, rb))
        for s, got in squashed.items():
            rb = _smooth_anisotropy(_squash(a, s))
            got.append(min(ra, rb) / max(ra, rb))
    return {"rigid moves": rigid, **{f"squash s={s}": v for s, v in squashed.items()}}


def thin_consensus(n_tiles: int) -> dict[str, list[tuple[int, float]]]:
    """(inliers, NCC) of every keypoint answer placed with the patch count off."""
    loose = RegistrationParams(search_min_patches=0, dense_fallback=False)
    wrong = [(r.inliers, r.ncc) for a, b in unrelated_tile_pairs(n_tiles, seed=1)
             for r in [register(a, b, TAXIM_MM_PER_PX, loose)] if r.ok]
    right = [(r.inliers, r.ncc) for part in ("usb", "plate") for data in [retouch_set(part, seed=0)]
             for t in data.touches for r in [register(data.a.height_mm, t.height_mm, data.mm_per_px, loose)] if r.ok]
    return {"unrelated tile pairs (placed, all wrong)": wrong, "re-touches seed 0 (placed)": right}


def _span(v: list[float]) -> str:
    return f"{min(v):.3f}-{max(v):.3f} (n={len(v)})" if v else "none"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--tiles", type=int, default=960, help="unrelated tile pairs for the thin consensus (default 960)")
    add_save_args(ap, "registration_bars.json")
    args = parse_args(ap)
    if args.tiles < 1:
        ap.error(f"--tiles must be >= 1, got {args.tiles}")
    cv2.setNumThreads(1)
    pin = rotation_pinning()
    for k, v in pin.items():
        print(f"rotation pinning, {k}: {_span(v)}  (min_rotation_pinning {PARAMS.min_rotation_pinning})")
    sq = squash()
    for k, v in sq.items():
        print(f"anisotropy ratio, {k}: {_span(v)}  (refused below 1/4)")
    thin = thin_consensus(args.tiles)
    for k, v in thin.items():
        inl = [i for i, _ in v]
        ncc = [c for _, c in v]
        thin_n = sum(1 for i, c in v if i < 20 and c < 0.98)
        print(f"keypoint answers, {k}: {len(v)}; inliers {_span(inl)}, NCC {_span(ncc)}; "
              f"thin (< 20 inliers and NCC < 0.98): {thin_n}")
    save_json(args, {"opencv": cv2.__version__, "numpy": np.__version__, "rotation_pinning": pin,
                     "anisotropy_ratio": sq, "thin_consensus": thin, "load_average_end": os.getloadavg()})
    return 0


if __name__ == "__main__":
    sys.exit(main())
