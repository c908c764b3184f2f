"""Where the jig can be while it moves, from the lines sent: the check on status reports read in motion.

A digit flipped into a digit on the wire still parses, and GRBL's lines carry no checksum. What the
host knows is the path it commanded: from the last confirmed Idle position, the absolute straight
moves sent since (what ``move_to`` and ``move_toward`` send) span a box, at a feed no faster than
the fastest one asked for (times GRBL's 200 % feed override). A report while moving outside that
box, or faster than that feed, was corrupted on the wire. A rapid, a relative or unknown move, or a
line that changes the work offset makes the box unknown, and then nothing is checked.

:class:`PathEnvelope` also counts the lines that may move the machine and those that may change
the work offset, which the Idle and WCO checks on reports compare against. Pure: no I/O.
"""

from __future__ import annotations

import re

from tactile_rig.devices import grbl as gp
from tactile_rig.drivers.grbl.status import GrblStatus

# Lines that may move the machine (axis words, G28/G30 to a stored position, homing, jogging, sleep)
# and lines that may change the work offset (WCO = coordinate system + G92 + tool length offset).
_MAY_MOVE = re.compile(r"[XYZABC][-+.0-9]|G0*28|G30|^\$H|^\$J|^\$SLP")
_MAY_OFFSET = re.compile(r"G10|G92|G5[4-9]|G43|G49|^\$RST")
# Absolute straight moves (what move_to and move_toward send): their targets bound the path.
_ABS_MOVE = re.compile(r"^(?:\$J=G90|G90G([01]))(?![0-9.])")
_AXIS_WORD = re.compile(r"([XYZA])(-?[0-9]+(?:\.[0-9]*)?)")
_FEED_WORD = re.compile(r"F([0-9]+(?:\.[0-9]*)?)")
ENVELOPE_TOL = 0.03  # mm (deg on θ): a step of the θ axis, plus the printed rounding
FEED_OVERRIDE_MAX = 2.0  # GRBL's feed override tops out at 200 %


class PathEnvelope:
    """The box the machine can be in while it moves (None: unknown) and the fastest feed commanded.

    ``tolerance`` (mm, deg on θ) is how far a report may lie outside the box: at least half a step
    of the coarsest axis (θ on the default jig: 0.028 deg per step). ``motion_mark`` and
    ``offset_mark`` count the lines sent that may move the machine or change its work offset.
    """

    def __init__(self, tolerance: float = ENVELOPE_TOL) -> None:
        self.tolerance = tolerance
        self.box: tuple[list[float], list[float]] | None = None
        #: the fastest feed (mm/min) asked for since the box was set; None: a rapid or unknown, no bound
        self.feed_cap: float | None = None
        self.motion_mark = 0
        self.offset_mark = 0

    def line_sent(self, upper: str) -> None:
        """A line (upper case) is being sent: count it and widen or forget the box."""
        if _MAY_MOVE.search(upper):
            self.motion_mark += 1
            self._extend(upper)
        if _MAY_OFFSET.search(upper):
            self.offset_mark += 1
            self.box = None

    def at_idle(self, st: GrblStatus) -> None:
        """A confirmed Idle report: the box shrinks to its work position."""
        if st.wpos is not None and not st.inches:
            self.box = (list(st.wpos), list(st.wpos))
            self.feed_cap = 0.0
        else:
            self.box = None

    def forget(self) -> None:
        """The position is unknown (GRBL rebooted)."""
        self.box = None

    def violation(self, st: GrblStatus) -> str | None:
        """Why a report read while moving cannot be true (off the commanded path, or too fast), or None."""
        box = self.box
        if box is not None and st.wpos is not None and not st.inches and len(st.wpos) == len(box[0]):
            for i, v in enumerate(st.wpos):
                if not box[0][i] - self.tolerance <= v <= box[1][i] + self.tolerance:
                    return (f"axis {gp.AXIS_LETTERS[i]} at {v:.3f}, outside the path commanded "
                            f"[{box[0][i]:.3f}, {box[1][i]:.3f}]")
        if (self.feed_cap is not None and st.feed_mm_per_min is not None
                and st.feed_mm_per_min > self.feed_cap * FEED_OVERRIDE_MAX + 1.0):
            return (f"feed {st.feed_mm_per_min:g} mm/min, above the {self.feed_cap:g} mm/min commanded "
                    f"(x{FEED_OVERRIDE_MAX:g} override)")
        return None

    def _extend(self, upper: str) -> None:
        """A line that may move was sent: widen the box to its target, or forget the box."""
        m = _ABS_MOVE.match(upper)
        if self.box is None or m is None or "G9" in upper[m.end():]:
            self.box = None
            self.feed_cap = None
            return
        lo, hi = self.box
        for letter, value in _AXIS_WORD.findall(upper[m.end():]):
            i = gp.AXIS_LETTERS.index(letter)
            if i >= len(lo):
                self.box = None
                return
            lo[i], hi[i] = min(lo[i], float(value)), max(hi[i], float(value))
        feed = _FEED_WORD.search(upper)
        if m.group(1) == "0" or feed is None or self.feed_cap is None:
            self.feed_cap = None  # a rapid runs at each axis's maximum rate, which the driver need not know
        else:
            self.feed_cap = max(self.feed_cap, float(feed.group(1)))
