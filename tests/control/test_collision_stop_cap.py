"""The collision-stop speed cap: the thesis figure, its exactness, monotonicity and refusals."""

from __future__ import annotations

import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from tactile_rig.core.clock import VirtualClock
from tactile_rig.control.protocols import TouchReading
from tactile_rig.control.safety import (
    check_speed,
    collision_speed_cap_mps,
    measure_sensing,
    worst_case_overtravel_mm,
)
from tactile_rig.core.errors import LimitError
from tactile_rig.sim.fakes.sensors import ModelSensor


def test_the_thesis_cap_is_one_millimetre_per_look_at_16_hz() -> None:
    assert collision_speed_cap_mps(1.0, 16.0) == pytest.approx(0.016)


@given(allowed=st.floats(0.01, 20.0), rate=st.floats(1.0, 2000.0), latency=st.floats(0.0, 0.5),
       stop=st.floats(0.0, 0.2), decel=st.one_of(st.just(math.inf), st.floats(0.05, 50.0)),
       det_frac=st.floats(0.0, 0.9))
def test_at_the_cap_the_worst_case_overtravel_is_exactly_the_allowance(allowed, rate, latency, stop, decel,
                                                                       det_frac) -> None:
    det = det_frac * allowed
    cap = collision_speed_cap_mps(allowed, rate, latency, stop_latency_s=stop, decel_mps2=decel,
                                  detection_travel_mm=det)
    assert cap > 0 and math.isfinite(cap)
    worst = worst_case_overtravel_mm(cap, rate, latency, stop_latency_s=stop, decel_mps2=decel,
                                     detection_travel_mm=det)
    assert worst == pytest.approx(allowed, rel=1e-6)
    # faster sensing, less latency: a higher cap
    assert collision_speed_cap_mps(allowed, rate * 2, latency, stop_latency_s=stop, decel_mps2=decel,
                                   detection_travel_mm=det) > cap
    if latency > 1e-3:
        assert collision_speed_cap_mps(allowed, rate, latency / 2, stop_latency_s=stop, decel_mps2=decel,
                                       detection_travel_mm=det) > cap


def test_no_budget_left_means_a_zero_cap_and_bad_figures_are_refused() -> None:
    assert collision_speed_cap_mps(1.0, 30.0, detection_travel_mm=1.5) == 0.0
    for bad in (dict(sensing_rate_hz=0.0), dict(sensing_rate_hz=math.nan), dict(latency_s=-1.0)):
        kw = {"allowed_overtravel_mm": 1.0, "sensing_rate_hz": 30.0, **bad}
        with pytest.raises(ValueError):
            collision_speed_cap_mps(**kw)
    with pytest.raises(ValueError, match="decel_mps2"):
        collision_speed_cap_mps(1.0, 30.0, decel_mps2=0.0)


@given(frac=st.floats(1.0001, 100.0))
def test_a_speed_above_the_cap_is_a_limit_error_that_names_the_cap(frac) -> None:
    with pytest.raises(LimitError, match="cap of 0.016"):
        check_speed(0.016 * frac, 0.016)
    assert check_speed(0.016, 0.016) == 0.016


@pytest.mark.parametrize("bad", [0.0, -0.01, math.nan, math.inf])
def test_a_speed_that_is_not_positive_and_finite_is_refused(bad) -> None:
    with pytest.raises(LimitError, match="speed_mps"):
        check_speed(bad, 1.0)


@given(rate=st.floats(5.0, 500.0), latency=st.floats(0.0, 0.2))
def test_measured_rate_and_latency_match_the_simulated_sensor(rate, latency) -> None:
    clock = VirtualClock()
    sensor = ModelSensor(clock, lambda t: TouchReading(t), rate_hz=rate, latency_s=latency)
    m = measure_sensing(sensor, clock, n_frames=6)
    assert m.rate_hz == pytest.approx(rate, rel=1e-6)
    assert latency - 1e-9 <= m.latency_s <= latency + 1.0 / rate + 1e-9
