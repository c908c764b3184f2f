"""Trade topic ``fingervision``: its settings, its scores, and a two-row table measured end to end, with
the shared real frames (skipped where absent) and without them."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from tactile_rig.perception.fingervision import FingerVisionParams
from tactile_rig.rig.trade import fingervision as topic
from tactile_rig.rig.trade.table import TradeRow, TradeTable
from tests._data import require_shared


def test_settings_start_with_the_default_and_each_changes_one_knob() -> None:
    rows = topic.settings()
    assert rows[0][1] == FingerVisionParams()
    labels = [tuple(sorted(label.items())) for label, _ in rows]
    assert len(set(labels)) == len(labels)
    assert all(p != FingerVisionParams() for _, p in rows[1:])


def test_rendered_score_separates_frame_baselines_from_lattice_ids() -> None:
    lattice = topic.score_rendered(FingerVisionParams(), [0])
    frames = topic.score_rendered(FingerVisionParams(init="frames"), [0])
    assert lattice.recall >= 0.95 and lattice.id_switches == 0
    assert frames.recall < 0.5, "10 of the 15 frames are baseline frames without ids"


def _two_settings() -> list:
    d = FingerVisionParams()
    return [({"setting": "default"}, d),
            ({"kalman": False}, dataclasses.replace(d, tracker=dataclasses.replace(d.tracker, use_kalman=False)))]


def _check_rows(table: TradeTable, real: list) -> None:
    """The default row's error is the per cent of (fn + fp + id switches) over the true markers of the
    scores it is made of: the real frames' (when present) and the two rendered sequences'."""
    assert isinstance(table, TradeTable) and len(table.rows) == 2 and table.rows[0].is_default
    params = _two_settings()[0][1]
    parts = [topic.score_rendered(params, [0, 1])] + ([topic.score_real(params, real)] if real else [])
    bad = sum(p.fn + p.fp + p.id_switches for p in parts)
    n_true = sum(p.tp + p.fn for p in parts)
    assert table.rows[0].error == pytest.approx(100.0 * bad / n_true)
    for row in table.rows:
        assert np.isfinite(row.speed) and row.speed > 0 and 0 <= row.error <= 100
        assert ("real_recall" in row.extra) == bool(real)


def test_without_the_shared_frames_the_table_is_rendered_only_and_says_so(monkeypatch) -> None:
    monkeypatch.setattr(topic, "settings", _two_settings)
    monkeypatch.setattr(topic, "labelled_real_frames", lambda: [])
    table = topic.measure(quick=True)
    assert table.data.startswith("shared real frames ABSENT: rendered only")
    _check_rows(table, [])


def test_with_the_shared_frames_every_row_is_scored_on_the_real_frames_too(monkeypatch) -> None:
    require_shared(topic.REAL_FOLDER)
    real = topic.labelled_real_frames()
    assert [lab.name for lab, _ in real] == sorted(topic.load_labels())
    monkeypatch.setattr(topic, "settings", _two_settings)
    table = topic.measure(quick=True)
    assert table.data.startswith(f"{len(real)} labelled real frames x 3 orders + ")
    _check_rows(table, real)
    default = table.rows[0].extra
    # every labelled marker of every frame in all three orders, none on print, no id switch
    assert (default["real_precision"], default["real_recall"], default["real_id_switches"]) == (1.0, 1.0, 0)


def test_the_default_note_names_what_beats_the_default_and_why_it_stays() -> None:
    rows = [TradeRow({"setting": "default"}, 100.0, 0.0, True, {"rest_force_px": 0.009}),
            TradeRow({"kalman": False}, 120.0, 0.0, False, {"rest_force_px": 0.018}),
            TradeRow({"refine_frames": 1}, 101.0, 0.0, False, {"rest_force_px": 0.021})]
    t = TradeTable("fingervision", "frames per CPU-s", "error", "test", rows)
    note = topic.explain_default(t)
    assert not t.default_on_front()
    assert "kalman=False" in note and "0.018 against 0.009" in note
    assert "refine_frames=1" not in note.split("off the front because")[1], "a tie within tolerance does not beat it"
    t.rows[1] = TradeRow({"kalman": False}, 102.0, 0.0, False, {"rest_force_px": 0.018})
    assert t.default_on_front() and "off the front" not in topic.explain_default(t)
