"""Every versioned file tactile-rig 0.2.0 wrote still loads, and today's writers use one envelope.

The files in ``tests/data/file_formats`` were written by 0.2.0's own writers (see its PROVENANCE.md):
the force map and the substance classifier carry the id spelled ``tactile-rig/...``, the others
``tactile_rig....``. Each is read here through the readers a user calls (the plain ``load`` of the
perception classes and the checked loaders of the rig); each is then written again and must carry the
one spelling, and read back the same.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from tactile_rig.core.errors import BadFile, CalibrationError, RunConflict
from tactile_rig.perception.gelsight import GelSightCalibration, TactileMap
from tactile_rig.rig.calibration_sessions import read_calibration, write_calibration
from tactile_rig.rig.jig_accuracy import JigAccuracyConfig, RunStore
from tactile_rig.rig.learning import ForceMapModel, SubstanceModel, load_force_map, load_substance_model
from tactile_rig.rig.loaders import load_gelsight_calibration, load_tactile_map
from tests._data import test_data

FILES = test_data("file_formats")


def _copy(tmp_path: Path, *names: str) -> Path:
    for n in names:
        shutil.copy(FILES / n, tmp_path / n)
    return tmp_path


@pytest.mark.parametrize("model", ["lut", "mlp"])
def test_a_gelsight_calibration_as_written_loads_and_is_written_back_the_same(tmp_path: Path, model: str) -> None:
    base = FILES / f"gelsight_calibration_{model}"
    plain, checked = GelSightCalibration.load(base), load_gelsight_calibration(base)
    frame = np.clip(plain.background.astype(int) + 9, 0, 255).astype(np.uint8)
    for a, b in zip(plain.gradients(frame), checked.gradients(frame)):
        np.testing.assert_array_equal(a, b)
    plain.save(tmp_path / "again")
    assert (tmp_path / "again.json").read_text() == (base.with_suffix(".json")).read_text()
    for a, b in zip(GelSightCalibration.load(tmp_path / "again").gradients(frame), plain.gradients(frame)):
        np.testing.assert_array_equal(a, b)


def test_a_tactile_map_as_written_loads_and_is_written_back_with_the_same_metadata(tmp_path: Path) -> None:
    plain, checked = TactileMap.load(FILES / "tactile_map.npz"), load_tactile_map(FILES / "tactile_map.npz")
    np.testing.assert_array_equal(plain.height_mm, checked.height_mm)
    assert len(plain.poses) == 1 and plain.mm_per_px == 0.1
    plain.save(tmp_path / "again.npz")
    with np.load(FILES / "tactile_map.npz") as old, np.load(tmp_path / "again.npz") as new:
        assert str(new["meta"]) == str(old["meta"])
        np.testing.assert_array_equal(new["total"], old["total"])


def test_a_scale_calibration_as_written_loads_and_is_written_with_the_same_envelope(tmp_path: Path) -> None:
    values = read_calibration(FILES / "scale_calibration.json", "scale")
    assert values == {"cal_factor_counts_per_g": 700.5, "known_mass_g": 200.0}
    path, _ = write_calibration(tmp_path / "scale.json", "scale", values, {"verify_error_g": 0.01}, device="scale@x")
    old, new = json.loads((FILES / "scale_calibration.json").read_text()), json.loads(path.read_text())
    assert list(new)[:2] == ["format", "version"] and (new["format"], new["version"]) == (old["format"], 1)
    assert {k: v for k, v in new.items() if k != "created"} == {k: v for k, v in old.items() if k != "created"}


@pytest.mark.parametrize(("stem", "cls", "checked_load", "old_id", "new_id"), [
    ("force_map", ForceMapModel, load_force_map, "tactile-rig/force-map", "tactile_rig.force_map"),
    ("substance", SubstanceModel, load_substance_model, "tactile-rig/substance-classifier",
     "tactile_rig.substance_classifier"),
])
def test_a_learned_model_in_the_other_spelling_loads_and_is_written_in_the_one_spelling(
        tmp_path: Path, stem: str, cls: type, checked_load, old_id: str, new_id: str) -> None:
    assert json.loads((FILES / f"{stem}.json").read_text())["format"] == old_id
    plain, checked = cls.load(FILES / stem), checked_load(FILES / f"{stem}.json")
    rng = np.random.default_rng(1)
    x = rng.normal(0, 1, (7, len(plain.feature_names)))
    assert np.array_equal(np.asarray(plain.predict(x)), np.asarray(checked.predict(x)))
    plain.save(tmp_path / stem)
    meta = json.loads((tmp_path / f"{stem}.json").read_text())
    assert meta["format"] == new_id and meta["version"] == 1 and list(meta)[:2] == ["format", "version"]
    assert np.array_equal(np.asarray(cls.load(tmp_path / stem).predict(x)), np.asarray(plain.predict(x)))


def test_a_jig_accuracy_run_as_written_is_resumed(tmp_path: Path) -> None:
    out = _copy(tmp_path, "jig_accuracy_run.json")
    (out / "jig_accuracy_run.json").rename(out / "run.json")
    store = RunStore(out)
    assert store.begin(JigAccuracyConfig(), bench={"kind": "mock"}, resume=True, overwrite=False) == []
    meta = json.loads((out / "run.json").read_text())
    assert (meta["format"], meta["version"], meta["attempts"]) == ("tactile_rig.jig_accuracy.run", 1, 2)


def test_a_run_folder_of_another_format_is_refused_naming_the_field(tmp_path: Path) -> None:
    meta = json.loads((FILES / "jig_accuracy_run.json").read_text())
    (tmp_path / "run.json").write_text(json.dumps({**meta, "version": 7}))
    with pytest.raises(RunConflict, match=r"run\.json: the field 'version' is 7.*--overwrite"):
        RunStore(tmp_path).begin(JigAccuracyConfig(), bench={"kind": "mock"}, resume=None, overwrite=False)


@pytest.mark.parametrize("field", ["format", "version"])
def test_each_reader_names_the_file_and_the_field_of_a_foreign_envelope(tmp_path: Path, field: str) -> None:
    bad = {"format": "tactile_rig.other", "version": 9}[field]
    out = _copy(tmp_path, "gelsight_calibration_lut.json", "gelsight_calibration_lut.npz", "force_map.json",
                "force_map.npz", "scale_calibration.json")
    for name in ("gelsight_calibration_lut.json", "force_map.json", "scale_calibration.json"):
        doc = json.loads((out / name).read_text())
        doc[field] = bad
        (out / name).write_text(json.dumps(doc))
    needle = rf"the field '{field}' is {bad!r}"
    with pytest.raises(BadFile, match=needle) as info:
        load_gelsight_calibration(out / "gelsight_calibration_lut")
    assert info.value.path == str(out / "gelsight_calibration_lut.json")
    with pytest.raises(CalibrationError, match=needle):
        GelSightCalibration.load(out / "gelsight_calibration_lut")
    with pytest.raises(CalibrationError, match=needle + r".*calibrate force-map"):
        load_force_map(out / "force_map")
    with pytest.raises(CalibrationError, match=needle):
        read_calibration(out / "scale_calibration.json", "scale")
    with np.load(FILES / "tactile_map.npz") as z:
        arrays = {k: z[k] for k in z.files}
    meta = json.loads(str(arrays["meta"]))
    meta[field] = bad
    np.savez(out / "map.npz", **{**arrays, "meta": np.array(json.dumps(meta))})
    for load in (TactileMap.load, load_tactile_map):
        with pytest.raises(BadFile, match=needle) as info:
            load(out / "map.npz")
        assert info.value.path == str(out / "map.npz")
