"""GRBL 1.1 facts shared by the jig driver and the GRBL mock, as data.

Sources: gnea/grbl ``doc/markdown/interface.md``, ``realtime_cmds.md``, ``settings.md``, ``jogging.md``
and ``doc/csv/{error,alarm}_codes_en_US.csv``. Messages are GRBL's own wording. The wire codecs
(the driver's status parser, the mock's G-code parser and report printer) live on each side.
"""

from __future__ import annotations

from tactile_rig.core.errors import GrblAlarm, GrblError

BAUD = 115200
VERSION = "1.1h"
BUILD_DATE = "20190830"  # grbl/grbl.h GRBL_VERSION_BUILD in gnea/grbl's 1.1h source ($I prints it)
BANNER_PREFIX = "Grbl "
BANNER = f"Grbl {VERSION} ['$' for help]"
RX_BUFFER_SIZE = 128  # serial receive buffer (usable bytes, character-counting budget)
PLANNER_BLOCKS = 16  # planner ring on an ATmega328p; reported available as 15 (one is in use)
LINE_MAX = 80  # LINE_BUFFER_SIZE: longer lines are rejected with error:14... (see ERRORS[11])

# Realtime commands: single bytes, never buffered, acted on at once.
RT_STATUS = b"?"
RT_FEED_HOLD = b"!"
RT_CYCLE_START = b"~"
RT_SOFT_RESET = b"\x18"
RT_SAFETY_DOOR = b"\x84"
RT_JOG_CANCEL = b"\x85"
REALTIME_BYTES = frozenset(b"?!~\x18") | frozenset(range(0x80, 0x100))

STATES = ("Idle", "Run", "Hold", "Jog", "Alarm", "Door", "Check", "Home", "Sleep")

# error:N → (short name, GRBL's message)
ERRORS: dict[int, tuple[str, str]] = {
    1: ("Expected command letter", "G-code words consist of a letter and a value. Letter was not found."),
    2: ("Bad number format", "Missing the expected G-code word value or numeric value format is not valid."),
    3: ("Invalid statement", "Grbl '$' system command was not recognized or supported."),
    4: ("Value < 0", "Negative value received for an expected positive value."),
    5: ("Setting disabled", "Homing cycle failure. Homing is not enabled via settings."),
    6: ("Value < 3 usec", "Minimum step pulse time must be greater than 3usec."),
    7: ("EEPROM read fail. Using defaults", "An EEPROM read failed. Auto-restoring affected EEPROM to default values."),
    8: ("Not idle", "Grbl '$' command cannot be used unless Grbl is IDLE. Ensures smooth operation during a job."),
    9: ("G-code lock", "G-code commands are locked out during alarm or jog state."),
    10: ("Homing not enabled", "Soft limits cannot be enabled without homing also enabled."),
    11: ("Line overflow", "Max characters per line exceeded. Received command line was not executed."),
    12: ("Step rate > 30kHz", "Grbl '$' setting value cause the step rate to exceed the maximum supported."),
    13: ("Check Door", "Safety door detected as opened and door state initiated."),
    14: ("Line length exceeded", "Build info or startup line exceeded EEPROM line length limit. Line not stored."),
    15: ("Travel exceeded", "Jog target exceeds machine travel. Jog command has been ignored."),
    16: ("Invalid jog command", "Jog command has no '=' or contains prohibited g-code."),
    17: ("Setting disabled", "Laser mode requires PWM output."),
    20: ("Unsupported command", "Unsupported or invalid g-code command found in block."),
    21: ("Modal group violation", "More than one g-code command from same modal group found in block."),
    22: ("Undefined feed rate", "Feed rate has not yet been set or is undefined."),
    23: ("Invalid gcode ID:23", "G-code command in block requires an integer value."),
    24: ("Invalid gcode ID:24", "More than one g-code command that requires axis words found in block."),
    25: ("Invalid gcode ID:25", "Repeated g-code word found in block."),
    26: ("Invalid gcode ID:26", "No axis words found in block for g-code command or current modal state which requires them."),
    27: ("Invalid gcode ID:27", "Line number value is invalid."),
    28: ("Invalid gcode ID:28", "G-code command is missing a required value word."),
    29: ("Invalid gcode ID:29", "G59.x work coordinate systems are not supported."),
    30: ("Invalid gcode ID:30", "G53 only allowed with G0 and G1 motion modes."),
    31: ("Invalid gcode ID:31", "Axis words found in block when no command or current modal state uses them."),
    32: ("Invalid gcode ID:32", "G2 and G3 arcs require at least one in-plane axis word."),
    33: ("Invalid gcode ID:33", "Motion command target is invalid."),
    34: ("Invalid gcode ID:34", "Arc radius value is invalid."),
    35: ("Invalid gcode ID:35", "G2 and G3 arcs require at least one in-plane offset word."),
    36: ("Invalid gcode ID:36", "Unused value words found in block."),
    37: ("Invalid gcode ID:37", "G43.1 dynamic tool length offset is not assigned to configured tool length axis."),
    38: ("Invalid gcode ID:38", "Tool number greater than max supported value."),
}

