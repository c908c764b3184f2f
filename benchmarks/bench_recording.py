"""Recording and live throughput, typed (Foxglove's protobuf types) against the JSON encoding.

    python benchmarks/bench_recording.py [--quick] [--session] [--save | --out PATH]

Part 1, per frame size (320x240, 640x480 BGR, a GelSight-like smooth image with sensor noise), N frames
plus a scale reading per frame, each encoding written through the project's MCAP writer (zstd chunks,
flushed every second) and read back:

- ``typed_raw`` / ``typed_jpeg`` / ``typed_png``: :class:`tactile_rig.rig.recording.Recorder`, frames as
  ``foxglove.RawImage`` / ``foxglove.CompressedImage`` in protobuf (the recorder's encoding);
- ``json_raw`` / ``json_jpeg``: the same frames as the JSON encoding writes them (``foxglove.RawImage`` /
  ``CompressedImage`` as JSON, the bytes in base64: the baseline, measured in the same run);
- ``baseline_bytes``: ``f.write(img.tobytes())`` (no container at all).

Reports bytes per frame on disk, CPU per message (process time / messages written: encode, write,
compress) and the read-back rate. JPEG quality 95 (OpenCV's default) in both encodings.

Part 2, live: the same JPEG frames published on a :class:`tactile_rig.rig.live.LiveServer` to a
subscribed WebSocket client (typed, and JSON on a JSON channel as the baseline): bytes per frame on
the wire and CPU per message of the publishing thread. Each encoding runs REPEATS times, the two taking
turns; the table gives the median and the range (a client thread in the same process shares the GIL, so
single runs scatter by a third).

Part 3, the MCAP writer alone: the same pre-encoded typed JPEG messages (3000, 320x240, 60 different
frames in turn) through the
project's writer (:class:`Recorder`, ``publish``) and through foxglove-sdk's own ``MCAPWriter`` (a
channel per topic, flushed once a second as the recorder does): CPU per message and bytes per message,
median and range over REPEATS runs taking turns.

Part 4 (``--session``): ``tactile-rig record`` of a rehearsal bench with two cameras at 30 fps
(the GelSight stage camera and a 30-fps footage camera) for 60 s; reports per camera the frames
recorded, those the host captured but the recording did not get (``dropped``) and the gaps in the
camera's own frame numbers (``camera_dropped``: lost before the host saw them), and the file size.

Prints tables; ``--save`` writes ``benchmarks/results/recording.json``.
"""

from __future__ import annotations

import argparse
import base64
import json
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

from _output import add_save_args, parse_args, save_json  # noqa: E402  (benchmarks/ is the script's folder)

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from tactile_rig.core.clock import VirtualClock  # noqa: E402
from tactile_rig.rig.live import LiveServer  # noqa: E402
from tactile_rig.rig.messages import Encoded, json_schema  # noqa: E402
from tactile_rig.rig.recording import Recorder, read_recording  # noqa: E402

JPEG_QUALITY = 95
REPEATS = 5


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


