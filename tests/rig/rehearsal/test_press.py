"""Calibrations made on the rehearsal bench (``bench rehearse --press --stage-scene
gelsight_ball_presses``): the GelSight ball-press session moving the jig, and the force map, where
the gripper presses the FingerVision fingertip on the scale, the guided collection records it and
fits the map, then live tracking reports newtons that agree with the scale. Real time, ptys and
emulated V4L2 cameras, separate processes (each command, and the live tracking, in a process started
with the cameras' emulation); each session's MCAP read by the mcap package's own reader."""

from __future__ import annotations

import json

import mcap.reader as mcap_reader
import numpy as np
import pytest
import sklearn  # noqa: F401  (the learn extra fits the force map)

from tactile_rig.cli import main
from tactile_rig.mocks.v4l2.child import run_in_child
from tactile_rig.rig.rehearsal import RehearsalBench, RehearsalOptions
from tests._rehearsal_bodies import press_while_tracking
from tests._v4l2 import require

pytestmark = [pytest.mark.pty, pytest.mark.slow]


@pytest.fixture(scope="module")
def press_bench(tmp_path_factory: pytest.TempPathFactory):
    require()
    out = tmp_path_factory.mktemp("press")
    opts = RehearsalOptions(press=True, calibration=False, stage_scene="gelsight_ball_presses")
    with RehearsalBench(out, opts) as rb:
        yield rb
        assert rb.problems() == []


def _topics(path: str) -> set[str]:
    with open(path, "rb") as f:
        return {c.topic for _s, c, _m in mcap_reader.make_reader(f).iter_messages()}


def test_gelsight_calibration_on_the_rehearsal(press_bench, capsys) -> None:
    out = press_bench.out / "calib" / "gelsight"
    out.parent.mkdir(exist_ok=True)  # an output's folder must exist (only the file is written)
    assert main(["calibrate", "gelsight", "--bench", str(press_bench.bench_path), "--yes", "--out", str(out),
                 "--grid-x", "-6", "6", "3", "--grid-y", "-4", "4", "2", "--json"]) == 0
    res = json.loads(capsys.readouterr().out.splitlines()[-1])
    assert res["values"]["presses"] == 6
    assert res["values"]["heldout_mean_normal_deg"] < 10.0  # the mock session: ~4.3°
    assert {"/camera_gelsight/image/compressed", "/jig/pose", "/command/jig"} <= _topics(res["files"]["recording"])


def test_force_map_collected_on_the_rehearsal_gives_newtons_in_live_tracking(press_bench, capsys) -> None:
    bench_path = str(press_bench.bench_path)
    model = press_bench.out / "calib" / "force_map"
    model.parent.mkdir(exist_ok=True)
    assert main(["calibrate", "force-map", "--bench", bench_path, "--live", "--yes", "--trials", "3",
                 "--max-force", "8", "--ramp", "0.4", "--hold", "0.2", "--out", str(model), "--no-figures",
                 "--json"]) == 0
    out = [json.loads(line) for line in capsys.readouterr().out.splitlines() if line.startswith("{")]
    recording = next(v for d in out for k, v in d.items() if k in ("recording", "mcap") and str(v).endswith(".mcap"))
    assert {"/scale/force", "/camera_fingervision/image/compressed"} <= _topics(recording)

    rows, scale_n = run_in_child(press_while_tracking, bench_path, str(model), env=press_bench.env, timeout_s=110.0)
    tracked = [r for r in rows if not r["calibrating"]]
    assert all("force_map_n" in r for r in tracked)
    at_rest = [r["force_map_n"] for r in rows[:20] if not r["calibrating"]]
    pressed = sorted(r["force_map_n"] for r in tracked)[-20:]  # the plateau of the press
    squeeze_n = float(np.median(scale_n[-40:]))
    assert 2.0 < squeeze_n < 8.0  # the gripper really pressed on the scale, within the trained range
    assert at_rest and max(at_rest) < 1.0  # frames 10-19: tracked, nothing pressing yet
    # The fitted map reads the scale's force back from the skin alone (measured: 6.2 N from the skin
    # for 5.2 N on the scale, after 3 presses of at most 8 N).
    assert float(np.median(pressed)) == pytest.approx(squeeze_n, rel=0.35)
    assert tracked[-1]["force_map_n"] < 0.5 * float(np.median(pressed))  # released at the end
