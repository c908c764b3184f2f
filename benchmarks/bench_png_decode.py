"""PNG frames to BGR pixels: the rig's own decoder against OpenCV, imagecodecs and pyspng, same frames.

Run: ``python benchmarks/bench_png_decode.py [--rounds R] [--save]`` (``pip install imagecodecs pyspng``
for their rows; a decoder that is not installed is reported as such). ONE CORE: the process pins itself
to one CPU (``--no-pin`` to skip) and runs one OpenCV thread.

Frames: every PNG of the real sensor data (``../shared/data/real``: GelSight Mini, GelSight, FingerVision
and 9DTact frames; ``--real DIR`` or ``TACTILE_RIG_SHARED_DATA``) and GelSight Mini ball presses rendered
on the real background and written by OpenCV, as the rig writes its frames (calibration presses,
recordings). Each decoder turns the file's bytes, in memory, into the BGR uint8 array OpenCV's
``imdecode`` gives (the RGB decoders convert with ``cv2.cvtColor``); every output is compared with
OpenCV's, pixel for pixel. Rows:

* ``rig (fast extra)``: :func:`~tactile_rig.rig.files.png.png_chunks` (every chunk's CRC-32) then
  :func:`~tactile_rig.rig.files.png.decode_rgb8_bgr` with ISA-L's inflate (OpenCV for a PNG it leaves),
  exactly what ``read_image`` does after reading the file;
* ``rig (zlib)``: the same with the standard library's inflate and CRC-32 (no ``fast`` extra);
* ``opencv``, ``imagecodecs libpng``, ``imagecodecs libspng``, ``pyspng``: the library's decode alone,
  and ``+ checks`` the same after the CRC walk the rig keeps whatever decodes (ISA-L's CRC-32).

Rounds alternate the decoders; each frame's best of ``--rounds`` counts. Prints ms per frame (mean of
the frames' best) per set and the ratio of each row to the rig's; ``--save`` writes
``benchmarks/results/png_decode.json`` (``--out PATH`` anywhere).
"""

from __future__ import annotations

import os

import _single_core  # noqa: E402,F401  (first: one BLAS/OpenMP thread before numpy loads)

import argparse  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
import zlib  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import Any, Callable  # noqa: E402

import cv2  # noqa: E402
import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from _output import add_save_args, parse_args, save_json  # noqa: E402
from _single_core import pin_one_core  # noqa: E402  (benchmarks/ is the script's folder)

from tactile_rig.perception.gelsight import load_presses  # noqa: E402
from tactile_rig.rig.files import deflate, png  # noqa: E402
from tactile_rig.rig.trade.registration_data import MINI_MM_PER_PX, MINI_SHAPE  # noqa: E402
from tactile_rig.sim.render import gelsight as render  # noqa: E402
from tests._data import SHARED_REAL  # noqa: E402

Decoder = Callable[[bytes], np.ndarray]


def _opencv(data: bytes) -> np.ndarray:
    return cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)


def _rig(data: bytes) -> np.ndarray:
    problem, chunks = png.png_chunks(data)
    if problem:
        raise ValueError(problem)
    img = png.decode_rgb8_bgr(chunks)
    return _opencv(data) if img is None else img


def _with_zlib(fn: Decoder) -> Decoder:
    def run(data: bytes) -> np.ndarray:
        saved = deflate._decompressobj, deflate._crc
        deflate._decompressobj, deflate._crc = zlib.decompressobj, zlib.crc32
        try:
            return fn(data)
        finally:
            deflate._decompressobj, deflate._crc = saved
    return run


def _checked(fn: Decoder) -> Decoder:
    def run(data: bytes) -> np.ndarray:
        if png.png_problem(data):
            raise ValueError("damaged")
        return fn(data)
    return run


def decoders() -> tuple[dict[str, Decoder], dict[str, str]]:
    """The rows, and the libraries that are not installed (row -> why)."""
    rows: dict[str, Decoder] = {"rig (fast extra)": _rig, "rig (zlib)": _with_zlib(_rig), "opencv": _opencv}
    missing: dict[str, str] = {}
    try:
        import imagecodecs

        rows["imagecodecs libpng"] = lambda d: cv2.cvtColor(imagecodecs.png_decode(d), cv2.COLOR_RGB2BGR)
        rows["imagecodecs libspng"] = lambda d: cv2.cvtColor(imagecodecs.spng_decode(d), cv2.COLOR_RGB2BGR)
    except ImportError:
        missing["imagecodecs"] = "not installed (pip install imagecodecs)"
    try:
        import pyspng

        rows["pyspng"] = lambda d: cv2.cvtColor(pyspng.load(d), cv2.COLOR_RGB2BGR)
    except ImportError:
        missing["pyspng"] = "not installed (pip install pyspng)"
    for name in [n for n in rows if not n.startswith("rig")]:
        rows[f"{name} + checks"] = _checked(rows[name])
    return rows, missing


