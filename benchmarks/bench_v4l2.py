"""Frames per second, added latency and CPU per frame of the emulated V4L2 camera, beside the HTTP camera.

Two emulated C310s (``tactile_rig.mocks.v4l2.V4L2Camera``) served from this process, each read by
OpenCV's V4L2 backend in its own client process started with the camera's environment; then the same
two cameras as the rehearsal bench's HTTP MJPEG servers (``rig/rehearsal/camera_server.py``) read by
``drivers/camera_http.HttpCameraSource`` in two client processes. For each, at 640x480 MJPG 30 fps
and 320x240 YUYV 30 fps (the HTTP camera always sends JPEG: its 320x240 row is MJPEG):

* frames/s each client got, and the frames it missed (timestamp steps beyond one interval);
* latency: from the frame's start (the V4L2 buffer timestamp, CLOCK_MONOTONIC; the HTTP camera's
  frame time on the same clock) to the moment the client holds the decoded BGR image; median, p95;
* CPU per frame: the server process's and the clients' CPU time over the frames delivered.

The sensor image (the C310 model rendering the GelSight scene, read noise, auto exposure) is the
same for both transports; its rendering cost is in the server's CPU of both.

    python benchmarks/bench_v4l2.py            # 10 s per row
    python benchmarks/bench_v4l2.py --quick    # 3 s per row
    python benchmarks/bench_v4l2.py --save     # benchmarks/results/v4l2.json
"""

from __future__ import annotations

import argparse
import os
import resource
import shutil
import statistics
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any, Callable

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import bench_v4l2  # noqa: E402  (this module by name: a child process imports the client bodies from it)
from _output import add_save_args, parse_args, save_json  # noqa: E402

MODES = (("MJPG", 640, 480, 30.0), ("YUYV", 320, 240, 30.0))
WARMUP_FRAMES = 10


# -- client bodies (run in child processes) ------------------------------------------------------------
def v4l2_client(port: str, fourcc: str, width: int, height: int, fps: float, duration_s: float) -> dict[str, Any]:
    """OpenCV's V4L2 backend: (latency of each frame, CPU seconds, wall seconds, frames)."""
    import cv2

    cap = cv2.VideoCapture(port, cv2.CAP_V4L2)
    cap.set(cv2.CAP_PROP_FOURCC, cv2.VideoWriter_fourcc(*fourcc))
    cap.set(cv2.CAP_PROP_FRAME_WIDTH, width)
    cap.set(cv2.CAP_PROP_FRAME_HEIGHT, height)
    cap.set(cv2.CAP_PROP_FPS, fps)
    stamps, lat = [], []
    for _ in range(WARMUP_FRAMES):
        cap.read()
    cpu0, t0 = time.process_time(), time.monotonic()
    while time.monotonic() - t0 < duration_s:
        ok, img = cap.read()
        now = time.monotonic()
        if not ok:
            raise RuntimeError(f"{port}: read() failed")
        ts = cap.get(cv2.CAP_PROP_POS_MSEC) / 1000.0
        stamps.append(ts)
        lat.append(now - ts)
    out = {"cpu_s": time.process_time() - cpu0, "wall_s": time.monotonic() - t0, "stamps": stamps, "latency_s": lat,
           "shape": list(img.shape)}
    cap.release()
    return out


def http_client(url: str, t0_s: float, duration_s: float) -> dict[str, Any]:
    """The rehearsal bench's HTTP camera source; the frame's time is the camera's t_device_s + t0."""
    from tactile_rig.drivers.camera_http import HttpCameraSource

    src = HttpCameraSource(url)
    src.open()
    for _ in range(WARMUP_FRAMES):
        src.read(2.0)
    stamps, lat = [], []
    cpu0, t0 = time.process_time(), time.monotonic()
    shape: list[int] = []
    while time.monotonic() - t0 < duration_s:
        raw = src.read(2.0)
        now = time.monotonic()
        if raw is None or raw.t_device_s is None:
            raise RuntimeError(f"{url}: no frame")
        ts = t0_s + raw.t_device_s
        stamps.append(ts)
        lat.append(now - ts)
        shape = list(raw.image.shape)
    out = {"cpu_s": time.process_time() - cpu0, "wall_s": time.monotonic() - t0, "stamps": stamps, "latency_s": lat,
           "shape": shape}
    src.close()
    return out


# -- the parent --------------------------------------------------------------------------------------------
def _self_cpu_s() -> float:
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def _run_clients(jobs: list[tuple[Callable[..., Any], tuple[Any, ...], dict[str, str]]]) -> list[dict[str, Any]]:
    from tactile_rig.mocks.v4l2.child import run_in_child

    results: list[Any] = [None] * len(jobs)

    def one(i: int) -> None:
        fn, args, env = jobs[i]
        try:
            results[i] = run_in_child(fn, *args, env=env, timeout_s=300)
        except BaseException as exc:  # noqa: BLE001  (reported below)
            results[i] = exc

    threads = [threading.Thread(target=one, args=(i,)) for i in range(len(jobs))]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    for r in results:
        if isinstance(r, BaseException):
            raise r
    return results


