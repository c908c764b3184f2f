"""The x-y-θ jig on GRBL 1.1: its axes and travel limits, GRBL's machine commands, and ``Motion``.

θ rides on a configurable GRBL channel (Z on stock GRBL, A on grblHAL; its steps/mm setting holds
steps per degree). :class:`Jig` homes (``$H``), unlocks (``$X``), moves (``move_to``), jogs, reads
and writes settings, enters check mode, and satisfies the controllers'
:class:`~tactile_rig.control.protocols.Motion` protocol (``move_toward``, ``pose``, ``stop``).
Targets are checked against the configured travel before anything is sent; the firmware's own soft
limits apply as well (:mod:`.limits`). GRBL's line protocol, the checks on its replies and the
reconnect after an unplug are :class:`~tactile_rig.drivers.grbl.controller.GrblController`'s.
"""

from __future__ import annotations

import math

from tactile_rig.core.clock import Clock, Deadline
from tactile_rig.core.deprecation import renamed_kwargs
from tactile_rig.core.errors import DeviceTimeout, LimitError, LinkCorrupt, check_range
from tactile_rig.core.geometry import Pose
from tactile_rig.devices import grbl as gp
from tactile_rig.drivers.base import Lifecycle, locked
from tactile_rig.drivers.grbl.controller import GrblController
from tactile_rig.drivers.grbl.status import GrblStatus
from tactile_rig.drivers.reconnect import Reconnect

#: mm/min per m/s: GRBL's feed rates are in mm/min
_MM_PER_MIN_PER_MPS = 60000.0


