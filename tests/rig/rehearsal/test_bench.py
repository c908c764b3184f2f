"""End to end on the rehearsal bench: every device a mock in its own process (ptys for the serial
devices, MJPEG over HTTP for the cameras), in real time, reached only through ``--bench bench.toml``
as a lab bench is. Each workflow's MCAP is opened with the independent ``mcap`` reader."""

from __future__ import annotations

import json
import socket
import threading
from pathlib import Path

import cv2
import foxglove  # noqa: F401  (the live extra serves the view: a broken install fails here)
import mcap.reader as mcap_reader
import numpy as np
import pytest
import sklearn  # noqa: F401  (the learn extra fits the force map)
import websockets  # noqa: F401  (the live view's test client)

from tactile_rig.cli import main
from tactile_rig.rig.bench import connect_bench, load_bench
from tactile_rig.rig.jig_accuracy import JigAccuracyConfig, execute_jig_accuracy
from tactile_rig.rig.learning import fit_force_map
from tactile_rig.rig.rehearsal import RehearsalBench, RehearsalOptions
from tests._foxglove_client import LiveClient

pytestmark = pytest.mark.pty

DEVICES = ["gripper", "scale", "jig", "camera_gelsight", "camera_fingervision"]


@pytest.fixture(scope="module")
def rehearsal(tmp_path_factory: pytest.TempPathFactory):
    out = tmp_path_factory.mktemp("rehearsal")
    with RehearsalBench(out, RehearsalOptions(cameras={"fingervision": "rendered"})) as rb:
        yield rb
        assert rb.problems() == []  # no device process died during the tests


def _mcap_counts(path: Path) -> dict[str, int]:
    """Messages per topic, read by the mcap package's own reader (not the project's)."""
    with open(path, "rb") as f:
        reader = mcap_reader.make_reader(f)
        counts: dict[str, int] = {}
        for _schema, channel, _message in reader.iter_messages():
            counts[channel.topic] = counts.get(channel.topic, 0) + 1
    return counts


def test_the_bench_file_names_device_paths_not_mock_urls(rehearsal) -> None:
    bench = load_bench(rehearsal.bench_path)
    assert list(bench.devices) == DEVICES
    assert not bench.is_mock
    for name in ("gripper", "scale", "jig"):
        port = Path(bench.devices[name].port)
        assert port.is_symlink() and str(port.resolve()).startswith("/dev/pts/")
    assert all(c.port.startswith("http://127.0.0.1:") for c in bench.cameras.values())
    pids = {p.pid for p in rehearsal.processes.values()}
    assert len(pids) == 4  # gripper, scale, stage (jig + its camera), footage camera


def test_bench_check_verifies_every_device(rehearsal, capsys) -> None:
    assert main(["bench", "check", "--bench", str(rehearsal.bench_path), "--json"]) == 0
    rows = {r["device"]: r for r in map(json.loads, capsys.readouterr().out.splitlines())}
    assert list(rows) == DEVICES and all(r["ok"] for r in rows.values())
    assert rows["gripper"]["details"]["model_number"] == 311
    assert rows["scale"]["details"]["firmware"] == "hx711-scale" and rows["scale"]["details"]["rate_sps"] == 80
    assert rows["jig"]["details"]["version"] == "1.1h"
    assert rows["camera_gelsight"]["details"]["controls"]["auto_exposure"] == 1.0
    assert rows["camera_gelsight"]["details"]["format"][:3] == ["MJPG", 320, 240]


def test_bench_check_fails_a_device_that_is_not_what_the_bench_says(rehearsal, capsys) -> None:
    text = rehearsal.bench_path.read_text()
    wrong = text.replace("rate_hz = 80.0", "rate_hz = 10.0").replace("protocol = 2", "protocol = 1")
    assert wrong != text
    bad = rehearsal.out / "bench-wrong.toml"  # beside the original: the calibration path is relative
    bad.write_text(wrong)
    assert main(["bench", "check", "--bench", str(bad), "--json"]) == 1
    rows = {r["device"]: r for r in map(json.loads, capsys.readouterr().out.splitlines())}
    assert not rows["scale"]["ok"] and "rate_hz = 10.0" in rows["scale"]["problem"]
    assert not rows["gripper"]["ok"]  # a Protocol 2.0 servo does not answer Protocol 1.0 pings
    assert rows["jig"]["ok"] and rows["camera_gelsight"]["ok"]


def test_camera_check_and_grab(rehearsal, tmp_path, capsys) -> None:
    b = str(rehearsal.bench_path)
    assert main(["camera", "check", "--bench", b, "--camera", "camera_fingervision"]) == 0
    assert main(["camera", "grab", "--bench", b, "--count", "2", "--out", str(tmp_path), "--json"]) == 0
    files = json.loads(capsys.readouterr().out.splitlines()[-1])["files"]
    assert len(files) == 2 and files[0] != files[1]
    assert cv2.imread(files[0]).shape == (240, 320, 3)
    assert main(["camera", "grab", "--bench", b, "--camera", "nope"]) == 2


