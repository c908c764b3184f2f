"""The bench file: one TOML file that says which device is on which port, with what limits.

``bench.toml`` has an optional ``[bench]`` head and one table per device::

    [bench]
    name = "lab bench 1"
    scene = "jig-rotation-sweep"   # mocks only: the world the rigsim:// devices share
    seed = 0

    [gripper]                      # Dynamixel MX-64
    port = "/dev/serial/by-id/usb-FTDI_...-if00-port0"
    baud = 57600
    ids = [1]
    protocol = 2
    current_limit_frac = 0.5
    calibration = "calib/gripper.json"
    latency_timer_ms = 16          # the USB adapter's (FTDI: 16, or 1 after the udev rule)
    retries = 2                    # of a read whose status was lost

    [scale]                        # Arduino HX711 load cell
    port = "rigsim://scale"
    baud = 57600                   # the sketch's rate
    max_force_n = 50.0
    calibration = "calib/scale.json"

    [jig]                          # GRBL x-y-θ stage
    port = "/dev/ttyACM0"
    baud = 115200
    x_limits_mm = [-20.0, 20.0]
    y_limits_mm = [-20.0, 20.0]
    theta_limits_deg = [-180.0, 180.0]

    [camera]                       # any table named camera or camera_<name>
    port = "/dev/video0"           # or "run.mcap#/camera_left/image": a recording as the camera
    sensor = "gelsight"            # gelsight | fingervision
    mm_per_px_x = 0.0634
    mm_per_px_y = 0.0634
    width = 320
    height = 240
    fps = 25.0
    calibration = "calib/gelsight.npz"

Every device table is optional. Relative calibration paths are relative to the bench file.
Errors name the file, the line, and the fix (a typo'd key gets a ``difflib`` suggestion; a port
that does not exist lists the ports that do; a missing calibration names the command that makes
it). Every problem in the file is reported at once, not just the first.

Environment overrides: ``TACTILE_RIG_<DEVICE>__<KEY>=value`` (e.g.
``TACTILE_RIG_SCALE__PORT=/dev/ttyUSB1``, ``TACTILE_RIG_CAMERA_LEFT__MM_PER_PX_X=0.05``) replace a key
after the file is read; the value is parsed as a TOML value when it parses (numbers, arrays,
booleans, quoted strings), else taken as a bare string.

Modules: :mod:`.devices` (one config class per device kind: fields, checks, connect),
:mod:`.load` (TOML, environment overrides, every problem with its line), :mod:`.toml_lines`,
:mod:`.connect` (drivers, mocks on one clock and world). The ``--bench``/``--mock`` arguments are the
CLI's (:mod:`tactile_rig.cli.bench_args`).

Mocks: a port ``rigsim://KIND?key=value`` in a bench is **not** opened on its own clock. On
:func:`connect_bench` every such device is built on ONE :class:`~tactile_rig.core.clock.VirtualClock`
and ONE world (the ``[bench] scene``), registered as ``rigsim://@<bench>.<device>``, and the driver
opens that instance: the devices of a mock bench see the same time and the same world. A port
``rigsim://@NAME`` (an instance a test registered) is used as it is.
"""

from tactile_rig.core.errors import BenchError
from tactile_rig.rig.bench.connect import ConnectContext, Connector, Rig, connect_bench
from tactile_rig.rig.bench.devices import (
    DEVICE_CLASSES,
    SENSOR_TYPES,
    CameraConfig,
    DeviceConfig,
    GripperConfig,
    JigConfig,
    ScaleConfig,
)
from tactile_rig.rig.bench.load import (
    ENV_PREFIX,
    MOCK_BENCH_NAME,
    Bench,
    device_kind,
    load_bench,
    mock_bench_path,
)
from tactile_rig.rig.bench.toml_lines import line_index

__all__ = [
    "DEVICE_CLASSES", "ENV_PREFIX", "MOCK_BENCH_NAME", "SENSOR_TYPES", "Bench", "BenchError", "CameraConfig",
    "ConnectContext", "Connector", "DeviceConfig", "GripperConfig", "JigConfig", "Rig", "ScaleConfig",
    "connect_bench", "device_kind", "line_index", "load_bench", "mock_bench_path",
]
