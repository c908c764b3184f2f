"""The x-y-θ jig on GRBL 1.1, one job per module.

* :mod:`.status`: status reports parsed strictly (:func:`parse_status`, :class:`GrblStatus`);
* :mod:`.link`: character-counted streaming and the resynchronisation after a lost ``ok``/``error``;
* :mod:`.envelope`: where the machine can be while it moves (the check on reports in motion);
* :mod:`.controller`: GRBL's line protocol on a port (:class:`GrblController`);
* :mod:`.jig`: the jig's axes, limits and ``Motion`` (:class:`Jig`);
* :mod:`.limits`: the firmware's soft-limit window in work coordinates (:func:`read_window`).

GRBL's facts (errors, alarms, settings, line formats) are :mod:`tactile_rig.devices.grbl`.
"""

from tactile_rig.drivers.grbl.controller import GrblController, GrblStats
from tactile_rig.drivers.grbl.envelope import ENVELOPE_TOL, FEED_OVERRIDE_MAX, PathEnvelope
from tactile_rig.drivers.grbl.jig import Jig
from tactile_rig.drivers.grbl.limits import FirmwareWindow, read_window
from tactile_rig.drivers.grbl.link import CharacterCounter, StreamResult, clean_gcode_line
from tactile_rig.drivers.grbl.status import MM_PER_INCH, GrblStatus, parse_status

__all__ = [
    "ENVELOPE_TOL", "FEED_OVERRIDE_MAX", "MM_PER_INCH", "CharacterCounter", "FirmwareWindow", "GrblController",
    "GrblStats", "GrblStatus", "Jig", "PathEnvelope", "StreamResult", "clean_gcode_line", "parse_status", "read_window",
]