# ALARM:N → (short name, GRBL's message)
ALARMS: dict[int, tuple[str, str]] = {
    1: ("Hard limit", "Hard limit has been triggered. Machine position is likely lost due to sudden halt. Re-homing is highly recommended."),
    2: ("Soft limit", "Soft limit alarm. G-code motion target exceeds machine travel. Machine position retained. Alarm may be safely unlocked."),
    3: ("Abort during cycle", "Reset while in motion. Machine position is likely lost due to sudden halt. Re-homing is highly recommended."),
    4: ("Probe fail", "Probe fail. Probe is not in the expected initial state before starting probe cycle when G38.2 and G38.3 is not triggered and G38.4 and G38.5 is triggered."),
    5: ("Probe fail", "Probe fail. Probe did not contact the workpiece within the programmed travel for G38.2 and G38.4."),
    6: ("Homing fail", "Homing fail. The active homing cycle was reset."),
    7: ("Homing fail", "Homing fail. Safety door was opened during homing cycle."),
    8: ("Homing fail", "Homing fail. Pull off travel failed to clear limit switch. Try increasing pull-off setting or check wiring."),
    9: ("Homing fail", "Homing fail. Could not find limit switch within search distances. Try increasing max travel, decreasing pull-off distance, or check wiring."),
    10: ("Homing fail", "Homing fail. On dual axis machines, could not find the second limit switch for self-squaring."),
}

# $N settings: number → (name, unit). Axis settings are generated per axis below.
SETTINGS: dict[int, tuple[str, str]] = {
    0: ("Step pulse time", "microseconds"),
    1: ("Step idle delay", "milliseconds"),
    2: ("Step pulse invert", "mask"),
    3: ("Step direction invert", "mask"),
    4: ("Invert step enable pin", "boolean"),
    5: ("Invert limit pins", "boolean"),
    6: ("Invert probe pin", "boolean"),
    10: ("Status report options", "mask"),
    11: ("Junction deviation", "millimeters"),
    12: ("Arc tolerance", "millimeters"),
    13: ("Report in inches", "boolean"),
    20: ("Soft limits enable", "boolean"),
    21: ("Hard limits enable", "boolean"),
    22: ("Homing cycle enable", "boolean"),
    23: ("Homing direction invert", "mask"),
    24: ("Homing locate feed rate", "mm/min"),
    25: ("Homing search seek rate", "mm/min"),
    26: ("Homing switch debounce delay", "milliseconds"),
    27: ("Homing switch pull-off distance", "millimeters"),
    30: ("Maximum spindle speed", "RPM"),
    31: ("Minimum spindle speed", "RPM"),
    32: ("Laser-mode enable", "boolean"),
}
AXIS_LETTERS = ("X", "Y", "Z", "A")
AXIS_SETTING_BASES = {100: ("steps", "step/mm"), 110: ("Maximum rate", "mm/min"),
                      120: ("Acceleration", "mm/sec^2"), 130: ("Maximum travel", "millimeters")}
