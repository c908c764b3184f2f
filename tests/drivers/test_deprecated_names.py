"""The drivers' old public names still work for one release, each with a DeprecationWarning naming the new one."""

from __future__ import annotations

import importlib
import sys

import pytest

from tactile_rig.core.clock import VirtualClock
from tactile_rig.core.geometry import Pose
from tactile_rig.core.types import GripperOutcome
from tactile_rig.drivers import grbl
from tactile_rig.drivers.dynamixel import DynamixelBus, DynamixelGripper
from tactile_rig.drivers.grbl import Jig
from tactile_rig.drivers.reconnect import Reconnect
from tactile_rig.drivers.scale import LineKind, ScaleInfo, grams_mg, mg_from_raw, parse_line
from tactile_rig.mocks.dynamixel import make_bus
from tactile_rig.mocks.grbl import GrblMock
from tactile_rig.sim.world.stage import Stage
from tactile_rig.testing import serve_in_process


@pytest.mark.parametrize("old,new,name", [
    ("tactile_rig.drivers.jig", "tactile_rig.drivers.grbl", "Jig"),
    ("tactile_rig.drivers.jig_limits", "tactile_rig.drivers.grbl.limits", "read_window"),
])
def test_the_old_jig_modules_import_with_a_warning_naming_the_new_path(monkeypatch, old: str, new: str,
                                                                      name: str) -> None:
    monkeypatch.delitem(sys.modules, old, raising=False)
    with pytest.warns(DeprecationWarning, match=rf"{old} moved to {new}"):
        module = importlib.import_module(old)
    assert getattr(module, name) is getattr(importlib.import_module(new), name)


def test_the_jigs_counters_as_attributes_warn_and_read_stats() -> None:
    clock = VirtualClock()
    with serve_in_process(GrblMock(clock=clock, stage=Stage(), homing=False), clock) as url, Jig(url) as jig:
        jig.stats.replies_lost, jig.stats.resets = 2, 1
        for old in ("resets", "lines_lost", "replies_lost", "corrupt_reports", "disconnects", "reconnects"):
            with pytest.warns(DeprecationWarning, match=rf"\.{old} is deprecated: use \.stats\.{old}"):
                assert getattr(jig, old) == getattr(jig.stats, old)
        with pytest.warns(DeprecationWarning, match=r"move_toward\(speed_mps=\.\.\.\) is deprecated: use path_speed_mps="):
            jig.move_toward(Pose(x_mm=1.0, y_mm=0.0, theta_deg=0.0), speed_mps=0.002)
        assert jig.status().state == "Jog"


def test_the_bus_reconnect_names_warn_and_mean_reconnect_policy() -> None:
    clock = VirtualClock()
    dev = make_bus(protocol=2, ids=[1], timing=True, return_delay_us=0)
    with serve_in_process(dev, clock) as url:
        policy = Reconnect(clock, initial_s=0.3)
        with pytest.warns(DeprecationWarning, match=r"reconnect=\.\.\.\) is deprecated: use reconnect_policy="):
            bus = DynamixelBus(url, reconnect=policy)
        with bus:
            assert bus.reconnect_policy is policy
            with pytest.warns(DeprecationWarning, match=r"\.reconnect is deprecated: use \.reconnect_policy"):
                assert bus.reconnect is policy
            with pytest.raises(TypeError, match="both reconnect= and reconnect_policy="):
                DynamixelBus(url, reconnect=policy, reconnect_policy=policy)


def test_the_grippers_old_keywords_and_the_normalized_flag_warn_and_still_move() -> None:
    clock = VirtualClock()
    dev = make_bus(protocol=2, ids=[1], timing=True, return_delay_us=0)
    with serve_in_process(dev, clock) as url, DynamixelGripper(url) as g:
        g.activate()
        with pytest.warns(DeprecationWarning, match=r"gripper_go\(position=\.\.\.\) is deprecated: use opening_m="):
            assert g.gripper_go(position=0.05, effort_frac=0.3) == GripperOutcome.REACHED
        with pytest.warns(DeprecationWarning, match=r"gripper_go\(effort=\.\.\.\) is deprecated: use effort_frac="):
            g.gripper_go(0.08, effort=0.3)
        assert g.state().opening_m == pytest.approx(0.08, abs=0.002)
        with pytest.warns(DeprecationWarning, match=r"normalized=True\) is deprecated: use gripper_go_frac"):
            gn = DynamixelGripper(g.bus, normalized=True)
        gn.activate()
        assert gn.gripper_go(0.5, 0.3) == GripperOutcome.REACHED  # 0-1 under the old flag
        assert g.state().opening_m == pytest.approx(0.05, abs=0.002)
        assert g.gripper_go_frac(0.25, 0.3) == GripperOutcome.REACHED
        assert g.state().opening_frac == pytest.approx(0.25, abs=0.02)


def test_the_scales_old_names_warn_and_give_the_same_values() -> None:
    info = ScaleInfo("hx711-scale", "1.1.0", 80, 696.5)
    with pytest.warns(DeprecationWarning, match=r"ScaleInfo\.cal_factor is deprecated: use \.cal_factor_counts_per_g"):
        assert info.cal_factor == 696.5
    with pytest.warns(DeprecationWarning, match=r"grams_mg\(\) is deprecated: use mg_from_raw\(\)"):
        assert grams_mg(12345, 345, 696_500) == mg_from_raw(12345, 345, 696_500) == 17229


def test_a_line_kind_is_an_enum_that_still_equals_and_hashes_as_its_old_string() -> None:
    p = parse_line(b"Load_cell output val: 12.50", 0.0)
    assert p is not None and p.kind is LineKind.STOCK_SAMPLE
    assert p.kind == "stock_sample" and "stock_sample" in {p.kind} and p.kind in {"stock_sample"}
    assert str(p.kind) == f"{p.kind}" == "stock_sample"
    assert {k.value for k in LineKind} == {"sample", "banner", "id", "tare", "cal", "error", "stock_sample",
                                           "stock_start", "stock_ready", "stock_tare", "corrupt", "invalid", "other"}


def test_the_grbl_package_exports_what_the_old_module_did() -> None:
    for name in ("Jig", "GrblStatus", "StreamResult", "parse_status", "clean_gcode_line", "MM_PER_INCH",
                 "ENVELOPE_TOL", "FEED_OVERRIDE_MAX", "FirmwareWindow", "read_window"):
        assert hasattr(grbl, name), name
