"""Trade topic ``fingervision``: its settings, its scores, and one small table end to end."""

from __future__ import annotations

import dataclasses

import numpy as np

from tactile_rig.perception.fingervision import FingerVisionParams
from tactile_rig.rig.trade import fingervision as topic
from tactile_rig.rig.trade.table import TradeTable


def test_settings_start_with_the_default_and_each_changes_one_knob() -> None:
    rows = topic.settings()
    assert rows[0][1] == FingerVisionParams()
    labels = [tuple(sorted(label.items())) for label, _ in rows]
    assert len(set(labels)) == len(labels)
    assert all(p != FingerVisionParams() for _, p in rows[1:])


def test_rendered_score_separates_the_old_baseline_from_lattice_ids() -> None:
    new = topic.score_rendered(FingerVisionParams(), [0])
    old = topic.score_rendered(FingerVisionParams(init="frames"), [0])
    assert new.recall >= 0.95 and new.id_switches == 0
    assert old.recall < 0.5, "10 of the 15 frames are baseline frames without ids"


def test_measure_returns_a_table_with_the_default_marked(monkeypatch) -> None:
    d = FingerVisionParams()
    small = [({"setting": "default"}, d),
             ({"kalman": False}, dataclasses.replace(d, tracker=dataclasses.replace(d.tracker, use_kalman=False)))]
    monkeypatch.setattr(topic, "settings", lambda: small)
    monkeypatch.setattr(topic, "labelled_real_frames", lambda: [])
    table = topic.measure(quick=True)
    assert isinstance(table, TradeTable) and len(table.rows) == 2 and table.rows[0].is_default
    assert all(np.isfinite(r.speed) and r.speed > 0 and 0 <= r.error <= 100 for r in table.rows)
    assert "ABSENT" in table.data


def test_the_default_note_names_what_beats_the_default_and_why_it_stays() -> None:
    from tactile_rig.rig.trade.table import TradeRow

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
