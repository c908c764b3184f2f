"""The GRBL mock's motion as GRBL 1.1h does it: arcs, G28/G30, probing, G93, blending, homing time.

Durations here are virtual-clock seconds (deterministic), compared with the firmware's own
algorithms written out independently in the test (never a wall-clock assertion).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from tactile_rig.mocks.grbl import planner
from tactile_rig.sim.world.stage import Stage
from tests._grbl import Host


def _mpos(st: str) -> tuple[float, ...]:
    field = next(p for p in st.strip("<>").split("|") if p.startswith(("MPos:", "WPos:")))
    return tuple(float(v) for v in field.split(":", 1)[1].split(","))


# -- arcs ------------------------------------------------------------------------------------------
def test_an_offset_arc_ends_on_target_through_the_circle() -> None:
    """gcode.c step 3 (offset mode) and motion_control.c mc_arc: the arc is cut into chords whose
    ends lie on the circle; the last one is the programmed target."""
    h = Host(homing=False)
    assert h.line("G1 X-5 F600") == ["ok"]
    h.until_idle()
    # A half circle of radius 2.5 about (-7.5, 0): 39 chords, so the ok comes once the last one is
    # in the planner (mc_arc waits in mc_line for room, as for any line).
    h.send("G2 X-10 Y0 I-2.5 J0\n", 0.0)
    ys, replies = [], []
    for _ in range(400):
        got = h.send("?", 0.02)
        replies += [ln for ln in got if not ln.startswith("<")]
        st = [ln for ln in got if ln.startswith("<")][-1]
        x, y, _z = _mpos(st)
        ys.append(y)
        assert math.hypot(x + 7.5, y) == pytest.approx(2.5, abs=0.01)  # on the circle (chord sag ≤ $12)
        if st.startswith("<Idle"):
            break
    assert replies == ["ok"]
    assert _mpos(h.status()) == pytest.approx((-10.0, 0.0, 0.0), abs=1e-3)
    assert min(ys) < -2.4  # clockwise (seen from +Z) from east of the centre: through y = -2.5


@pytest.mark.parametrize("tol,expected", [(0.002, 39), (0.01, 17), (0.1, 5)])
def test_arc_segment_count_follows_the_arc_tolerance(tol: float, expected: int) -> None:
    """motion_control.c mc_arc: segments = floor(|θ r / 2| / sqrt(tol (2r − tol)))."""
    pts = planner.arc_points(np.zeros(3), np.array([-5.0, 0.0, 0.0]), np.array([-2.5, 0.0, 0.0]), 2.5,
                             (0, 1, 2), True, tol)
    assert len(pts) == expected == max(1, math.floor(abs(0.5 * math.pi * 2.5) / math.sqrt(tol * (5 - tol))))
    # GRBL rotates the radius vector by a 3rd-order sin/cos (exact every N_ARC_CORRECTION=12 chords):
    # the chord ends stay within the tolerance of the circle.
    assert all(abs(math.hypot(p[0] + 2.5, p[1]) - 2.5) <= tol for p in pts)


def test_radius_arcs_and_the_arc_errors() -> None:
    """gcode.c step 3: R mode needs a target other than the start (33) and 2R ≥ chord (34); offset
    mode needs an in-plane offset (35) and equal radii to 0.005 mm or 0.1 % (33)."""
    h = Host(homing=False)
    h.line("G1 F300")
    assert h.line("G2 X0 Y0 R2") == ["error:33"]
    assert h.line("G2 X-10 R2") == ["error:34"]
    assert h.line("G2 X-4 K1") == ["error:35"]
    assert h.line("G2 X-4 I-1") == ["error:33"]
    assert h.line("G2 Z-4 I-1") == ["error:32"]
    h.line("G3 X-4 Y0 R2")
    h.until_idle()
    assert _mpos(h.status()) == pytest.approx((-4.0, 0.0, 0.0), abs=1e-3)


def test_g18_arcs_run_in_the_zx_plane() -> None:
    """gcode.c gc_execute_line step 3 [11]: G18 takes Z and X as the arc axes (axis_0 = Z, axis_1 = X)."""
    h = Host(homing=False)
    h.line("G18 G2 X-2 Z0 I-1 K0 F600")
    assert "ok" in h.until_idle()
    assert _mpos(h.status()) == pytest.approx((-2.0, 0.0, 0.0), abs=0.03)


# -- G28 / G30 -------------------------------------------------------------------------------------
def test_g28_and_g30_store_and_return_through_an_intermediate_point() -> None:
    """gcode.c steps 3 and 4: G28.1/G30.1 store the parser position in EEPROM; G28 X.. goes through the
    given point (rapid), then to the stored one on those axes only; $# lists both."""
    h = Host(homing=False)
    h.line("G0 X-3 Y-4")
    h.until_idle()
    assert h.line("G28.1") == ["ok"]
    h.line("G0 X-8 Y-1")
    h.until_idle()
    assert h.line("G30.1") == ["ok"]
    params = h.line("$#")
    assert "[G28:-3.000,-4.000,0.000]" in params and "[G30:-8.000,-1.000,0.000]" in params
    h.line("G0 X-1 Y-1")
    h.until_idle()
    assert h.line("G28 X-2") == ["ok"]  # through X-2 (Y stays), then X to the stored -3 only
    h.until_idle()
    assert _mpos(h.status()) == pytest.approx((-3.0, -1.0, 0.0), abs=1e-3)
    assert h.line("G30") == ["ok"]
    h.until_idle()
    assert _mpos(h.status()) == pytest.approx((-8.0, -1.0, 0.0), abs=1e-3)
    assert h.line("G28 G0 X1") == ["error:24"]