def rendered_frames(tmp: Path, n: int) -> list[tuple[str, bytes]]:
    """GelSight Mini ball presses on the real background, PNG-encoded by OpenCV as the rig writes them."""
    render.render_ball_press_dataset(tmp / "presses", n_presses=n, shape_px=MINI_SHAPE, mm_per_px=MINI_MM_PER_PX,
                                     background="gsmini", seed=5)
    frames = load_presses(tmp / "presses").frames
    return [(f"press_{i:02d}", cv2.imencode(".png", f)[1].tobytes()) for i, f in enumerate(frames)]


def real_frames(folder: Path | None) -> list[tuple[str, bytes]]:
    if folder is None or not folder.is_dir():
        return []
    return [(str(p.relative_to(folder)), p.read_bytes()) for p in sorted(folder.rglob("*.png"))]


def measure(frames: list[tuple[str, bytes]], rows: dict[str, Decoder], rounds: int) -> dict[str, Any]:
    """Each row's ms per frame (mean of each frame's best of ``rounds``), the rows alternating."""
    best = {name: [float("inf")] * len(frames) for name in rows}
    for _ in range(rounds):
        for name, fn in rows.items():
            for i, (_, data) in enumerate(frames):
                t0 = time.perf_counter()
                fn(data)
                best[name][i] = min(best[name][i], time.perf_counter() - t0)
    ref = [_opencv(d) for _, d in frames]
    out: dict[str, Any] = {}
    for name, fn in rows.items():
        same = all(np.array_equal(fn(d), r) for (_, d), r in zip(frames, ref))
        out[name] = {"ms_per_frame": 1e3 * float(np.mean(best[name])), "identical_to_opencv": bool(same)}
    rig = out["rig (fast extra)"]["ms_per_frame"]
    for v in out.values():
        v["ratio_to_rig"] = v["ms_per_frame"] / rig
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rounds", type=int, default=7, help="alternating rounds; each frame's best counts (default 7)")
    ap.add_argument("--rendered", type=int, default=40, help="rendered GelSight Mini frames (default 40)")
    ap.add_argument("--real", default=None, help="folder of real frames (default ../shared/data/real)")
    ap.add_argument("--no-pin", action="store_true", help="do not pin the process to one CPU")
    add_save_args(ap, "png_decode.json")
    args = parse_args(ap)
    if args.rounds < 1 or args.rendered < 1:
        ap.error(f"--rounds and --rendered must be >= 1 (got {args.rounds}, {args.rendered})")
    cpu = None if args.no_pin else pin_one_core()
    cv2.setNumThreads(1)
    rows, missing = decoders()
    load0 = os.getloadavg()
    real_dir = Path(args.real) if args.real else SHARED_REAL
    with tempfile.TemporaryDirectory() as tmp:
        sets = {"rendered GelSight Mini (written by OpenCV)": rendered_frames(Path(tmp), args.rendered),
                "real sensor frames": real_frames(real_dir)}
    results: dict[str, Any] = {}
    for set_name, frames in sets.items():
        if not frames:
            print(f"{set_name}: no frames (real data folder {real_dir} absent)")
            continue
        fast = sum(png.decode_rgb8_bgr(png.png_chunks(d)[1]) is not None for _, d in frames)
        mpx = float(np.mean([_opencv(d).shape[0] * _opencv(d).shape[1] for _, d in frames])) / 1e6
        res = measure(frames, rows, args.rounds)
        results[set_name] = {"frames": len(frames), "mean_megapixels": mpx, "rig_fast_path_frames": fast,
                             "rows": res}
        print(f"{set_name}: {len(frames)} frames, {mpx:.3f} Mpx each on average, {fast} on the rig's fast path")
        for name, r in res.items():
            print(f"  {name:28} {r['ms_per_frame']:7.3f} ms/frame  x{r['ratio_to_rig']:5.2f} of the rig's"
                  f"{'' if r['identical_to_opencv'] else '  PIXELS DIFFER FROM OPENCV'}")
    for name, why in missing.items():
        print(f"  {name}: {why}")
    save_json(args, {"opencv": cv2.__version__, "numpy": np.__version__, "cpu_pinned": cpu,
                     "load_average_start": load0, "load_average_end": os.getloadavg(), "rounds": args.rounds,
                     "missing": missing, "sets": results})
    return 0


if __name__ == "__main__":
    sys.exit(main())
