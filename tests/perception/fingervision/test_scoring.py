"""Scoring of marker tracking: one-to-one matching within a radius, don't-care markers, id switches."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from tactile_rig.perception.fingervision.scoring import match_frame, score_sequence

TRUE = np.array([[10.0, 10.0], [50.0, 10.0], [10.0, 50.0]])


def test_hits_misses_and_false_positives_are_counted_once() -> None:
    pred = np.array([[10.5, 10.0], [10.8, 10.2], [200.0, 200.0]])  # two on marker 0, one far away
    s = match_frame(pred, TRUE, 3.0)
    assert (s.tp, s.fp, s.fn) == (1, 2, 2)
    assert s.matches == {0: 0}, "the closer prediction takes the marker"
    assert s.errors_px == [pytest.approx(0.5)]
    assert s.precision == pytest.approx(1 / 3) and s.recall == pytest.approx(1 / 3)


def test_match_radius_is_per_marker_and_inclusive() -> None:
    pred = TRUE + [4.0, 0.0]
    assert match_frame(pred, TRUE, np.array([4.0, 3.9, 5.0])).tp == 2


def test_unsure_markers_and_dont_care_points_count_neither_way() -> None:
    pred = np.array([[10.0, 10.0], [50.0, 10.0], [300.0, 300.0]])
    s = match_frame(pred, TRUE, 3.0, unsure=np.array([False, True, False]), dont_care_px=np.array([[301.0, 301.0]]))
    assert (s.tp, s.fp, s.fn) == (1, 0, 1)


def test_empty_inputs_and_nan_predictions() -> None:
    assert (match_frame(np.zeros((0, 2)), TRUE).fn, match_frame(np.zeros((0, 2)), np.zeros((0, 2))).precision) == (3, 1.0)
    s = match_frame(np.array([[np.nan, 1.0], [10.0, 10.0]]), TRUE)
    assert (s.tp, s.fp) == (1, 1)
    with pytest.raises(ValueError, match="radius_px"):
        match_frame(TRUE, TRUE, -1.0)


def test_id_switches_counted_when_a_marker_changes_its_predicted_id() -> None:
    ids = np.array([0, 1, 2])
    frames = [
        (np.array([7, 8, 9]), TRUE, ids, TRUE),
        (np.array([7, 8]), TRUE[:2], ids, TRUE),  # marker 2 missed: not a switch
        (np.array([7, 8, 9]), TRUE, ids, TRUE),  # marker 2 back with its old id
        (np.array([8, 7, 9]), TRUE, ids, TRUE),  # markers 0 and 1 swap ids: two switches
    ]
    s = score_sequence(frames, 3.0)
    assert s.id_switches == 2 and s.fn == 1 and s.fp == 0
    with pytest.raises(ValueError, match="repeats"):
        score_sequence([(np.array([1, 1]), TRUE[:2], ids, TRUE)])


@given(hnp.arrays(np.float64, st.tuples(st.integers(0, 12), st.just(2)), elements=st.floats(0, 300)),
       st.floats(0.5, 10))
def test_truth_scores_perfectly_and_counts_add_up(true: np.ndarray, radius: float) -> None:
    s = match_frame(true, true, radius)
    assert s.tp == len(true) or len({tuple(p) for p in true}) < len(true)
    assert s.tp + s.fn == len(true) and s.tp + s.fp == len(true)
    seq = score_sequence([(np.arange(len(true)), true, np.arange(len(true)), true)] * 3, radius)
    assert seq.id_switches == 0 or len({tuple(p) for p in true}) < len(true)
