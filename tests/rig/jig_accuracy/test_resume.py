"""A resumed mock jig accuracy run equals an uninterrupted one, and a resume loses no recording:
per-point noise seeded from (seed, point), run.mcap never truncated."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest

import mcap  # noqa: F401  (the record extra is part of the test install)

from tactile_rig.core.clock import VirtualClock
from tactile_rig.rig.jig_accuracy import JigAccuracyConfig, execute_jig_accuracy, mock_gelsight_calibration
from tactile_rig.rig.jig_accuracy import devices as jig_devices
from tactile_rig.rig.jig_accuracy import session as jig_session
from tactile_rig.rig.recording import Recorder, read_recording

CFG = dict(sweep="rotation", rotations_deg=(-30.0, 30.0, 15.0))
VOLATILE = {"t_s", "wall_s", "timestamp"}


@pytest.fixture(scope="module")
def calibration(tmp_path_factory) -> Path:
    return mock_gelsight_calibration(tmp_path_factory.mktemp("cal") / "gelsight", seed=0)


@pytest.fixture(scope="module")
def straight(tmp_path_factory, calibration) -> tuple[list[dict], list[tuple]]:
    out = tmp_path_factory.mktemp("straight")
    res = execute_jig_accuracy(JigAccuracyConfig(**CFG), out, calibration=calibration, report=False)
    return [_result(r) for r in res.results], _messages(out / "run.mcap")


def _result(r: Any) -> dict:
    return {k: v for k, v in r.to_json().items() if k not in VOLATILE}


def _messages(path: Path) -> list[tuple]:
    """Every message without its times (a resumed attempt's clock starts later)."""
    rec = read_recording(path)
    assert not rec.truncated
    return [(m.topic, json.dumps(_timeless(m.data), sort_keys=True)) for m in rec.messages]


def _timeless(value: Any) -> Any:
    """A decoded message without its times, at any depth (typed messages stamp their frames and
    transforms); bytes (image payloads) as hex."""
    if isinstance(value, dict):
        return {k: _timeless(v) for k, v in value.items() if k not in VOLATILE}
    if isinstance(value, list):
        return [_timeless(v) for v in value]
    return value.hex() if isinstance(value, bytes) else value


def test_stopped_and_resumed_run_equals_an_uninterrupted_one(tmp_path, calibration, straight) -> None:
    cfg = JigAccuracyConfig(**CFG)
    first = execute_jig_accuracy(cfg, tmp_path, calibration=calibration, report=False, stop_after=2)
    assert not first.summary["complete"]
    second = execute_jig_accuracy(cfg, tmp_path, calibration=calibration, report=False)
    assert second.resumed_from == 2 and second.summary["complete"]
    results, messages = straight
    assert [_result(r) for r in second.results] == results
    assert _messages(tmp_path / "run.mcap") == messages  # same messages, none duplicated


class Killed(BaseException):
    """Stands for SIGKILL: nothing after it runs (not even ``except Exception``)."""


@pytest.mark.parametrize("kill_at_touch", [2, 4, 5])
def test_killed_mid_point_and_resumed_run_equals_an_uninterrupted_one(tmp_path, calibration, straight,
                                                                     monkeypatch, kill_at_touch: int) -> None:
    cfg = JigAccuracyConfig(**CFG)
    touch = jig_devices.DeviceJigRig.touch
    calls = {"n": 0}

    def dying_touch(self):
        calls["n"] += 1
        if calls["n"] == kill_at_touch:  # the move and pose of this point are already recorded
            self.recorder.flush()
            raise Killed
        return touch(self)

    monkeypatch.setattr(jig_devices.DeviceJigRig, "touch", dying_touch)
    with pytest.raises(Killed):
        execute_jig_accuracy(cfg, tmp_path, calibration=calibration, report=False)
    monkeypatch.setattr(jig_devices.DeviceJigRig, "touch", touch)
    second = execute_jig_accuracy(cfg, tmp_path, calibration=calibration, report=False)
    results, messages = straight
    assert [_result(r) for r in second.results] == results
    assert _messages(tmp_path / "run.mcap") == messages


def _earlier_attempt_recording(path: Path, n_points: int) -> list[tuple]:
    clock = VirtualClock()
    with Recorder(path, clock=clock) as rec:
        for i in range(n_points):
            clock.advance(1.0)
            rec.write_command("jig", "move_to", x_mm=float(i))
            rec.write_perception("jig_accuracy_point", {"index": i})
        rec.write_command("jig", "move_to", x_mm=99.0)  # the point that was cut short
    return _messages(path)


class Crash(BaseException):
    pass


def test_a_crash_at_any_step_of_a_resume_loses_nothing(tmp_path, monkeypatch) -> None:
    """The resume's steps (writes, flushes, fsyncs, the rename) fail one at a time: after each crash
    run.mcap still holds every message of the earlier attempt, and a later resume completes."""
    path = tmp_path / "run.mcap"
    before = _earlier_attempt_recording(path, 30)
    # Up to the 30th point message (each point: the move's command, its log line, the point); the
    # cut-short move goes.
    kept = before[: [i for i, (topic, _) in enumerate(before) if topic == "/perception/jig_accuracy_point"][29] + 1]
    steps = {"n": 0, "crash_at": 0}
    real = {"write": Recorder.publish, "sync": jig_session.os.replace}

    def counting(fn):
        def wrapped(*a, **kw):
            steps["n"] += 1
            if steps["n"] == steps["crash_at"]:
                raise Crash
            return fn(*a, **kw)
        return wrapped

    monkeypatch.setattr(Recorder, "publish", counting(real["write"]))
    monkeypatch.setattr(jig_session.os, "replace", counting(real["sync"]))
    monkeypatch.setattr("tactile_rig.rig.recording.writer.os.replace", counting(real["sync"]))
    monkeypatch.setattr("tactile_rig.rig.recording.writer.os.fsync", counting(__import__("os").fsync))
    crash_at = 1
    while True:
        steps.update(n=0, crash_at=crash_at)
        try:
            rec = jig_session.open_run_recording(tmp_path, VirtualClock(100.0), resume=True, finished=30)
        except Crash:
            now = _messages(path)
            assert now in (before, kept), f"crash at step {crash_at} lost messages"
            crash_at += 1
            continue
        rec.close()
        break
    assert crash_at > len(kept)  # every write of the copy was a crash point
    assert _messages(path) == kept


RESUMER = """
import sys
from pathlib import Path
from tactile_rig.core.clock import VirtualClock
from tactile_rig.rig.jig_accuracy.session import open_run_recording
print("ready", flush=True)
rec = open_run_recording(Path(sys.argv[1]), VirtualClock(1e4), resume=True, finished=int(sys.argv[2]))
print("renamed", flush=True)
clock = rec.clock
for i in range(100000):
    clock.advance(0.01)
    rec.write_command("jig", "move_to", x_mm=float(i))
"""


@pytest.mark.parametrize("delay_s", [0.0, 0.02, 0.05, 0.1, 0.2, 0.4, 0.8])
def test_sigkill_at_any_moment_of_a_resume_loses_nothing(tmp_path, delay_s: float) -> None:
    """A real resume process SIGKILLed ``delay_s`` after its imports (during the copy of the earlier
    attempt, the rename, or the new attempt's writes): run.mcap still holds every kept message."""
    import os  # noqa: PLC0415 - stdlib, this test only
    import signal  # noqa: PLC0415
    import subprocess  # noqa: PLC0415
    import sys  # noqa: PLC0415
    import time  # noqa: PLC0415

    path = tmp_path / "run.mcap"
    clock = VirtualClock()
    with Recorder(path, clock=clock) as rec:
        for i in range(1500):
            clock.advance(0.01)
            rec.write_command("jig", "move_to", x_mm=float(i), pad="x" * 200)
            rec.write_perception("jig_accuracy_point", {"index": i})
    before = _messages(path)
    proc = subprocess.Popen([sys.executable, "-c", RESUMER, str(tmp_path), "1500"], stdout=subprocess.PIPE,
                            env={**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)})
    assert proc.stdout.readline() == b"ready\n"
    time.sleep(delay_s)
    proc.send_signal(signal.SIGKILL)
    proc.wait(timeout=30)
    proc.stdout.close()
    after = _messages_any(path)
    assert after[: len(before)] == before  # the earlier attempt whole, whatever the new one managed


def _messages_any(path: Path) -> list[tuple]:
    """Like _messages, but a recording cut off by the kill is fine (read up to its last flush)."""
    rec = read_recording(path)
    return [(m.topic, json.dumps(_timeless(m.data), sort_keys=True)) for m in rec.messages]