# -- probing -----------------------------------------------------------------------------------------
def _probe_host() -> Host:
    stage = Stage(probe_boxes_mm=[[-20.0, -6.0, -20.0, 20.0]])  # contact once x <= -6 mm
    return Host(homing=False, stage=stage)


def test_g38_2_stops_on_contact_and_reports_where() -> None:
    """motion_control.c mc_probe_cycle: the stepper records sys_probe_position when the pin closes,
    the motion is cancelled (decelerates), [PRB:...:1] is printed, the parser syncs to the stop."""
    h = _probe_host()
    out = h.line("G38.2 X-10 F100", 10.0)
    assert out == ["[PRB:-6.000,0.000,0.000:1]", "ok"]
    x = _mpos(h.status())[0]
    assert -6.05 < x <= -6.0  # stopped just past the contact (100 mm/min decelerates in 0.014 mm)
    assert "Pn:P" in h.status()
    assert h.line("$#")[-2] == "[PRB:-6.000,0.000,0.000:1]"


def test_g38_2_without_contact_is_alarm_5_and_g38_3_is_not() -> None:
    """mc_probe_cycle: no contact within the move: ALARM:5 for G38.2 (probe position unchanged,
    :0), none for G38.3 (probe position = where it stopped, :0)."""
    h = _probe_host()
    assert h.line("G38.3 X-4 F300", 5.0) == ["[PRB:-4.000,0.000,0.000:0]", "ok"]
    out = h.line("G38.2 X-1 F300", 5.0)
    assert out == ["ALARM:5", "[PRB:-4.000,0.000,0.000:0]", "ok"]
    assert h.status().startswith("<Alarm|") and h.line("G0 X0") == ["error:9"]


def test_probing_from_contact_is_alarm_4_and_away_probes_invert_it() -> None:
    """mc_probe_cycle: a probe already closed (G38.2/3) or open (G38.4/5) before moving is ALARM:4;
    probe_configure_invert_mask makes G38.4 stop when contact is lost."""
    h = _probe_host()
    h.line("G0 X-8")
    h.until_idle()
    assert h.line("G38.2 X-10 F100", 1.0) == ["ALARM:4", "ok"]
    h.line("$X")
    assert h.line("G38.4 X-2 F100", 10.0) == ["[PRB:-6.000,0.000,0.000:1]", "ok"]
    assert h.line("G38.5 X-1 F100", 1.0) == ["ALARM:4", "ok"]


def test_probe_errors_and_check_mode() -> None:
    """gcode.c step 3: G38.x needs axis words (26), a new target (33) and a feed (22); G38.1 is 20;
    in check mode mc_probe_cycle returns at once (parser moves to the target)."""
    h = _probe_host()
    assert h.line("G38.2 X-1") == ["error:22"]
    assert h.line("G38.2 F10") == ["error:26"]
    assert h.line("G38.2 X0 F10") == ["error:33"]
    assert h.line("G38.1 X-1 F10") == ["error:20"]
    h.line("$C")
    assert h.line("G38.2 X-10 F100") == ["ok"]


