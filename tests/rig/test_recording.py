"""MCAP recordings: every channel round-trips, a truncated or SIGKILLed file stays readable."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import mcap  # noqa: E402,F401  (extra [record] is installed by .[all,test]; absent = fail, not skip)

from tactile_rig.core.errors import BadFile  # noqa: E402
from tactile_rig.core.clock import VirtualClock  # noqa: E402
from tactile_rig.control.protocols import Pose  # noqa: E402
from tactile_rig.rig.recording import Recorder, read_recording  # noqa: E402


def _session(path: Path, n: int = 200, dt_s: float = 0.01) -> None:
    clock = VirtualClock()
    rng = np.random.default_rng(0)
    with Recorder(path, clock=clock) as rec:
        for i in range(n):
            clock.advance(dt_s)
            rec.write_scale(0.1 * i)
            if i % 20 == 0:
                rec.write_frame("left", rng.integers(0, 255, (6, 8, 3), dtype=np.uint8))


def test_every_channel_round_trips(tmp_path: Path) -> None:
    from tactile_rig.rig.bench import load_bench, mock_bench_path

    clock = VirtualClock()
    img = np.arange(6 * 8 * 3, dtype=np.uint8).reshape(6, 8, 3)
    gray = np.arange(48, dtype=np.uint8).reshape(6, 8)
    cal = tmp_path / "scale.json"
    cal.write_text('{"newton_per_count": 0.001}')
    path = tmp_path / "s.mcap"
    with Recorder(path, clock=clock) as rec:
        rec.add_bench(load_bench(mock_bench_path(), env={}))
        rec.add_calibration("scale", path=cal, values={"version": 1})
        clock.advance(0.5)
        rec.write_frame("left", img)
        rec.write_frame("gray", gray)
        rec.write_frame("left", img, compress="png")
        rec.write_perception("gelsight", {"rotation_deg": 12.5, "shift_mm": [0.1, -0.2]})
        rec.write_state("gripper", {"opening_m": 0.05, "moving": False})
        rec.write_command("jig", "move", x_mm=1.0)
        rec.write_jig_pose(Pose(x_mm=1.0, theta_deg=30.0), true_theta_deg=30.1)
        clock.advance(0.25)
        rec.write_scale(2.5)
    r = read_recording(path)
    assert not r.truncated
    frames = r.on("/left/image")
    assert len(frames) == 1 and np.array_equal(frames[0].image(), img) and frames[0].t_s == 0.5
    assert np.array_equal(r.on("/gray/image")[0].image(), gray)
    png = r.on("/left/image/compressed")[0]
    assert png.schema == "foxglove.CompressedImage" and np.array_equal(png.image(), img)
    assert frames[0].schema == "foxglove.RawImage" and frames[0].data["encoding"] == "bgr8"
    assert r.on("/perception/gelsight")[0].data["shift_mm"] == [0.1, -0.2]
    assert r.on("/state/gripper")[0].data["opening_m"] == 0.05
    assert r.on("/command/jig")[0].data == {"command": "move", "x_mm": 1.0, "t_s": 0.5}
    pose = r.on("/jig/pose")[0].data
    assert pose["theta_deg"] == 30.0 and pose["true_theta_deg"] == 30.1
    s = r.on("/scale/force")[0]
    assert s.data["force_n"] == 2.5 and s.t_s == 0.75 and s.log_time_ns == 750_000_000
    bench_meta = r.metadata_json("bench")
    assert bench_meta["name"] == "mock" and bench_meta["device.scale"]["port"] == "rigsim://scale"
    assert b"[scale]" in r.attachments["bench.toml"]
    assert r.metadata_json("calibration.scale")["version"] == 1
    assert r.attachments["calibration/scale/scale.json"] == cal.read_bytes()


def test_bad_frames_and_options_are_named(tmp_path: Path) -> None:
    with Recorder(tmp_path / "x.mcap", clock=VirtualClock()) as rec:
        with pytest.raises(ValueError, match="camera 'c'.*uint8"):
            rec.write_frame("c", np.zeros((4, 4), np.float32))
        with pytest.raises(ValueError, match="compress='gif'"):
            rec.write_frame("c", np.zeros((4, 4), np.uint8), compress="gif")
    with pytest.raises(ValueError, match="at most one second"):
        Recorder(tmp_path / "y.mcap", flush_interval_s=5.0)
    with pytest.raises(FileNotFoundError):
        read_recording(tmp_path / "missing.mcap")
    (tmp_path / "bench.toml").write_text("[scale]\nport = 'x'\n")
    with pytest.raises(ValueError, match="not an MCAP recording"):
        read_recording(tmp_path / "bench.toml")


@pytest.fixture(scope="module")
def full_recording(tmp_path_factory: pytest.TempPathFactory) -> tuple[bytes, list[float]]:
    path = tmp_path_factory.mktemp("rec") / "full.mcap"
    _session(path)
    r = read_recording(path)
    return path.read_bytes(), [m.data["force_n"] for m in r.on("/scale/force")]


@settings(max_examples=30)
@given(frac=st.floats(0.0, 1.0))
def test_truncated_file_reads_a_prefix(full_recording, tmp_path_factory, frac: float) -> None:
    data, forces = full_recording
    cut = int(frac * len(data))
    path = tmp_path_factory.mktemp("cut") / "cut.mcap"
    path.write_bytes(data[:cut])
    header_end = 8 + 9 + int.from_bytes(data[9:17], "little")
    if cut < header_end:  # not even the header record: nothing was ever recorded in it, refused by name
        with pytest.raises(BadFile, match="cut.mcap"):
            read_recording(path)
        return
    r = read_recording(path)  # a cut anywhere after the header record never raises
    got = [m.data["force_n"] for m in r.on("/scale/force")]
    assert got == forces[: len(got)]  # a prefix, in order, nothing corrupted
    if cut < len(data) - 8:
        assert r.truncated
    # flushed once per second of session time: a cut just before the end keeps all but ~1 s
    if cut >= len(data) - 100:
        assert len(got) >= len(forces) - 100


WRITER = textwrap.dedent("""
    import sys, time
    from tactile_rig.core.clock import VirtualClock
    from tactile_rig.rig.recording import Recorder
    clock = VirtualClock()
    rec = Recorder(sys.argv[1], clock=clock, flush_interval_s=1.0)
    i = 0
    while True:
        clock.advance(0.01)
        rec.write_scale(float(i))
        i += 1
        if i == 500:
            print(repr(clock.now_s()), flush=True)
        if i > 500:
            time.sleep(0.0002)  # keep writing, mid-chunk, until killed
