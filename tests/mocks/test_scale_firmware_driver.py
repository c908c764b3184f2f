"""The project's scale driver against the real sketch on the simulated board, over a pty, in real time.

What ``tests/drivers/test_scale.py`` checks against the Python mock, checked against the firmware:
the reset on open (bootloader silence, then the banner), every framed line delivered in order with
none lost or corrupted at 10 and 80 samples/s, tare and known-mass calibration giving the expected
grams, the factor surviving the reboot a reopen causes (EEPROM), a reboot mid-session detected,
and faults on the link all accounted for.
"""

from __future__ import annotations

import statistics

import pytest

from tactile_rig.drivers.scale import Scale
from tactile_rig.core.errors import DeviceTimeout
from tactile_rig.mocks.scale_firmware import BoardConfig, SimulatedScaleBoard
from tests._firmware import firmware_build

pytestmark = [pytest.mark.pty, pytest.mark.slow]

# The bridge: 696 counts per gram (the sketch's default factor is right for it), HX711 noise as the
# mock's default for each rate, warm-up drift off so that grams stay put over a short test.


@pytest.fixture(scope="module")
def firmware():
    """The compiled sketch and board (skip, or fail under TACTILE_RIG_REQUIRE_FIRMWARE=1, without them)."""
    return firmware_build()


def _board(rate: int, **kw) -> SimulatedScaleBoard:
    return SimulatedScaleBoard(BoardConfig(rate_sps=rate, drift_counts=0.0, spike_prob=0.0, **kw))


def _settle(scale: Scale, n: int) -> None:
    """Let ``n`` new conversions pass (the HX711's filter takes 4 to follow a new load)."""
    scale.poll()  # readings queued before the load changed
    scale.read_many(n, timeout_s=2.0)


def _mean_grams(scale: Scale, n: int) -> float:
    scale.poll()
    return statistics.fmean(r.grams for r in scale.read_many(n, timeout_s=2.0))


def _check_stream(scale: Scale, n: int, rate: int) -> None:
    got = scale.read_many(n, timeout_s=2.0)
    seqs = [r.seq for r in got]
    assert seqs == list(range(seqs[0], seqs[0] + n))
    assert scale.info.rate_sps == rate and scale.info.version == "1.1.0"
    assert scale.stats.dropped == 0 and scale.stats.bad_checksum == 0 and scale.stats.rejected_lines == 0


def test_at_80_sps_every_line_arrives_tare_and_calibration_hold_and_a_reopen_reboots(firmware) -> None:
    with _board(80, counts_per_g=720.0) as board, Scale(board.port, boot_timeout_s=6.0) as scale:
        assert scale.format == "tactile" and scale.info.cal_factor_counts_per_g == 696.0  # a fresh EEPROM
        _check_stream(scale, 160, 80)
        board.set_mass_g(50.0)  # a tray: tared away
        _settle(scale, 8)
        scale.tare()
        assert abs(_mean_grams(scale, 20)) < 0.3
        board.set_mass_g(250.0)  # + the known 200 g
        _settle(scale, 24)
        assert _mean_grams(scale, 10) == pytest.approx(200 * 720 / 696, abs=1.0)  # the default factor is off
        factor = scale.calibrate(200.0)
        assert factor == pytest.approx(720.0, rel=0.003)
        assert _mean_grams(scale, 20) == pytest.approx(200.0, abs=0.5)
        scale.reconnect()  # the port reopened: DTR resets the Uno, the factor comes back from EEPROM
        assert scale.stats.resets == 1 and scale.events[-1].kind == "reset"
        assert scale.info.cal_factor_counts_per_g == pytest.approx(factor, abs=1e-3)
        after = scale.read(timeout_s=2.0)
        assert after.seq == 0 and after.raw == pytest.approx(84_000 + 250 * 720, abs=60)  # raw is absolute
        assert scale.stats.dropped == 0 and scale.stats.bad_checksum == 0
        hx = board.stats()["hx711"]
    assert hx["missed"] == 0 and set(hx["violations"].values()) == {0}  # the HX711's timing rules kept


def test_at_10_sps_every_line_arrives_and_tare_and_calibration_hold(firmware) -> None:
    with _board(10) as board, Scale(board.port, boot_timeout_s=6.0) as scale:
        _check_stream(scale, 10, 10)
        board.set_mass_g(80.0)
        _settle(scale, 4)  # tare and calibration take the window after the command: settle first
        scale.tare()
        board.set_mass_g(180.0)  # + 100 g
        _settle(scale, 4)
        assert scale.calibrate(100.0) == pytest.approx(696.0, rel=0.003)
        scale.poll()  # readings from before K were smoothed over the load change and use the old factor
        reading = scale.read(timeout_s=2.0)
        assert reading.grams == pytest.approx(100.0, abs=0.5) and reading.newtons == pytest.approx(0.981, abs=0.01)
        assert scale.stats.dropped == 0 and scale.stats.bad_checksum == 0 and scale.stats.resets == 0


def test_a_reboot_mid_session_and_a_lossy_link_are_all_accounted_for(firmware) -> None:
    with _board(80) as board:
        url = f"rigfault://{board.port}#drop=0.002&flip=0.002&seed=4"
        with Scale(url, boot_timeout_s=6.0) as scale:
            got = scale.read_many(240, timeout_s=2.0)
            seqs = [r.seq for r in got]
            assert seqs == sorted(set(seqs))  # in order, never duplicated
            s = scale.stats
            assert s.readings + s.dropped == seqs[-1] - seqs[0] + 1  # every missing sample is counted
            assert s.dropped > 0 and s.bad_checksum > 0
            board.reset()
            with pytest.raises(DeviceTimeout):
                scale.read_many(400, timeout_s=0.5)  # silent while the bootloader runs
            after = scale.read(timeout_s=3.0)
        assert scale.stats.resets == 1 and after.seq < 5