def json_frame(rec: Recorder, camera: str, img: np.ndarray, t: float, compress: str | None) -> Encoded:
    """A frame as the JSON encoding writes it: the Foxglove image type as JSON, its bytes in base64."""
    ns = rec.log_time_ns(t)
    stamp = {"sec": ns // 1_000_000_000, "nsec": ns % 1_000_000_000}
    if compress == "jpeg":
        ok, buf = cv2.imencode(".jpg", img, [int(cv2.IMWRITE_JPEG_QUALITY), JPEG_QUALITY])
        body = json.dumps({"timestamp": stamp, "frame_id": camera, "format": "jpeg", "t_s": t,
                           "data": base64.b64encode(buf.tobytes()).decode("ascii")}, separators=(",", ":")).encode()
        return Encoded(f"/{camera}/image/compressed", json_schema("foxglove.CompressedImage"), body, t, ns)
    h, w = img.shape[:2]
    head = {"timestamp": stamp, "frame_id": camera, "width": w, "height": h, "encoding": "bgr8",
            "step": int(img.strides[0]), "t_s": t}
    body = json.dumps(head, separators=(",", ":"))[:-1].encode() + b',"data":"' + \
        base64.b64encode(img.tobytes()) + b'"}'
    return Encoded(f"/{camera}/image", json_schema("foxglove.RawImage"), body, t, ns)


def _record(mode: str, frames: list[np.ndarray], path: Path) -> dict[str, float]:
    n_msgs = 2 * len(frames)
    t0, c0 = time.perf_counter(), time.process_time()
    if mode == "baseline_bytes":
        with open(path, "wb") as f:
            for img in frames:
                f.write(img.tobytes())
                f.write(b"0.0")
            f.flush()
    else:
        clock = VirtualClock()
        kind, _, comp = mode.partition("_")
        compress = None if comp == "raw" else comp
        with Recorder(path, clock=clock) as rec:
            rec.jpeg_quality = JPEG_QUALITY
            for i, img in enumerate(frames):
                clock.advance(1 / 30)
                if kind == "typed":
                    rec.write_frame("cam", img, compress=compress)
                else:
                    rec.publish(json_frame(rec, "cam", img, clock.now_s(), compress))
                rec.write_scale(0.01 * i)
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    row = {"fps_wall": len(frames) / wall, "cpu_us_per_message": 1e6 * cpu / n_msgs,
           "bytes_per_frame": path.stat().st_size / len(frames)}
    if mode != "baseline_bytes":
        t0 = time.perf_counter()
        back = read_recording(path)
        images = [m for m in back.messages if m.schema.startswith("foxglove.") and "Image" in m.schema]
        assert len(images) == len(frames), (len(images), len(frames))
        assert images[-1].image().shape == frames[-1].shape
        row["read_fps"] = len(frames) / (time.perf_counter() - t0)
    return row


def _live(kind: str, frames: list[np.ndarray]) -> dict[str, float]:
    """Publish JPEG frames to one subscribed client; CPU of the publishing thread per message."""
    from websockets.sync.client import connect

    got = {"n": 0, "bytes": 0}
    with LiveServer(port=0, jpeg_quality=JPEG_QUALITY) as live:
        topic = "/cam/image/compressed"
        live.advertise(topic, "foxglove.CompressedImage" if kind == "typed" else "tactile_rig.Json")
        done = threading.Event()

        def client() -> None:
            with connect(live.url, subprotocols=["foxglove.sdk.v1"], max_size=None) as ws:
                while not done.is_set():
                    try:
                        msg = ws.recv(timeout=0.2)
                    except TimeoutError:
                        continue
                    if isinstance(msg, str):
                        d = json.loads(msg)
                        if d.get("op") == "advertise":
                            ws.send(json.dumps({"op": "subscribe", "subscriptions": [
                                {"id": i + 1, "channelId": ch["id"]} for i, ch in enumerate(d["channels"])]}))
                    elif msg[0] == 1:
                        got["n"] += 1
                        got["bytes"] += len(msg) - 13

        th = threading.Thread(target=client, daemon=True)
        th.start()
        live.wait_for_subscriber(10.0, {topic})
        clock = VirtualClock()
        live.use_clock(clock)
        schema = json_schema("foxglove.CompressedImage")
        c0 = time.thread_time()
        for img in frames:
            clock.advance(1 / 30)
            if kind == "typed":
                live.write_frame("cam", img, compress="jpeg")
            else:
                enc = json_frame(live, "cam", img, clock.now_s(), "jpeg")  # type: ignore[arg-type]
                live.publish(Encoded(topic, schema, enc.data, enc.t_s, enc.log_time_ns))
        cpu = time.thread_time() - c0
        deadline = time.monotonic() + 10
        while got["n"] < len(frames) and time.monotonic() < deadline:
            time.sleep(0.01)
        done.set()
        th.join(2)
    return {"cpu_us_per_message": 1e6 * cpu / len(frames), "bytes_per_frame": got["bytes"] / max(got["n"], 1),
            "received": got["n"]}


def _spread(runs: list[dict]) -> dict:
    """The median of every number over ``runs``, and the range of the CPU per message."""
    out = {k: statistics.median(r[k] for r in runs) for k, v in runs[0].items() if isinstance(v, (int, float))}
    cpu = [r["cpu_us_per_message"] for r in runs]
    return {**out, "cpu_us_per_message_range": [min(cpu), max(cpu)]}


def _writers(tmp: Path, n: int) -> list[dict]:
    """CPU and bytes per message of the project's MCAP writer and of foxglove-sdk's, the same messages."""
    import foxglove
    from foxglove.mcap import MCAPWriteOptions
    from foxglove.messages import CompressedImage, Timestamp

    from tactile_rig.rig.messages import foxglove_schema

    # 60 different frames in turn: a chunk (256 KiB, ~20 frames) never holds the same frame twice,
    # so zstd compresses what a camera gives, not repeats.
    jpegs = [cv2.imencode(".jpg", f, [int(cv2.IMWRITE_JPEG_QUALITY), JPEG_QUALITY])[1].tobytes()
             for f in _frames((240, 320), 60)]
    msgs = [CompressedImage(timestamp=Timestamp(i // 30, (i % 30) * 33_333_333), frame_id="cam",
                            data=jpegs[i % len(jpegs)], format="jpeg").encode() for i in range(n)]
    schema = foxglove_schema("CompressedImage")
    topic = "/cam/image/compressed"
    rows = []
    path = tmp / "project.mcap"
    clock = VirtualClock()
    c0 = time.process_time()
    with Recorder(path, clock=clock, background_flush=False) as rec:
        for m in msgs:
            clock.advance(1 / 30)
            rec.publish(Encoded(topic, schema, m, clock.now_s(), rec.log_time_ns(clock.now_s())))
    rows.append({"writer": "project (mcap.writer.Writer)", "cpu_us_per_message": 1e6 * (time.process_time() - c0) / n,
                 "bytes_per_message": path.stat().st_size / n})
    path = tmp / "foxglove.mcap"
    ctx = foxglove.Context()
    c0 = time.process_time()
    with foxglove.open_mcap(path, context=ctx, writer_options=MCAPWriteOptions(chunk_size=256 * 1024)) as w:
        ch = foxglove.Channel(topic, schema=foxglove.Schema(name=schema.name, encoding=schema.encoding, data=schema.data),
                              message_encoding="protobuf", context=ctx)
        for i, m in enumerate(msgs):
            ch.log(m, log_time=int(i * 1e9 / 30))
            if i % 30 == 29:
                w.flush()
    rows.append({"writer": "foxglove-sdk MCAPWriter", "cpu_us_per_message": 1e6 * (time.process_time() - c0) / n,
                 "bytes_per_message": path.stat().st_size / n})
    assert len(read_recording(path).messages) == n  # the project's reader reads it, CRCs checked
    return rows


def _session(seconds: float, tmp: Path) -> dict:
    """``tactile-rig record`` of a two-camera rehearsal bench at 30 fps for ``seconds``."""
    video = tmp / "footage_30fps.avi"
    frames = _frames((240, 320), 90)
    vw = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"MJPG"), 30.0, (320, 240))
    for img in frames:
        vw.write(img)
    vw.release()
    bench_dir = tmp / "rehearsal"
    cli = [sys.executable, "-m", "tactile_rig.cli"]
    proc = subprocess.Popen(cli + ["bench", "rehearse", "--out", str(bench_dir), "--gelsight-fps", "30",
                                   "--camera", f"footage={video}", "--no-calibration",
                                   "--duration", str(seconds + 120)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 120
        while not (bench_dir / "bench.toml").exists() and time.monotonic() < deadline:
            time.sleep(0.2)
        time.sleep(2.0)
        out = tmp / "session.mcap"
        c0 = time.monotonic()
        r = subprocess.run(cli + ["record", "--bench", str(bench_dir / "bench.toml"), "--duration", str(seconds),
                                  "--out", str(out), "--json"], capture_output=True, text=True, timeout=seconds + 120)
        wall = time.monotonic() - c0
        if r.returncode != 0:
            raise RuntimeError(f"record failed ({r.returncode}): {r.stderr.strip()}")
        summary = json.loads(r.stdout.splitlines()[-1])
    finally:
        proc.terminate()
        proc.wait(30)
    frames_by_cam = {t.split("/")[1]: n for t, n in summary["topics"].items() if t.endswith("/image/compressed")}
    return {"seconds": seconds, "wall_s": round(wall, 2), "frames": frames_by_cam, "camera_fps": summary["camera_fps"],
            "dropped": summary["dropped"], "camera_dropped": summary["camera_dropped"], "missed_polls": summary["missed"],
            "mb": round(out.stat().st_size / 1e6, 2), "messages": sum(summary["topics"].values())}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="fewer frames")
    ap.add_argument("--session", action="store_true", help="also the 60-s two-camera record session (part 3)")
    add_save_args(ap, "recording.json")
    args = parse_args(ap)
    n = 30 if args.quick else 150
    repeats = 2 if args.quick else REPEATS
    results, live = [], []
    with tempfile.TemporaryDirectory() as tmp:
        for shape in ((240, 320), (480, 640)):
            frames = _frames(shape, n)
            size = f"{shape[1]}x{shape[0]}"
            for mode in ("baseline_bytes", "json_raw", "typed_raw", "json_jpeg", "typed_jpeg", "typed_png"):
                results.append({"size": size, "mode": mode, "frames": n, **_record(mode, frames, Path(tmp) / f"{mode}.bin")})
            runs: dict[str, list[dict]] = {"json": [], "typed": []}
            for _ in range(repeats):
                for kind in runs:
                    runs[kind].append(_live(kind, frames))
            for kind, rs in runs.items():
                live.append({"size": size, "mode": f"{kind}_jpeg", "frames": n, "runs": len(rs), **_spread(rs)})
        writer_runs = []
        for i in range(repeats):
            (Path(tmp) / f"writers{i}").mkdir()
            writer_runs.append(_writers(Path(tmp) / f"writers{i}", 600 if args.quick else 3000))
        writers = [{"writer": rows[0]["writer"], "runs": len(rows), **_spread(rows)}
                   for rows in zip(*writer_runs)]
        session = _session(10.0 if args.quick else 60.0, Path(tmp)) if args.session else None
    out = {"benchmark": "recording", "python": platform.python_version(), "machine": platform.machine(),
           "cpus": os.cpu_count(), "load_avg": os.getloadavg(), "quick": args.quick, "jpeg_quality": JPEG_QUALITY,
           "results": results, "live": live, "writers": writers, "session": session}
    save_json(args, out)
    print(f"{'size':>8} {'recording':>15} {'bytes/frame':>12} {'CPU us/msg':>11} {'fps wall':>9} {'read fps':>9}")
    for r in results:
        print(f"{r['size']:>8} {r['mode']:>15} {r['bytes_per_frame']:12.0f} {r['cpu_us_per_message']:11.1f} "
              f"{r['fps_wall']:9.1f} {r.get('read_fps', float('nan')):9.1f}")
    print(f"{'size':>8} {'live':>15} {'bytes/frame':>12} {'CPU us/msg':>11} {'received':>9}")
    for r in live:
        lo, hi = r["cpu_us_per_message_range"]
        print(f"{r['size']:>8} {r['mode']:>15} {r['bytes_per_frame']:12.0f} {r['cpu_us_per_message']:11.1f} "
              f"{r['received']:9.0f}  ({lo:.0f}-{hi:.0f} over {r['runs']} runs)")
    for r in writers:
        lo, hi = r["cpu_us_per_message_range"]
        print(f"{'writer':>8} {r['writer']:>30} {r['bytes_per_message']:9.0f} B/msg {r['cpu_us_per_message']:8.1f} us/msg "
              f"({lo:.0f}-{hi:.0f} over {r['runs']} runs)")
    if session is not None:
        print(f"session: {session['seconds']:.0f} s, frames {session['frames']}, fps {session['camera_fps']}, "
              f"dropped by the recording {session['dropped'] or 'none'}, missing from the cameras' own sequence "
              f"{session['camera_dropped'] or 'none'}, {session['mb']} MB")


if __name__ == "__main__":
    main()