""")


def test_sigkill_mid_run_loses_at_most_the_last_second(tmp_path: Path) -> None:
    path = tmp_path / "killed.mcap"
    proc = subprocess.Popen([sys.executable, "-c", WRITER, str(path)], stdout=subprocess.PIPE, text=True)
    try:
        line = proc.stdout.readline()
        assert line, "writer died before reporting"
        t_reported = float(line)
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait(timeout=10)
    finally:
        if proc.poll() is None:
            proc.kill()
        proc.stdout.close()
    assert proc.returncode == -signal.SIGKILL
    r = read_recording(path)
    assert r.truncated
    msgs = r.on("/scale/force")
    values = [m.data["force_n"] for m in msgs]
    assert values == [float(i) for i in range(len(values))]  # intact, contiguous from the start
    assert msgs[-1].t_s >= t_reported - 1.0


def test_idle_wall_clock_session_is_flushed_by_the_timer(tmp_path: Path) -> None:
    path = tmp_path / "idle.mcap"
    rec = Recorder(path, flush_interval_s=0.1)  # wall clock: background flushing
    try:
        rec.write_scale(1.25)
        deadline = time.monotonic() + 10.0
        seen: list = []
        while time.monotonic() < deadline and not seen:
            time.sleep(0.05)
            seen = read_recording(path).on("/scale/force")
        assert seen and seen[0].data["force_n"] == 1.25
        assert seen[0].log_time_ns > 1_500_000_000 * 10**9  # Unix-epoch times for Foxglove
    finally:
        rec.close()
    assert not read_recording(path).truncated


def test_replay_cli_summarises_and_dumps(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    from tactile_rig.cli import main

    path = tmp_path / "s.mcap"
    _session(path, n=50)
    assert main(["replay", str(path), "--json"]) == 0
    s = json.loads(capsys.readouterr().out)
    assert s["topics"]["/scale/force"]["count"] == 50 and s["topics"]["/left/image"]["count"] == 3
    assert not s["truncated"] and abs(s["duration_s"] - 0.49) < 1e-9
    assert main(["replay", str(path), "--topic", "/scale/force", "--json"]) == 0
    rows = [json.loads(x) for x in capsys.readouterr().out.splitlines()]
    assert [r["data"]["force_n"] for r in rows] == pytest.approx([0.1 * i for i in range(50)])
    assert main(["replay", str(path), "--dump", "--json"]) == 0
    frames = [json.loads(x) for x in capsys.readouterr().out.splitlines() if "/image" in x]
    assert frames and frames[0]["data"]["data"].startswith("<")  # image payloads are elided
    assert main(["replay", str(path), "--topic", "/nope"]) == 2
    assert "no messages on topic '/nope'" in capsys.readouterr().err
    path.write_bytes(path.read_bytes()[:-300])
    assert main(["replay", str(path)]) == 0
    assert "TRUNCATED" in capsys.readouterr().out


def test_missing_extra_is_one_line_naming_the_pip_extra(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                        capsys: pytest.CaptureFixture) -> None:
    from tactile_rig.cli import main
    from tactile_rig.rig import replay

    def no_mcap(path):
        raise ModuleNotFoundError("No module named 'mcap'", name="mcap")

    monkeypatch.setattr(replay, "summarize", no_mcap)
    assert main(["replay", str(tmp_path / "x.mcap")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "pip install 'tactile-rig[all]'" in err


def test_camera_topics_and_both_calibration_files(tmp_path):
    cal_json, cal_npz = tmp_path / "gelsight.json", tmp_path / "gelsight.npz"
    cal_json.write_text(json.dumps({"format": "x"}))
    np.savez(cal_npz, a=np.arange(3))
    with Recorder(tmp_path / "r.mcap", clock=VirtualClock()) as rec:
        rec.write_frame("camera", np.zeros((4, 4, 3), np.uint8))
        rec.write_frame("camera_left", np.zeros((4, 4, 3), np.uint8), compress="jpeg")
        rec.add_calibration("gelsight", path=cal_npz)
    r = read_recording(tmp_path / "r.mcap")
    assert set(r.topics()) == {"/camera/image", "/camera_left/image/compressed"}
    assert {"calibration/gelsight/gelsight.json", "calibration/gelsight/gelsight.npz"} <= set(r.attachments)
    assert r.attachments["calibration/gelsight/gelsight.npz"] == cal_npz.read_bytes()
