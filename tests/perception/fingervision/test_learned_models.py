"""The learned fingertip models read back only what fits them: every array's shape against the model."""

from __future__ import annotations

import json

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from tactile_rig.core.errors import CalibrationError
from tactile_rig.perception.fingervision.force_map import FORCE_FEATURES, ForceMapModel
from tactile_rig.perception.fingervision.substance import STIR_FEATURES, SubstanceModel, stirring_features
from tests._data import test_data

FILES = test_data("file_formats")


def _saved(stem: str) -> tuple[dict, dict[str, np.ndarray]]:
    with np.load(FILES / f"{stem}.npz", allow_pickle=False) as z:
        return json.loads((FILES / f"{stem}.json").read_text()), {k: z[k] for k in z.files}


@pytest.mark.parametrize(("key", "value", "problem"), [
    ("x_fit", np.zeros((30, 5)), r"'x_fit' has shape \(30, 5\); the model needs \(N, 6\)"),
    ("dual_coef", np.zeros(29), r"'dual_coef' has shape \(29,\); the model needs \(30,\)"),
    ("center", np.zeros((6, 1)), r"'center' has shape \(6, 1\)"),
    ("scale", np.full(6, np.inf), r"'scale' holds NaN or infinity"),
    ("gamma", np.zeros(2), r"'gamma' has shape \(2,\); the model needs \(\)"),
    ("alpha", None, r"'alpha' is missing"),
])
def test_a_force_map_array_that_does_not_fit_is_refused_naming_it(key: str, value, problem: str) -> None:
    meta, arrays = _saved("force_map")
    model = ForceMapModel.from_saved(meta, arrays, "fm.npz")
    assert model.x_fit.shape == (30, 6) and model.feature_names == FORCE_FEATURES
    bad = {k: v for k, v in {**arrays, key: value}.items() if v is not None}
    with pytest.raises(CalibrationError, match=r"fm\.npz: the array " + problem):
        ForceMapModel.from_saved(meta, bad, "fm.npz")


def test_a_force_map_listing_other_features_is_refused() -> None:
    meta, arrays = _saved("force_map")
    with pytest.raises(CalibrationError, match=r"'features' is \['fx_px'\]; 6 names"):
        ForceMapModel.from_saved({**meta, "features": ["fx_px"]}, arrays, "fm.npz")


@pytest.mark.parametrize(("change", "problem"), [
    ({"W0": np.zeros((7, 3))}, r"'W0' has shape \(7, 3\); the model needs \(8, N\)"),
    ({"W1": np.zeros((3, 2))}, r"'W1' has shape \(3, 2\); the model needs \(3, 1\)"),
    ({"b0": np.zeros(4)}, r"'b0' has shape \(4,\); the model needs \(3,\)"),
    ({"W1": np.zeros((2, 1))}, r"'W1' has shape \(2, 1\); the model needs \(3, 1\)"),
    ({"center": np.zeros(7)}, r"'center' has shape \(7,\)"),
])
def test_a_substance_layer_that_does_not_fit_the_one_before_is_refused(change: dict, problem: str) -> None:
    meta, arrays = _saved("substance")
    model = SubstanceModel.from_saved(meta, arrays, "s.npz")
    assert [w.shape for w in model.weights] == [(8, 3), (3, 1)] and model.out_activation == "logistic"
    with pytest.raises(CalibrationError, match=r"s\.npz: the array " + problem):
        SubstanceModel.from_saved(meta, {**arrays, **change}, "s.npz")


@pytest.mark.parametrize(("change", "problem"), [
    ({"classes": ["honey"]}, "two or more names"),
    ({"classes": ["a", "b", "c"]}, "'out_activation' is 'logistic' for 3 classes"),
    ({"layers": 0}, "'layers' is 0"),
    ({"layers": 3}, "'W2' is missing"),
    ({"out_activation": "relu"}, "'out_activation' is 'relu'"),
])
def test_a_substance_metadata_that_does_not_fit_its_arrays_is_refused(change: dict, problem: str) -> None:
    meta, arrays = _saved("substance")
    with pytest.raises(CalibrationError, match=problem):
        SubstanceModel.from_saved({**meta, **change}, arrays, "s.npz")


@given(st.sampled_from(["zeros", "const", "huge", "nan", "spiky"]), st.integers(8, 200))
def test_stirring_features_are_finite_on_extreme_series(kind: str, n: int) -> None:
    rng = np.random.default_rng(n)
    s = {"zeros": np.zeros((n, 3)), "const": np.full((n, 3), 3.0), "huge": rng.normal(0, 1e12, (n, 3)),
         "nan": np.where(rng.random((n, 3)) < 0.3, np.nan, 1.0), "spiky": (rng.random((n, 3)) > 0.95) * 1e6}[kind]
    f = stirring_features(s, 30.0, window_s=8 / 30)
    assert f.shape == (n // 8, len(STIR_FEATURES)) and np.all(np.isfinite(f))