class Jig(GrblController):
    """The jig's GRBL controller on ``port`` (path or URL), opened here.

    ``theta_axis`` is the GRBL channel θ rides on (``"Z"`` on stock GRBL 1.1, ``"A"`` on grblHAL).
    ``x_range_mm`` / ``y_range_mm`` / ``theta_range_deg`` (optional) are checked before a move is sent.

    Lifecycle (:mod:`tactile_rig.drivers.base`): ``active`` once GRBL is unlocked (after a clean boot,
    :meth:`home`, :meth:`unlock` or :meth:`activate`); ``connected`` while it is locked in its boot
    alarm; an ``ALARM:N`` or an unasked reset puts it in ``fault``, where moves are refused until
    :meth:`activate` (soft reset if needed, then home or unlock) starts again from the measured pose.
    """

    def __init__(
        self,
        port: str,
        *,
        baudrate: int = gp.BAUD,
        theta_axis: str = "Z",
        clock: Clock | None = None,
        boot_timeout_s: float = 3.0,
        x_range_mm: tuple[float, float] | None = None,
        y_range_mm: tuple[float, float] | None = None,
        theta_range_deg: tuple[float, float] | None = None,
        device: str | None = None,
        reconnect_policy: Reconnect | None = None,
    ) -> None:
        theta_axis = theta_axis.upper()
        if theta_axis not in ("Z", "A"):
            raise ValueError(f"theta_axis={theta_axis!r}: expected 'Z' (stock GRBL 1.1) or 'A' (grblHAL)")
        self.theta_axis = theta_axis
        self.ranges = {"x_mm": x_range_mm, "y_mm": y_range_mm, "theta_deg": theta_range_deg}
        super().__init__(port, baudrate=baudrate, clock=clock, boot_timeout_s=boot_timeout_s,
                         device=device or f"jig@{port}", reconnect_policy=reconnect_policy)

    # -- locks and faults ---------------------------------------------------------------------------------
    @locked
    def home(self, timeout_s: float = 60.0) -> None:
        """Run the homing cycle (``$H``); returns when GRBL answers ``ok`` (the cycle is done)."""
        self.command("$H", timeout_s)
        self.alarm_on_boot = False
        self._unlocked()

    @locked
    def unlock(self) -> None:
        """Clear an alarm lock without homing (``$X``): only if you know where the stage is."""
        self.command("$X")
        self.alarm_on_boot = False
        self._unlocked()

    def _unlocked(self) -> None:
        self.lifecycle = Lifecycle.ACTIVE
        self.last_fault = None

    @locked
    def activate(self, *, home: bool = True, timeout_s: float = 60.0) -> None:
        """Make the jig ready to move from wherever it is: a soft reset if a critical alarm needs one,
        then, if GRBL is locked (Alarm), ``$H`` (``home=True``) or ``$X`` (only if you know where the
        stage is). Clears a fault; the next move starts from the measured pose."""
        self.require_open()
        if self.needs_reset:
            self.soft_reset()
        self._alarms.clear()
        self._unexpected_reset = False
        st = self.status()
        if st.state.startswith("Alarm"):
            if home:
                self.home(timeout_s)
            else:
                self.unlock()
        self._unlocked()

    # -- axes and limits ------------------------------------------------------------------------------------
    def _axis_words(self, x_mm: float | None, y_mm: float | None, theta_deg: float | None) -> str:
        words = []
        for letter, name, v in (("X", "x_mm", x_mm), ("Y", "y_mm", y_mm), (self.theta_axis, "theta_deg", theta_deg)):
            if v is None:
                continue
            if not math.isfinite(v):
                raise ValueError(f"{name}={v!r} must be a finite number")
            words.append(f"{letter}{v:.3f}")
        return "".join(words)

    def _check_ranges(self, **pose: float | None) -> None:
        for name, v in pose.items():
            rng = self.ranges.get(name)
            if v is not None and rng is not None and not (rng[0] <= v <= rng[1]):
                unit = "deg" if name == "theta_deg" else "mm"
                raise LimitError(f"{name}={v!r} {unit} is outside the jig's travel [{rng[0]}, {rng[1]}] {unit}",
                                 device=self.device)

    @locked
    def move_to(self, x_mm: float | None = None, y_mm: float | None = None, theta_deg: float | None = None,
                feed_mm_per_min: float | None = None, *, wait: bool = False, timeout_s: float = 60.0) -> None:
        """Go to a work-coordinate pose (None: that axis stays). ``feed_mm_per_min`` None: a rapid (G0),
        each axis at its own maximum rate. With ``wait`` returns when Idle there."""
        self.require_not_faulted("move_to")
        self._check_ranges(x_mm=x_mm, y_mm=y_mm, theta_deg=theta_deg)
        words = self._axis_words(x_mm, y_mm, theta_deg)
        if not words:
            return
        if feed_mm_per_min is None:
            line = f"G90G0{words}"
        else:
            check_range("feed_mm_per_min", feed_mm_per_min, 1e-3, 1e6, "mm/min")
            line = f"G90G1{words}F{feed_mm_per_min:.1f}"
        self.command(line, timeout_s)
        if wait:
            self.wait_idle(timeout_s)

    @locked
    def jog(self, dx_mm: float = 0.0, dy_mm: float = 0.0, dtheta_deg: float = 0.0, *,
            feed_mm_per_min: float, relative: bool = True) -> None:
        """Jog (``$J=``): relative by default; absolute work coordinates with ``relative=False``.
        A jog past the soft limits is refused by GRBL (error:15 → GrblError)."""
        self.require_not_faulted("jog")
        check_range("feed_mm_per_min", feed_mm_per_min, 1e-3, 1e6, "mm/min")
        if not relative:
            self._check_ranges(x_mm=dx_mm, y_mm=dy_mm, theta_deg=dtheta_deg)
            words = self._axis_words(dx_mm, dy_mm, dtheta_deg)
        else:  # a zero step is no motion: leave the word out (an all-zero jog sends nothing)
            words = self._axis_words(*(v if v != 0.0 else None for v in (dx_mm, dy_mm, dtheta_deg)))
            if not words:
                return
        self.command(f"$J={'G91' if relative else 'G90'}{words}F{feed_mm_per_min:.1f}")

    # -- settings and modes ---------------------------------------------------------------------------------
    @locked
    def read_settings(self) -> dict[int, float]:
        """``$$`` → {setting number: value}."""
        out: dict[int, float] = {}
        for line in self.command("$$"):
            if line.startswith("$") and "=" in line:
                key, _, val = line[1:].partition("=")
                try:
                    out[int(key)] = float(val.split(" ")[0])
                except ValueError:
                    continue
        return out

    @locked
    def write_setting(self, number: int, value: float) -> None:
        """``$N=value`` (persists in GRBL's EEPROM); unknown numbers are refused here, bad values by GRBL."""
        if number not in gp.SETTINGS:
            raise ValueError(f"GRBL setting ${number} does not exist; known: {sorted(gp.SETTINGS)}")
        text = str(int(value)) if number in gp.INTEGER_SETTINGS else f"{float(value):.3f}"
        self.command(f"${number}={text}")

    @locked
    def set_check_mode(self, enabled: bool, timeout_s: float = 2.0) -> None:
        """Enter or leave check mode (``$C``: lines are parsed and answered but nothing moves).
        Leaving it soft-resets GRBL, as the firmware does; this waits for that banner."""
        if (self.status().state == "Check") == bool(enabled):
            return
        if not enabled:
            self._expect_banner = True
        self.command("$C", timeout_s)
        self._pump_until(lambda: not self._expect_banner, Deadline(self.clock, timeout_s), lambda: DeviceTimeout(
            f"no banner within {timeout_s:.3g} s of leaving check mode", device=self.device))

    @locked
    def build_info(self) -> list[str]:
        """``$I``: the version and build-info lines."""
        return self.command("$I")

    @locked
    def parser_state(self) -> list[str]:
        """``$G``: the G-code parser's modal state line."""
        return self.command("$G")

    # -- Motion protocol ---------------------------------------------------------------------------------------
    @renamed_kwargs(speed_mps="path_speed_mps")
    @locked
    def move_toward(self, target: Pose, path_speed_mps: float) -> None:
        """Start jogging toward ``target`` (a Pose: x_mm, y_mm, theta_deg); a newer call replaces an
        older one. ``path_speed_mps`` is GRBL's feed along the straight line in (x, y, θ) with a
        degree of θ counted as a millimetre: m/s for a move in x-y, ``1000 × path_speed_mps`` deg/s
        for a pure rotation."""
        self.require_not_faulted("move_toward")
        check_range("path_speed_mps", path_speed_mps, 1e-6, 10.0, "m/s")
        self._check_ranges(x_mm=target.x_mm, y_mm=target.y_mm, theta_deg=target.theta_deg)
        st = self.last_status
        if st is not None and st.state == "Jog":
            self.jog_cancel()
        words = self._axis_words(target.x_mm, target.y_mm, target.theta_deg)
        self.command(f"$J=G90{words}F{path_speed_mps * _MM_PER_MIN_PER_MPS:.1f}")

    @locked
    def pose(self) -> Pose:
        """The work-coordinate pose now (mm, θ in degrees)."""
        return self.pose_from_status(self.status())

    def pose_from_status(self, st: GrblStatus) -> Pose:
        """The work-coordinate pose in a status report (WPos, else MPos); ``LinkCorrupt`` if it has none."""
        pos = st.wpos or st.mpos
        if pos is None:
            raise LinkCorrupt(f"status report has no position: {st.raw!r}", device=self.device)
        idx = gp.AXIS_LETTERS.index(self.theta_axis)
        if idx >= len(pos):
            raise LinkCorrupt(f"status reports {len(pos)} axes; θ is on {self.theta_axis}: {st.raw!r}",
                              device=self.device)
        return Pose(x_mm=pos[0], y_mm=pos[1], z_mm=0.0, theta_deg=pos[idx])

    @locked
    def stop(self) -> None:
        """Stop as fast as GRBL allows: jog cancel when jogging, else feed hold, then flush the plan
        with a soft reset once stopped (position is kept; no alarm)."""
        st = self.status()
        if st.state == "Jog":
            self.jog_cancel()
            return
        if st.state in ("Run", "Hold"):
            self.feed_hold()
            dl = Deadline(self.clock, 5.0)
            while not (st.state == "Hold" and st.substate == 0) and st.state != "Idle" and not dl.expired():
                self.clock.sleep(0.01)
                st = self.status()
            self.soft_reset()
