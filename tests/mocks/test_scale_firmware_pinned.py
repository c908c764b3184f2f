"""The scale mock behaves as the sketch does where the two are easiest to tell apart: boot and reset
timing, the receive ring, the command and mass grammar, the sketch's integer arithmetic, raw counts
across a reboot, the Uno's real baud rate, an unplugged HX711 and its settling.

``tests/mocks/test_scale_firmware_differential.py`` holds the mock against the sketch compiled for the
ATmega328P on the simulated board, line for line; these run without the AVR toolchain. Times are the
mock's virtual time, not wall time.
"""

from __future__ import annotations

import math
import re
from fractions import Fraction

import pytest
from hypothesis import given
from hypothesis import strategies as st

from tactile_rig.devices import scale as sp
from tactile_rig.drivers.scale import parse_line
from tactile_rig.mocks import scale as ms
from tactile_rig.mocks.hx711 import RAW_MAX, RAW_MIN, Hx711
from tactile_rig.mocks.scale_firmware import BoardConfig, Script, run_script_mock

G = sp.STANDARD_GRAVITY_MPS2
QUIET = BoardConfig(noise_counts=0.0, drift_counts=0.0, spike_prob=0.0, boot_junk=0)


def _parsed(lines):
    return [parse_line(line.data.rstrip(b"\r\n"), line.t_first_s) for line in lines]


def _kinds(lines) -> list[str]:
    return [p.kind for p in _parsed(lines)]


# -- start-up ---------------------------------------------------------------------------------------

@pytest.mark.parametrize("rate", [10, 80])
def test_the_banner_follows_the_bootloader_then_the_hx711_settling_and_20_conversions(rate: int) -> None:
    # Not at the bootloader's end with the window already full: the sketch resets the HX711 (first
    # data 4 periods later), drops 2 conversions and fills 18 for the start-up tare.
    cfg = BoardConfig(rate_sps=rate, noise_counts=0.0, drift_counts=0.0, spike_prob=0.0, boot_junk=0)
    s = Script().at(0.0, "open")
    s.end_s = cfg.bootloader_s + 24.5 / rate
    lines = run_script_mock(s, cfg).lines
    assert [p.kind for p in _parsed(lines)] == ["banner", "sample"]
    period = 1.0 / rate
    startup = lines[0].t_first_s - cfg.bootloader_s
    assert 23 * period < startup < 23 * period + 0.002  # 4 settling + 2 discarded + 18 window - 1
    assert lines[1].t_first_s - lines[0].t_first_s == pytest.approx(period, abs=0.002)
    assert _parsed(lines)[1].reading.seq == 0


def test_bytes_in_the_bootloader_are_lost_and_in_setup_wait_in_a_63_byte_ring() -> None:
    # Bytes sent before the banner are not all lost: the sketch's Serial.begin() runs first thing,
    # so they wait in HardwareSerial's 64-byte ring (63 usable) and run after the banner.
    boot = QUIET.bootloader_s
    s = Script().at(0.0, "open")
    s.at(0.5, "send", b"?\n" * 5)  # the bootloader's: gone
    s.at(boot + 0.05, "send", b"?\n" * 40)  # 80 bytes during setup: the first 63 fit
    s.at(boot + 1.0, "send", b"\n")  # completes the "?" left in the line buffer
    s.end_s = boot + 1.1
    result = run_script_mock(s, QUIET)
    kinds = _kinds(result.lines)
    first_sample = kinds.index("sample")
    assert kinds[0] == "banner" and kinds[1:first_sample] == ["id"] * 31
    assert kinds[first_sample:].count("id") == 1  # the 63rd byte, "?", waited for its newline
    assert result.stats["rx_dropped"] == 10 + 80 - 63


def test_a_reset_loses_what_the_board_had_not_read() -> None:
    s = Script().at(0.0, "open").at(2.0, "send", b"c,100\n").at(2.0005, "reset")
    s.end_s = 4.5
    kinds = _kinds(run_script_mock(s, QUIET).lines)
    assert kinds.count("banner") == 2 and "error" not in kinds and "cal" not in kinds


# -- command lines ------------------------------------------------------------------------------------

def _session(*sends: bytes, gap_s: float = 0.1, cfg: BoardConfig = QUIET):
    s = Script().at(0.0, "open")
    t = cfg.bootloader_s + 0.6
    for data in sends:
        s.at(t, "send", data)
        t += gap_s
    s.end_s = t + 0.4
    return [p for p in _parsed(run_script_mock(s, cfg).lines) if p.kind != "sample"]


