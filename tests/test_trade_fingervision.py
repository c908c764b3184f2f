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
