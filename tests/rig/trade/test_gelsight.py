"""Trade topics ``gelsight`` and ``registration``: registered, settings well formed, scoring honest.

The full measurements take minutes (``tactile-rig trade gelsight|registration --quick``); these tests
check the pieces they are built from.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from tactile_rig.perception.gelsight import IntegrationParams, RegistrationParams
from tactile_rig.perception.gelsight.registration import RegistrationResult
from tactile_rig.rig import trade
from tactile_rig.rig.trade import gelsight as topic_gelsight
from tactile_rig.rig.trade import registration as topic_registration
from tactile_rig.rig.trade.registration_data import Score


def test_topics_are_registered() -> None:
    assert trade.topic_module("gelsight") is topic_gelsight
    assert trade.topic_module("registration") is topic_registration
    for mod in (topic_gelsight, topic_registration):
        assert mod.TOPIC in trade.TOPICS and mod.SUMMARY


def test_gelsight_settings_have_one_default_and_cover_every_knob() -> None:
    rows = topic_gelsight.settings()
    assert rows.count(topic_gelsight.DEFAULT) == 1 and len(set(rows)) == len(rows)
    assert {s.model for s in rows} == {"mlp", "poly", "lut"}
    assert {s.solver for s in rows} == {"dct", "dst", "fc"}
    assert {s.downsample for s in rows} >= {1, 2} and {s.crop_px for s in rows} >= {0, 3}
    assert {s.lookup for s in rows} == {"full", "reduced"}
    assert {s.table for s in rows} >= {16, 32, 48, None}


def test_registration_settings_are_valid_params_with_one_default() -> None:
    rows = topic_registration.settings()
    assert sum(not r for r in rows) == 1
    for over in rows:
        over = dict(over)
        IntegrationParams(downsample=over.pop("heights_downsample", None), lookup=over.pop("heights_lookup", "full"))
        RegistrationParams(**over)  # every override names a real knob with a valid value


def _result(rot_deg: float, t_px: tuple[float, float]) -> RegistrationResult:
    th = math.radians(rot_deg)
    m = np.array([[math.cos(th), -math.sin(th), t_px[0]], [math.sin(th), math.cos(th), t_px[1]]])
    return RegistrationResult(True, m, rot_deg, np.zeros(2), 1.0, 10, "orb", None, m)


def test_score_counts_right_wrong_and_refused() -> None:
    shape, mm = (240, 320), 0.0634
    truth = _result(10.0, (5.0, -3.0)).matrix_px
    sc = Score()
    sc.add(_result(10.2, (5.5, -3.0)), truth, shape, mm)  # 0.2 deg, ~0.03 mm: right
    sc.add(_result(12.0, (5.0, -3.0)), truth, shape, mm)  # 2 deg off: wrong
    sc.add(_result(10.0, (7.0, -3.0)), truth, shape, mm)  # 2 px = 0.127 mm off: wrong
    sc.add(RegistrationResult(False, None, float("nan"), np.full(2, np.nan), 0.0, 0, "orb", "no_contact"),
           truth, shape, mm)
    assert (sc.right, sc.wrong, sc.refused, sc.cases) == (1, 2, 1, 4)
    assert sc.reasons == {"no_contact": 1}
    assert sc.rot_mae_deg == pytest.approx(0.2, abs=1e-9)
    assert 0.02 < sc.trans_mae_mm < 0.1


def test_interleaved_timing_returns_one_figure_per_function() -> None:
    calls = []
    per = topic_gelsight.interleaved_best_s([lambda: calls.append("a"), lambda: calls.append("b")], [2, 3], rounds=2)
    assert len(per) == 2 and all(p >= 0 for p in per)
    # Warm-up once each, then the rounds interleave the functions, each batch after one untimed call;
    # each round starts one function further on, so no function always follows the same one.
    assert calls[:2] == ["a", "b"] and calls[2:5] == ["a", "a", "a"] and calls[5:9] == ["b"] * 4
    assert calls[9:13] == ["b"] * 4 and calls[13:16] == ["a"] * 3
    assert len(calls) == 2 + 2 * (3 + 4)
