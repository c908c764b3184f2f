"""MCAP recordings read back only when intact: every CRC checked, a damaged chunk named, a zero-byte
or bit-flipped file refused by `replay` with exit 2 and one line."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import mcap  # noqa: F401  (the record extra is a test dependency)

from tactile_rig.cli import main
from tactile_rig.core.clock import VirtualClock
from tactile_rig.core.errors import BadFile
from tactile_rig.rig.messages import Encoded, json_schema
from tactile_rig.rig.recording import Recorder, read_recording


def _session(path: Path) -> None:
    clock = VirtualClock()
    with Recorder(path, clock=clock, chunk_size=2048) as rec:
        rec.add_metadata("bench", {"name": "test"})
        for i in range(120):
            clock.advance(0.05)
            rec.write_scale(float(i))
            if i % 20 == 0:
                rec.write_frame("cam", np.full((8, 8, 3), i, np.uint8), compress="png")


def _key(r):
    return [(m.topic, m.log_time_ns, m.data) for m in r.messages], r.metadata, r.attachments


@pytest.fixture(scope="module")
def session(tmp_path_factory: pytest.TempPathFactory) -> tuple[bytes, object]:
    path = tmp_path_factory.mktemp("rec") / "s.mcap"
    _session(path)
    return path.read_bytes(), _key(read_recording(path))


@settings(max_examples=150, deadline=None)
@given(frac=st.floats(0.0, 1.0, exclude_max=True), bit=st.integers(0, 7))
def test_a_flipped_bit_is_refused_or_harmless(session, tmp_path_factory, frac: float, bit: int) -> None:
    data, ref = session
    pos = int(frac * len(data))
    b = bytearray(data)
    b[pos] ^= 1 << bit
    path = tmp_path_factory.mktemp("flip") / "f.mcap"
    path.write_bytes(bytes(b))
    try:
        got = _key(read_recording(path))
    except BadFile as exc:
        assert str(path) in str(exc)
        return
    assert got == ref  # never a silently different message, metadata or attachment


def _one_line_exit_2(capsys, argv) -> str:
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err
    return err


def test_replay_refuses_a_zero_byte_file(tmp_path: Path, capsys) -> None:
    p = tmp_path / "empty.mcap"
    p.write_bytes(b"")
    err = _one_line_exit_2(capsys, ["replay", str(p)])
    assert "empty.mcap" in err and "empty (0 bytes)" in err


def test_replay_names_the_corrupt_chunk(tmp_path: Path, session, capsys) -> None:
    data, _ = session
    from mcap.records import Chunk  # noqa: PLC0415 - third-party, test only
    from mcap.stream_reader import StreamReader  # noqa: PLC0415

    p = tmp_path / "good.mcap"
    p.write_bytes(data)
    f = open(p, "rb")
    reader = StreamReader(f, emit_chunks=True)
    offsets = []
    for rec in reader.records:
        if isinstance(rec, Chunk):
            offsets.append(f.tell() - len(rec.data) // 2)  # the middle of the chunk's payload
    f.close()
    b = bytearray(data)
    b[offsets[2]] ^= 0x10
    bad = tmp_path / "flipped.mcap"
    bad.write_bytes(bytes(b))
    err = _one_line_exit_2(capsys, ["replay", str(bad)])
    assert "flipped.mcap" in err and "chunk 2" in err
    err = _one_line_exit_2(capsys, ["replay", str(bad), "--dump", "--json"])
    assert "chunk 2" in err


def test_deeply_nested_message_is_refused_by_name(tmp_path: Path, capsys) -> None:
    p = tmp_path / "deep.mcap"
    with Recorder(p, clock=VirtualClock()) as rec:
        rec.publish(Encoded("/deep", json_schema("tactile_rig.Json"), b"[" * 50000 + b"]" * 50000, 0.0, 0))
    with pytest.raises(BadFile, match="levels deep"):
        read_recording(p)
    err = _one_line_exit_2(capsys, ["replay", str(p)])
    assert "deep.mcap" in err and "/deep" in err


def test_truncated_recording_still_replays(tmp_path: Path, session, capsys) -> None:
    data, _ = session
    p = tmp_path / "cut.mcap"
    p.write_bytes(data[: len(data) // 2])
    assert main(["replay", str(p), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["truncated"] and 0 < out["messages"] < 126
