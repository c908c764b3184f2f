"""Contract of the scale driver: identity, a numbered stream, tare, calibration refusals, reopen.

Runs in process, over a pty against the mock in another process, and on a real scale (--hw-bench:
leave the scale empty; the calibration test only checks refusals, it calibrates nothing).
"""

from __future__ import annotations

import math

import pytest

from tactile_rig.core.errors import CalibrationError, NotConnected
from tactile_rig.devices import scale as sp
from tactile_rig.drivers.scale import Scale

pytestmark = pytest.mark.pty


def _scale(ep) -> Scale:
    return Scale(ep.port, baudrate=ep.baud, boot_timeout_s=5.0)


def test_identity_is_the_projects_sketch(scale_endpoint) -> None:
    with _scale(scale_endpoint) as scale:
        assert scale.format == "tactile"
        info = scale.info or scale.identify(timeout_s=1.0)
        assert info.firmware == sp.FIRMWARE_NAME and info.rate_sps in sp.RATES_SPS
        assert info.cal_factor_counts_per_g > 0


def test_readings_are_numbered_finite_and_arrive_at_the_rate(scale_endpoint) -> None:
    with _scale(scale_endpoint) as scale:
        got = scale.read_many(16, timeout_s=2.0)
        seqs = [r.seq for r in got]
        assert seqs == [(seqs[0] + i) % sp.SEQ_MODULO for i in range(16)]
        assert all(math.isfinite(r.grams) and sp.RAW_MIN <= r.raw <= sp.RAW_MAX for r in got)
        assert scale.stats.bad_checksum == 0 and scale.stats.dropped == 0


def test_tare_zeroes_what_is_on_the_scale(scale_endpoint) -> None:
    with _scale(scale_endpoint) as scale:
        scale.tare()
        after = scale.read_many(8, timeout_s=2.0)
        spread_g = 5.0 / (scale.info.cal_factor_counts_per_g / sp.DEFAULT_CAL_FACTOR) if scale.info else 5.0
        assert abs(sum(r.grams for r in after) / len(after)) < spread_g


def test_a_calibration_with_a_bad_mass_is_refused(scale_endpoint) -> None:
    with _scale(scale_endpoint) as scale:
        with pytest.raises(ValueError, match="known_mass_g"):
            scale.calibrate(-5.0)
        scale.tare()
        with pytest.raises(CalibrationError, match="refused"):
            scale.calibrate(100.0)  # nothing on the scale: the sketch answers 'load too small'
        assert scale.read(timeout_s=1.0)  # still streaming


def test_reopening_reads_the_same_device(scale_endpoint) -> None:
    with _scale(scale_endpoint) as scale:
        first = scale.info.firmware if scale.info else None
    with pytest.raises(NotConnected):
        scale.read(timeout_s=0.1)
    with _scale(scale_endpoint) as scale:
        assert scale.read(timeout_s=1.0)
        assert (scale.info.firmware if scale.info else None) == first
