"""Safe motion: the bench's jig limits are checked before any motion, and the gripper reports
``reached`` only once its fingers have settled."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tactile_rig.core.types import GripperOutcome
from tactile_rig.drivers.dynamixel import DynamixelGripper
from tactile_rig.drivers.dynamixel.gripper import SETTLED_SPEED_MPS


@settings(max_examples=25, deadline=None)
@given(st.lists(st.floats(0.0, 0.1), min_size=1, max_size=4), st.floats(0.2, 1.0), st.sampled_from([1, 2]))
def test_reached_means_at_the_goal_and_settled(goals, effort, protocol):
    with DynamixelGripper(f"rigsim://dynamixel?ids=1&protocol={protocol}", protocol=protocol) as g:
        g.activate(effort)
        for goal in goals:
            out = g.gripper_go(goal, effort)
            st_ = g.state()
            assert out == GripperOutcome.REACHED
            assert abs(st_.velocity_mps) <= SETTLED_SPEED_MPS, (goal, st_)
            assert abs(st_.opening_m - goal) <= g.position_tolerance_m


def test_a_position_check_alone_would_report_a_moving_finger():
    """The settle threshold is what makes the difference (so the test above can fail)."""
    with DynamixelGripper("rigsim://dynamixel?ids=1", settled_speed_mps=10.0) as g:
        g.activate(0.5)
        assert g.gripper_go(0.09, 0.5) == GripperOutcome.REACHED
        assert abs(g.state().velocity_mps) > 0.1  # still at full speed: 0.21 m/s


def test_the_docs_example_object_is_not_squashed():
    with DynamixelGripper("rigsim://dynamixel?object_width_mm=40", dxl_id=1, protocol=2) as g:
        g.activate(effort=0.3)
        assert g.gripper_go(0.02, 0.4) == GripperOutcome.STALLED
        assert 0.038 < g.state().opening_m < 0.040  # ~100 N of grip on a rigid part: about 1 mm


# -- jig: the bench's limits and the firmware's window, before any motion ---------------------------
from tactile_rig.core.errors import LimitError  # noqa: E402
from tactile_rig.drivers.grbl import Jig, read_window  # noqa: E402
from tactile_rig.rig.bench import JigConfig, load_bench  # noqa: E402


@pytest.mark.parametrize("args, axis, value, limit", [
    (["--x", "50"], "x", "50 mm", "x_limits_mm = [-20, 20] mm"),
    (["--theta", "190"], "theta", "190 deg", "theta_limits_deg = [-180, 180] deg"),
    (["--y", "-20.5", "--x", "0"], "y", "-20.5 mm", "y_limits_mm = [-20, 20] mm"),
])
def test_jig_move_outside_the_bench_limits_is_a_limit_error_before_motion(args, axis, value, limit, capsys):
    from tactile_rig.cli import main

    assert main(["jig", "move", "--mock", *args]) == 2
    err = capsys.readouterr().err
    assert f"{axis} = {value} is outside [jig] {limit}" in err and "nothing was moved" in err
    assert len(err.strip().splitlines()) == 1


def test_jig_move_to_plus_and_minus_180_deg_needs_no_override(capsys, monkeypatch):
    from tactile_rig.cli import main

    monkeypatch.delenv("TACTILE_RIG_JIG__THETA_LIMITS_DEG", raising=False)
    import json

    for theta, x in (("180", "20"), ("-180", "-20")):  # corners of the bench's limits
        assert main(["jig", "move", "--mock", "--home", "--theta", theta, "--x", x, "--json"]) == 0
        st = json.loads(capsys.readouterr().out)
        assert st["state"] == "Idle" and abs(abs(st["theta_deg"]) - 180.0) < 0.01 and abs(abs(st["x_mm"]) - 20) < 0.01


def test_bare_port_uses_the_default_limits(capsys):
    from tactile_rig.cli import main

    assert main(["jig", "move", "--port", "rigsim://jig", "--theta", "190"]) == 2
    assert "the default jig limits" in capsys.readouterr().err
    assert JigConfig(name="jig", port="x").theta_limits_deg == (-180.0, 180.0)
    assert load_bench(text='[jig]\nport = "rigsim://jig"\n').devices["jig"].theta_limits_deg == (-180.0, 180.0)


def test_a_bench_wider_than_the_firmware_is_caught_by_the_firmware_window():
    with Jig("rigsim://jig") as jig:
        jig.home()
        before = jig.pose()
        window = read_window(jig)
        assert window.limits["theta_deg"][1] == pytest.approx(179.997, abs=1e-6)
        with pytest.raises(LimitError, match=r"x_mm = 25 mm is outside the firmware's soft limits \[-19.999, 19.999\]"):
            window.fit(x_mm=25.0)
        assert window.fit(theta_deg=180.0)["theta_deg"] == pytest.approx(179.997)  # within a step: onto the edge
        assert jig.pose() == before and jig.lifecycle.value == "active"


@settings(max_examples=200, deadline=None)
@given(st.floats(allow_nan=True, allow_infinity=True), st.sampled_from(["x_mm", "y_mm", "theta_deg"]))
def test_check_target_refuses_exactly_what_lies_outside(value, axis):
    cfg = JigConfig(name="jig", port="x", x_limits_mm=(-10.0, 15.0), theta_limits_deg=(-180.0, 180.0))
    key = {"x_mm": "x_limits_mm", "y_mm": "y_limits_mm", "theta_deg": "theta_limits_deg"}[axis]
    lo, hi = getattr(cfg, key)
    inside = lo <= value <= hi  # NaN compares False: outside
    if inside:
        cfg.check_target(**{axis: value})
    else:
        with pytest.raises(LimitError, match=key):
            cfg.check_target(**{axis: value})