def test_jig_accuracy_on_the_rehearsal_bench_matches_the_mock_run(rehearsal, tmp_path, capsys) -> None:
    sweep = ["--rotations", "-20", "20", "20", "--shifts", "-2", "2", "2"]
    out = tmp_path / "bench-run"
    assert main(["run", "jig-accuracy", "--bench", str(rehearsal.bench_path), *sweep, "--out", str(out),
                 "--no-report", "--json"]) == 0
    summary = json.loads(capsys.readouterr().out.splitlines()[-1])
    assert summary["n_points"] == 6 and summary["n_refused"] == 0
    cfg = JigAccuracyConfig(rotations_deg=(-20.0, 20.0, 20.0), shifts_mm=(-2.0, 2.0, 2.0))
    mock = execute_jig_accuracy(cfg, tmp_path / "mock-run", report=False).summary
    # Same localization on real-time devices over ptys and HTTP as in virtual time in process: the
    # differences are the camera's JPEG and read noise (docs/your_bench.md has the full sweep).
    assert summary["rotation_mae_deg"] <= mock["rotation_mae_deg"] + 0.3
    assert summary["translation_mae_mm"] <= mock["translation_mae_mm"] + 0.05
    counts = _mcap_counts(out / "run.mcap")
    assert counts["/perception/jig_accuracy_point"] == 6
    assert counts["/camera_gelsight/image/compressed"] >= 9  # 3 map touches + 6 points


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_record_live_streams_what_it_records(rehearsal, tmp_path, capsys) -> None:
    port = _free_port()
    out = tmp_path / "session.mcap"
    client = LiveClient(f"ws://127.0.0.1:{port}")
    rc: list[int] = []
    rec = threading.Thread(target=lambda: rc.append(main([
        "record", "--bench", str(rehearsal.bench_path), "--duration", "3", "--out", str(out), "--live",
        "--live-port", str(port), "--live-wait", "30", "--json"])))
    rec.start()
    client.start()
    rec.join(60)
    client.stop()
    assert rc == [0]
    summary = json.loads(capsys.readouterr().out.splitlines()[-1])
    counts = _mcap_counts(out)
    assert counts == summary["topics"]
    for topic in ("/scale/force", "/state/gripper", "/state/jig", "/jig/pose",
                  "/camera_gelsight/image/compressed", "/camera_fingervision/image/compressed"):
        assert counts.get(topic, 0) > 0, topic
    assert client.advertised["/camera_gelsight/image/compressed"] == "foxglove.CompressedImage"
    assert client.advertised["/scale/force"] == "tactile_rig.ScaleReading"
    for topic in ("/scale/force", "/camera_fingervision/image/compressed", "/jig/pose"):
        got = client.on(topic)
        # The topics are advertised and subscribed before the recording starts (--live-wait): the
        # client gets what was recorded, in order (a message or two may still be in flight at the end).
        assert counts[topic] - 5 <= len(got) <= counts[topic], topic
        t = [m.data["t_s"] if m.encoding == "json" else m.log_time_ns for m in got]
        assert t == sorted(t) and len(set(t)) == len(t), topic
        assert [m.log_time_ns for m in got] == sorted(m.log_time_ns for m in got)
    seqs = [m.data["seq"] for m in client.on("/scale/force")]
    assert all((b - a) % 65536 == 1 for a, b in zip(seqs, seqs[1:]))  # no sample lost or reordered
    frame = client.on("/camera_fingervision/image/compressed")[-1]
    assert frame.encoding == "protobuf" and frame.message.format == "jpeg"
    assert frame.message.frame_id == "camera_fingervision" and frame.message.data[:2] == b"\xff\xd8"


