"""``tactile-rig camera list|check`` with cameras named by model in bench.toml: the model gives the
stream, checks a stream it does not offer, chooses the lock and the SDK view; ``camera check`` on an
emulated camera (OpenCV's V4L2 backend, in a process started with the emulation's environment) says
what it configured and found."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from tactile_rig.cli import main
from tactile_rig.rig.bench import load_bench
from tests._v4l2 import emulated


def _bench(tmp_path: Path, camera: str) -> Path:
    path = tmp_path / "bench.toml"
    path.write_text(f"[camera]\n{camera}\n", encoding="utf-8")
    return path


def test_a_model_gives_the_stream_the_lock_and_the_view(tmp_path: Path) -> None:
    bench = load_bench(_bench(tmp_path, 'port = "rigsim://camera"\nmodel = "gelsight-mini"\nmains_hz = 60'))
    cam = bench.cameras["camera"]
    assert (cam.fourcc, cam.width, cam.height, cam.fps) == ("MJPG", 3280, 2464, 25.0)
    assert cam.view is not None and cam.view.name == "gs_sdk" and cam.view.output_px == (320, 240)
    assert cam.locked_controls() == {"auto_exposure": 1, "exposure_time_absolute": 157, "white_balance_automatic": 0,
                                     "white_balance_temperature": 4600, "gain": 0, "exposure_dynamic_framerate": 0,
                                     "power_line_frequency": 2}
    digit = load_bench(_bench(tmp_path, 'port = "rigsim://camera"\nmodel = "digit"\nfps = 60.0\nwidth = 320\n'
                                        'height = 240\nsdk_view = "none"')).cameras["camera"]
    assert (digit.fourcc, digit.width, digit.height, digit.fps, digit.view) == ("YUYV", 320, 240, 60.0, None)
    slow = load_bench(_bench(tmp_path, 'port = "rigsim://camera"\nmodel = "c310"\nwidth = 1280\nheight = 960'))
    assert slow.cameras["camera"].fps == 7.5  # the fastest rate of that mode, YUYV being the C310's first format
    plain = load_bench(_bench(tmp_path, 'port = "rigsim://camera"')).cameras["camera"]
    assert (plain.fourcc, plain.width, plain.height, plain.fps, plain.view) == ("MJPG", 320, 240, 25.0, None)


@pytest.mark.parametrize("table, problem", [
    ('model = "gelsight-mni"', "model = 'gelsight-mni' must be one of c310, gelsight-mini, digit; did you mean "
                               "'gelsight-mini'?"),
    ('model = "digit"\nfourcc = "MJPG"', "the DIGIT (Meta / GelSight) offers YUYV 640x480, YUYV 320x240"),
    ('model = "c310"\nfourcc = "YUYV"\nwidth = 1280\nheight = 960\nfps = 30.0',
     "fps = 30: the Logitech HD Webcam C310 offers 7.5, 5 fps at YUYV 1280x960"),
    ('model = "digit"\nsdk_view = "gsrobotics"', "sdk_view = 'gsrobotics' must be one of digit-interface, gs_sdk, none"),
    ('sdk_view = "gs_sdk"', "sdk_view needs a model"),
    ("mains_hz = 55", "mains_hz = 55 must be 50 or 60"),
])
def test_a_camera_table_the_model_contradicts_is_one_line_exit_2(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                                                  table: str, problem: str) -> None:
    path = _bench(tmp_path, f'port = "rigsim://camera"\n{table}')
    assert main(["camera", "check", "--bench", str(path)]) == 2
    err = capsys.readouterr().err
    assert problem in err and "Traceback" not in err


def test_camera_list_names_each_cameras_model(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = _bench(tmp_path, 'port = "rigsim://camera"\nmodel = "c310"\n\n[camera_b]\nport = "rigsim://camera"')
    assert main(["camera", "list", "--bench", str(path), "--json"]) == 0
    rows = [json.loads(line) for line in capsys.readouterr().out.splitlines() if '"camera"' in line]
    assert [(r["camera"], r["model"], r["format"], r["fps"]) for r in rows] == [
        ("camera", "c310", "YUYV 640x480", 30.0), ("camera_b", None, "MJPG 320x240", 25.0)]


def _check(cam_env: dict[str, str], bench: Path, *args: str) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, **cam_env}
    env.pop("OPENCV_VIDEOIO_V4L_SELECT_TIMEOUT", None)
    return subprocess.run([sys.executable, "-m", "tactile_rig.cli", "camera", "check", "--bench", str(bench), *args],
                          capture_output=True, text=True, env=env, timeout=120)


def test_camera_check_configures_an_emulated_c310_from_its_model_and_says_what_it_found(tmp_path: Path) -> None:
    with emulated("c310") as cam:
        bench = _bench(tmp_path, f'port = "{cam.port}"\nmodel = "c310"\nfourcc = "MJPG"\nwidth = 320\nheight = 240\n'
                                 f'mains_hz = 50')
        done = _check(cam.env, bench)
        table = dict(cam.sim.table.values)
    assert done.returncode == 0, done.stdout + done.stderr
    lines = done.stdout.splitlines()
    assert any(" ok " in ln and "MJPG 320x240 @ 30 fps, 7/7 controls, c310" in ln for ln in lines)
    found = {ln.split()[0]: ln.split(None, 1)[1] for ln in lines if ln.startswith("  ")}
    assert found["model"] == "c310 (Logitech HD Webcam C310)"
    assert found["power_line_frequency"] == "1" and found["exposure_dynamic_framerate"] == "0"
    assert found["frames"].startswith("320x240 px (the raw frame)")
    # the camera itself holds the lock (it powered up with exposure_dynamic_framerate 1 and 60 Hz)
    assert (table["exposure_dynamic_framerate"], table["power_line_frequency"], table["auto_exposure"]) == (0, 1, 1)


def test_camera_check_of_a_digit_locks_its_leds_and_gives_the_portrait_view(tmp_path: Path) -> None:
    with emulated("digit") as cam:
        bench = _bench(tmp_path, f'port = "{cam.port}"\nmodel = "digit"\nsensor = "gelsight"')
        done = _check(cam.env, bench, "--json")
    assert done.returncode == 0, done.stdout + done.stderr
    row = json.loads(done.stdout)
    d = row["details"]
    assert (d["model"], d["format"], d["controls"], d["frame_shape"]) == (
        "digit", ["YUYV", 640, 480, 30.0], {"zoom_absolute": 4095.0}, [640, 480, 3])
    assert d["view"].startswith("digit-interface")
