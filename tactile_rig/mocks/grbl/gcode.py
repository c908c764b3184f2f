"""GRBL 1.1h's G-code parser as a pure function: a line and the modal state in, a checked block out.

No I/O and no state of its own: :func:`parse_block` takes a line already cleaned by the protocol
loop (upper case, no spaces, no comments), the parser state and the stored coordinate systems, and
returns either GRBL's ``error:N`` code or a :class:`Block` with every value converted to machine
millimetres, exactly as ``gc_execute_line`` steps 1-3 do in GRBL's ``gcode.c`` (word import, modal
groups, the error checks in the firmware's order). Executing the block (planner, syncs, EEPROM) is
the firmware's job; :func:`commit` applies the block's modal changes to the parser state.
The module is a little over 500 lines because it is one job: the error checks must stay in the
firmware's order in one place to be read side by side with ``gcode.c``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any, Sequence

import numpy as np

MM_PER_INCH = 25.4
MAX_LINE_NUMBER = 10_000_000
MAX_TOOL_NUMBER = 255
MAX_INT_DIGITS = 8  # read_float keeps 8 significant digits
N_COORDINATE_SYSTEMS = 6  # G54..G59
G28_INDEX, G30_INDEX = 6, 7  # their slots in the stored coordinate table

# Motion modes (gc_state.modal.motion); probing keeps GRBL's 38.2..38.5 as floats.
SEEK, LINEAR, CW_ARC, CCW_ARC, NONE = 0.0, 1.0, 2.0, 3.0, 80.0
PROBES = (38.2, 38.3, 38.4, 38.5)

# Non-modal commands (group 0), numbered like GRBL: G28.1 is 38, G30.1 is 40, G92.1 is 102.
NM_NONE, NM_DWELL, NM_SET_COORD, NM_HOME0, NM_SET_HOME0 = 0, 4, 10, 28, 38
NM_HOME1, NM_SET_HOME1, NM_ABS_OVERRIDE, NM_SET_OFFSET, NM_RESET_OFFSET = 30, 40, 53, 92, 102

# Modal groups (bit numbers only matter for violations and the jog check).
G0, G1, G2, G3, G4, G5, G6, G7, G8, G12, G13 = "g0", "g1", "g2", "g3", "g4", "g5", "g6", "g7", "g8", "g12", "g13"
M4, M7, M8 = "m4", "m7", "m8"
_JOG_GROUPS = frozenset({G0, G3, G6})

# Program flow (M0 pause, M2/M30 end).
FLOW_RUNNING, FLOW_PAUSED, FLOW_END_M2, FLOW_END_M30 = 0, 3, 2, 30


@dataclass(frozen=True)
class ModalState:
    """GRBL's modal groups, in GRBL's own terms (``$G`` prints these)."""

    motion: float = SEEK
    coord_select: int = 0  # 0..5 for G54..G59
    plane: int = 17
    inches: bool = False
    incremental: bool = False
    inverse_time: bool = False  # G93 (else G94)
    tlo_dynamic: bool = False  # G43.1 active (else G49)
    spindle: int = 5  # M3, M4, M5
    coolant_flood: bool = False  # M8 (M7 is compiled out of stock GRBL 1.1h)
    program_flow: int = FLOW_RUNNING


@dataclass
class ParserState:
    """``gc_state``: modal groups plus the parser's position and offsets (machine mm)."""

    n_axes: int = 3
    modal: ModalState = field(default_factory=ModalState)
    position: np.ndarray = field(default_factory=lambda: np.zeros(3))
    coord_system: np.ndarray = field(default_factory=lambda: np.zeros(3))  # the active G54..G59 offsets
    g92: np.ndarray = field(default_factory=lambda: np.zeros(3))
    tlo_mm: float = 0.0
    feed_rate: float = 0.0  # mm/min (G94) or 1/min (G93)
    spindle_rpm: float = 0.0
    tool: int = 0
    line_number: int = 0

    @classmethod
    def fresh(cls, n_axes: int, coord_system: np.ndarray, position: np.ndarray) -> "ParserState":
        """``gc_init`` + ``gc_sync_position``: defaults, G54 loaded, position from the step counters."""
        return cls(n_axes=n_axes, position=np.array(position, float), coord_system=np.array(coord_system, float),
                   g92=np.zeros(n_axes))

    def wco(self, tlo_axis: int = 2) -> np.ndarray:
        """Work coordinate offset: active system + G92 + tool length offset (on ``tlo_axis``)."""
        w = self.coord_system + self.g92
        if tlo_axis < self.n_axes:
            w = w.copy()
            w[tlo_axis] += self.tlo_mm
        return w


