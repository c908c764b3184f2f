"""End to end on the rehearsal bench: every device a mock in its own process (ptys for the serial
devices, emulated V4L2 devices for the cameras), in real time, reached only through ``--bench
bench.toml`` as a lab bench is. Every command runs in a process of its own started with the cameras'
emulation (the console script re-executes itself; ``main`` as a function runs a child), so the
cameras are opened by OpenCV's V4L2 backend as on hardware. Each workflow's MCAP is opened with the
independent ``mcap`` reader."""

from __future__ import annotations

import json
import os
import shutil
import socket
import subprocess
import sys
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
from tactile_rig.cli.emulation import bench_emulation
from tactile_rig.core.errors import BenchError
from tactile_rig.mocks.v4l2.child import run_in_child
from tactile_rig.rig.bench import connect_bench, load_bench
from tactile_rig.rig.jig_accuracy import JigAccuracyConfig, execute_jig_accuracy
from tactile_rig.rig.learning import fit_force_map
from tactile_rig.rig.rehearsal import RehearsalBench, RehearsalOptions
from tests._foxglove_client import LiveClient
from tests._rehearsal_bodies import bench_ports
from tests._v4l2 import require

pytestmark = pytest.mark.pty

DEVICES = ["gripper", "scale", "jig", "camera_gelsight", "camera_fingervision"]


@pytest.fixture(scope="module")
def rehearsal(tmp_path_factory: pytest.TempPathFactory):
    require()
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


def _tactile_rig(*argv: str, timeout_s: float = 120.0) -> subprocess.CompletedProcess[str]:
    """The console script a lab runs (the virtualenv's ``tactile-rig``), in a process of its own."""
    script = shutil.which("tactile-rig", path=os.path.dirname(sys.executable)) or "tactile-rig"
    return subprocess.run([script, *argv], capture_output=True, text=True, timeout=timeout_s)


def test_the_bench_file_names_video_nodes_and_their_emulation(rehearsal) -> None:
    bench = load_bench(rehearsal.bench_path, check_ports=False)
    assert list(bench.devices) == DEVICES
    assert not bench.is_mock
    for name in ("gripper", "scale", "jig"):
        port = Path(bench.devices[name].port)
        assert port.is_symlink() and str(port.resolve()).startswith("/dev/pts/")
    assert [c.port for c in bench.cameras.values()] == ["/dev/video42", "/dev/video43"]
    assert bench.v4l2_registry == rehearsal.registry == rehearsal.out / "v4l2"
    assert bench.v4l2_preload == rehearsal.library and rehearsal.library.is_file()
    emu = bench_emulation(rehearsal.bench_path)
    assert emu is not None and emu.env() == rehearsal.env  # what the CLI loads is what the rehearsal serves
    pids = {p.pid for p in rehearsal.processes.values()}
    assert len(pids) == 4  # gripper, scale, stage (jig + its camera), footage camera
    # This process was not started with the emulation: its cameras do not exist here, and the loader says why.
    with pytest.raises(BenchError, match="emulated camera .*'tactile-rig bench env"):
        load_bench(rehearsal.bench_path)
    # A process started with it sees every device path (the nodes are character devices 81:N there).
    ports = run_in_child(bench_ports, str(rehearsal.bench_path), env=rehearsal.env)
    assert ports["camera_gelsight"] == "/dev/video42" and ports["gripper"].startswith("/dev/pts/")


def test_bench_check_from_the_console_script_verifies_every_device(rehearsal) -> None:
    done = _tactile_rig("bench", "check", "--bench", str(rehearsal.bench_path), "--json")
    assert done.returncode == 0, done.stderr
    assert done.stderr == ""  # no warning: the cameras open, stream and close cleanly
    rows = {r["device"]: r for r in map(json.loads, done.stdout.splitlines())}
    assert list(rows) == DEVICES and all(r["ok"] for r in rows.values())
    assert rows["gripper"]["details"]["model_number"] == 311
    assert rows["scale"]["details"]["firmware"] == "hx711-scale" and rows["scale"]["details"]["rate_sps"] == 80
    assert rows["jig"]["details"]["version"] == "1.1h"
    cam = rows["camera_gelsight"]["details"]
    # OpenCV's CAP_PROP_* controls, and exposure_dynamic_framerate by its V4L2 id (no CAP_PROP for it).
    assert cam["controls"] == {"auto_exposure": 1.0, "exposure_time_absolute": 166.0, "white_balance_automatic": 0.0,
                               "white_balance_temperature": 4000.0, "gain": 64.0, "exposure_dynamic_framerate": 0.0}
    assert cam["format"][:3] == ["MJPG", 320, 240] and cam["frame_shape"] == [240, 320, 3]


def test_bench_env_is_what_other_programs_need(rehearsal) -> None:
    require("v4l2-ctl")
    done = _tactile_rig("bench", "env", "--bench", str(rehearsal.bench_path), "--json")
    assert done.returncode == 0, done.stderr
    env = json.loads(done.stdout)
    assert env == rehearsal.env
    info = subprocess.run(["v4l2-ctl", "-d", "/dev/video42", "--info"], capture_output=True, text=True, timeout=30,
                          env={**os.environ, **env})
    assert info.returncode == 0, info.stderr
    assert "uvcvideo" in info.stdout and "UVC Camera (046d:081b)" in info.stdout


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


def test_camera_list_check_grab_and_fps(rehearsal, tmp_path, capsys) -> None:
    b = str(rehearsal.bench_path)
    assert main(["camera", "list", "--bench", b, "--json"]) == 0
    rows = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    assert [r["port"] for r in rows if "camera" in r] == ["/dev/video42", "/dev/video43"]
    nodes = {r["v4l2"]: r["links"] for r in rows if "v4l2" in r}  # what the process saw in /dev
    assert {"/dev/video42", "/dev/video43"} <= set(nodes)
    assert any(link.startswith("/dev/v4l/by-id/usb-046d_081b_") for link in nodes["/dev/video42"])
    assert main(["camera", "check", "--bench", b, "--camera", "camera_fingervision"]) == 0
    assert main(["camera", "grab", "--bench", b, "--count", "2", "--out", str(tmp_path), "--json"]) == 0
    files = json.loads(capsys.readouterr().out.splitlines()[-1])["files"]
    assert len(files) == 2 and files[0] != files[1]
    assert cv2.imread(files[0]).shape == (240, 320, 3)
    assert main(["camera", "fps", "--bench", b, "--camera", "camera_fingervision", "--duration", "2", "--json"]) == 0
    fps = json.loads(capsys.readouterr().out.splitlines()[-1])
    # The rate on the device's clock is the buffers' timestamps (CAP_PROP_POS_MSEC), the emulation's 25 fps.
    assert fps["device_fps"] == pytest.approx(25.0, abs=0.5) and fps["host_fps"] > 20.0
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
    # Same localization on real-time devices over ptys and V4L2 as in virtual time in process: the
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
    bench = load_bench(b, check_ports=False)  # only the jig is opened here
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
