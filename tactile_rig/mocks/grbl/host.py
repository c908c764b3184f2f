"""What the GRBL mock's mixins (``MotionControl``, ``Stepper``) use of the firmware class that composes them.

Declarations for the type checker only: at run time :class:`GrblHost` is an empty base, so it can shadow
nothing in ``GrblMock``'s method resolution order.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    import tactile_rig.mocks.grbl.gcode as gcode
    import tactile_rig.mocks.grbl.homing as homing
    import tactile_rig.mocks.grbl.report as report
    from tactile_rig.mocks.grbl.planner import Limits, Planner, Profile


class GrblHost:
    """State and services of ``GrblMock`` that its mixins read and call (declared, not defined)."""

    if TYPE_CHECKING:
        n_axes: int
        axes_word: str
        theta_index: int
        settings: dict[int, float]
        startup_lines: list[str]
        coords: list[np.ndarray]
        origin: np.ndarray
        phys_lo: np.ndarray
        phys_hi: np.ndarray
        pos: np.ndarray
        state: str
        gc: gcode.ParserState
        planner: Planner
        counters: report.ReportCounters
        feed_ovr: int
        rapid_ovr: int
        spindle_ovr: int
        probe_pos: np.ndarray
        probe_ok: bool
        _t_now: float
        _busy_until: float
        _active: Profile | None
        _event_t: float | None
        _trip: tuple[str, int] | None
        _hold: bool
        _hold_done: bool
        _cancel: str | None
        _probe_active: tuple[bool, bool] | None
        _home_leg: homing.HomingLeg | None
        _critical: bool
        _fail_next_homing: bool

        def phys(self, pos: np.ndarray | None = None) -> np.ndarray: ...
        def _travel(self) -> np.ndarray: ...
        def _limits(self) -> Limits: ...
        def _steps(self) -> np.ndarray: ...
        def _quantize(self, p: np.ndarray) -> np.ndarray: ...
        def _pressed(self, pos: np.ndarray | None = None) -> list[int]: ...
        def _probe_closed(self, pos: np.ndarray | None = None, *, away: bool = False) -> bool: ...
        def _write_stage(self, t_s: float) -> None: ...
        def _say(self, text: str, t_s: float, delay_s: float = ...) -> None: ...
        def _maybe_report(self, t_s: float) -> None: ...
        def _auto_cycle_start(self, t_s: float) -> None: ...
        def _halt(self, t_s: float) -> None: ...
        def _alarm(self, code: int, t_s: float, *, critical: bool) -> None: ...
        def _hard_limit(self, t_s: float) -> None: ...
        def _abort(self, t_s: float, alarm: int | None) -> None: ...
        # the Stepper's, called from MotionControl
        def _speed_now(self, t_s: float) -> float: ...
        def _sync_active(self, t_s: float) -> None: ...
        def _rebuild_active(self, t_s: float) -> None: ...
        def _start_block(self, t_s: float, *, v0: float | None = None, from_pos: np.ndarray | None = None) -> None: ...
        def _feed_hold(self, t_s: float) -> None: ...
