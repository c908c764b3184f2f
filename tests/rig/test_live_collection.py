"""Guided live collection: the gripper presses a FingerVision fingertip on the scale (force map) and
the operator stirs named substances (substance classifier), on the mock scene and on a scripted rig."""

from __future__ import annotations

import json

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import mcap  # noqa: F401  (extras installed by .[all,test]: absent = fail, not skip)
import sklearn  # noqa: F401

from tactile_rig.core.clock import VirtualClock
from tactile_rig.core.errors import CalibrationError
from tactile_rig.rig.bench import Bench, connect_bench, load_bench, mock_bench_path
from tactile_rig.rig.calibration_sessions import Guide
from tactile_rig.rig.camera_calibrations import CalibratedFingerVision, camera_calibrations
from tactile_rig.rig.jig_accuracy import sim_camera_connector
from tactile_rig.rig.learning import force_trials_from_recording, substance_session
from tactile_rig.rig.live_collection import PressPlan, collect_force_map, collect_stirring, press_profile
from tactile_rig.rig.recording import read_recording
from tactile_rig.sim.render.fingervision import FingerVisionRenderer, contact_shear_field
from tactile_rig.sim.world.stirring import StirringScene


def _press_rig():
    base = load_bench(mock_bench_path(), check_files=False)
    sub = Bench(name="mock", devices={n: base.devices[n] for n in ("gripper", "scale", "camera")},
                source=base.source, text=base.text, scene="force_map_press", seed=0)
    return connect_bench(sub, connectors={"camera": sim_camera_connector("fingervision")}, clock=VirtualClock())


def test_press_profile_and_plan_checks():
    assert [press_profile(t, 1.0, 0.5) for t in (0.0, 0.5, 1.0, 1.4, 2.0, 2.5, 3.0)] == [0, 0.5, 1, 1, 0.5, 0, 0]
    with pytest.raises(ValueError, match="needs >= 2 presses"):
        PressPlan(peaks_n=(5.0,))
    with pytest.raises(ValueError, match="max_effort"):
        PressPlan(max_effort=1.5)


def test_scale_press_model_loads_the_cell_as_the_fingers_squeeze_it():
    from tactile_rig.sim.scenes import load_scene

    world = load_scene("force_map_press", clock=VirtualClock()).world
    fingers, cell, contact = world.get("fingers"), world.get("load_cell"), world.get("contact")
    fingers.position_ticks = fingers.closed_ticks + 0.025 / fingers.m_per_tick  # 5 mm past the platform
    cell.advance_to(1.0)
    contact.advance_to(1.0)
    assert cell.force_n == pytest.approx(4000.0 * 0.005)
    assert contact.normal_force_n == pytest.approx(20.0) and contact.shear_y_n == pytest.approx(5.0)
    fingers.position_ticks = fingers.closed_ticks + 0.05 / fingers.m_per_tick  # clear of the platform
    cell.advance_to(2.0)
    assert cell.force_n == 0.0
    assert fingers.external_force_n(fingers.closed_ticks + 0.025 / fingers.m_per_tick) == pytest.approx(20.0)


@pytest.fixture(scope="module")
def live_map(tmp_path_factory):
    """`calibrate force-map --mock --live`: the guided session on the simulated scene, fitted."""
    from tactile_rig.cli import main

    out = tmp_path_factory.mktemp("fm")
    rc = main(["calibrate", "force-map", "--mock", "--live", "--trials", "3", "--max-force", "12",
               "--no-figures", "--out", str(out), "--json"])
    assert rc == 0
    return out


