"""Force map (thesis 3.4.1) and substance classifier (3.4.2) on the mock sessions."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

import mcap  # noqa: E402,F401  (extras [learn,record] are installed by .[all,test]; absent = fail, not skip)
import sklearn  # noqa: E402,F401

from tactile_rig.core.errors import CalibrationError  # noqa: E402
from tactile_rig.rig.learning import (  # noqa: E402
    STIR_FEATURES,
    ForceMapModel,
    SubstanceModel,
    fit_force_map,
    force_map_session,
    substance_session,
)
from tactile_rig.sim.world.stick_press import StickPressScene, increasing_peaks  # noqa: E402


@pytest.fixture(scope="module")
def force_map(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict]:
    out = tmp_path_factory.mktemp("fm")
    return out, force_map_session(out, n_trials=10, max_force_n=20.0, seed=0, figures=False)


def test_force_map_session_reports_holdout_mse(force_map) -> None:
    out, report = force_map
    assert report["holdout_trial"] == 5 and report["n_train"] > 400
    assert report["alpha"] == 0.02
    # the held-out trial is predicted at the scene's noise floor, not merely "somehow"
    assert report["mse_holdout_n2"] < (1.5 * report["scene_noise_rms_n"]) ** 2
    assert (out / "force_map.mcap").is_file()


def test_force_map_predicts_new_trials_within_the_scene_noise(force_map) -> None:
    out, _ = force_map
    model = ForceMapModel.load(out / "force_map")
    scene = StickPressScene()
    within, ratios = [], []
    for k, peak in enumerate([3.5, 9.0, 14.5, 18.0]):
        tr = scene.trials([peak], seed=1000 + k)[0]  # a new trial: unseen gain, squeeze and noise
        err = model.predict(tr.features) - tr.scale_n
        noise = scene.force_noise_n(tr.force_true_n)
        ratios.append(np.sqrt(np.mean(err**2)) / np.sqrt(np.mean(noise**2)))
        within.append(np.mean(np.abs(err) <= 2 * noise))
    assert max(ratios) < 2.0, ratios
    assert np.mean(within) > 0.8, within
    # and it is a real fit: a constant guess is far outside the noise
    tr = scene.trials([15.0], seed=7)[0]
    assert np.sqrt(np.mean((tr.scale_n - tr.scale_n.mean()) ** 2)) > 5 * np.sqrt(np.mean(scene.force_noise_n(tr.force_true_n) ** 2))


def test_force_map_file_is_not_a_pickle_and_matches_sklearn(force_map) -> None:
    from sklearn.kernel_ridge import KernelRidge

    out, _ = force_map
    meta = json.loads((out / "force_map.json").read_text())
    assert meta["format"] == "tactile_rig.force_map" and meta["version"] == 1 and meta["kernel"] == "rbf"
    with np.load(out / "force_map.npz", allow_pickle=False) as z:  # raises if anything needed pickle
        assert set(z.files) == {"center", "scale", "x_fit", "dual_coef", "gamma", "alpha"}
    m = ForceMapModel.load(out / "force_map.npz")
    krr = KernelRidge(alpha=m.alpha, kernel="rbf", gamma=m.gamma)
    krr.X_fit_, krr.dual_coef_ = m.x_fit, m.dual_coef
    x = StickPressScene().trials([10.0], seed=3)[0].features
    assert np.allclose(m.predict(x), krr.predict((x - m.center) / m.scale), atol=1e-9)


def test_force_map_errors() -> None:
    with pytest.raises(ValueError, match=r"\(n, 6\)"):
        fit_force_map(np.zeros((5, 3)), np.zeros(5))
    with pytest.raises(ValueError, match="alpha"):
        fit_force_map(np.zeros((5, 6)), np.zeros(5), alpha=0)
    with pytest.raises(CalibrationError, match="does not exist"):
        ForceMapModel.load("/nonexistent/force_map")
    with pytest.raises(ValueError, match="n_trials"):
        increasing_peaks(1, 10.0)


def test_wrong_model_file_kind_is_named(tmp_path: Path, force_map) -> None:
    out, _ = force_map
    meta = json.loads((out / "force_map.json").read_text())
    meta["format"] = "tactile-rig/substance-classifier"
    (tmp_path / "m.json").write_text(json.dumps(meta))
    with pytest.raises(CalibrationError, match=r"m\.json: the field 'format' is 'tactile-rig/substance-classifier'"
                       r".*expected 'format' 'tactile_rig\.force_map'"):
        ForceMapModel.load(tmp_path / "m.json")


def test_force_map_from_a_truncated_recording(force_map, tmp_path: Path) -> None:
    out, _ = force_map
    data = (out / "force_map.mcap").read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: int(len(data) * 0.8)])  # the session crashed in trial 8 or so
    report = force_map_session(tmp_path / "o", recording=cut, figures=False)
    assert len(report["trials"]) >= 6 and report["mse_holdout_n2"] < 1.0


@pytest.fixture(scope="module")
def substance(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict]:
    out = tmp_path_factory.mktemp("sub")
    return out, substance_session(out, per_substance=12, seed=0, figures=False)


def test_substance_classifier_held_out_accuracy(substance) -> None:
    out, report = substance
    assert report["classes"] == ["empty", "honey", "oil", "water"]
    assert report["n_test_trials"] == 12  # 3 trials per substance, whole trials held out
    assert report["accuracy_holdout"] >= 0.75  # chance is 0.25
    conf = np.array(report["confusion"])
    assert conf.sum() == report["n_test_windows"] and np.trace(conf) / conf.sum() == pytest.approx(
        report["accuracy_holdout"])


def test_substance_numpy_predictor_matches_sklearn(substance) -> None:
    from sklearn.neural_network import MLPClassifier
    from sklearn.preprocessing import RobustScaler

    from tactile_rig.rig.learning import fit_substance

    out, _ = substance
    m = SubstanceModel.load(out / "substance")
    assert m.out_activation == "softmax" and [w.shape[1] for w in m.weights[:-1]] == [10, 10, 10]
    rng = np.random.default_rng(0)
    x = rng.normal(size=(60, len(STIR_FEATURES)))
    y = np.where(x[:, 0] + 0.5 * x[:, 1] > 0, "thick", "thin")
    mine = fit_substance(x, y, seed=3, max_iter=200)
    assert mine.out_activation == "logistic"  # two classes: one logistic output, as sklearn
    scaler = RobustScaler().fit(x)
    ref = MLPClassifier(hidden_layer_sizes=(10, 10, 10), activation="logistic", solver="lbfgs", max_iter=200,
                        random_state=3)
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ref.fit(scaler.transform(x), y)
    xt = rng.normal(size=(20, len(STIR_FEATURES)))
    assert np.allclose(mine.predict_proba(xt), ref.predict_proba(scaler.transform(xt)), atol=1e-9)
    assert mine.predict(xt) == list(ref.predict(scaler.transform(xt)))
    mine.save(out / "two")
    assert SubstanceModel.load(out / "two.json").predict(xt) == mine.predict(xt)


def test_calibrate_cli(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    from tactile_rig.cli import main

    assert main(["calibrate", "force-map", "--mock", "--trials", "6", "--out", str(tmp_path / "fm"),
                 "--json"]) == 0
    r = json.loads(capsys.readouterr().out)
    assert r["mse_holdout_n2"] > 0 and (tmp_path / "fm" / "force_map.md").is_file()
    assert (tmp_path / "fm" / "force_map_holdout.png").is_file()
    assert main(["calibrate", "substance", "--per-substance", "4", "--out", str(tmp_path / "s"),
                 "--no-figures"]) == 0
    assert "held-out accuracy" in capsys.readouterr().out
    with pytest.raises(SystemExit) as info:  # a usage error: one trial leaves none to train on
        main(["calibrate", "force-map", "--trials", "1", "--out", str(tmp_path / "x")])
    assert info.value.code == 2 and "--trials: 1 is outside the allowed range [2, 10000]" in capsys.readouterr().err


def test_calibrate_on_a_hardware_bench_without_the_devices_says_what_is_missing(tmp_path: Path,
                                                                                capsys: pytest.CaptureFixture) -> None:
    from tactile_rig.cli import main
    from tactile_rig.rig.recording import read_recording

    tty = tmp_path / "ttyFAKE"
    tty.write_text("")
    bench = tmp_path / "bench.toml"
    bench.write_text(f'[scale]\nport = "{tty}"\n')
    assert main(["calibrate", "force-map", "--bench", str(bench), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert "has no [gripper]" in err and "--from-recording" in err
    assert main(["calibrate", "force-map", "--mock", "--trials", "3", "--no-figures", "--out",
                 str(tmp_path / "m")]) == 0
    rec = read_recording(tmp_path / "m" / "force_map.mcap")
    assert rec.metadata_json("bench")["name"] == "mock"  # the session recorded its bench