@dataclass
class Block:
    """A checked block: what ``gc_execute_line`` step 4 will do, every value in machine mm and mm/min."""

    modal: ModalState
    non_modal: int = NM_NONE
    feed_rate: float = 0.0
    spindle_rpm: float = 0.0
    tool: int = 0
    line_number: int = 0
    dwell_s: float = 0.0
    coord_system: np.ndarray | None = None  # the active system after this block
    motion: float | None = None  # a motion mode to execute (axis words or an explicit motion command)
    target: np.ndarray | None = None  # motion / G28-G30 intermediate target (machine mm)
    home_target: np.ndarray | None = None  # G28/G30: the stored position, completed with current axes
    home_via_target: bool = False  # G28/G30 with axis words: go through ``target`` first
    coord_write: tuple[int, np.ndarray] | None = None  # G10: (slot, values)
    g92: np.ndarray | None = None  # G92: the new offset
    tlo_mm: float | None = None  # G43.1 / G49: the new tool length offset
    arc_offset: np.ndarray | None = None  # centre offset from the start (machine mm)
    arc_radius_mm: float = 0.0
    arc_axes: tuple[int, int, int] = (0, 1, 2)  # axis_0, axis_1, axis_linear of the plane
    clockwise: bool = False
    probe_away: bool = False
    probe_no_error: bool = False
    jog: bool = False
    spindle_changed: bool = False
    coolant_changed: bool = False


def read_float(line: str, pos: int) -> tuple[float, int] | None:
    """GRBL's ``read_float`` (nuts_bolts.c): optional sign, digits with one '.', no exponent; eight
    significant digits kept (extra integer digits scale, extra decimals are dropped). None: no digit."""
    i = pos
    n = len(line)
    negative = False
    if i < n and line[i] in "+-":
        negative = line[i] == "-"
        i += 1
    intval, exp, ndigit, decimal = 0, 0, 0, False
    while i < n:
        c = line[i]
        if "0" <= c <= "9":
            ndigit += 1
            if ndigit <= MAX_INT_DIGITS:
                if decimal:
                    exp -= 1
                intval = intval * 10 + (ord(c) - 48)
            elif not decimal:
                exp += 1
        elif c == "." and not decimal:
            decimal = True
        else:
            break
        i += 1
    if ndigit == 0:
        return None
    value = float(intval) * (10.0 ** exp)
    return (-value if negative else value), i


def _c_round(x: float) -> int:
    """C's ``round``: halves away from zero."""
    return int(math.floor(abs(x) + 0.5)) * (1 if x >= 0 else -1)


def _uint8(v: float) -> int:
    return int(math.trunc(v)) & 0xFF