def test_live_force_map_records_a_session_that_fits(live_map, capsys):
    summary = json.loads((live_map / "force_map.json").read_text())
    assert summary["rmse_holdout_n"] < 1.0
    rec = read_recording(live_map / "force_map.mcap")
    assert rec.metadata_json("session")["live"] is True
    phases = {m.data["phase"] for m in rec.on("/perception/camera")}
    assert phases == {"rest", "probe", "press", "release"}
    assert [m.data["peak_force_n"] for m in rec.on("/command/session")] == [4.0, 8.0, 12.0]
    frames = [m for m in rec.messages if m.topic.endswith("compressed")]
    assert len(frames) > 100 and frames[0].image().shape == (240, 320, 3)
    from mcap.reader import make_reader  # the independent reader opens it as Foxglove would

    with open(live_map / "force_map.mcap", "rb") as fh:
        reader = make_reader(fh)
        counts = {ch.topic: n for ch_id, n in reader.get_summary().statistics.channel_message_counts.items()
                  for ch in [reader.get_summary().channels[ch_id]]}
    assert counts["/scale/force"] > 100 and counts["/camera/image/compressed"] == len(frames)
    trials = force_trials_from_recording(live_map / "force_map.mcap", camera="camera")
    # every trial's top reading is its commanded peak: the probe found the effort per newton
    for tr, peak in zip(trials, (4.0, 8.0, 12.0)):
        assert tr.force_n.max() == pytest.approx(peak, rel=0.1)


def test_the_fitted_map_reads_newtons_that_the_scale_confirms(live_map):
    """A new press on the mock, read by the fingertip through the fitted map, against the scale."""
    rig = _press_rig()
    try:
        cal = camera_calibrations(None, force_map=live_map, defaults=False)
        sensor = CalibratedFingerVision(rig.devices["camera"], cal)
        g, scale = rig.gripper, rig.scale
        g.activate(0.1)
        g.gripper_go(0.06, 0.1, blocking=True)
        scale.tare()
        for _ in range(12):  # the baseline from frames at rest (no stored one here)
            sensor.read(2.0)
        target = 7.0
        errors = []
        for k in range(30):  # ramp to about 7 N over a second, then hold
            g.gripper_go(0.0, min(1.0, (k + 1) / 25) * target / 260.0, blocking=False)
            reading = sensor.read(2.0)
            if k >= 26:
                errors.append(np.linalg.norm(reading.force_n) - scale.poll()[-1].newtons)
        assert scale.force_n() == pytest.approx(target, rel=0.1)
        assert np.max(np.abs(errors)) < 1.0, errors
    finally:
        rig.close()


def test_probe_names_the_limit_when_the_effort_cap_is_too_low(tmp_path, capsys):
    from tactile_rig.cli import main

    rc = main(["calibrate", "force-map", "--mock", "--live", "--trials", "2", "--max-force", "20",
               "--max-effort", "0.02", "--out", str(tmp_path), "--no-figures"])
    err = capsys.readouterr().err
    assert rc == 2 and "raise --max-effort" in err and "effort cap 0.02" in err
    rig = _press_rig()
    try:
        with pytest.raises(CalibrationError, match="short of the top press 20 N"):
            collect_force_map(rig, tmp_path / "x.mcap", camera="camera",
                              plan=PressPlan(peaks_n=(10.0, 20.0), max_effort=0.02, probe_s=0.5))
    finally:
        rig.close()


# -- substance: a scripted operator stirs what the session asks for ---------------------------------
class _StirCamera:
    """FingerVision frames whose marker shear follows a simulated stirring trial of the current substance."""

    name = "fv"

    def __init__(self, clock: VirtualClock) -> None:
        self.clock = clock
        self.renderer = FingerVisionRenderer((240, 320), seed=5)
        self.scene = StirringScene()
        self.rng = np.random.default_rng(0)
        self.series: np.ndarray | None = None
        self.i = 0

    def stir(self, label: str) -> None:
        self.series, self.i = self.scene.trial(label, self.rng).series, 0

    def read(self, timeout_s: float = 1.0) -> np.ndarray:
        self.clock.advance(1 / 30)
        if self.series is None:
            return self.renderer.render(None)[0]
        fx, fy, _ = self.series[self.i % len(self.series)]
        self.i += 1
        field = lambda p: contact_shear_field(p, (159.5, 119.5), shift_px=(fx, fy), radius_px=120)  # noqa: E731
        return self.renderer.render(field, normal_load=0.2)[0]


