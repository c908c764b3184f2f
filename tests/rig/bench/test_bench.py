"""bench.toml: typed loading, errors that name the line and the fix, env overrides, connecting."""

from __future__ import annotations

import argparse
import textwrap
from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st

from tactile_rig.cli.bench_args import add_bench_arguments, bench_from_args
from tactile_rig.core.errors import ConnectErrors, NotConnected
from tactile_rig.rig.bench import (
    BenchError,
    CameraConfig,
    GripperConfig,
    JigConfig,
    ScaleConfig,
    connect_bench,
    line_index,
    load_bench,
    mock_bench_path,
)
from tactile_rig.cli import main
from tactile_rig.core.clock import VirtualClock

DOCS = Path(__file__).resolve().parents[3] / "docs"

GOOD = textwrap.dedent("""\
    [bench]
    name = "lab"

    [gripper]
    port = "rigsim://dynamixel?ids=1"
    ids = [1, 2]
    protocol = 1

    [scale]
    port = "rigsim://scale"
    baud = 9600
    max_force_n = 20.0

    [camera_left]
    port = "rigsim://camera"
    sensor = "fingervision"
    mm_per_px_x = 0.05
    mm_per_px_y = 0.06
""")


def _problems(text: str, **kw) -> BenchError:
    with pytest.raises(BenchError) as ei:
        load_bench(text=text, env=kw.pop("env", {}), **kw)
    return ei.value


def test_mock_bench_loads_as_typed_dataclasses() -> None:
    b = load_bench(mock_bench_path(), env={})
    assert b.is_mock
    assert isinstance(b.devices["gripper"], GripperConfig)
    assert isinstance(b.devices["scale"], ScaleConfig)
    assert isinstance(b.devices["jig"], JigConfig)
    assert b.devices["jig"].x_limits_mm == (-20.0, 20.0)
    cam = b.devices["camera"]
    assert isinstance(cam, CameraConfig) and cam.sensor == "gelsight"
    assert b.cameras == {"camera": cam}


def test_good_bench_values_and_camera_prefix() -> None:
    b = load_bench(text=GOOD, env={})
    assert b.name == "lab"
    assert b.devices["gripper"].ids == [1, 2] and b.devices["gripper"].protocol == 1
    assert b.devices["scale"].baud == 9600 and b.devices["scale"].max_force_n == 20.0
    cam = b.devices["camera_left"]
    assert (cam.sensor, cam.mm_per_px_x, cam.mm_per_px_y) == ("fingervision", 0.05, 0.06)
    assert b.devices["scale"].line == 9


def test_typo_key_names_line_and_suggestion() -> None:
    text = GOOD.replace("baud = 9600", "baudrate = 9600")
    err = _problems(text)
    assert "<bench> line 11: unknown key 'baudrate' in [scale]; did you mean 'baud'?" in str(err)


def test_typo_table_is_suggested() -> None:
    err = _problems(GOOD.replace("[scale]", "[scael]"))
    assert "line 9" in str(err) and "did you mean 'scale'?" in str(err)


def test_wrong_port_names_device_port_and_that_it_does_not_exist(tmp_path: Path) -> None:
    text = GOOD.replace('port = "rigsim://scale"', 'port = "/dev/serial/by-id/usb-nothing-here"')
    err = _problems(text)
    msg = str(err)
    assert "line 10" in msg and "scale: port '/dev/serial/by-id/usb-nothing-here'" in msg
    assert "does not exist" in msg
    # a port that exists passes
    dev = tmp_path / "ttyFAKE"
    dev.write_text("")
    assert load_bench(text=text.replace("/dev/serial/by-id/usb-nothing-here", str(dev)), env={})


def test_missing_calibration_names_path_and_command(tmp_path: Path) -> None:
    bench = tmp_path / "bench.toml"
    bench.write_text(GOOD.replace("max_force_n = 20.0", 'max_force_n = 20.0\ncalibration = "cal/scale.json"'))
    with pytest.raises(BenchError) as ei:
        load_bench(bench, env={})
    msg = str(ei.value)
    assert f"{bench} line 13" in msg
    assert str(tmp_path / "cal" / "scale.json") in msg
    assert "tactile-rig calibrate scale" in msg
    (tmp_path / "cal").mkdir()
    (tmp_path / "cal" / "scale.json").write_text("{}")
    assert load_bench(bench, env={}).devices["scale"].calibration == tmp_path / "cal" / "scale.json"