def parse_block(line: str, state: ParserState, coords: Sequence[np.ndarray], *, axes: str = "XYZ",
                jog: bool = False, tlo_axis: int = 2) -> Block | int:
    """Check one cleaned line against ``state``; return a :class:`Block` or GRBL's error code.

    ``coords`` holds the stored G54..G59, G28 and G30 positions (machine mm); ``axes`` the axis
    letters the firmware knows (``XYZ`` on GRBL 1.1h); ``jog`` parses the text after ``$J=``.
    """
    n_axes = len(axes)
    modal = state.modal
    if jog:
        modal = replace(modal, motion=LINEAR, inverse_time=False)
    new: dict[str, Any] = {"motion": modal.motion, "coord_select": modal.coord_select, "plane": modal.plane,
           "inches": modal.inches, "incremental": modal.incremental, "inverse_time": modal.inverse_time,
           "tlo_dynamic": modal.tlo_dynamic, "spindle": modal.spindle, "coolant_flood": modal.coolant_flood,
           "program_flow": FLOW_RUNNING}
    axis_command = None  # "non_modal" | "motion" | "tlo"
    non_modal = NM_NONE
    groups: set[str] = set()
    values: dict[str, float] = {}
    xyz = np.zeros(n_axes)
    axis_words = 0
    ijk = np.zeros(max(3, n_axes))
    ijk_words = 0

    # -- step 2: import every word ------------------------------------------------------------------
    pos = 0
    while pos < len(line):
        letter = line[pos]
        if not ("A" <= letter <= "Z"):
            return 1
        got = read_float(line, pos + 1)
        if got is None:
            return 2
        value, pos = got
        if letter in "GM":
            if value < 0:
                return 20 if letter == "G" else 23  # a negative command number never names a command
            int_value = _uint8(value)
            mantissa = _c_round(100 * (value - int_value)) & 0xFFFF
        if letter == "G":
            group: str
            if int_value in (10, 28, 30, 92, 4, 53):
                if int_value in (10, 28, 30, 92) and mantissa == 0:
                    if axis_command:
                        return 24
                    axis_command = "non_modal"
                group = G0
                non_modal = int_value
                if int_value in (28, 30, 92):
                    if mantissa not in (0, 10):
                        return 20
                    non_modal += mantissa
                    mantissa = 0
            elif int_value in (0, 1, 2, 3, 38, 80):
                if int_value != 80:
                    if axis_command:
                        return 24
                    axis_command = "motion"
                group = G1
                new["motion"] = float(int_value)
                if int_value == 38:
                    if mantissa not in (20, 30, 40, 50):
                        return 20
                    new["motion"] = 38 + mantissa / 100.0
                    mantissa = 0
            elif int_value in (17, 18, 19):
                group = G2
                new["plane"] = int_value
            elif int_value in (90, 91):
                if mantissa == 0:
                    group = G3
                    new["incremental"] = int_value == 91
                else:
                    group = G4
                    if mantissa != 10 or int_value == 90:
                        return 20
                    mantissa = 0  # G91.1: arc IJK are always incremental; nothing to do
            elif int_value in (93, 94):
                group = G5
                new["inverse_time"] = int_value == 93
            elif int_value in (20, 21):
                group = G6
                new["inches"] = int_value == 20
            elif int_value == 40:
                group = G7
            elif int_value in (43, 49):
                group = G8
                if axis_command:
                    return 24
                axis_command = "tlo"
                if int_value == 49:
                    new["tlo_dynamic"] = False
                elif mantissa == 10:
                    new["tlo_dynamic"] = True
                else:
                    return 20
                mantissa = 0
            elif 54 <= int_value <= 59:
                group = G12
                new["coord_select"] = int_value - 54
            elif int_value == 61:
                group = G13
                if mantissa != 0:
                    return 20
            else:
                return 20
            if mantissa > 0:
                return 23
            if group in groups:
                return 21
            groups.add(group)
        elif letter == "M":
            if mantissa > 0:
                return 23
            if int_value in (0, 1, 2, 30):
                group = M4
                if int_value == 0:
                    new["program_flow"] = FLOW_PAUSED
                elif int_value != 1:  # M1 (optional stop) is ignored
                    new["program_flow"] = int_value
            elif int_value in (3, 4, 5):
                group = M7
                new["spindle"] = int_value
            elif int_value in (8, 9):
                group = M8
                new["coolant_flood"] = int_value == 8
            else:
                return 20  # M7 included: ENABLE_M7 is off in stock GRBL 1.1h
            if group in groups:
                return 21
            groups.add(group)
        else:
            if letter == "T" and value > MAX_TOOL_NUMBER:
                return 38
            if letter in axes:
                idx = axes.index(letter)
                xyz[idx] = value
                axis_words |= 1 << idx
            elif letter in "IJK":
                idx = "IJK".index(letter)
                ijk[idx] = value
                ijk_words |= 1 << idx
            elif letter not in "FLNPRST":
                return 20
            if letter in values:
                return 25
            if letter in "FNPTS" and value < 0.0:
                return 4
            values[letter] = value

    # -- step 3: error-check the block ------------------------------------------------------------------
    if axis_words and not axis_command:
        axis_command = "motion"
    line_number = int(math.trunc(values["N"])) if "N" in values else 0
    if "N" in values and line_number > MAX_LINE_NUMBER:
        return 27
    f = values.get("F", 0.0)
    if jog:
        if "F" not in values:
            return 22
        if new["inches"]:
            f *= MM_PER_INCH
    elif new["inverse_time"]:
        if axis_command == "motion" and new["motion"] not in (NONE, SEEK) and "F" not in values:
            return 22
    elif not state.modal.inverse_time:
        if "F" in values:
            if new["inches"]:
                f *= MM_PER_INCH
        else:
            f = state.feed_rate
    s = values.get("S", state.spindle_rpm)
    tool = _uint8(values["T"]) if "T" in values else state.tool
    unused = set(values) - {"N", "F", "S", "T"} if not jog else set(values) - {"N", "F"}
    dwell_s = 0.0
    if non_modal == NM_DWELL:
        if "P" not in values:
            return 28
        dwell_s = values["P"]
        unused.discard("P")
    plane = new["plane"]
    axis_0, axis_1, axis_linear = {17: (0, 1, 2), 18: (2, 0, 1), 19: (1, 2, 0)}[plane]
    if new["inches"]:
        xyz = xyz * MM_PER_INCH
    if axis_command == "tlo" and new["tlo_dynamic"]:
        if axis_words ^ (1 << tlo_axis):
            return 37
    block_coord = np.array(state.coord_system, float)
    if G12 in groups and new["coord_select"] != state.modal.coord_select:
        block_coord = np.array(coords[new["coord_select"]], float)

    block = Block(modal=ModalState(**new), non_modal=non_modal, feed_rate=f, spindle_rpm=s, tool=tool,
                  line_number=line_number, dwell_s=dwell_s, coord_system=block_coord, jog=jog)
    position = np.array(state.position, float)
    target = position.copy()
    if non_modal == NM_SET_COORD:
        if not axis_words:
            return 26
        if "P" not in values and "L" not in values:
            return 28
        slot = _uint8(values.get("P", 0.0))
        if slot > N_COORDINATE_SYSTEMS:
            return 29
        l_word = _uint8(values.get("L", 0.0))
        if l_word != 20:
            if l_word == 2:
                if "R" in values:
                    return 20
            else:
                return 20
        unused -= {"L", "P"}
        slot = slot - 1 if slot > 0 else new["coord_select"]
        data = np.array(coords[slot], float)
        for i in range(n_axes):
            if axis_words & (1 << i):
                if l_word == 20:
                    data[i] = position[i] - state.g92[i] - xyz[i] - (state.tlo_mm if i == tlo_axis else 0.0)
                else:
                    data[i] = xyz[i]
        block.coord_write = (slot, data)
    elif non_modal == NM_SET_OFFSET:
        if not axis_words:
            return 26
        g92 = np.array(state.g92, float)
        for i in range(n_axes):
            if axis_words & (1 << i):
                g92[i] = position[i] - block_coord[i] - xyz[i] - (state.tlo_mm if i == tlo_axis else 0.0)
        block.g92 = g92
    else:
        if axis_command != "tlo" and axis_words:
            for i in range(n_axes):
                if axis_words & (1 << i):
                    if non_modal == NM_ABS_OVERRIDE:
                        target[i] = xyz[i]
                    elif not new["incremental"]:
                        target[i] = xyz[i] + block_coord[i] + state.g92[i] + (state.tlo_mm if i == tlo_axis else 0.0)
                    else:
                        target[i] = xyz[i] + position[i]
        if non_modal in (NM_HOME0, NM_HOME1):
            stored = np.array(coords[G28_INDEX if non_modal == NM_HOME0 else G30_INDEX], float)
            if axis_words:
                for i in range(n_axes):
                    if not axis_words & (1 << i):
                        stored[i] = position[i]
            else:
                axis_command = None
            block.home_target = stored
            block.home_via_target = bool(axis_words)
        elif non_modal == NM_ABS_OVERRIDE and new["motion"] not in (SEEK, LINEAR):
            return 30
    if axis_command == "tlo":
        block.tlo_mm = float(xyz[tlo_axis]) if new["tlo_dynamic"] else 0.0

    motion = new["motion"]
    if motion == NONE:
        if axis_words:
            return 31
    elif axis_command == "motion":
        if motion == SEEK:
            if not axis_words:
                axis_command = None
        else:
            if f == 0.0:
                return 22
            if motion == LINEAR:
                if not axis_words:
                    axis_command = None
            elif motion in (CW_ARC, CCW_ARC):
                if not axis_words:
                    return 26
                if not axis_words & ((1 << axis_0) | (1 << axis_1)):
                    return 32
                x = target[axis_0] - position[axis_0]
                y = target[axis_1] - position[axis_1]
                if "R" in values:
                    unused.discard("R")
                    if np.array_equal(position, target):
                        return 33
                    r = values["R"] * (MM_PER_INCH if new["inches"] else 1.0)
                    h_x2_div_d = 4.0 * r * r - x * x - y * y
                    if h_x2_div_d < 0:
                        return 34
                    h_x2_div_d = -math.sqrt(h_x2_div_d) / math.hypot(x, y)
                    if motion == CCW_ARC:
                        h_x2_div_d = -h_x2_div_d
                    if r < 0:
                        h_x2_div_d = -h_x2_div_d
                        r = -r
                    ijk[axis_0] = 0.5 * (x - y * h_x2_div_d)
                    ijk[axis_1] = 0.5 * (y + x * h_x2_div_d)
                    radius = r
                else:
                    if not ijk_words & ((1 << axis_0) | (1 << axis_1)):
                        return 35
                    unused -= {"I", "J", "K"}
                    if new["inches"]:
                        ijk = ijk * MM_PER_INCH
                    target_r = math.hypot(x - ijk[axis_0], y - ijk[axis_1])
                    radius = math.hypot(ijk[axis_0], ijk[axis_1])
                    delta_r = abs(target_r - radius)
                    if delta_r > 0.005 and (delta_r > 0.5 or delta_r > 0.001 * radius):
                        return 33
                block.arc_offset = ijk[:n_axes].copy()
                block.arc_radius_mm = radius
                block.arc_axes = (axis_0, axis_1, axis_linear)
                block.clockwise = motion == CW_ARC
            else:  # probing
                block.probe_no_error = motion in (38.3, 38.5)
                block.probe_away = motion in (38.4, 38.5)
                if not axis_words:
                    return 26
                if np.array_equal(position, target):
                    return 33
    if axis_command:
        unused -= {"X", "Y", "Z", "A"}
    if unused:
        return 36
    if jog:
        if groups - _JOG_GROUPS:
            return 16
        if non_modal not in (NM_ABS_OVERRIDE, NM_NONE):
            return 16
    block.target = target
    if axis_command == "motion" and motion != NONE:
        block.motion = motion
    block.spindle_changed = new["spindle"] != state.modal.spindle
    block.coolant_changed = new["coolant_flood"] != state.modal.coolant_flood
    return block


