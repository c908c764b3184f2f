"""Contract of the GRBL jig driver: identity, settings, a move that lands, limits, refusals, reopen.

Runs in process, over a pty against the mock in another process, and on a real jig (--hw-bench:
it homes the jig and moves 1 mm and 5° from the work origin and back).
"""

from __future__ import annotations

import pytest

from tactile_rig.core.errors import GrblError, LimitError, NotConnected
from tactile_rig.drivers.base import Lifecycle
from tactile_rig.drivers.grbl import Jig

pytestmark = pytest.mark.pty


def _jig(ep) -> Jig:
    return Jig(ep.port, baudrate=ep.baud, x_range_mm=(-5.0, 5.0), y_range_mm=(-5.0, 5.0),
               theta_range_deg=(-180.0, 180.0))


def test_identity_is_grbl_1_1_with_its_settings(jig_endpoint) -> None:
    with _jig(jig_endpoint) as jig:
        assert jig.banner is not None and jig.banner.startswith("Grbl 1.1")
        settings = jig.read_settings()
        for n in (100, 101, 110, 111, 120, 121, 130, 131):
            assert n in settings and settings[n] > 0
        assert any(line.startswith("[VER:1.1") for line in jig.build_info())


def test_a_move_lands_where_it_was_sent(jig_endpoint) -> None:
    with _jig(jig_endpoint) as jig:
        jig.activate()
        assert jig.lifecycle is Lifecycle.ACTIVE
        jig.move_to(0.0, 0.0, 0.0, wait=True)  # the work origin (a homed jig ends at its switches)
        jig.move_to(1.0, 0.0, 5.0, wait=True)
        there = jig.pose()
        assert (there.x_mm, there.y_mm) == pytest.approx((1.0, 0.0), abs=0.01)
        assert there.theta_deg == pytest.approx(5.0, abs=0.05)
        jig.move_to(0.0, 0.0, 0.0, wait=True)


def test_a_move_past_the_configured_travel_is_refused_before_motion(jig_endpoint) -> None:
    with _jig(jig_endpoint) as jig:
        jig.activate()
        before = jig.pose()
        with pytest.raises(LimitError, match=r"x_mm=50.0 mm is outside the jig's travel \[-5.0, 5.0\]"):
            jig.move_to(50.0, 0.0, 0.0)
        assert jig.pose() == before


def test_a_line_grbl_refuses_is_a_grbl_error_naming_it(jig_endpoint) -> None:
    with _jig(jig_endpoint) as jig:
        jig.activate()  # unlocked: in Alarm GRBL answers every G-code line with error:9
        with pytest.raises(GrblError) as info:
            jig.command("G5")  # not a GRBL command
        assert info.value.code == 20 and "'G5'" in str(info.value)
        jig.status()  # still talking


def test_reopening_gets_a_fresh_banner(jig_endpoint) -> None:
    with _jig(jig_endpoint) as jig:
        banner = jig.banner
    with pytest.raises(NotConnected):
        jig.status()
    with _jig(jig_endpoint) as jig:
        assert jig.banner == banner
