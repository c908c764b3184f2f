"""Recordings in the JSON encoding (every channel ``json``, images base64; tests/data/recordings, written
by the recorder at commit 61d975b) replay, serve as a camera, resume and export."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np

from tactile_rig.cli import main
from tactile_rig.core.clock import VirtualClock
from tactile_rig.rig.recording import Recorder, read_recording
from tactile_rig.rig.replay import RecordedFrameSource, summarize
from tests._typed import bag_messages

FIXTURE = Path(__file__).resolve().parents[1] / "data" / "recordings" / "json_session.mcap"


def test_the_json_fixture_reads_with_its_values() -> None:
    rec = read_recording(FIXTURE)
    assert not rec.truncated and len(rec.messages) == 35 and all(m.encoding == "json" for m in rec.messages)
    s = rec.on("/scale/force")
    assert [m.data["force_n"] for m in s] == [0.0, 0.5, 1.0, 1.5, 2.0] and s[2].t_s == 0.30000000000000004
    assert rec.on("/command/jig")[1].data == {"command": "move", "x_mm": 1.0, "t_s": 0.2}
    png, raw = rec.on("/camera_left/image/compressed"), rec.on("/camera_left/image")
    for a, b in zip(png, raw):  # the PNG and the raw frame of each step are the same picture
        assert np.array_equal(a.image(), b.image()) and a.image().shape == (24, 32, 3)
    assert rec.metadata_json("fixture")["frames"] == 5 and rec.attachments["note.txt"] == b"fixture"


def test_replay_summarises_and_dumps_it(capsys) -> None:
    assert main(["replay", str(FIXTURE), "--json"]) == 0
    s = json.loads(capsys.readouterr().out)
    assert s["messages"] == 35 and s["topics"]["/jig/pose"]["encoding"] == "json"
    assert main(["replay", str(FIXTURE), "--topic", "/camera_left/image/compressed", "--json"]) == 0
    rows = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    assert len(rows) == 5 and rows[0]["data"]["data"].startswith("<") and rows[0]["data"]["format"] == "png"
    assert summarize(FIXTURE)["topics"]["/scale/force"]["count"] == 5


def test_it_serves_as_a_camera() -> None:
    src = RecordedFrameSource(FIXTURE, topic="/camera_left/image/compressed", clock=VirtualClock())
    assert src.native_format()[:2] == (32, 24)
    frames = list(src.frames())
    assert [round(t, 3) for t, _ in frames] == [0.1, 0.2, 0.3, 0.4, 0.5]
    assert frames[3][1][0, 1].tolist() == [(8 + 30) % 256, 0, 120]


def test_a_resumed_recording_keeps_its_json_messages(tmp_path: Path) -> None:
    out = tmp_path / "resumed.mcap"
    old = read_recording(FIXTURE).messages
    with Recorder(out, clock=VirtualClock(1.0)) as rec:
        for m in old:
            rec.write_message(m)
        rec.write_scale(9.0)
    new = read_recording(out)
    assert [m.raw for m in new.messages[:35]] == [m.raw for m in old]
    assert new.on("/scale/force")[-1].data["force_n"] == 9.0


def test_it_exports_to_a_ros2_bag(tmp_path: Path) -> None:
    shutil.copy(FIXTURE, tmp_path / "s.mcap")
    assert main(["export", "ros2", str(tmp_path / "s.mcap"), str(tmp_path / "bag"), "--json"]) == 0
    bag = bag_messages(tmp_path / "bag")
    img = bag["/camera_left/image/compressed"]
    assert len(img) == 5 and img[0][0] == "sensor_msgs/msg/CompressedImage" and img[0][1].format == "png"
    raw = bag["/camera_left/image"][2][1]
    assert (raw.width, raw.height, raw.encoding) == (32, 24, "bgr8")
    assert [m.wrench.force.z for _, m, _ in bag["/scale/force"]] == [0.0, 0.5, 1.0, 1.5, 2.0]
    assert abs(bag["/jig/pose"][4][1].pose.position.x - 4.0e-3) < 1e-12  # mm -> m
