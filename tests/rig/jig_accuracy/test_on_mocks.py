"""Jig accuracy runs end to end on the mocks: GRBL jig driver ↔ GRBL mock ↔ stage ↔ GelSight renderer ↔
simulated camera ↔ camera driver ↔ calibration ↔ tactile map; interruption and resume; the CLI.

The sweeps are reduced to a few points (the full run is measured by benchmarks/bench_jig_accuracy.py).
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from tactile_rig.rig.jig_accuracy import (
    JigAccuracyConfig,
    RunConflict,
    execute_jig_accuracy,
    mock_gelsight_calibration,
    plan_points,
)

import mcap  # noqa: E402,F401  (the record extra is part of the test install)
from tactile_rig.rig.recording import read_recording  # noqa: E402

SMALL = dict(rotations_deg=(-40.0, 40.0, 40.0), shifts_mm=(-4.0, 4.0, 4.0))


@pytest.fixture(scope="module")
def calibration(tmp_path_factory) -> Path:
    """One GelSight calibration made by the ball-press session on the mocks, shared by the tests."""
    return mock_gelsight_calibration(tmp_path_factory.mktemp("cal") / "gelsight", seed=0)


def test_mock_run_localizes_every_point_against_the_worlds_truth(tmp_path, calibration):
    cfg = JigAccuracyConfig(**SMALL)
    out = execute_jig_accuracy(cfg, tmp_path, calibration=calibration, report=False)
    assert out.summary["complete"] and out.summary["n_points"] == 6
    assert out.summary["n_refused"] == 0
    for r in out.results:
        # The truth is the stage the GRBL mock moved (steps quantise it), not the command echoed back.
        assert abs(r.truth.theta_deg - r.commanded.theta_deg) < 0.05
        assert abs(r.truth.x_mm - r.commanded.x_mm) < 0.01
        assert r.rotation_error_deg < 1.5 and r.translation_error_mm < 0.15
    assert any(r.truth.theta_deg != r.commanded.theta_deg for r in out.results if r.sweep == "rotation")
    assert out.summary["rotation_mae_deg"] < 1.0 and out.summary["translation_mae_mm"] < 0.1
    # Every accepted map touch was localized with c above the paper's bar.
    assert out.map_report[0]["accepted"]
    assert all(row["confidence"] > 0.98 for row in out.map_report if row["accepted"])
    lines = (tmp_path / "points.jsonl").read_text().splitlines()
    assert [json.loads(line)["index"] for line in lines] == list(range(6))
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["rotation_mae_deg"] == pytest.approx(out.summary["rotation_mae_deg"])
    rec = read_recording(tmp_path / "run.mcap")
    assert not rec.truncated
    assert len(rec.on("/perception/jig_accuracy_point")) == 6
    frames = rec.on("/camera/image/compressed")
    assert len(frames) >= 6 + len(cfg.map_touches_mm)
    assert frames[0].image().shape == (240, 320, 3)
    assert "calibration.gelsight" in rec.metadata and "bench" in rec.metadata


def test_interrupted_run_resumes_at_the_next_point(tmp_path, calibration):
    cfg = JigAccuracyConfig(sweep="rotation", rotations_deg=(-20.0, 20.0, 10.0))
    first = execute_jig_accuracy(cfg, tmp_path, calibration=calibration, report=False, stop_after=2)
    assert not first.summary["complete"] and [r.index for r in first.results] == [0, 1]
    assert json.loads((tmp_path / "run.json").read_text())["status"] == "running"
    before = (tmp_path / "points.jsonl").read_text().splitlines()
    second = execute_jig_accuracy(cfg, tmp_path, calibration=calibration, report=False)
    assert second.resumed_from == 2 and second.summary["complete"]
    assert [r.index for r in second.results] == list(range(len(plan_points(cfg))))
    after = (tmp_path / "points.jsonl").read_text().splitlines()
    assert after[:2] == before  # finished points are kept, not measured again
    # The resumed attempt's clock starts after the interrupted one: times keep increasing.
    times = [json.loads(line)["t_s"] for line in after]
    assert times == sorted(times)
    rec = read_recording(tmp_path / "run.mcap")
    assert [m.data["index"] for m in rec.on("/perception/jig_accuracy_point")] == list(range(5))
    assert json.loads((tmp_path / "run.json").read_text())["status"] == "complete"
    with pytest.raises(RunConflict, match="another configuration"):
        execute_jig_accuracy(JigAccuracyConfig(sweep="translation"), tmp_path, calibration=calibration,
                             report=False)


def _cli(*args: str) -> list[str]:
    return [sys.executable, "-m", "tactile_rig.cli", *args]


def test_cli_killed_mid_run_leaves_readable_files_and_resumes(tmp_path, calibration, capsys):
    out = tmp_path / "run"
    args = ["run", "jig-accuracy", "--mock", "--sweep", "rotation", "--rotations", "-60", "60", "10", "--out", str(out),
            "--calibration", str(calibration), "--no-report"]
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    proc = subprocess.Popen(_cli(*args), stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env)
    points = out / "points.jsonl"
    t_end = time.monotonic() + 60
    try:
        while time.monotonic() < t_end and proc.poll() is None:
            if points.exists() and len(points.read_bytes().splitlines()) >= 2:
                break
            time.sleep(0.01)
        assert proc.poll() is None, "the run ended before it could be interrupted"
        proc.send_signal(signal.SIGKILL)
    finally:
        proc.wait(timeout=30)
    n_done = len(points.read_bytes().splitlines())
    assert 2 <= n_done < 13
    rec = read_recording(out / "run.mcap")  # cut off mid-write: still readable up to its last flush
    assert len(rec.on("/perception/jig_accuracy_point")) >= 1
    res = subprocess.run(_cli(*args, "--json"), capture_output=True, text=True, env=env, timeout=120)
    assert res.returncode == 0, res.stderr
    rows = [json.loads(line) for line in res.stdout.splitlines()]
    summary = rows[-1]
    assert summary["type"] == "summary" and summary["resumed_from"] >= 2
    assert [r["index"] for r in rows[:-1]] == list(range(13))
    for key in ("rotation_mae_deg", "rotation_std_deg", "translation_mae_mm", "translation_std_mm"):
        assert key in summary
    assert summary["rotation_mae_deg"] < 1.0 and summary["translation_mae_mm"] is None
    # Another configuration in the same folder is refused with a one-line error (exit 2).
    from tactile_rig.cli import main

    assert main(["run", "jig-accuracy", "--mock", "--out", str(out), "--calibration", str(calibration)]) == 2
    assert "another configuration" in capsys.readouterr().err


def test_cli_prints_the_table(tmp_path, calibration, capsys):
    from tactile_rig.cli import main

    code = main(["run", "jig-accuracy", "--mock", "--sweep", "translation", "--shifts", "-2", "2", "2", "--out",
                 str(tmp_path), "--calibration", str(calibration), "--no-record",
                 "--max-translation-mae-mm", "0.2"])
    text = capsys.readouterr().out
    assert code == 0
    assert "translation sweep ( 3 points)" in text and "Li 2014" in text
    assert (tmp_path / "report.md").exists() and not (tmp_path / "run.mcap").exists()
    code = main(["run", "jig-accuracy", "--mock", "--sweep", "translation", "--shifts", "-2", "2", "2", "--out",
                 str(tmp_path), "--calibration", str(calibration), "--no-record", "--no-report",
                 "--max-translation-mae-mm", "0.0"])
    assert code == 1  # the same finished run, judged against an impossible bar


def test_cli_rejects_bad_ranges(capsys):
    from tactile_rig.cli import main

    with pytest.raises(SystemExit):
        main(["run", "jig-accuracy", "--mock", "--rotations", "-90", "90"])
    assert "expected 3 arguments" in capsys.readouterr().err


def test_a_run_resumes_only_with_its_own_calibration(tmp_path, calibration):
    cfg = JigAccuracyConfig(sweep="translation", shifts_mm=(-2.0, 2.0, 2.0))
    execute_jig_accuracy(cfg, tmp_path, calibration=calibration, record=False, report=False, stop_after=1)
    meta = json.loads((tmp_path / "run.json").read_text())
    assert meta["calibration"]["path"].endswith(".json") and len(meta["calibration"]["sha256"]) == 16
    other = tmp_path / "other"
    other.mkdir()
    for suffix in (".json", ".npz"):
        data = calibration.with_suffix(suffix).read_bytes()
        (other / f"gelsight{suffix}").write_bytes(data + (b"\n" if suffix == ".json" else b""))
    with pytest.raises(RunConflict, match="another GelSight calibration"):
        execute_jig_accuracy(cfg, tmp_path, calibration=other / "gelsight.json", record=False, report=False)
    # Without --calibration the resumed run picks the one it started with (no new session).
    out = execute_jig_accuracy(cfg, tmp_path, record=False, report=False)
    assert out.resumed_from == 1 and out.summary["complete"]
    assert not (tmp_path / "calibration").exists()


def test_a_bench_file_of_mocks_runs_on_its_own_seed(tmp_path, calibration, capsys):
    from tactile_rig.cli import main

    bench = tmp_path / "bench.toml"
    bench.write_text('[bench]\nname = "mine"\nseed = 3\n\n[jig]\nport = "rigsim://jig"\n\n'
                     '[camera]\nport = "rigsim://camera"\nsensor = "gelsight"\n')
    out = tmp_path / "out"
    assert main(["run", "jig-accuracy", "--bench", str(bench), "--sweep", "translation", "--shifts", "0", "3", "3",
                 "--out", str(out), "--calibration", str(calibration), "--json", "--no-report", "--no-record"]) == 0
    rows = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    assert rows[-1]["n_localized"] == 2 and rows[-1]["translation_mae_mm"] < 0.1
    meta = json.loads((out / "run.json").read_text())
    assert meta["bench_kind"] == "mock" and meta["bench"]["seed"] == 3 and meta["bench"]["bench"] == str(bench)