def commit(state: ParserState, block: Block) -> ParserState:
    """Step 4's bookkeeping: the parser state after ``block`` (positions are set by the firmware)."""
    modal = block.modal
    st = replace(state, modal=replace(modal, program_flow=FLOW_RUNNING), feed_rate=block.feed_rate,
                 spindle_rpm=block.spindle_rpm, tool=block.tool, line_number=block.line_number)
    if block.coord_system is not None:
        st.coord_system = np.array(block.coord_system, float)
    if block.tlo_mm is not None:
        st.tlo_mm = block.tlo_mm
    if block.coord_write is not None and block.coord_write[0] == modal.coord_select:
        st.coord_system = np.array(block.coord_write[1], float)
    if block.g92 is not None:
        st.g92 = np.array(block.g92, float)
    if block.non_modal == NM_RESET_OFFSET:
        st.g92 = np.zeros(state.n_axes)
    return st


def program_end(state: ParserState, g54: np.ndarray) -> ParserState:
    """M2/M30: LinuxCNC's subset of modal groups back to G1 G17 G90 G94 G54 M5 M9 (gcode.c step 21)."""
    modal = replace(state.modal, motion=LINEAR, plane=17, incremental=False, inverse_time=False,
                    coord_select=0, spindle=5, coolant_flood=False, program_flow=FLOW_RUNNING)
    return replace(state, modal=modal, coord_system=np.array(g54, float))