def test_long_lines_and_nul_bytes_are_unknown_commands_and_blank_lines_nothing() -> None:
    # A line over the buffer is one unknown command; its tail is not taken as a new one.
    got = _session(b"a" * 32 + b"\n", b"?" * 33 + b"\n", b"t\x00\n", b"\r\n", b"\n", b"?\r\n")
    assert [p.kind for p in got[1:]] == ["error", "error", "error", "id"]
    assert [p.code for p in got[1:4]] == [1, 1, 1]


def test_a_repeated_tare_restarts_the_wait_and_is_answered_once() -> None:
    # One T,ok, not one per 't'.
    s = Script().at(0.0, "open")
    t0 = QUIET.bootloader_s + 0.6
    s.at(t0, "send", b"t\n").at(t0 + 0.05, "send", b"t\n")
    s.end_s = t0 + 0.6
    parsed = _parsed(run_script_mock(s, QUIET).lines)
    tares = [i for i, p in enumerate(parsed) if p.kind == "tare"]
    assert len(tares) == 1
    after_second = [p for p in parsed if p.kind == "sample" and p.t_s > t0 + 0.05]
    # The 18th conversion after the second 't' takes the tare: 17 samples come before T,ok.
    assert parsed[tares[0] + 1].reading.seq - after_second[0].reading.seq == ms.WINDOW - 1


@pytest.mark.parametrize(("command", "code"), [
    (b"c,100.0000", 2), (b"c,1e2", 2), (b"c,+5", 2), (b"c,.5", 2), (b"c,5.", 2), (b"c,1000001", 2),
    (b"c,0", 2), (b"c,0.000", 2), (b"c,", 2), (b"c, 5", 2), (b"c,5 ", 2), (b"C,5", 1), (b"c5", 1),
])
def test_calibration_masses_outside_the_sketch_grammar_are_refused(command: bytes, code: int) -> None:
    # The sketch's own grammar, not float()'s ("1e2", " 5" and "100.0000" are refused).
    got = _session(command + b"\n")
    assert [(p.kind, p.code) for p in got[1:]] == [("error", code)]


@given(st.text(alphabet="0123456789.+-e ,", min_size=0, max_size=12))
def test_the_mass_grammar_is_digits_with_up_to_three_decimals(text: str) -> None:
    mg = ms.parse_mass_mg(text)
    m = re.fullmatch(r"(\d{1,7})(?:\.(\d{1,3}))?", text)
    if m is None:
        assert mg is None
        return
    expected = int(m.group(1)) * 1000 + int((m.group(2) or "").ljust(3, "0"))
    assert mg == (expected if 0 < expected <= 1_000_000_000 else None)


def test_calibration_factor_out_of_range_is_e5_and_a_reversed_cell_calibrates_negative() -> None:
    s = Script().at(0.0, "open")
    t0 = QUIET.bootloader_s + 0.6
    s.at(t0, "force_n", 0.2 * G).at(t0 + 0.3, "send", b"c,0.001\n")  # 139200 counts / 1 mg: 1.4e8 counts/g
    s.at(t0 + 0.7, "force_n", -0.2 * G).at(t0 + 1.0, "send", b"c,200\n")
    s.end_s = t0 + 1.5
    got = [p for p in _parsed(run_script_mock(s, QUIET).lines) if p.kind in ("error", "cal")]
    assert [(p.kind, p.code) for p in got] == [("error", 5), ("cal", None)]
    assert got[1].value == pytest.approx(-696.0, abs=0.01)


# -- numbers ----------------------------------------------------------------------------------------

@given(st.integers(-(10**15), 10**15), st.integers(-(10**9), 10**9).filter(lambda d: d != 0))
def test_division_rounds_half_away_from_zero_like_the_sketch(n: int, d: int) -> None:
    exact = Fraction(n, d)
    q = ms.div_round(n, d)
    assert abs(exact - q) <= Fraction(1, 2)
    if abs(exact - q) == Fraction(1, 2):
        assert abs(q) > abs(exact)  # a tie goes away from zero


@given(st.integers(-(10**14), 10**14))
def test_thousandths_print_with_three_decimals_and_no_negative_zero(v: int) -> None:
    text = ms.milli_str(v)
    assert re.fullmatch(r"-?\d+\.\d{3}", text) and Fraction(text) == Fraction(v, 1000)
    assert not text.startswith("-0.000")