def test_every_problem_is_reported_at_once() -> None:
    text = GOOD.replace("baud = 9600", "baudrate = 9600").replace('"fingervision"', '"gelsigt"').replace(
        "protocol = 1", "protocol = 3")
    err = _problems(text)
    lines = [ln for ln, _ in err.problems]
    assert lines == [7, 11, 16]
    assert "did you mean 'gelsight'?" in str(err)
    assert "must be 1 or 2" in str(err)


def test_wrong_types_and_ranges_name_the_key() -> None:
    err = _problems(GOOD.replace("ids = [1, 2]", 'ids = "one"').replace("mm_per_px_y = 0.06", "mm_per_px_y = 0"))
    msg = str(err)
    assert "line 6: [gripper] ids must be a non-empty list of integers" in msg
    assert "line 18: [camera_left] mm_per_px_y = 0.0 must be in (0, 10) mm/px" in msg


def test_missing_port_and_toml_syntax_error() -> None:
    assert "has no 'port'" in str(_problems("[scale]\nbaud = 9600\n"))
    err = _problems("[scale]\nport = \n")
    assert err.problems[0][0] == 2 and "not valid TOML" in str(err)


def test_env_overrides_replace_keys_and_typos_are_named() -> None:
    env = {"TACTILE_RIG_SCALE__BAUD": "57600", "TACTILE_RIG_CAMERA_LEFT__MM_PER_PX_X": "0.07",
           "TACTILE_RIG_GRIPPER__PORT": "rigsim://dynamixel?ids=3", "UNRELATED": "x"}
    b = load_bench(text=GOOD, env=env)
    assert b.devices["scale"].baud == 57600
    assert b.devices["camera_left"].mm_per_px_x == 0.07
    assert b.devices["gripper"].port == "rigsim://dynamixel?ids=3"
    b = load_bench(text=GOOD, env={"TACTILE_RIG_BENCH__SEED": "7", "TACTILE_RIG_CAMERA_RIGHT__PORT": "rigsim://camera",
                                   "TACTILE_RIG_CAMERA_RIGHT__SENSOR": "fingervision"})
    assert b.seed == 7 and b.devices["camera_right"].sensor == "fingervision"  # a device added from the env
    err = _problems(GOOD, env={"TACTILE_RIG_SCAEL__BAUD": "1"})
    assert "TACTILE_RIG_SCAEL__BAUD" in str(err) and "TACTILE_RIG_SCALE__BAUD" in str(err)
    err = _problems(GOOD, env={"TACTILE_RIG_SCALE__BAUD": "fast"})
    assert "$TACTILE_RIG_SCALE__BAUD" in str(err) and "must be an int" in str(err)


