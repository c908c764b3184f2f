"""The file-checking layer over typed recordings: a malformed protobuf message or schema is one clear
BadFile naming the file, topic and offset; garbage never escapes as another error; a typed recording
cut off anywhere still reads; copying a recorded message keeps its bytes."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from tactile_rig.cli import main
from tactile_rig.core.clock import VirtualClock
from tactile_rig.core.errors import BadFile
from tactile_rig.rig.messages import Encoded, SchemaDef, foxglove_schema
from tactile_rig.rig.recording import Recorder, read_recording


def _with(path: Path, schema: SchemaDef, payload: bytes) -> None:
    with Recorder(path, clock=VirtualClock()) as rec:
        rec.write_scale(1.0, t_s=0.5)
        rec.publish(Encoded("/cam/image/compressed", schema, payload, 1.0, 1_000_000_000))


def test_a_malformed_protobuf_message_is_one_bad_file_naming_topic_and_offset(tmp_path: Path, capsys) -> None:
    p = tmp_path / "bad.mcap"
    _with(p, foxglove_schema("CompressedImage"), b"\x0a\xff\xff\xff\xff\x0f")  # a length past the end
    with pytest.raises(BadFile) as err:
        read_recording(p)
    text = str(err.value)
    assert str(p) in text and "/cam/image/compressed" in text and "foxglove.CompressedImage" in text
    # Where it lies: the chunk, its byte offset in the file, the record in the chunk.
    assert re.search(r"chunk 0 \(byte \d+\) record \d+ on /cam/image/compressed", text), text
    assert main(["replay", str(p)]) == 2
    out = capsys.readouterr()
    assert out.err.count("\n") == 1 and "Traceback" not in out.err


def test_a_protobuf_schema_that_does_not_define_its_message_is_refused(tmp_path: Path) -> None:
    p = tmp_path / "schema.mcap"
    fds = foxglove_schema("CompressedImage").data
    _with(p, SchemaDef("foxglove.NoSuchThing", "protobuf", fds, "protobuf"), b"")
    with pytest.raises(BadFile, match="protobuf schema .*foxglove.NoSuchThing.* does not define its message"):
        read_recording(p)
    _with(p, SchemaDef("foxglove.CompressedImage", "protobuf", b"\xff\xff garbage", "protobuf"), b"")
    with pytest.raises(BadFile, match="does not define its message"):
        read_recording(p)


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(st.binary(max_size=300))
def test_garbage_protobuf_is_a_message_or_a_bad_file(tmp_path: Path, payload: bytes) -> None:
    p = tmp_path / "fuzz.mcap"
    _with(p, foxglove_schema("CompressedImage"), payload)
    try:
        rec = read_recording(p)
    except BadFile as exc:
        assert "/cam/image/compressed" in str(exc)
        return
    msg = rec.on("/cam/image/compressed")[0]
    assert msg.encoding == "protobuf" and isinstance(msg.data["data"], bytes) and msg.raw == payload


def test_a_typed_recording_cut_off_anywhere_keeps_its_complete_chunks(tmp_path: Path) -> None:
    full = tmp_path / "full.mcap"
    clock = VirtualClock()
    img = (np.arange(48 * 64 * 3) % 256).astype(np.uint8).reshape(48, 64, 3)
    with Recorder(full, clock=clock, flush_interval_s=0.1) as rec:
        for i in range(40):
            clock.advance(0.05)
            rec.write_frame("cam", img, compress="png")
            rec.write_markers("cam", [[1.0 + i, 2.0]], image_size_px=(64, 48), mm_per_px=0.1,
                              displacements_px=[[0.5, 0.0]])
    data = full.read_bytes()
    last = -1
    for cut in range(100, len(data), max(1, len(data) // 37)):
        part = tmp_path / "cut.mcap"
        part.write_bytes(data[:cut])
        rec_ = read_recording(part)
        n = len(rec_.on("/cam/image/compressed"))
        assert rec_.truncated and n >= last  # more of the file, never fewer messages
        last = n
        for m in rec_.on("/cam/image/compressed"):
            assert np.array_equal(m.image(), img)
    assert last > 30


def test_write_message_copies_typed_and_json_messages_byte_for_byte(tmp_path: Path) -> None:
    src, dst = tmp_path / "a.mcap", tmp_path / "b.mcap"
    clock = VirtualClock()
    with Recorder(src, clock=clock) as rec:
        clock.advance(2.0)
        rec.write_frame("cam", np.zeros((4, 4, 3), np.uint8), compress="jpeg")
        rec.write_command("jig", "move_to", x_mm=1.0)
    old = read_recording(src).messages
    with Recorder(dst, clock=VirtualClock()) as rec:
        for m in old:
            rec.write_message(m)
    new = read_recording(dst).messages
    assert [(m.topic, m.schema, m.encoding, m.raw, m.log_time_ns) for m in new] == \
        [(m.topic, m.schema, m.encoding, m.raw, m.log_time_ns) for m in old]
    assert new[0].t_s == 2.0
