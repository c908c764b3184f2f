"""Recording throughput: can the MCAP recorder keep up with a fingertip camera?

    python benchmarks/bench_recording.py [--quick]

Writes N frames (320x240 and 640x480 BGR, a GelSight-like smooth image with sensor noise) plus a
scale reading per frame through :class:`tactile_rig.rig.recording.Recorder`, side by side with the
baseline of writing the same raw bytes to a plain file (no JSON, no base64, no chunking):

- ``raw_json``: foxglove.RawImage (base64 in JSON), zstd chunks, flushed every second;
- ``jpeg``: foxglove.CompressedImage, JPEG quality 95 (OpenCV's default);
- ``png``: foxglove.CompressedImage, PNG;
- ``baseline_bytes``: ``f.write(img.tobytes())``.

Reports frames per second (wall and CPU), MB per frame on disk, and the time to read the file back.
Prints a table; ``--save`` writes ``benchmarks/results/recording.json``.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

from _output import add_save_args, parse_args, save_json  # noqa: E402  (benchmarks/ is the script's folder)

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from tactile_rig.core.clock import VirtualClock  # noqa: E402
from tactile_rig.rig.recording import Recorder, read_recording  # noqa: E402


def _frames(shape: tuple[int, int], n: int) -> list[np.ndarray]:
    h, w = shape
    y, x = np.mgrid[0:h, 0:w].astype(np.float32)
    base = 120 + 40 * np.sin(x / 37.0) * np.cos(y / 23.0)
    rng = np.random.default_rng(0)
    out = []
    for k in range(n):
        img = base + 30 * np.exp(-((x - w / 2 - 3 * k) ** 2 + (y - h / 2) ** 2) / (0.02 * w * w))
        img = img[..., None] + np.array([0.0, 8.0, -8.0]) + rng.normal(0, 1.5, (h, w, 3))
        out.append(np.clip(img, 0, 255).astype(np.uint8))
    return out


def _run(mode: str, frames: list[np.ndarray], path: Path) -> dict[str, float]:
    t0, c0 = time.perf_counter(), time.process_time()
    if mode == "baseline_bytes":
        with open(path, "wb") as f:
            for img in frames:
                f.write(img.tobytes())
                f.write(b"0.0")
            f.flush()
    else:
        clock = VirtualClock()
        with Recorder(path, clock=clock) as rec:
            for i, img in enumerate(frames):
                clock.advance(1 / 30)
                rec.write_frame("cam", img, compress=None if mode == "raw_json" else mode)
                rec.write_scale(0.01 * i)
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    row = {"fps_wall": len(frames) / wall, "fps_cpu": len(frames) / max(cpu, 1e-9),
           "mb_per_frame": path.stat().st_size / len(frames) / 1e6}
    if mode != "baseline_bytes":
        t0 = time.perf_counter()
        rec_back = read_recording(path)
        n = sum(1 for m in rec_back.messages if m.schema.startswith("foxglove.") and "Image" in m.schema)
        assert n == len(frames), (n, len(frames))
        row["read_fps"] = len(frames) / (time.perf_counter() - t0)
    return row


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="fewer frames")
    add_save_args(ap, "recording.json")
    args = parse_args(ap)
    n = 30 if args.quick else 150
    results = []
    with tempfile.TemporaryDirectory() as tmp:
        for shape in ((240, 320), (480, 640)):
            frames = _frames(shape, n)
            for mode in ("baseline_bytes", "raw_json", "jpeg", "png"):
                row = {"size": f"{shape[1]}x{shape[0]}", "mode": mode, "frames": n,
                       **_run(mode, frames, Path(tmp) / f"{mode}.bin")}
                results.append(row)
    out = {"benchmark": "recording", "python": platform.python_version(), "machine": platform.machine(),
           "load_avg": os.getloadavg(), "quick": args.quick, "results": results}
    save_json(args, out)
    print(f"{'size':>8} {'mode':>15} {'fps wall':>9} {'fps cpu':>9} {'MB/frame':>9} {'read fps':>9}")
    for r in results:
        print(f"{r['size']:>8} {r['mode']:>15} {r['fps_wall']:9.1f} {r['fps_cpu']:9.1f} {r['mb_per_frame']:9.3f} "
              f"{r.get('read_fps', float('nan')):9.1f}")


if __name__ == "__main__":
    main()