def test_fingervision_track_live_from_the_bench_camera_in_newtons(rehearsal, tmp_path, capsys) -> None:
    # A force map fitted on pairs where |F| = 2 N per px of marker force (the fit is the calib
    # session's business; here it only has to be a fitted map the bench path loads and applies).
    rng = np.random.default_rng(0)
    # Forces dense near zero (radius 4 px · u², random direction): a 60-frame run may press only a
    # fraction of a pixel, where forces drawn from a uniform cube fit |F| = 2|f| poorly (3.8 N for 0.6 px);
    # torques wider than any the rehearsal gives, so the map depends on the marker force alone.
    d = rng.normal(size=(800, 3))
    f = d / np.linalg.norm(d, axis=1, keepdims=True) * 4.0 * rng.uniform(0.0, 1.0, (800, 1)) ** 2
    x = np.hstack([f, rng.uniform(-2000.0, 2000.0, (800, 3))])  # px, px²
    fm = fit_force_map(x, 2.0 * np.linalg.norm(x[:, :3], axis=1))
    fm.save(tmp_path / "force_map")
    port = _free_port()
    client = LiveClient(f"ws://127.0.0.1:{port}")
    rc: list[int] = []
    run = threading.Thread(target=lambda: rc.append(main([
        "fingervision", "track", "--bench", str(rehearsal.bench_path), "--camera", "camera_fingervision",
        "--force-map", str(tmp_path / "force_map"), "--frames-max", "60", "--json", "--live", "--live-port",
        str(port), "--live-wait", "30"])))
    run.start()
    client.start()
    run.join(60)
    client.stop()
    assert rc == [0]
    rows = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    frames, summary = rows[:-1], rows[-1]
    assert summary["summary"] and summary["frames"] == 60 == len(frames)
    assert [r["frame"] for r in frames] == list(range(60))
    assert frames[0]["calibrating"] and not frames[-1]["calibrating"]
    tracked = [r for r in frames if not r["calibrating"]]
    assert all(r["marker_count"] >= 20 for r in tracked)
    assert all(r["force_map_n"] >= 0 and len(r["force_n"]) == 3 for r in tracked)
    # What the bench path printed on every frame is the saved map applied to what it tracked. How
    # well a map fitted this way reads |F| = 2 N/px is the fit's business (tests/rig/test_learning.py):
    # here the rehearsal's torques fall where 800 samples over a 6-D box fit loosely, and a check of
    # the fit against 2|f| failed CI once (0.95 N for 1.38 N) without the bench path being wrong.
    for r in tracked:
        assert r["force_map_n"] == pytest.approx(fm.to_newtons(r["force_px"], r["torque_px2"])[2], abs=1e-3)
    assert len({round(r["force_map_n"], 4) for r in tracked}) > 1  # it follows the frames, not a constant
    assert all(r["fps"] > 0 for r in frames[1:])
    got = client.on("/perception/camera_fingervision/fingervision")
    assert [m.data["frame"] for m in got] == list(range(60))  # subscribed before the first frame
    assert client.advertised["/camera_fingervision/image/compressed"] == "foxglove.CompressedImage"


def test_gelsight_height_live_saves_the_last_map(rehearsal, tmp_path, capsys) -> None:
    out = tmp_path / "h.npy"
    assert main(["gelsight", "height", "--bench", str(rehearsal.bench_path), "--frames-max", "5", "--json",
                 "-o", str(out)]) == 0
    rows = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    assert len(rows) == 6 and rows[-1]["camera"] == "camera_gelsight"
    h = np.load(out)
    assert h.shape == (240, 320)
    assert rows[-2]["max_height_mm"] == pytest.approx(float(h.max()), abs=1e-4)
    assert rows[-2]["max_height_mm"] > 0.05  # the jig's object presses the gel
    assert main(["gelsight", "height"]) == 2  # neither files nor a bench: one line, exit 2


def test_gelsight_localize_live_follows_the_jig(rehearsal, tmp_path, capsys) -> None:
    b = str(rehearsal.bench_path)
    bench = load_bench(b)
    # One connection for the whole test: GRBL resets when its port is opened (an Uno's DTR reset) and,
    # without homing, takes wherever the stage stands as its new zero.
    jig = connect_bench(load_bench(text=f'[jig]\nport = "{bench.devices["jig"].port}"\n')).jig
    try:
        assert main(["camera", "grab", "--bench", b, "--out", str(tmp_path), "--json"]) == 0
        frame = json.loads(capsys.readouterr().out.splitlines()[-1])["files"][0]
        cal = str(rehearsal.out / "calib" / "gelsight.json")
        assert main(["gelsight", "map", frame, "--calib", cal, "--mm-per-px", "0.0634", "-o",
                     str(tmp_path / "map.npz"), "--json"]) == 0
        capsys.readouterr()

        def localize() -> dict:
            # The jig accuracy run's registration knobs (rig/jig_accuracy/plan.py DEFAULT_REGISTRATION).
            assert main(["gelsight", "localize", str(tmp_path / "map.npz"), "--bench", b, "--frames-max", "2",
                         "--detect-short-px", "160", "--max-sigma-px", "0.5", "--max-sigma-rot-deg", "0.5",
                         "--json"]) == 0
            rows = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
            assert rows[-1]["summary"] and rows[-1]["frames"] == 2
            return rows[-2]

        home = localize()
        assert home["ok"] and abs(home["rotation_deg"]) < 0.5 and np.hypot(*home["translation_mm"]) < 0.1
        jig.move_to(0.0, 0.0, 15.0)
        jig.wait_idle(timeout_s=30)
        turned = localize()
        jig.move_to(0.0, 0.0, 0.0)
        jig.wait_idle(timeout_s=30)
    finally:
        jig.close()
    assert turned["ok"] and abs(abs(turned["rotation_deg"]) - 15.0) < 1.0  # the jig's turn, seen in the gel