def _summary(clients: list[dict[str, Any]], server_cpu_s: float, fps: float) -> dict[str, Any]:
    period = 1.0 / fps
    per_client = []
    frames = 0
    for c in clients:
        steps = [b - a for a, b in zip(c["stamps"], c["stamps"][1:])]
        missed = sum(max(0, round(s / period) - 1) for s in steps)
        n = len(c["stamps"])
        frames += n
        lat = sorted(c["latency_s"])
        per_client.append({"frames": n, "fps": n / c["wall_s"], "missed": missed,
                           "latency_ms_median": 1e3 * statistics.median(lat),
                           "latency_ms_p95": 1e3 * lat[int(0.95 * (len(lat) - 1))],
                           "client_cpu_ms_per_frame": 1e3 * c["cpu_s"] / max(n, 1), "shape": c["shape"]})
    client_cpu = sum(c["cpu_s"] for c in clients)
    return {"cameras": per_client,
            "fps_per_camera": statistics.mean(p["fps"] for p in per_client),
            "latency_ms_median": statistics.median(p["latency_ms_median"] for p in per_client),
            "latency_ms_p95": max(p["latency_ms_p95"] for p in per_client),
            "server_cpu_ms_per_frame": 1e3 * server_cpu_s / max(frames, 1),
            "client_cpu_ms_per_frame": 1e3 * client_cpu / max(frames, 1),
            "total_cpu_ms_per_frame": 1e3 * (server_cpu_s + client_cpu) / max(frames, 1)}


def bench_v4l2_mode(fourcc: str, width: int, height: int, fps: float, duration_s: float) -> dict[str, Any]:
    from tactile_rig.mocks.v4l2 import V4L2Camera

    registry = tempfile.mkdtemp(prefix="trv-bench-")
    cams = [V4L2Camera("c310", registry=registry, seed=i).start() for i in range(2)]
    try:
        jobs = [(bench_v4l2.v4l2_client, (c.port, fourcc, width, height, fps, duration_s), c.env) for c in cams]
        cpu0 = _self_cpu_s()
        clients = _run_clients(jobs)
        server_cpu = _self_cpu_s() - cpu0
    finally:
        for c in cams:
            c.stop()
        shutil.rmtree(registry, ignore_errors=True)
    return _summary(clients, server_cpu, fps)


def bench_http_mode(fourcc: str, width: int, height: int, fps: float, duration_s: float) -> dict[str, Any]:
    from tactile_rig.devices.camera_models import camera_model
    from tactile_rig.mocks.v4l2.frames import build_camera
    from tactile_rig.rig.rehearsal.camera_server import CameraServer

    servers = []
    for i in range(2):
        sim = build_camera(camera_model("c310"), seed=i)
        server = CameraServer(sim, jpeg_quality=90).start()
        sim.set_format("MJPG", width, height, fps)
        servers.append((server, sim))
    try:
        jobs = [(bench_v4l2.http_client, (s.url, sim._t0, duration_s), {}) for s, sim in servers]
        cpu0 = _self_cpu_s()
        clients = _run_clients(jobs)
        server_cpu = _self_cpu_s() - cpu0
    finally:
        for s, _ in servers:
            s.stop()
    return _summary(clients, server_cpu, fps)


def _row(name: str, r: dict[str, Any]) -> str:
    missed = sum(c["missed"] for c in r["cameras"])
    return (f"{name:<28} {r['fps_per_camera']:6.1f} fps  missed {missed:3d}  latency {r['latency_ms_median']:6.1f} ms "
            f"(p95 {r['latency_ms_p95']:6.1f})  CPU/frame server {r['server_cpu_ms_per_frame']:5.1f} ms "
            f"client {r['client_cpu_ms_per_frame']:5.1f} ms")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="3 s per row instead of 10")
    add_save_args(ap, "v4l2.json")
    args = parse_args(ap)
    duration = 3.0 if args.quick else 10.0
    from tactile_rig.mocks.v4l2 import toolchain_problem

    problem = toolchain_problem()
    if problem:
        print(problem, file=sys.stderr)
        return 2
    results: dict[str, Any] = {"duration_s_per_row": duration, "cameras": 2, "cpu_count": os.cpu_count(),
                               "load_average_before": list(os.getloadavg()), "rows": {}}
    for fourcc, w, h, fps in MODES:
        key = f"{w}x{h} {fourcc} {fps:g} fps"
        v = bench_v4l2_mode(fourcc, w, h, fps, duration)
        print(_row(f"V4L2 emulation {key}", v), flush=True)
        hkey = f"{w}x{h} MJPG {fps:g} fps"
        h_ = bench_http_mode(fourcc, w, h, fps, duration)
        print(_row(f"HTTP camera {hkey}", h_), flush=True)
        results["rows"][key] = {"v4l2": v, "http": h_}
    results["load_average_after"] = list(os.getloadavg())
    save_json(args, results)
    return 0


if __name__ == "__main__":
    sys.exit(main())
