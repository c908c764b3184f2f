"""The scale's line codec: framed lines split anywhere with noise between them, stock lines, CRC."""

from __future__ import annotations

from pathlib import Path

from hypothesis import given
from hypothesis import strategies as st

from tactile_rig.devices import scale as sp
from tactile_rig.drivers.scale import ScaleLineParser, crc8, parse_line
from tactile_rig.mocks.scale import frame
from tactile_rig.mocks.scale.sketch import _crc8 as mock_crc8
from tactile_rig.testing.strategies import split_stream
from tactile_rig.testing.strategies_scale import (
    corrupted,
    crc8_reference,
    noise,
    sample_line,
    samples,
    stock_line,
)

GOLDEN = Path(__file__).resolve().parents[1] / "data" / "scale" / "stock_read_1x_load_cell.txt"


@given(st.binary(max_size=64))
def test_three_crc_implementations_agree(data: bytes) -> None:
    # Driver (table), mock (bitwise on the AVR's model) and the test's long division: independent codecs.
    expected = crc8_reference(data)
    assert crc8(data) == expected
    assert mock_crc8(data) == expected


def test_crc_known_value() -> None:
    # CRC-8/SMBUS check value: crc("123456789") = 0xF4 (the catalogue's check for poly 0x07, init 0).
    assert crc8(b"123456789") == 0xF4 == crc8_reference(b"123456789")


@given(st.data())
def test_lines_split_anywhere_with_noise_parse_to_exactly_the_valid_readings(data: st.DataObject) -> None:
    items = data.draw(st.lists(samples(), min_size=1, max_size=8))
    stream = bytearray(b"\n")  # the parser's first-line resync is exercised elsewhere
    for seq, grams, raw in items:
        stream += data.draw(noise())
        stream += sample_line(seq, grams, raw)
    parser = ScaleLineParser(sync=False)
    got = []
    for chunk in data.draw(split_stream(bytes(stream), max_chunks=20)):
        got += [p for p in parser.feed(chunk, 0.0) if p.kind == "sample"]
    assert [(p.reading.seq, p.reading.grams, p.reading.raw) for p in got] == items


@given(st.data())
def test_a_corrupted_frame_is_rejected_and_counted_as_corrupt(data: st.DataObject) -> None:
    good = sample_line(*data.draw(samples()))
    bad = data.draw(corrupted(good))
    kinds = [p.kind for p in ScaleLineParser(sync=False).feed(b"\n" + bad + good, 0.0)]
    assert kinds.count("sample") == 1
    assert "sample" not in kinds[:-1] and kinds[-1] == "sample"
    assert len(kinds) == 1 or kinds[0] in ("corrupt", "other")


@given(st.floats(-1e5, 1e5, allow_nan=False))
def test_stock_lines_parse(grams: float) -> None:
    p = parse_line(stock_line(grams).rstrip(b"\r\n"), 1.5)
    assert p is not None and p.kind == "stock_sample"
    assert p.reading.grams == float(f"{grams:.2f}") and p.reading.raw is None and p.t_s == 1.5


def test_golden_lines_of_the_stock_example_parse() -> None:
    parser = ScaleLineParser(sync=False)
    lines = parser.feed(GOLDEN.read_bytes(), 0.0)
    kinds = [p.kind for p in lines]
    values = [p.reading.grams for p in lines if p.kind == "stock_sample"]
    assert kinds[:2] == ["stock_start", "stock_ready"]
    assert values == [0.0, -0.03, 0.12, 245.67, 1002.5, -1.25, 3.4]
    assert kinds.count("stock_tare") == 1 and kinds.count("invalid") == 2  # nan and ovf


def test_banner_and_replies_decode() -> None:
    parser = ScaleLineParser(sync=False)
    out = parser.feed(frame("B,hx711-scale,1.0.0,80,696.000") + frame("T,ok") + frame("K,702.125")
                      + frame("E,3,load too small") + frame("S,65535,-1.500,-8388608"), 2.0)
    assert [p.kind for p in out] == ["banner", "tare", "cal", "error", "sample"]
    assert out[0].info.rate_sps == 80 and out[0].info.cal_factor_counts_per_g == 696.0
    assert out[2].value == 702.125 and out[3].code == 3
    assert out[4].reading.saturated and out[4].reading.raw == sp.RAW_MIN


def test_out_of_range_fields_are_corrupt_even_with_a_good_crc() -> None:
    for body in ("S,65536,1.000,5", "S,1,1.000,8388608", "S,1,nan,5", "S,x,1,2"):
        p = parse_line(frame(body).rstrip(b"\r\n"), 0.0)
        assert p is not None and p.kind == "corrupt", body


def test_first_partial_line_is_dropped_unless_whole() -> None:
    half = sample_line(7, 1.0, 100)[5:]
    assert [p.kind for p in ScaleLineParser().feed(half + sample_line(8, 1.0, 100), 0.0)] == ["sample"]
    assert [p.reading.seq for p in ScaleLineParser().feed(sample_line(7, 1.0, 100), 0.0)] == [7]


@given(st.binary(max_size=300))
def test_arbitrary_bytes_never_raise(data: bytes) -> None:
    parser = ScaleLineParser(sync=False)
    for p in parser.feed(data, 0.0):
        assert p.kind in ("sample", "banner", "id", "tare", "cal", "error", "stock_sample", "stock_start",
                          "stock_ready", "stock_tare", "corrupt", "invalid", "other")