class _Operator(Guide):
    def __init__(self, camera: _StirCamera) -> None:
        super().__init__(False, quiet=True)
        self.camera = camera

    def step(self, text: str) -> None:
        if " in " in text:
            self.camera.stir(text.split(" in ")[1].split(" and ")[0])


def test_live_stirring_records_labelled_trials_and_fits(tmp_path):
    from tactile_rig.rig.bench import Rig

    clock = VirtualClock()
    cam = _StirCamera(clock)
    rig = Rig(bench=Bench(name="scripted", devices={}, source="<test>"), devices={"fv": cam}, clock=clock)
    names = ["water", "honey"]

    def collect(path):
        return collect_stirring(rig, path, camera="fv", substances=names, per_substance=3, trial_s=4.0,
                                guide=_Operator(cam), record_frames=False)

    report = substance_session(tmp_path, per_substance=3, collect=collect, figures=False, test_fraction=0.34)
    rec = read_recording(report["recording"])
    starts = rec.on("/command/session")
    assert [m.data["label"] for m in starts] == names * 3
    assert report["n_train_trials"] == 4 and report["n_test_trials"] == 2
    assert sorted(report["classes"]) == sorted(names)
    assert report["accuracy_holdout"] >= 0.75  # water and honey differ by three orders of viscosity
    with pytest.raises(ValueError, match="at least two different substances"):
        collect_stirring(rig, tmp_path / "y.mcap", camera="fv", substances=["water", "water"])


def test_live_collection_starts_from_the_stored_baseline_and_attaches_it(tmp_path):
    from tactile_rig.rig.calibration_sessions import fingervision_session

    rig = _press_rig()
    try:
        fingervision_session(rig.devices["camera"], tmp_path / "fv", frames=5)
        cal = camera_calibrations(None, calibration=tmp_path / "fv.json", defaults=False)
        plan = PressPlan(peaks_n=(3.0, 6.0), ramp_s=0.4, hold_s=0.2, gap_s=0.2, rest_frames=4)
        collect_force_map(rig, tmp_path / "s.mcap", camera="camera", plan=plan, calibrations=cal, record_frames=False)
    finally:
        rig.close()
    rec = read_recording(tmp_path / "s.mcap")
    rest = [m for m in rec.on("/perception/camera") if m.data["phase"] == "rest"]
    assert len(rest) == 4 and all(np.linalg.norm(m.data["force_px"]) < 0.3 for m in rest)  # tracked from frame 1
    assert {"calibration/fingervision/fv.json", "calibration/fingervision/fv.npz"} <= set(rec.attachments)
    assert not [m for m in rec.messages if "image" in m.topic]  # record_frames=False


@settings(max_examples=30, deadline=None)
@given(st.floats(0.0, 0.15), st.floats(2.0, 20.0))
def test_scale_lag_is_found_from_the_pairing_itself(lag, peak):
    """A scale that reports a press ``lag`` s late (its moving average, the line's arrival) is paired
    with the frames ``lag`` later: the estimate lands within one 5 ms step."""
    from tactile_rig.rig.learning import scale_lag_s

    t_cam = np.arange(0.0, 6.0, 1 / 25)
    press = lambda t: peak * np.array([press_profile(float(x % 3.0), 1.0, 0.5) for x in np.atleast_1d(t)])  # noqa: E731
    force_px = np.column_stack([0.02 * press(t_cam), 0.3 * press(t_cam), np.full(t_cam.size, 1.0)])
    t_scale = np.arange(0.0, 6.2, 1 / 80)
    f_scale = press(t_scale - lag)
    assert scale_lag_s(t_cam, force_px, t_scale, f_scale) == pytest.approx(lag, abs=0.0051)
