"""``IntegrationParams(lookup="reduced")``: the frame area-reduced before the colour lookup.

Against the full lookup on the real Taxim ball presses: heights within a few um (the table is not
linear in colour, so not equal), the same refusals of whole-frame faults (a clipped pixel in four
must not average away), and nothing new at the extremes.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from tactile_rig.core.errors import GradientOutOfRange, HeightOutOfRange, PerceptionError, SaturatedFrame
from tactile_rig.perception.gelsight import ContactParams, IntegrationParams, Reconstructor
from tests._data import EXTREME_KINDS, extreme_frame, taxim_calibration, taxim_presses


@pytest.fixture(scope="module")
def presses():
    return taxim_presses()


@pytest.fixture(scope="module")
def cals():
    # lut20: bins no shift can make, the checked (unpacked) path
    return {"mlp": taxim_calibration("mlp"), "lut": taxim_calibration("lut", 32), "lut20": taxim_calibration("lut", 20)}


@pytest.mark.parametrize("model", ["mlp", "lut", "lut20"])
@pytest.mark.parametrize("downsample", [2, 3])
def test_reduced_lookup_reads_the_presses_within_microns_of_the_full_one(cals, presses, model, downsample) -> None:
    full = Reconstructor(cals[model], IntegrationParams(downsample=downsample))
    red = Reconstructor(cals[model], IntegrationParams(downsample=downsample, lookup="reduced"))
    # Measured: at 2, at most 0.5-0.8 % of the press depth RMS and 2.6-5.5 % at the worst pixel; at 3
    # (which does not tile 160 columns) up to 1.3 % and 9 %.
    rms_bound, max_bound = (0.01, 0.07) if downsample == 2 else (0.02, 0.11)
    for frame in presses.frames:
        a, b = full.height_mm(frame), red.height_mm(frame)
        assert b.dtype == np.float32 and b.shape == frame.shape[:2] and np.isfinite(b).all()
        peak = float(np.abs(a).max())
        assert peak > 0.05  # a press, not a flat map
        assert np.sqrt(np.mean((a - b) ** 2)) <= rms_bound * peak
        assert np.abs(a - b).max() <= max_bound * peak
        assert not np.array_equal(a, b)


def test_reduced_lookup_is_the_full_one_without_a_downsample(cals, presses) -> None:
    frame = presses.frames[3]
    a = Reconstructor(cals["mlp"], IntegrationParams(downsample=1)).height_mm(frame)
    b = Reconstructor(cals["mlp"], IntegrationParams(downsample=1, lookup="reduced")).height_mm(frame)
    np.testing.assert_array_equal(a, b)


def test_reduced_lookup_keeps_the_whole_frame_refusals(cals, presses) -> None:
    red = Reconstructor(cals["mlp"], IntegrationParams(downsample=2, lookup="reduced"))
    frame = presses.frames[3].copy()
    # A quarter of the pixels clipped (every other one of every other row), beyond the 20 % bound:
    # averaged in 2x2 blocks, none is clipped any more.
    frame[::2, ::2] = 255
    with pytest.raises(SaturatedFrame):
        Reconstructor(cals["mlp"], IntegrationParams(downsample=2)).height_mm(frame)
    with pytest.raises(SaturatedFrame):
        red.height_mm(frame)
    for value in (0, 255):
        with pytest.raises(SaturatedFrame):
            red.height_mm(np.full_like(frame, value))
    with pytest.raises(ValueError, match="frame"):
        red.height_mm(frame[:, :-1])
    with pytest.raises(ValueError, match="lookup"):
        IntegrationParams(lookup="half")


@settings(deadline=None, max_examples=40, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(st.sampled_from(EXTREME_KINDS), st.integers(0, 255), st.integers(0, 2**31 - 1), st.sampled_from([2, 3, 4]),
       st.sampled_from(["mlp", "lut20"]))
def test_reduced_lookup_at_the_extremes_is_bounded_or_refused(cals, presses, kind, value, seed, downsample,
                                                                 model) -> None:
    rng = np.random.default_rng(seed)
    frame = extreme_frame(presses.frames[seed % len(presses.frames)], kind, value, rng)
    contact = ContactParams()
    red = Reconstructor(cals[model], IntegrationParams(downsample=downsample, lookup="reduced"), contact)
    try:
        z = red.height_mm(frame)
    except PerceptionError as exc:  # a typed refusal names its reason, its value and the bound it broke
        assert isinstance(exc, (SaturatedFrame, GradientOutOfRange, HeightOutOfRange))
        assert exc.value is not None and exc.limit is not None and exc.value > exc.limit
        return
    assert np.isfinite(z).all() and z.shape == frame.shape[:2]
    assert float(z.max() - z.min()) <= contact.max_height_range_mm
