"""``tactile-rig mock serve camera --v4l2``: one JSON line with the port and the client environment,
the control FIFO, clean shutdown; bad options are one line and exit code 2."""

from __future__ import annotations

import json
import os
import select
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pytest

from tests._v4l2 import require


def _serve(*args: str) -> tuple[subprocess.Popen[str], dict]:  # type: ignore[type-arg]
    proc = subprocess.Popen([sys.executable, "-m", "tactile_rig.cli", "mock", "serve", "camera", "--v4l2", *args],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    assert proc.stdout is not None
    ready, _, _ = select.select([proc.stdout], [], [], 60)
    line = proc.stdout.readline() if ready else ""
    if not line:
        proc.kill()
        raise AssertionError(f"no JSON line; stderr: {proc.communicate()[1][-2000:]}")
    return proc, json.loads(line)


def _ctl(info: dict, *args: str) -> subprocess.CompletedProcess[str]:  # type: ignore[type-arg]
    env = {**os.environ, **info["env"]}
    return subprocess.run(["v4l2-ctl", "-d", info["port"], *args], capture_output=True, text=True, env=env, timeout=30)


def test_serve_prints_the_port_and_env_and_obeys_its_control_fifo() -> None:
    require("v4l2-ctl")
    registry = Path(tempfile.mkdtemp(prefix="trv-cli-"))
    proc, info = _serve("--camera", "digit", "--registry", str(registry), "--node", "61", "--kernel", "6.1")
    try:
        assert info["device"] == "camera" and info["port"] == "/dev/video61" and info["camera"] == "digit"
        assert set(info["env"]) == {"LD_PRELOAD", "TACTILE_RIG_V4L2_DIR"}
        assert info["env"]["TACTILE_RIG_V4L2_DIR"] == str(registry)
        assert info["by_id"] == "/dev/v4l/by-id/usb-Facebook_DIGIT_D20001-video-index0"
        out = _ctl(info, "--info").stdout
        assert "Card type        : DIGIT: DIGIT" in out and "Driver version   : 6.1.0" in out
        fifo = info["control"]
        with open(fifo, "w") as f:
            f.write("unplug\n")
        deadline = time.monotonic() + 10
        while _ctl(info, "--info").returncode == 0 and time.monotonic() < deadline:
            time.sleep(0.05)
        assert _ctl(info, "--info").returncode != 0
        with open(fifo, "w") as f:
            f.write("replug\n")
        while _ctl(info, "--info").returncode != 0 and time.monotonic() < deadline:
            time.sleep(0.05)
        assert "DIGIT: DIGIT" in _ctl(info, "--info").stdout
    finally:
        proc.send_signal(signal.SIGTERM)
        code = proc.wait(30)
        leftover = sorted(p.name for p in (registry / "root" / "dev").iterdir() if p.name.startswith("video"))
        shutil.rmtree(registry, ignore_errors=True)
    assert code == 0
    assert leftover == [], "the socket is removed on exit"


@pytest.mark.parametrize(("args", "message"), [
    (["--camera", "nope"], "invalid choice: 'nope'"),
    (["--fault", "explode=1"], "unknown camera fault(s) explode"),
    (["--kernel", "six"], "--kernel 'six': expected MAJOR.MINOR"),
    (["--video", "x.mp4", "--model", "gelsight"], "--video is the frame source"),
    (["--baud", "9600"], "--v4l2: --baud does not apply to a camera"),
])
def test_bad_camera_options_are_one_line_and_exit_2(args: list[str], message: str) -> None:
    done = subprocess.run([sys.executable, "-m", "tactile_rig.cli", "mock", "serve", "camera", "--v4l2", *args],
                          capture_output=True, text=True, timeout=60)
    assert done.returncode == 2
    assert message in done.stderr
    assert len(done.stderr.strip().splitlines()) == 1 and not done.stdout


def test_a_camera_without_v4l2_is_refused() -> None:
    done = subprocess.run([sys.executable, "-m", "tactile_rig.cli", "mock", "serve", "camera"],
                          capture_output=True, text=True, timeout=60)
    assert done.returncode == 2 and "add --v4l2" in done.stderr