def test_bench_from_args(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    p = argparse.ArgumentParser()
    add_bench_arguments(p)
    assert bench_from_args(p.parse_args(["--mock"])).name == "mock"
    f = tmp_path / "b.toml"
    f.write_text(GOOD)
    assert bench_from_args(p.parse_args(["--bench", str(f)])).name == "lab"
    monkeypatch.delenv("TACTILE_RIG_BENCH", raising=False)
    with pytest.raises(ValueError, match="--bench FILE, --mock"):
        bench_from_args(p.parse_args([]))
    with pytest.raises(SystemExit):
        p.parse_args(["--mock", "--bench", "x"])
    with pytest.raises(BenchError, match="does not exist"):
        bench_from_args(p.parse_args(["--bench", str(tmp_path / "nope.toml")]))


@given(st.dictionaries(st.from_regex(r"[a-z][a-z_]{0,8}", fullmatch=True),
                       st.one_of(st.integers(-5, 5), st.text("ab #=[]\\\"'", max_size=4), st.lists(st.integers(0, 3))),
                       max_size=6),
       st.integers(0, 3))
def test_line_index_finds_every_key(values: dict, blank_lines: int) -> None:
    import json

    lines = ["# head", "[dev]"]
    where = {}
    for k, v in values.items():
        lines += [""] * blank_lines
        if isinstance(v, list):  # a multi-line array must not be mistaken for keys or tables
            lines.append(f"{k} = [")
            where[k] = len(lines)
            lines += [f"  {x}," for x in v] + ["]"]
        else:
            lines.append(f"{k} = {json.dumps(v)}")
            where[k] = len(lines)
    tables, keys = line_index("\n".join(lines) + "\n")
    assert tables == {"dev": 2}
    assert {k: n for (t, k), n in keys.items()} == where


# -- connecting -----------------------------------------------------------------------------
def test_connect_reports_every_failed_device_and_closes_the_others() -> None:
    b = load_bench(text=GOOD, env={})
    closed: list[str] = []

    class Dev:
        def __init__(self, name: str) -> None:
            self.name = name

        def close(self) -> None:
            closed.append(self.name)

    def ok(cfg, ctx):
        return Dev(cfg.name)

    def fail(cfg, ctx):
        raise NotConnected(f"cannot open port {cfg.port!r}", device=cfg.name)

    def boom(cfg, ctx):
        raise OSError("permission denied")

    with pytest.raises(ConnectErrors) as ei:
        connect_bench(b, connectors={"gripper": ok, "scale": fail, "camera": boom})
    errs = ei.value.errors
    assert set(errs) == {"scale", "camera_left"}
    assert "rigsim://scale" in str(errs["scale"]) and isinstance(errs["scale"], NotConnected)
    assert "permission denied" in str(errs["camera_left"]) and "rigsim://camera" in str(errs["camera_left"])
    assert "2 device(s) failed" in str(ei.value)
    assert closed == ["gripper"]


def test_mock_devices_share_one_clock_and_world() -> None:
    """rigsim://KIND?... ports become registered instances on one VirtualClock (and one world)."""
    from tactile_rig.drivers.transport import SerialTransport
    from tactile_rig.mocks.registry import register_kind
    from tactile_rig.mocks.serial_device import SerialDevice

    class Echo(SerialDevice):
        kind = "echo-test"

        def __init__(self, params, *, clock, world):
            super().__init__(baud=params.integer("baud", 9600), timing=False)
            self.world = world

        def on_bytes(self, data: bytes, t_s: float) -> None:
            self.emit(data, t_s)

    register_kind("echo-test", lambda params, *, clock, world: Echo(params, clock=clock, world=world),
                  default_baud=9600, description="test echo")
    text = '[bench]\nname = "t"\n[scale]\nport = "rigsim://echo-test?baud=9600"\n[jig]\nport = "rigsim://echo-test"\n'
    b = load_bench(text=text, env={})

    def connect(cfg, ctx):
        assert cfg.port.startswith("rigsim://@t.")
        return SerialTransport(cfg.port, baudrate=9600, device=cfg.name)

    rig = connect_bench(b, connectors={"scale": connect, "jig": connect})
    try:
        assert rig.scale.clock is rig.jig.clock is rig.clock
        assert rig.clock.is_virtual
        rig.scale.write(b"hi")
        assert rig.scale.read_exact(2, 0.1) == b"hi"
    finally:
        rig.close()
    from tactile_rig.mocks.registry import device_from_url

    with pytest.raises(ValueError, match="no mock instance"):
        device_from_url("rigsim://@t.scale")


def test_unknown_mock_kind_is_a_connect_error_for_that_device() -> None:
    b = load_bench(text='[scale]\nport = "rigsim://nosuchkind"\n', env={})
    with pytest.raises(ConnectErrors) as ei:
        connect_bench(b)
    assert set(ei.value.errors) == {"scale"}
    assert "nosuchkind" in str(ei.value)


def test_builtin_mock_bench_connects_every_driver_on_one_clock() -> None:
    """The drivers of the built-in bench reach their firmware mocks through rigsim://@mock.<device>."""
    rig = connect_bench(load_bench(mock_bench_path(), env={}))
    try:
        assert set(rig.devices) == {"gripper", "scale", "jig", "camera"}
        assert rig.clock.is_virtual
        assert rig.gripper.clock is rig.scale.transport.clock is rig.jig.clock is rig.clock
        t0 = rig.clock.now_s()
        rig.scale.read()
        frame = rig.cameras["camera"].read(timeout_s=1.0)
        assert frame.image.shape == (240, 320, 3)
        assert rig.clock.now_s() > t0  # reading advanced the one shared virtual time
    finally:
        rig.close()
    from tactile_rig.mocks.registry import device_from_url

    with pytest.raises(ValueError, match="no mock instance"):
        device_from_url("rigsim://@mock.scale")  # closing the rig unregisters its mocks


@pytest.mark.parametrize("bad, line, expected", [
    ('x_limits_mm = [-inf, inf]', 7, "x_limits_mm must be [low, high], two finite numbers"),
    ('max_speed_mmps = nan', 7, "max_speed_mmps must be a finite number"),
    ('theta_limits_deg = [-400.0, 90.0]', 7, "must lie within [-360, 360] deg"),
])
def test_non_finite_and_absurd_jig_limits_are_refused_with_their_line(bad: str, line: int, expected: str) -> None:
    text = f'[bench]\nname = "lab"\n\n[jig]\nport = "rigsim://jig"\nbaud = 115200\n{bad}\n'
    err = _problems(text)
    assert f"line {line}:" in str(err) and expected in str(err)


def test_non_finite_force_duplicate_ids_empty_port_and_absurd_frames_are_refused() -> None:
    text = textwrap.dedent("""\
        [gripper]
        port = "rigsim://dynamixel"
        ids = [1, 1]

        [scale]
        port = ""
        max_force_n = inf

        [camera]
        port = "rigsim://camera"
        width = 100000000000
        fourcc = "MJPEG"
    """)
    err = _problems(text)
    msgs = dict((ln, m) for ln, m in err.problems)
    assert "names ID 1 twice" in msgs[3]
    assert "[scale] port is empty" in msgs[6]
    assert "max_force_n must be a finite number" in msgs[7]
    assert "width = 100000000000 must be a frame size in 1..8192 px" in msgs[11]
    assert "fourcc = 'MJPEG' must be four ASCII characters" in msgs[12]


def test_an_environment_override_problem_names_the_variable() -> None:
    err = _problems(GOOD, env={"TACTILE_RIG_SCALE__BAUDRATE": "9600", "TACTILE_RIG_SCALE__MAX_FORCE_N": "inf"})
    text = str(err)
    assert "unknown key 'baudrate' in [scale]; did you mean 'baud'? (from $TACTILE_RIG_SCALE__BAUDRATE)" in text
    assert "[scale] max_force_n (from $TACTILE_RIG_SCALE__MAX_FORCE_N) must be a finite number" in text
    err = _problems(GOOD, env={"TACTILE_RIG_SCALE__": "1"})
    assert "environment variable TACTILE_RIG_SCALE__: no key after '__'" in str(err)


def test_a_new_device_kind_is_one_config_class() -> None:
    """Adding a device to the bench is one DeviceConfig subclass: the loader finds it by kind, types its
    fields from their annotations and runs its own check."""
    from dataclasses import dataclass
    from typing import ClassVar

    from tactile_rig.rig.bench.devices import DEVICE_CLASSES, DeviceConfig

    @dataclass
    class _ThermometerConfig(DeviceConfig):
        baud: int = 9600
        max_temperature_c: float = 100.0
        kind: ClassVar[str] = "thermometer_test"

        def check(self, problem) -> None:
            super().check(problem)
            if self.max_temperature_c > 500:
                problem("max_temperature_c", f"= {self.max_temperature_c} is above the sensor's 500 °C")

    try:
        b = load_bench(text='[thermometer_test]\nport = "rigsim://x"\nmax_temperature_c = 80.0\n', env={})
        assert isinstance(b.devices["thermometer_test"], _ThermometerConfig)
        err = _problems('[thermometer_test]\nport = "rigsim://x"\nmax_temperature_c = 900.0\n')
        assert "line 3: [thermometer_test] max_temperature_c = 900.0 is above the sensor's 500 °C" in str(err)
    finally:
        DEVICE_CLASSES.pop("thermometer_test")


def test_the_scale_runs_at_the_sketchs_57600_baud_everywhere(capsys):
    assert load_bench(mock_bench_path(), check_files=False).devices["scale"].baud == 57600
    rig_md = (DOCS / "rig.md").read_text()
    scale_table = rig_md.split("[scale]", 1)[1].split("[", 1)[0]
    assert "baud = 57600" in scale_table
    # the mock refuses another rate instead of adopting it ...
    assert main(["mock", "serve", "scale", "--baud", "115200"]) == 2
    assert "talks at 57600 baud only" in capsys.readouterr().err
    # ... and a bench that sets one sees what a real scale shows: no valid line at that rate
    b = load_bench(text='[scale]\nport = "rigsim://scale"\nbaud = 115200\n')
    with pytest.raises(ConnectErrors, match="at 115200 baud; check the sketch, the baud rate"):
        connect_bench(b, clock=VirtualClock())
