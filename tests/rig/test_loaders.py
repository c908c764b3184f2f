"""The checked loader of a GelSight calibration refuses model arrays that do not fit their model."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from tactile_rig.core.errors import BadFile
from tactile_rig.rig.loaders import load_gelsight_calibration
from tests._data import test_data


def _calibration(tmp_path: Path, **arrays: np.ndarray | None) -> Path:
    src = test_data("file_formats") / "gelsight_calibration_mlp"
    shutil.copy(src.with_suffix(".json"), tmp_path / "cal.json")
    with np.load(src.with_suffix(".npz"), allow_pickle=False) as z:
        saved = {k: z[k] for k in z.files}
    saved.update(arrays)
    np.savez(tmp_path / "cal.npz", **{k: v for k, v in saved.items() if v is not None})
    return tmp_path / "cal"


def test_the_mlp_calibration_as_written_loads(tmp_path: Path) -> None:
    cal = load_gelsight_calibration(_calibration(tmp_path))
    assert cal.model.kind == "mlp" and [w.shape for w in cal.model.weights] == [(5, 4), (4, 2)]


@pytest.mark.parametrize(("key", "value", "problem"), [
    ("model_w0", np.zeros((3, 4), np.float32), r"model_w0 has shape \(3, 4\); the layer sizes \[5, 4, 2\] need \(5, 4\)"),
    ("model_w1", np.zeros((4, 7), np.float32), r"model_w1 has shape \(4, 7\).*need \(4, 2\)"),
    ("model_b0", np.zeros(3, np.float32), r"model_b0 has shape \(3,\).*need \(4,\)"),
    ("model_w0", None, r"model_w0 is missing"),
    ("model_w0", np.full((5, 4), np.nan, np.float32), r"'model_w0' holds 20 NaN"),
])
def test_a_model_array_that_does_not_fit_is_a_badfile_naming_the_npz(tmp_path: Path, key: str, value, problem: str
                                                                      ) -> None:
    base = _calibration(tmp_path, **{key: value})
    with pytest.raises(BadFile, match=problem) as info:
        load_gelsight_calibration(base)
    assert info.value.path == str(base.with_suffix(".npz"))


def test_an_unknown_model_is_a_badfile_naming_the_json(tmp_path: Path) -> None:
    base = _calibration(tmp_path)
    meta = json.loads(base.with_suffix(".json").read_text())
    (tmp_path / "cal.json").write_text(json.dumps({**meta, "model": "svm"}))
    with pytest.raises(BadFile, match="model='svm'.*one of lut, mlp, poly") as info:
        load_gelsight_calibration(base)
    assert info.value.path == str(base.with_suffix(".json"))
