"""Calibration sessions: collect the data on the rig, fit, and write a versioned calibration with its report.

The public face of :mod:`tactile_rig.rig.sessions` (one module per session and per shared piece):

* **Scale** (:func:`scale_session`): tare the empty scale, put a known mass on it, calibrate
  (the factor is stored in the sketch's EEPROM and in the file), read it back as a check.
* **Gripper** (:func:`gripper_session`): find the closed and open stops at a low effort.
* **FingerVision** (:func:`fingervision_session`): marker rest positions (baseline) and the
  proximity-vision background histogram from no-contact frames.
* **GelSight** (:func:`gelsight_session`): a ball pressed into the gel is moved by the jig over a
  grid of positions and the calibration fitted on the labelled presses.

Every session is guided on a terminal and scriptable elsewhere (:class:`Guide`), writes ``<out>.json``
(or, for GelSight, ``<out>.npz`` + ``<out>.json`` from
:meth:`~tactile_rig.perception.gelsight.calibration.GelSightCalibration.save`) and a report
``<out>.report.json`` + ``<out>.report.md``; JSON calibrations share one envelope
(:func:`write_calibration`, :func:`read_calibration`). Files are versioned
(:mod:`tactile_rig.rig.calibrations`): asked for ``calib/scale.json`` a session writes
``calib/scale-vN.json`` and points the stable name at it; ``force=True`` rewrites the newest version.
Every session also records what it measured to ``<stem>-vN.mcap`` (:class:`SessionRecording`) when the
``record`` extra (mcap) is installed.
"""

from __future__ import annotations

from tactile_rig.perception.gelsight.press_centres import contact_centroid_px, even_colour_direction
from tactile_rig.rig.sessions.calibration_file import (
    CALIBRATION_FILE,
    CALIBRATION_FORMAT,
    CALIBRATION_VERSION,
    JSON_SUFFIXES,
    LINKED_SUFFIXES,
    SessionOutcome,
    read_calibration,
    write_calibration,
)
from tactile_rig.rig.sessions.fingervision import fingervision_session
from tactile_rig.rig.sessions.gelsight import (
    BallPressPlan,
    PressRig,
    collect_ball_presses,
    gelsight_session,
    press_positions,
)
from tactile_rig.rig.sessions.gripper import gripper_session
from tactile_rig.rig.sessions.guide import Guide
from tactile_rig.rig.sessions.scale import scale_session, wait_for_load
from tactile_rig.rig.sessions.session_recording import SessionRecording

__all__ = [
    "CALIBRATION_FILE",
    "CALIBRATION_FORMAT",
    "CALIBRATION_VERSION",
    "JSON_SUFFIXES",
    "LINKED_SUFFIXES",
    "SessionOutcome",
    "SessionRecording",
    "Guide",
    "write_calibration",
    "read_calibration",
    "BallPressPlan",
    "PressRig",
    "press_positions",
    "collect_ball_presses",
    "contact_centroid_px",
    "even_colour_direction",
    "gelsight_session",
    "scale_session",
    "gripper_session",
    "fingervision_session",
    "wait_for_load",
]