for _base, (_name, _unit) in AXIS_SETTING_BASES.items():
    for _i, _ax in enumerate(AXIS_LETTERS):
        SETTINGS[_base + _i] = (f"{_ax}-axis {_name}", _unit)
INTEGER_SETTINGS = frozenset({0, 1, 2, 3, 4, 5, 6, 10, 13, 20, 21, 22, 23, 26, 32})

# $10 status report mask bits
MASK_MPOS = 1  # position field is MPos (else WPos)
MASK_BUFFER = 2  # Bf:planner,rx

# Fields of a status report (everything after the state), in GRBL's printing order.
STATUS_FIELDS = ("MPos", "WPos", "Bf", "Ln", "F", "FS", "WCO", "Pn", "Ov", "A")
PIN_LETTERS = "XYZAPDHRS"  # Pn: limits X Y Z (A), probe, door, hold, soft-reset, cycle-start

# How GRBL prints the numbers of a status report (report.c through print.c's printFloat): a sign
# only when negative, the integer part without leading zeros (at least one digit), then a fixed
# number of decimals. Coordinates
# (MPos, WPos, WCO) have 3 decimals in mm and 4 in inches ($13=1); feed and spindle rates 0 in mm/min
# and 1 in inches/min; Bf, Ln and Ov are unsigned integers. A report whose numbers break these
# formats was corrupted on the wire (GRBL's lines carry no checksum: the format is all we have).
COORD_DECIMALS = {"mm": 3, "inch": 4}
RATE_DECIMALS = {"mm": 0, "inch": 1}
COORD_FIELDS = ("MPos", "WPos", "WCO")
MAX_AXES = 6  # N_AXIS never exceeds 6 in GRBL and grblHAL builds
SUBSTATES = {"Hold": range(0, 2), "Door": range(0, 4)}  # the only states GRBL prints with ':<n>'
OVERRIDE_LIMITS = ((10, 200), (25, 100), (10, 200))  # Ov: feed %, rapid % (25, 50 or 100), spindle %
RAPID_OVERRIDES = (25, 50, 100)
ACCESSORY_LETTERS = "SCFM"  # A: spindle CW, CCW, flood, mist
PIN_OVERRIDE_LETTERS = "BCUVW"  # grblHAL's extra Pn letters (block delete, ..., optional stop)
# Fields grblHAL adds after GRBL's (kept as text in ``extras``); any other name is line noise.
GRBLHAL_FIELDS = ("SD", "H", "T", "TLR", "Sc", "MPG", "FW", "In", "Ld", "D", "TH", "THC", "Q")
# The states in which GRBL executes no motion and has nothing queued in its planner: a line it
# read is answered within milliseconds (a dwell, G4, is the exception, and is never presumed lost).
QUIESCENT_STATES = ("Idle", "Alarm", "Check")


def error(code: int, *, device: str | None = None, line: str | None = None) -> GrblError:
    """The typed error for GRBL's ``error:<code>`` answering ``line``, with GRBL 1.1's name and message."""
    name, meaning = ERRORS.get(code, ("Unknown error", f"error code {code} is not in GRBL 1.1's table"))
    return GrblError(code, name, meaning, device=device, line=line)


def alarm(code: int, *, device: str | None = None, hint: str = "") -> GrblAlarm:
    """The typed fault for GRBL's ``ALARM:<code>``, with GRBL 1.1's name and message."""
    name, meaning = ALARMS.get(code, ("Unknown alarm", f"alarm code {code} is not in GRBL 1.1's table"))
    return GrblAlarm(code, name, meaning, device=device, hint=hint)
