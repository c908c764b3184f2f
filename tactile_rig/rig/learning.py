"""Learned fingertip models on the rig: the force map (thesis 3.4.1) and the substance classifier (3.4.2).

The models are pure array code in perception (:mod:`tactile_rig.perception.fingervision.force_map`,
:mod:`tactile_rig.perception.fingervision.substance`: numpy prediction, scikit-learn fits); the
sessions that record trials and fit them are :mod:`tactile_rig.rig.sessions.force_map` and
:mod:`tactile_rig.rig.sessions.substance`. This module is their public face on the rig, and the place a
bench's consumers load a model from: :func:`load_force_map` and :func:`load_substance_model` read the
files a bench names (a session folder, a stem, its ``.json`` or ``.npz``; the stable name reads the
newest version) through the checked loaders of :mod:`tactile_rig.rig.files`, and name the command that
makes a missing or unusable model.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Callable, Mapping, TypeVar

from tactile_rig.core.envelope import FileFormat
from tactile_rig.core.errors import CalibrationError
from tactile_rig.perception.fingervision.force_map import (
    DEFAULT_GAMMA,
    FORCE_FEATURES,
    FORCE_MAP_FILE,
    ForceMapModel,
    fit_force_map,
)
from tactile_rig.perception.fingervision.learned import model_paths
from tactile_rig.perception.fingervision.substance import (
    STIR_FEATURES,
    SUBSTANCE_FILE,
    SubstanceModel,
    fit_substance,
    predict_substance,
    stirring_features,
)
from tactile_rig.rig.files import checked, load_json, load_npz
from tactile_rig.rig.sessions.force_map import (
    MAX_SCALE_LAG_S,
    ForceTrialData,
    fit_force_map_trials,
    force_map_session,
    force_trials_from_recording,
    record_force_map_session,
    scale_lag_s,
)
from tactile_rig.rig.sessions.substance import (
    record_stirring_session,
    stirring_series_from_recording,
    stirring_trials_from_recording,
    substance_session,
)

__all__ = [
    "DEFAULT_GAMMA", "FORCE_FEATURES", "FORCE_MAP_FILE", "FORCE_MAP_FORMAT", "FORMAT_VERSION", "MAX_SCALE_LAG_S",
    "STIR_FEATURES", "SUBSTANCE_FILE", "SUBSTANCE_FORMAT", "ForceMapModel", "ForceTrialData", "SubstanceModel",
    "fit_force_map", "fit_force_map_trials", "fit_substance", "force_map_session", "force_trials_from_recording",
    "load_force_map", "load_substance_model", "model_json_path", "predict_substance", "record_force_map_session",
    "record_stirring_session", "scale_lag_s", "stirring_features", "stirring_series_from_recording",
    "stirring_trials_from_recording", "substance_session",
]

FORCE_MAP_FORMAT = FORCE_MAP_FILE.format_id
SUBSTANCE_FORMAT = SUBSTANCE_FILE.format_id
FORMAT_VERSION = FORCE_MAP_FILE.version

_Model = TypeVar("_Model", ForceMapModel, SubstanceModel)


def _model_path(path: str | Path, name: str) -> Path:
    """A model named by its .json, .npz, stem, or the session's output folder (``<folder>/<name>``)."""
    p = Path(path)
    return p / name if p.is_dir() else p


def model_json_path(path: str | Path, name: str) -> Path:
    """The ``.json`` of a model named by a bench (its folder, stem, ``.json`` or ``.npz``); ``name`` is
    the file name inside a session folder (``force_map``, ``substance``)."""
    return model_paths(_model_path(path, name))[1]


def load_force_map(path: str | Path) -> ForceMapModel:
    """The force map a bench names (``calib/force_map``, ``.../force_map.json`` or ``.npz``; the
    stable name reads the newest version). Raises CalibrationError naming the file and the command."""
    return _load_model(ForceMapModel.from_saved, FORCE_MAP_FILE, path, "force_map", "force-map")


def load_substance_model(path: str | Path) -> SubstanceModel:
    """The substance classifier a bench names (folder, ``.json``, ``.npz`` or stem)."""
    return _load_model(SubstanceModel.from_saved, SUBSTANCE_FILE, path, "substance", "substance")


def _load_model(from_saved: Callable[[Mapping[str, Any], Mapping[str, Any], str], _Model], fmt: FileFormat,
                path: str | Path, name: str, command: str) -> _Model:
    """The model ``path`` names, its files bounded and checked before use; a missing, foreign or
    inconsistent model is a CalibrationError naming the file and the command that makes it, a
    damaged ``.npz`` a BadFile."""
    npz, js = model_paths(_model_path(path, name))
    make = f"make it with: tactile-rig calibrate {command}"
    if not js.is_file():
        raise CalibrationError(f"model file {js} does not exist; {make}", device=command)
    try:
        meta = load_json(js, "model file")
    except ValueError as exc:
        raise CalibrationError(f"model file {js} is not valid JSON: {exc}; {make}", device=command) from None
    if not npz.is_file():
        raise CalibrationError(f"{fmt.what} arrays {npz} are missing ({js.name} is there); {make}", device=command)
    with checked(npz, fmt.what, f"a model written by 'tactile-rig calibrate {command}'"):
        arrays = load_npz(npz, f"{fmt.what} arrays")
    try:
        model = from_saved(meta, arrays, str(npz))
    except CalibrationError as exc:
        raise CalibrationError(f"{exc}; {make}", device=command) from None
    model.meta.setdefault("path", str(js))
    return model
