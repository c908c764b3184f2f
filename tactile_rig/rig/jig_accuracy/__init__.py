"""Jig accuracy runs (Li et al. 2014, Fig. 7): how well does GelSight localization recover a jig move?

A run builds a tactile map of the object from a few touches, then steps the x-y-θ jig through
rotations (default −90..+90° in 10° steps) and shifts (−6..+6 mm in 1 mm steps), touches, localizes
the touch in the map, and compares the estimate with the truth: the stage pose of the simulated
world on mocks, the jig's commanded pose on a bench. The paper's bench figures are a rotation MAE of
1.15° (std 1.02) and a translation MAE of 0.14 mm (std 0.055).

Frames (all planar, mm and degrees, image axes: x right, y down, θ clockwise on screen):

* the *sensor* frame S: millimetres from the image centre;
* the *map* frame M: the sensor frame of the first map touch, taken at the jig's home pose;
* a stage pose ``(x_mm, y_mm, theta_deg)`` puts the object at ``p_s = R(θ) p_m + t`` in S, the
  convention of :func:`tactile_rig.sim.world.objects.view_in_sensor`.

A registration of a touch B onto the map returns the 2x3 matrix taking B's sensor points into the
map, ``p_m = R(−θ) (p_s − t)``; :func:`pose_from_touch_matrix` inverts it into the stage pose.

Resumability: every finished point is appended (and fsynced) to ``OUT/points.jsonl`` and the run's
configuration and fingerprint live in ``OUT/run.json``; a run started again on the same ``OUT`` with
the same configuration continues at the first unfinished point (the calibration and the tactile map
are reloaded from ``OUT`` so the points before and after the interruption share them).

The run sees the devices through :class:`JigRig` (:class:`DeviceJigRig` wraps a jig driver and a
camera driver; :func:`connect_mock_jig_rig` connects them to the mocks of the ``jig_accuracy``
scene) and perception through :class:`TouchLocalizer`.

Modules: :mod:`.plan` (configuration, points, pose algebra), :mod:`.results` (scores and figures),
:mod:`.store` (the run folder), :mod:`.localizer`, :mod:`.run`, :mod:`.report`, :mod:`.devices`,
:mod:`.session` (the whole run as the CLI starts it).
"""

import warnings
from typing import Any

from tactile_rig.core.errors import RunConflict
from tactile_rig.core.geometry import Pose, wrap_deg
from tactile_rig.rig.jig_accuracy.devices import (
    MOCK_SCENE,
    DeviceJigRig,
    connect_bench_jig_rig,
    connect_mock_jig_rig,
    prepare_jig,
    sim_camera_connector,
)
from tactile_rig.rig.jig_accuracy.localizer import (
    JigRig,
    TouchLocalization,
    TouchLocalizer,
)
from tactile_rig.rig.jig_accuracy.plan import (
    DEFAULT_REGISTRATION,
    PAPER_FIGURES,
    SWEEPS,
    JigAccuracyConfig,
    JigPoint,
    plan_points,
    pose_from_touch_matrix,
    touch_matrix_from_pose,
)
from tactile_rig.rig.jig_accuracy.report import format_table, write_report
from tactile_rig.rig.jig_accuracy.results import PointResult, summarize
from tactile_rig.rig.jig_accuracy.run import (
    RunOutcome,
    build_map,
    measure_point,
    run_jig_accuracy,
)
from tactile_rig.rig.jig_accuracy.session import (
    RunRecorder,
    calibration_digest,
    execute_jig_accuracy,
    mock_gelsight_calibration,
    open_run_recording,
)
from tactile_rig.rig.jig_accuracy.store import RUN_FORMAT, RUN_FORMAT_VERSION, RunStore
from tactile_rig.sim.scenes import GELSIGHT_BALL_PRESS_SCENE

__all__ = [
    "DEFAULT_REGISTRATION", "MOCK_SCENE", "PAPER_FIGURES", "RUN_FORMAT", "RUN_FORMAT_VERSION",
    "SWEEPS", "DeviceJigRig", "JigAccuracyConfig", "JigPoint", "JigRig", "PointResult", "Pose", "RunConflict",
    "RunOutcome", "RunRecorder", "RunStore", "TouchLocalization", "TouchLocalizer", "build_map",
    "calibration_digest", "connect_bench_jig_rig", "connect_mock_jig_rig", "execute_jig_accuracy", "format_table",
    "measure_point", "mock_gelsight_calibration", "open_run_recording", "plan_points", "pose_from_touch_matrix",
    "prepare_jig", "run_jig_accuracy", "sim_camera_connector", "summarize", "touch_matrix_from_pose", "wrap_deg",
    "write_report",
]


def __getattr__(name: str) -> Any:
    """``MOCK_PRESS_SCENE``, the old name of :data:`tactile_rig.sim.scenes.GELSIGHT_BALL_PRESS_SCENE`,
    kept for one release with a DeprecationWarning."""
    if name == "MOCK_PRESS_SCENE":
        warnings.warn("tactile_rig.rig.jig_accuracy.MOCK_PRESS_SCENE is "
                      "tactile_rig.sim.scenes.GELSIGHT_BALL_PRESS_SCENE; the old name goes away in the next release",
                      DeprecationWarning, stacklevel=2)
        return GELSIGHT_BALL_PRESS_SCENE
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