# -- inverse time --------------------------------------------------------------------------------------
def test_g93_takes_one_over_f_minutes_per_block_and_needs_f_each_time() -> None:
    """gcode.c step 3 [2]: in G93 every G1/G2/G3 needs its own F (22); planner.c programmed_rate =
    F × block length, so a 6 mm line at F10 takes 1/10 min."""
    h = Host(homing=False)
    assert h.line("G93 G1 X-6 F10") == ["ok"]
    t0 = h.t
    h.until_idle(step_s=0.01)
    assert h.t - t0 == pytest.approx(6.0, abs=0.2)  # 1/10 min, accelerations included
    assert h.line("G1 X-1") == ["error:22"]
    assert h.line("$G")[0].startswith("[GC:G1 G54 G17 G21 G90 G93")


# -- planner ---------------------------------------------------------------------------------------------
def _burst(n: int, jd: float) -> list[str]:
    pts = [(-10.0 + 4.0 * math.cos(2 * math.pi * k / n), 4.0 * math.sin(2 * math.pi * k / n)) for k in range(n + 1)]
    return [f"G1 X{x:.3f} Y{y:.3f}" for x, y in pts]


def test_junction_deviation_blends_corners_and_zero_stops_at_each() -> None:
    """planner.c plan_buffer_line / planner_recalculate: a 20-segment polygon runs through its corners
    at the junction speed of $11; with $11=0 every corner is a full stop (virtual time)."""
    times = {}
    for jd in (0.01, 0.0):
        h = Host(homing=False, settings={11: jd})
        h.line("G0 X-6 Y0")
        h.until_idle()
        h.line("G1 F3000")
        t0 = h.t
        h.send("".join(line + "\n" for line in _burst(20, jd)), 0.0)
        h.until_idle(step_s=0.005)
        times[jd] = h.t - t0
    assert times[0.0] > 1.5 * times[0.01]


def test_the_planner_reports_fifteen_free_blocks_and_fills() -> None:
    """planner.c plan_get_block_buffer_available: 16 slots, one always empty: Bf: counts down from 15."""
    h = Host(homing=False, settings={10: 3})
    h.line("G1 F60")
    h.send("".join(f"G1 X{-(i % 2) - 0.5:.3f}\n" for i in range(20)), 0.05)
    st = h.status()
    assert "|Bf:0," in st


# -- homing --------------------------------------------------------------------------------------------
def _trapezoid_s(length: float, v: float, a: float) -> float:
    if length >= v * v / a:
        return length / v + v / a
    return 2 * math.sqrt(length / a)


def test_homing_takes_seek_locate_and_pull_off_time() -> None:
    """limits.c limits_go_home: per cycle a seek at $25, a pull-off, a locate at $24 and a pull-off,
    each followed by $26 ms; Z (θ) first, then X and Y together (virtual time, exact to 1 %)."""
    h = Host(work_origin="zero")
    t0 = h.t
    h.send("$H\n", 0.0)
    while not any(line == "ok" for line in h.read(0.05)):
        assert h.t - t0 < 60
    took = h.t - t0
    s = h.mock.settings
    seek, feed, pull, deb = s[25] / 60, s[24] / 60, s[27], s[26] / 1000

    def cycle(dist: float, a: float, steps: float) -> float:
        pull_steps = round(pull * steps) / steps
        t_seek = dist / seek + seek / (2 * a)
        t_locate = pull_steps / feed + feed / (2 * a)
        return t_seek + 2 * _trapezoid_s(pull_steps, seek, a) + t_locate + 4 * deb

    expected = cycle(180.0 - 0.0, s[122], s[102]) + cycle(20.0, s[120], s[100])
    assert took == pytest.approx(expected, rel=0.01, abs=0.06)


def test_status_during_a_move_follows_the_trapezoid() -> None:
    """stepper.c st_prep_buffer traces the planner's trapezoid: from rest at $120 up to the feed, then
    cruise; report.c report_realtime_status prints sys_position (whole steps) and st_get_realtime_rate."""
    h = Host(homing=False)
    h.send("G1 X-10 F600\n", 0.0)
    start = h.t + len("G1 X-10 F600\n") * 10 / 115200  # the line's last byte reaches GRBL
    for t_after in (0.05, 0.5, 0.9):
        h.read(start + t_after - h.t - 10 / 115200)  # the '?' arrives t_after into the move
        st = h.status(0.01)
        x = -_mpos(st)[0]
        v, a = 10.0, 100.0  # mm/s, mm/s²
        ramp = v / a
        expect = 0.5 * a * t_after ** 2 if t_after < ramp else 0.5 * a * ramp ** 2 + v * (t_after - ramp)
        assert x == pytest.approx(expect, abs=0.02)
        feed = float(st.split("FS:")[1].split(",")[0])
        assert feed == pytest.approx(min(a * t_after, v) * 60.0, abs=15.0)
