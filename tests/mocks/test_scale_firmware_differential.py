"""The Python scale mock held against the real sketch, line for line.

Each session runs twice: on the sketch compiled for the ATmega328P inside the simulated board
(``firmware/sim``, simulated time, as fast as the simulator goes) and on the Python mock (virtual
time). The host receives the same lines, byte for byte (tags, formats, values, error codes,
sequence numbers, CRCs), each starting within 0.25 ms of simulated time (1.5 ms for ``E,4``, which
the sketch times with ``millis()``). Wall-clock timing is measured in ``benchmarks/bench_firmware.py``.
"""

from __future__ import annotations

import collections
from concurrent.futures import ThreadPoolExecutor

import pytest

from tactile_rig.devices import scale as sp
from tactile_rig.drivers.scale import parse_line
from tactile_rig.mocks.scale_firmware import BoardConfig, Script, compare, reference_session, run_script
from tests._firmware import firmware_build

G = sp.STANDARD_GRAVITY_MPS2
pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def firmware():
    """The compiled sketch and board (skip, or fail under TACTILE_RIG_REQUIRE_FIRMWARE=1, without them)."""
    return firmware_build()


def _quiet(rate: int = 80, **kw) -> BoardConfig:
    return BoardConfig(rate_sps=rate, noise_counts=0.0, drift_counts=0.0, spike_prob=0.0, **kw)


def _kinds(result) -> list[str]:
    return [parse_line(line.data.rstrip(b"\r\n"), 0.0).kind for line in result.lines]


@pytest.mark.parametrize("rate", [80, 10])
def test_the_reference_session_is_the_same_line_for_line(firmware, rate: int) -> None:
    cfg = _quiet(rate, boot_junk=2)
    c = compare(reference_session(cfg), cfg)
    assert c.differences() == []
    parsed = [parse_line(line.data.rstrip(b"\r\n"), 0.0) for line in c.firmware.lines]
    kinds = [p.kind for p in parsed]
    # What the session exercised, seen on the board's side.
    assert kinds.count("banner") == 3 and kinds.count("tare") == 1 and kinds.count("cal") == 1
    assert kinds.count("id") == 1 and [p.code for p in parsed if p.kind == "error"] == [1, 2]
    cal = next(p for p in parsed if p.kind == "cal")
    assert cal.value == pytest.approx(696.0, abs=0.01)  # the known 200 g gives the bridge's counts per gram
    # The glitch bytes of each reset, on both sides.
    junk = [sum(line.data[0] >= 0x80 for line in r.lines) for r in (c.firmware, c.mock)]
    assert junk == [3, 3]
    # The sketch read every conversion and kept the HX711's timing rules.
    hx = c.firmware.stats["hx711"]
    assert hx["missed"] == 0 and set(hx["violations"].values()) == {0}


def test_receive_ring_command_lines_and_calibration_refusals_agree(firmware) -> None:
    cfg = _quiet(boot_junk=0)
    boot = cfg.bootloader_s
    s = Script().at(0.0, "open")
    s.at(0.5, "send", b"?\n" * 40)  # the bootloader's: lost
    s.at(boot + 0.05, "send", b"?\n" * 40)  # setup: 63 bytes wait for the banner
    t = boot + 0.8
    for data in (b"x" * 40 + b"\n", b"t\x00\n", b"\r\n\n", b"t\n", b"t\n", b"c,100.0000\n", b"c,1e2\n",
                 b"c,+5\n", b"c,1000001\n", b"c,0\n", b"c,100\n"):
        s.at(t, "send", data)
        t += 0.03
    s.at(t + 0.3, "force_n", -0.05 * G).at(t + 0.6, "send", b"c,50\n")  # a reversed cell: negative factor
    s.at(t + 1.0, "send", b"c,0.001\n")  # factor out of range: E,5
    s.at(t + 1.3, "force_n", 200.0)  # far past the 24-bit range
    s.end_s = t + 1.8
    c = compare(s, cfg)
    assert c.differences() == []
    codes = [parse_line(line.data.rstrip(), 0.0).code for line in c.firmware.lines if line.data.startswith(b"E,")]
    # The 63rd byte ("?") waited in the line buffer and joined the 40 x's: an overlong line, E,1.
    assert codes == [1, 1, 2, 2, 2, 2, 2, 3, 5]
    assert _kinds(c.firmware).count("id") == 31 and any(b",8388607*" in line.data for line in c.firmware.lines)