def test_raw_is_absolute_counts_the_tare_only_moves_grams() -> None:
    # The host keeps its own zero from raw across a reboot of the board.
    s = Script().at(0.0, "open")
    t0 = QUIET.bootloader_s + 0.4
    s.at(t0, "force_n", 0.1 * G).at(t0 + 0.5, "send", b"t\n").at(t0 + 1.2, "reset")
    s.end_s = t0 + 3.3
    parsed = _parsed(run_script_mock(s, QUIET).lines)
    reboot = [i for i, p in enumerate(parsed) if p.kind == "banner"][1]
    before = [p.reading for p in parsed[:reboot] if p.kind == "sample"]
    after = [p.reading for p in parsed[reboot:] if p.kind == "sample"]
    loaded = 84_000 + 69_600  # offset + 696 counts/g x 100 g
    tare_at = next(i for i, p in enumerate(parsed) if p.kind == "tare")
    settled = [r for r in before if r.raw == loaded]
    assert {(r.grams, r.t_host_s < parsed[tare_at].t_s) for r in settled} == {(100.0, True), (0.0, False)}
    assert after[0].seq == 0 and {(r.grams, r.raw) for r in after} == {(0.0, loaded)}  # the boot tare


def test_the_uno_sends_57600_as_58824_baud() -> None:
    # The core's exception for 57600 at 16 MHz: UBRR 16 without U2X, 170 us a byte.
    s = Script().at(0.0, "open")
    s.end_s = QUIET.bootloader_s + 0.4
    line = run_script_mock(s, QUIET).lines[1]
    assert line.t_last_s - line.t_first_s == pytest.approx((len(line.data) - 1) * 170e-6, rel=1e-6)


# -- the HX711 ----------------------------------------------------------------------------------------

def test_an_unplugged_hx711_is_e4_once_a_second_and_the_stream_resumes_when_back() -> None:
    s = Script().at(0.0, "open")
    t0 = QUIET.bootloader_s + 0.5
    s.at(t0, "hx711", "disconnect").at(t0 + 3.5, "hx711", "connect")
    s.end_s = t0 + 4.0
    parsed = _parsed(run_script_mock(s, QUIET).lines)
    e4 = [p.t_s for p in parsed if p.kind == "error"]
    assert len(e4) == 3 and [b - a for a, b in zip(e4, e4[1:])] == pytest.approx([1.0, 1.0], abs=0.002)
    seqs = [p.reading.seq for p in parsed if p.kind == "sample"]
    assert seqs == list(range(len(seqs)))  # numbering continues: nothing was sent meanwhile


def test_no_hx711_at_start_up_repeats_e4_until_one_is_plugged_in() -> None:
    s = Script().at(0.0, "hx711", "disconnect").at(0.1, "open").at(4.0, "hx711", "connect")
    s.end_s = 4.5
    kinds = _kinds(run_script_mock(s, QUIET).lines)
    assert kinds[:2] == ["error", "error"] and "banner" in kinds and kinds.index("banner") == 2


def _step_response(before: float, after: float, rate: int = 80) -> list[int]:
    level = {"v": before}
    hx = Hx711(rate, lambda t: level["v"])
    hx.reset(0.0)
    out = [v for _, v in hx.convert_until(10.5 / rate)]
    level["v"] = after
    out += [v for _, v in hx.convert_until(16.5 / rate)]
    return out


def test_the_hx711_settles_4_periods_after_reset_and_a_step_takes_its_sinc4_shape() -> None:
    hx = Hx711(80, lambda t: 1000.0)
    hx.reset(1.0)
    assert hx.next_data_s() == pytest.approx(1.0 + 4 / 80)
    out = _step_response(0.0, 24_000.0)
    assert out[:7] == [0] * 7  # conversions 4..10 before the step
    assert out[7:12] == [1000, 12_000, 23_000, 24_000, 24_000]


@given(st.floats(min_value=-2e7, max_value=2e7, allow_nan=False), st.sampled_from([10, 80]))
def test_a_constant_input_converts_to_itself_clamped_to_24_bits(level: float, rate: int) -> None:
    hx = Hx711(rate, lambda t: level)
    hx.reset(0.0)
    values = [v for _, v in hx.convert_until(12.5 / rate)]
    expected = min(max(math.floor(level + 0.5), RAW_MIN), RAW_MAX)  # the board's double arithmetic
    assert len(values) == 9 and set(values) == {expected}


def test_the_hx711_model_refuses_impossible_settings() -> None:
    with pytest.raises(ValueError, match="rate_sps"):
        Hx711(40, lambda t: 0.0)
    with pytest.raises(ValueError, match="noise_counts"):
        Hx711(80, lambda t: 0.0, noise_counts=float("nan"))
    with pytest.raises(ValueError, match="spike_prob"):
        Hx711(80, lambda t: 0.0, spike_prob=2.0)


def test_a_flood_while_running_overflows_the_ring_and_answers_what_fitted() -> None:
    s = Script().at(0.0, "open")
    t0 = QUIET.bootloader_s + 0.5
    s.at(t0, "send", b"?\n" * 100)
    s.end_s = t0 + 0.5
    result = run_script_mock(s, QUIET)
    answers = [p for p in _parsed(result.lines) if p.kind in ("id", "error")]
    assert 31 < len(answers) < 100 and result.stats["rx_dropped"] > 0
