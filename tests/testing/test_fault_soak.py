"""A short, deterministic subset of the fault soak (in process, virtual time): for every serial
device (Dynamixel P2 and P1, scale, jig), every fault kind ends in values that are true, typed errors
and recoveries, never an untyped exception, a hang or a silently wrong value. The full table is
``benchmarks/bench_faults.py``."""

from __future__ import annotations

import pytest

from tactile_rig.drivers.scale import Scale
from tactile_rig.mocks.faults import KINDS
from tactile_rig.testing.faultsoak import FAULT_QUERIES, format_table, moving_reports, soak_row


@pytest.mark.parametrize("fault", KINDS)
@pytest.mark.parametrize("device", ["scale", "jig", "dynamixel_p2", "dynamixel_p1"])
def test_every_fault_ends_typed_or_true(device: str, fault: str) -> None:
    row = soak_row(device, fault, n=80, seed=3)
    assert row.operations == 80 and row.ok + row.typed_errors + row.untyped == 80
    assert (row.untyped, row.hangs, row.wrong) == (0, 0, 0), format_table([row]) + "\n" + "\n".join(row.examples)
    assert row.ok > 0


def test_the_soak_sees_a_wrong_value_when_a_driver_returns_one(monkeypatch: pytest.MonkeyPatch) -> None:
    # A driver that forgets its zero and trusts the sketch's grams reads ~0 g after a reboot with
    # 150 g on: the soak must count those as silently wrong.
    monkeypatch.setattr(Scale, "_apply_zero", lambda self, r: r)
    monkeypatch.setattr(Scale, "_reset_seen", lambda self, t_s, detail: None)
    row = soak_row("scale", "reboot", n=300, seed=3)
    assert row.injected.get("reboot", 0) >= 1 and row.wrong > 0


def test_every_fault_kind_has_a_query() -> None:
    assert set(FAULT_QUERIES) == set(KINDS)


def test_reports_read_while_the_jig_moves_are_ones_grbl_printed_or_typed_errors() -> None:
    m = moving_reports("garbage", moves=10, seed=1)
    assert m.reports > 50 and m.wrong == 0, m.examples