def test_an_unplugged_hx711_agrees_at_start_up_and_mid_run(firmware) -> None:
    cfg = _quiet(boot_junk=0)
    # Times off the conversion grid: an event at the very instant of a conversion may go either way.
    s = Script().at(0.0, "hx711", "disconnect").at(0.05, "open").at(3.9013, "hx711", "connect")
    s.at(5.0037, "hx711", "disconnect").at(7.6021, "hx711", "connect")
    s.end_s = 8.0
    c = compare(s, cfg)
    assert c.differences() == []
    kinds = _kinds(c.firmware)
    assert kinds[:2] == ["error", "error"] and kinds.count("error") == 4 and kinds.count("banner") == 1


def test_with_noise_drift_and_glitches_the_lines_agree_in_kind_number_and_framing(firmware) -> None:
    # Different random numbers on each side: only the values differ.
    cfg = BoardConfig(rate_sps=80, boot_junk=0, spike_prob=0.01, seed=3)
    s = Script().at(0.0, "open").at(2.5, "send", b"t\n").at(3.0, "force_n", 1.0)
    s.end_s = 4.0
    c = compare(s, cfg)
    fw = [parse_line(line.data.rstrip(b"\r\n"), 0.0) for line in c.firmware.lines]
    mk = [parse_line(line.data.rstrip(b"\r\n"), 0.0) for line in c.mock.lines]
    assert [p.kind for p in fw] == [p.kind for p in mk] and "corrupt" not in {p.kind for p in fw}
    assert [p.reading.seq for p in fw if p.reading] == [p.reading.seq for p in mk if p.reading]
    last_fw = [p.reading.grams for p in fw if p.reading][-20:]
    last_mk = [p.reading.grams for p in mk if p.reading][-20:]
    assert sum(last_fw) / 20 == pytest.approx(sum(last_mk) / 20, abs=2.0)  # ~102 g either way


def test_a_command_flood_overflows_the_ring_alike(firmware) -> None:
    # Which byte a full ring drops depends on microseconds; the answers agree in kind and number.
    cfg = _quiet(boot_junk=0)
    s = Script().at(0.0, "open").at(2.0, "send", b"?\n" * 100).at(2.5, "send", b"t\n")
    s.end_s = 3.0
    c = compare(s, cfg)
    answers = [collections.Counter(k for k in _kinds(r) if k != "sample") for r in (c.firmware, c.mock)]
    assert answers[0] == answers[1] and 31 < answers[0]["id"] < 100
    seqs = [[p.reading.seq for p in (parse_line(line.data.rstrip(), 0.0) for line in r.lines) if p.reading]
            for r in (c.firmware, c.mock)]
    assert seqs[0] == seqs[1]  # conversions the busy sketch skipped are skipped alike


def test_a_reset_at_any_phase_of_a_conversion_is_charged_to_the_reset_not_the_sketch(firmware) -> None:
    # A reset while the sketch shifts a conversion out leaves the HX711 mid-read with PD_SCK floating
    # low: every conversion until the restarted sketch powers it down is lost. The board counts those
    # apart; the sketch itself misses none and keeps every timing rule at every phase.
    cfg = _quiet(boot_junk=0)
    offsets_s = [2.0 + i * 0.0005 for i in range(26)]  # 13 ms: one 12.5 ms period and the reads in it

    def one(reset_s: float):
        s = Script().at(0.0, "open").at(reset_s, "reset")
        s.end_s = reset_s + 2.3
        return run_script(s, cfg)

    with ThreadPoolExecutor(max_workers=2) as pool:
        results = list(pool.map(one, offsets_s))
    for reset_s, r in zip(offsets_s, results):
        hx = r.stats["hx711"]
        assert hx["missed"] == 0 and set(hx["violations"].values()) == {0}, (reset_s, hx)
        assert hx["missed_after_reset"] > 0  # the bootloader's 1.5 s and the settling: nobody read those
        after = [p for p in (parse_line(line.data.rstrip(b"\r\n"), 0.0) for line in r.lines
                             if line.t_first_s > reset_s) if p.reading]
        assert [p.reading.seq for p in after] == list(range(len(after))) and len(after) > 10
    assert sum(r.stats["hx711"]["reads_cut_by_reset"] for r in results) >= 1  # the phase that cuts a read was hit
