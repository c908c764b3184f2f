"""The calibrations on the rehearsal bench, end to end in real time: each device a mock served by
another process (the gripper and the scale on ptys, the fingertip camera as MJPEG over HTTP, sharing
the ``force_map_press`` world), reached only through ``--bench bench.toml``. A FingerVision
baseline, a guided force-map collection and fit, then a live ``fingervision track`` that reports
newtons from the fitted map while the gripper presses, checked against the scale."""

from __future__ import annotations

import json
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from tactile_rig.cli import main
from tactile_rig.drivers.dynamixel import DynamixelGripper
from tactile_rig.drivers.scale import Scale
from tactile_rig.rig.bench import load_bench
from tactile_rig.rig.rehearsal import RehearsalBench, RehearsalOptions

mcap_reader = pytest.importorskip("mcap.reader")
pytest.importorskip("sklearn")

pytestmark = pytest.mark.pty


@pytest.fixture(scope="module")
def press(tmp_path_factory: pytest.TempPathFactory):
    out = tmp_path_factory.mktemp("press")
    with RehearsalBench(out, RehearsalOptions(press=True, calibration=False)) as rb:
        yield rb
        assert rb.problems() == []


def _calibrated_bench(rb: RehearsalBench) -> Path:
    """The rehearsal's bench file with the fingertip naming its calibrations (as a lab's would)."""
    text = rb.bench_path.read_text()
    keys = 'calibration = "calib/fingervision.json"\nforce_map = "calib/force_map"\n'
    p = rb.out / "bench-calibrated.toml"
    p.write_text(text.replace("[camera_fingertip]\n", "[camera_fingertip]\n" + keys))
    return p


def test_baseline_force_map_and_live_newtons_on_the_rehearsal_bench(press, capsys) -> None:
    bench = press.bench_path
    b = load_bench(bench)
    assert not b.is_mock and b.cameras["camera_fingertip"].sensor == "fingervision"
    calib = press.out / "calib"
    # 1. the marker baseline, fingers open
    assert main(["calibrate", "fingervision", "--bench", str(bench), "--device", "camera_fingertip", "--frames", "6",
                 "--out", str(calib / "fingervision"), "--yes", "--json"]) == 0
    capsys.readouterr()
    # 2. the guided collection: the gripper presses the fingertip on the scale at stepped forces
    calibrated = _calibrated_bench(press)
    assert main(["calibrate", "force-map", "--bench", str(calibrated), "--camera", "camera_fingertip", "--trials",
                 "3", "--max-force", "8", "--no-figures", "--yes", "--out", str(calib / "force_map"), "--json"]) == 0
    report = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert report["source"] == "live collection" and report["rmse_holdout_n"] < 1.0
    with open(report["recording"], "rb") as f:  # the independent reader opens the session's MCAP
        topics = {ch.topic for _s, ch, _m in mcap_reader.make_reader(f).iter_messages()}
    assert {"/scale/force", "/perception/camera_fingertip", "/camera_fingertip/image/compressed"} <= topics
    # 3. live track from the bench camera, in newtons from the fitted map, while the gripper presses
    cfg = load_bench(calibrated)
    readings: list[float] = []
    done = threading.Event()

    def squeeze() -> None:
        """Press to ~6 N over a second (the tracker follows a press that builds up) and hold it,
        reading the scale, until the track is over."""
        with DynamixelGripper(cfg.devices["gripper"].port, protocol=2, baudrate=57600) as g, \
                Scale(cfg.devices["scale"].port, device="scale") as scale:
            g.activate(0.05)
            time.sleep(0.5)
            for k in range(1, 21):
                g.gripper_go(0.0, k / 20 * 6.0 / 260.0, blocking=False)
                time.sleep(0.05)
            while not done.is_set():
                readings.extend(r.newtons for r in scale.poll())
                time.sleep(0.05)

    th = threading.Thread(target=squeeze)
    th.start()
    try:
        rc = main(["fingervision", "track", "--bench", str(calibrated), "--camera", "camera_fingertip",
                   "--frames-max", "150", "--json"])
    finally:
        done.set()
        th.join(30)
    assert rc == 0
    rows = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    frames = rows[:-1]
    assert not frames[0]["calibrating"]  # the stored baseline: tracked from the first frame
    assert all("force_n" in r for r in frames)
    assert frames[0]["force_map_n"] < 1.0
    pressed = np.mean([r["force_map_n"] for r in frames[-10:]])
    held = np.mean(readings[-40:])  # the scale over the last half second
    assert held > 4.0 and pressed == pytest.approx(held, abs=1.5), (pressed, held)
