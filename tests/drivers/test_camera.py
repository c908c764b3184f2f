"""FingertipCamera against the simulated UVC camera, on a virtual clock (no sleeping)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from tactile_rig.core.clock import VirtualClock
from tactile_rig.drivers.camera import (
    PHOTOMETRIC_CONTROLS,
    CameraConfig,
    ControlReadbackError,
    FingertipCamera,
    FrameSource,
    FrozenStream,
    ReopenPolicy,
)
from tactile_rig.core.errors import DeviceTimeout, NotConnected
from tactile_rig.devices.camera import photometric_lock
from tactile_rig.devices.camera_models import DIGIT, GELSIGHT_MINI
from tactile_rig.drivers.reconnect import Reconnect
from tactile_rig.mocks.camera import C310_CONTROLS, SimulatedCamera, UvcControlTable


def scene(t_s: float) -> np.ndarray:
    """Distinct channels (B ramp, G constant, R moving bar) so channel swaps and motion are visible."""
    img = np.zeros((48, 64, 3), np.uint8)
    img[..., 0] = np.linspace(20, 120, 64, dtype=np.uint8)[None, :]
    img[..., 1] = 90
    x = int((t_s * 10) % 64)
    img[:, x:x + 4, 2] = 200
    return img


def make(clock=None, **kw):
    clock = clock or VirtualClock()
    sim = SimulatedCamera(scene, clock=clock, width=64, height=48, fps=30,
                          modes={("MJPG", 64, 48): 30, ("YUYV", 64, 48): 15}, **kw)
    cfg = CameraConfig(width=64, height=48, fps=30)
    policy = Reconnect(clock, initial_s=0.1, factor=2.0, max_s=0.8)
    return clock, sim, FingertipCamera(sim, cfg, clock=clock, reconnect_policy=policy)


def read_through_faults(cam, clock, until_s, timeout_s=0.5):
    """Frames read until ``until_s`` (clock time); while the camera is away the reads fail fast with
    NotConnected and time passes in 50 ms steps."""
    got, away = [], 0
    while clock.now_s() < until_s:
        try:
            got.append(cam.read(timeout_s=timeout_s))
        except NotConnected:
            away += 1
            clock.advance(0.05)
    return got, away


def test_simulated_camera_is_a_frame_source():
    assert isinstance(SimulatedCamera(scene), FrameSource)


def test_open_locks_controls_and_reads_them_back():
    clock, sim, cam = make()
    with cam:
        for name, value in PHOTOMETRIC_CONTROLS.items():
            assert sim.table.get(name) == value
        # Locked: the image brightness does not follow the auto-exposure drift.
        means = [cam.read().image.astype(float)[..., 1].mean() for _ in range(60)]
    assert max(means) - min(means) < 1.0


def test_auto_exposure_drift_is_visible_when_not_locked():
    clock, sim, cam = make()
    cam.config.controls = {}
    with cam:
        means = []
        for _ in range(8):
            means.append(cam.read().image.astype(float)[..., 1].mean())
            clock.advance(0.8)
    assert max(means) - min(means) > 10.0


def test_manual_value_written_before_its_auto_switch_still_sticks():
    clock, sim, cam = make()
    cam.config.controls = {"exposure_time_absolute": 300, "auto_exposure": 1}
    with cam:
        assert sim.table.get("exposure_time_absolute") == 300


def test_manual_control_is_inactive_while_auto_is_on():
    t = UvcControlTable()
    assert t.get("auto_exposure") == 3
    assert not t.set("exposure_time_absolute", 500)
    assert t.get("exposure_time_absolute") == 166
    assert t.set("exposure_auto", 1)  # old kernel name
    assert t.set("exposure_absolute", 500) and t.get("exposure_time_absolute") == 500


@pytest.mark.parametrize("controls, fragment", [
    ({"auto_exposure": 1, "gain": 300}, "gain=300 reads back as 255"),
    ({"auto_exposure": 2}, "auto_exposure=2 was refused"),
    ({"focus_absolute": 10}, "focus_absolute=10 was refused"),
])
def test_readback_failure_is_loud(controls, fragment):
    clock, sim, cam = make()
    cam.config.controls = controls
    with pytest.raises(ControlReadbackError, match=fragment.replace("(", r"\(")):
        cam.open()
    assert not sim.is_open  # a half-configured camera is closed again


def test_firmware_that_ignores_a_control_is_caught():
    clock, sim, cam = make(ignore_controls=("white_balance_temperature",))
    cam.config.controls = {"white_balance_automatic": 0, "white_balance_temperature": 5000}
    with pytest.raises(ControlReadbackError, match="white_balance_temperature=5000 reads back as 4000"):
        cam.open()


def test_format_change_resets_controls_so_driver_sets_format_first():
    clock, sim, cam = make()
    sim.reset_controls_on_format = True  # a camera whose firmware resets its controls on a format change
    with cam:
        assert sim.table.get("auto_exposure") == 1
        sim.set_format("YUYV", 64, 48, 15)  # what a naive "controls, then format" order would do
        assert sim.table.get("auto_exposure") == 3


def test_unsupported_fps_is_refused():
    clock, sim, cam = make()
    cam.config.fourcc, cam.config.fps = "YUYV", 30
    with pytest.raises(ControlReadbackError, match="fps 30"):
        cam.open()


def test_unsupported_size_is_refused():
    clock, sim, cam = make()
    cam.config.width, cam.config.height = 1920, 1080
    with pytest.raises(ControlReadbackError, match="1920x1080 was not accepted"):
        cam.open()


def test_frames_carry_sequence_times_and_measured_fps():
    clock, sim, cam = make()
    with cam:
        frames = [cam.read() for _ in range(40)]
    assert [f.seq for f in frames] == list(range(frames[0].seq, frames[0].seq + 40))
    t_dev = np.array([f.t_device_s for f in frames])
    assert np.all(np.diff(t_dev) > 0)
    assert cam.stats.measured_fps == pytest.approx(30.0, rel=0.02)
    assert not any(f.duplicate for f in frames)


def test_read_returns_the_newest_frame_not_a_backlog():
    clock, sim, cam = make()
    with cam:
        cam.read()
        clock.advance(1.0)
        f = cam.read()
        assert clock.now_s() - (f.t_device_s + sim._t0) <= 1.0 / 30 + 1e-9
        assert cam.stats.dropped >= 25


def test_duplicate_frames_are_flagged():
    clock, sim, cam = make()
    sim.duplicate_every = 4
    with cam:
        frames = [cam.read() for _ in range(20)]
    dups = [f for f in frames if f.duplicate]
    assert 3 <= len(dups) <= 6
    assert cam.stats.duplicates == len(dups)


def test_frozen_stream_raises():
    clock, sim, cam = make()
    cam.config.frozen_after = 5
    with cam:
        sim.freeze(clock.now_s() + 0.2)
        with pytest.raises(FrozenStream, match="identical"):
            for _ in range(30):
                cam.read()


def test_stall_times_out_then_recovers():
    clock, sim, cam = make()
    with cam:
        cam.read()
        t0 = clock.now_s()
        sim.stall(t0, t0 + 1.0)
        with pytest.raises(DeviceTimeout, match="no new frame within 0.3 s"):
            cam.read(timeout_s=0.3)
        assert clock.now_s() == pytest.approx(t0 + 0.3, abs=1e-6)
        f = cam.read(timeout_s=2.0)
        assert f.t_device_s + sim._t0 >= t0 + 1.0


def test_disappearance_fails_fast_then_reopens_and_relocks():
    clock, sim, cam = make()
    with cam:
        cam.read()
        t0 = clock.now_s()
        sim.unplug(t0 + 0.1, t0 + 0.5)
        got, away = read_through_faults(cam, clock, t0 + 1.5)
        assert away >= 1 and cam.stats.disconnects == 1 and cam.stats.reconnects == 1
        assert sim.table.get("auto_exposure") == 1  # power-on values after the replug, locked again
        assert sim.table.get("exposure_dynamic_framerate") == 0  # powers up at 1
        # frames keep coming after the replug, captured after the camera came back
        assert got[-1].t_device_s is not None and got[-1].t_device_s + sim._t0 > t0 + 0.5


def test_while_away_reads_fail_fast_naming_the_port_and_the_next_attempt():
    clock, sim, cam = make()
    with cam:
        cam.read()
        t0 = clock.now_s()
        sim.unplug(t0)  # for good
        with pytest.raises(NotConnected):
            cam.read(timeout_s=10.0)  # the read that finds it gone
        assert clock.now_s() - t0 < 0.1
        with pytest.raises(NotConnected, match=r"port 'simcam' is gone .*next reconnect attempt in 0\.1 s"):
            cam.read(timeout_s=10.0)
        assert clock.now_s() - t0 < 0.1  # fails fast: no waiting for the deadline
        # attempts follow the backoff: 0.1, then 0.2, 0.4, 0.8, 0.8 ... s after each failed one
        for _ in range(40):
            clock.advance(0.1)
            with pytest.raises(NotConnected):
                cam.read(timeout_s=1.0)
        lost_s = cam.reconnect_policy.since_s
        attempts = [lost_s + 0.1, lost_s + 0.3, lost_s + 0.7, lost_s + 1.5, lost_s + 2.3, lost_s + 3.1, lost_s + 3.9]
        assert cam.reconnect_policy.attempts == sum(a <= clock.now_s() + 1e-9 for a in attempts) == 7
        assert cam.stats.reconnects == 0 and cam.stats.disconnects == 1


def test_old_names_of_the_reconnect_policy_still_work_with_a_warning():
    clock = VirtualClock()
    sim = SimulatedCamera(scene, clock=clock, width=64, height=48, fps=30, modes={("MJPG", 64, 48): 30})
    with pytest.warns(DeprecationWarning, match=r"CameraConfig\(reopen=ReopenPolicy\(\.\.\.\)\) is deprecated"):
        cfg = CameraConfig(width=64, height=48, fps=30, reopen=ReopenPolicy(initial_backoff_s=0.3, max_backoff_s=1.0))
    with FingertipCamera(sim, cfg, clock=clock) as cam:
        assert (cam.reconnect_policy.initial_s, cam.reconnect_policy.max_s) == (0.3, 1.0)
        cam.stats.reconnects = 2
        with pytest.warns(DeprecationWarning, match=r"reopens is deprecated: use \.reconnects"):
            assert cam.stats.reopens == 2


def test_a_replugged_camera_that_refuses_its_controls_is_reported_to_the_reader():
    clock, sim, cam = make()
    with cam:
        cam.read()
        sim.ignore_controls = {"gain"}  # the replugged unit's firmware ignores gain
        sim.unplug(clock.now_s(), clock.now_s() + 0.05)
        cam.config.controls = {"auto_exposure": 1, "gain": 10}
        with pytest.raises(NotConnected):
            cam.read()
        clock.advance(0.1)
        with pytest.raises(ControlReadbackError, match="gain=10 reads back as 64"):
            cam.read()  # the reopen: the camera is back and ignores the lock
        assert not sim.is_open  # not left half-configured
        clock.advance(0.05)
        with pytest.raises(ControlReadbackError, match="gain=10"):
            cam.read()  # until the next attempt, the reader is told why it is away
        assert cam.stats.reconnects == 0 and cam.reconnect_policy.away
        sim.ignore_controls = set()  # swapped for a good unit
        clock.advance(1.0)
        assert cam.read().image.shape == (48, 64, 3) and cam.stats.reconnects == 1


def test_rgb_source_is_converted_to_bgr_once():
    clock, sim, cam = make(channel_order="RGB", noise_sigma=0.0)
    sim.auto_drift = False
    cam.config.controls = {}
    with cam:
        f = cam.read()
    expected = scene(f.t_device_s + sim._t0)
    assert np.array_equal(f.image, expected)


def test_read_latest_rejects_stale_frames():
    clock, sim, cam = make()
    with cam:
        cam.read()
        sim.stall(clock.now_s())
        clock.advance(0.5)
        with pytest.raises(DeviceTimeout, match="stale"):
            cam.read_latest(max_age_s=0.1)


def test_camera_config_rejects_bad_values():
    with pytest.raises(ValueError, match="fourcc"):
        CameraConfig(fourcc="MJPEG")
    with pytest.raises(ValueError, match="fps"):
        CameraConfig(fps=0)


@given(st.sampled_from([c.name for c in C310_CONTROLS]),
       st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.integers(-10**6, 10**6)),
       st.booleans())
def test_control_table_invariants(name, value, manual):
    t = UvcControlTable()
    if manual:
        t.set("auto_exposure", 1)
        t.set("white_balance_automatic", 0)
    before = dict(t.values)
    ok = t.set(name, value)
    c = t.controls[name]
    v = t.get(name)
    if not ok:
        assert t.values == before
    if c.kind == "menu":
        assert v in c.menu
    else:
        assert c.minimum <= v <= c.maximum and (v - c.minimum) % c.step == 0
    if c.active_when is not None and not manual:
        assert not ok
    if ok and isinstance(value, int) and c.kind != "menu" and c.minimum <= value <= c.maximum and c.step == 1:
        assert v == value
    assert all(math.isfinite(x) for x in t.values.values())


def test_camera_renders_the_scene_through_the_world():
    from tactile_rig.sim import World

    clock = VirtualClock()
    world = World(clock, seed=0)
    obj = world.build("object", "primitive_object", primitive="sphere", radius_mm=2.0, press_depth_mm=0.0)
    world.build("gelsight", "gelsight_renderer", background="taxim")
    sim = SimulatedCamera("rigsim://camera?model=gelsight", clock=clock, world=world, width=160, height=120,
                          fps=30, noise_sigma=0.0)
    with FingertipCamera(sim, CameraConfig(width=160, height=120, fps=30), clock=clock) as cam:
        free = cam.read().image.astype(int)
        obj.press_depth_mm = 0.8
        pressed = cam.read().image.astype(int)
    d = np.abs(pressed - free).sum(axis=2)
    assert d[50:70, 70:90].mean() > 8 * max(1.0, d[:20, :20].mean())


def test_simulated_camera_url_errors():
    with pytest.raises(ValueError, match="rigsim://"):
        SimulatedCamera("http://camera")
    with pytest.raises(ValueError, match="no world"):
        SimulatedCamera("rigsim://camera?model=gelsight")


def test_driver_accepts_a_device_path_and_overrides():
    from tactile_rig.drivers.camera import OpenCVSource

    cam = FingertipCamera("/dev/v4l/by-id/usb-x-video-index0", width=320, height=240, fps=25)
    assert isinstance(cam.source, OpenCVSource)
    assert (cam.config.width, cam.config.height, cam.config.fps) == (320, 240, 25)
    assert cam.config.controls == PHOTOMETRIC_CONTROLS


@given(st.lists(st.tuples(st.sampled_from(["stall", "unplug", "freeze"]), st.floats(0.0, 3.0), st.floats(0.01, 2.0)),
                max_size=4))
def test_any_fault_schedule_gives_frames_or_typed_errors(faults):
    clock, sim, cam = make()
    cam.config.frozen_after = 6
    cam.open()
    t0 = clock.now_s()
    for kind, start, length in faults:
        getattr(sim, kind)(t0 + start, t0 + start + length)
    last_seq, last_dev = -1, -1.0
    while clock.now_s() < t0 + 6.0:
        before = clock.now_s()
        try:
            f = cam.read(timeout_s=0.5)
        except NotConnected:  # found gone within the read's deadline; while away, fails at once
            assert clock.now_s() - before <= 0.5 + 1e-6
            clock.advance(0.05)
            continue
        except DeviceTimeout:  # includes FrozenStream
            assert clock.now_s() - before <= 0.5 + 1e-6  # the deadline holds
            if clock.now_s() == before:
                clock.advance(0.1)  # a frozen stream raises at once; let time pass
            continue
        assert f.seq > last_seq and f.t_device_s is not None
        if not f.duplicate:
            assert f.t_device_s + sim._t0 > last_dev
        last_seq, last_dev = f.seq, f.t_device_s + sim._t0
    unplugs = sum(1 for k, _, _ in faults if k == "unplug")
    assert cam.stats.disconnects <= unplugs and cam.stats.reconnects == cam.stats.disconnects
    if not unplugs:
        assert cam.stats.disconnects == 0
    # whatever happened, the camera is back and streaming
    assert cam.read(timeout_s=1.0).t_device_s + sim._t0 >= t0 + 5.0


def test_the_lock_adds_the_power_line_frequency_of_the_mains():
    clock, sim, cam = make()
    cam.config.mains_hz = 50
    with cam:
        assert sim.table.get("power_line_frequency") == 1 and cam.readback["power_line_frequency"] == 1
        assert list(cam.config.locked_controls())[:3] == ["auto_exposure", "white_balance_automatic",
                                                          "exposure_dynamic_framerate"]
        assert cam.read_controls(["power_line_frequency", "gain"]) == {"power_line_frequency": 1.0, "gain": 64.0}
    with pytest.raises(ValueError, match="mains_hz=55 must be 50 or 60"):
        CameraConfig(mains_hz=55)


def test_the_lock_of_a_model_holds_the_controls_it_has_at_its_own_defaults():
    assert photometric_lock(GELSIGHT_MINI, 60) == {
        "auto_exposure": 1, "exposure_time_absolute": 157, "white_balance_automatic": 0,
        "white_balance_temperature": 4600, "gain": 0, "exposure_dynamic_framerate": 0, "power_line_frequency": 2}
    assert photometric_lock(DIGIT, 50) == {"zoom_absolute": 0xFFF}  # its LEDs; it has no power line control
    assert photometric_lock(None, 50) == {**PHOTOMETRIC_CONTROLS, "power_line_frequency": 1}
