"""The rehearsal bench: every device in its own process, a bench file naming them, one object to stop it.

    with RehearsalBench("rehearsal") as rb:          # or: tactile-rig bench rehearse --out rehearsal
        bench = load_bench(rb.bench_path)            # the --bench path, exactly as on hardware

Devices (each its own process, real time):

* ``gripper``: the MX-64 mock on a pty (``tactile-rig mock serve dynamixel``), Protocol 2.0, ID 1, 57600 baud;
* ``scale``: the HX711 sketch's mock on a pty (``tactile-rig mock serve scale``), 57600 baud, 80 samples/s;
* ``jig`` + ``camera_gelsight``: the GRBL mock on a pty and the GelSight camera rendering the object on
  its stage (:mod:`.child` ``stage``: one process, one world);
* ``camera_<name>`` for each recorded footage given (``cameras={"fingervision": "run.mcap#/camera_x/image/compressed"}``):
  the footage played at its recorded rate (:mod:`.child` ``camera``); the source ``"rendered"`` is a
  FingerVision video the rehearsal writes first to ``OUT/footage/<name>.avi``.

Every camera is a UVC camera model (a Logitech C310 unless ``camera_models`` names another), served
by default as an emulated V4L2 device (``camera_transport="v4l2"``): the bench file names
``/dev/videoN`` and, in ``[bench]``, the emulation's registry and preload library, which a process
opening the cameras needs in its environment when it starts (:attr:`RehearsalBench.env`; the
``tactile-rig`` command loads it by itself). ``camera_transport="http"`` serves them as MJPEG over
HTTP instead, which any process reads.

The serial devices are named in the bench file through links in ``OUT/dev/`` (``OUT/dev/gripper`` →
``/dev/pts/N``), as a lab names USB adapters through ``/dev/serial/by-path`` links; each process's
stderr is ``OUT/logs/<device>.log``. A GelSight
calibration made on the mocks (the ball-press session) is written to ``OUT/calib/gelsight.json`` and
named by the camera, so ``run jig-accuracy --bench`` runs at once. With ``press``, a force map or a
marker baseline made earlier in ``OUT/calib/`` (``force_map/``, ``fingervision.json``) is named by
``camera_fingervision`` on the next start.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import socket
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

from tactile_rig.devices.camera_models import camera_model
from tactile_rig.mocks.v4l2 import PreloadUnavailable, preload_env
from tactile_rig.mocks.v4l2 import build as v4l2_build
from tactile_rig.mocks.v4l2.server import FIRST_NODE, MAX_SOCKET_PATH
from tactile_rig.rig.jig_accuracy import mock_gelsight_calibration
from tactile_rig.rig.rehearsal.cameras import (DEFAULT_MODEL, DEFAULT_TRANSPORT, FOURCCS, TRANSPORTS,
                                               check_mode)
from tactile_rig.rig.rehearsal.child import CAMERA_SIZE, STAGE_SCENE
from tactile_rig.rig.rehearsal.bench_file import RehearsalDevice, bench_toml, link_device
from tactile_rig.rig.rehearsal.frames import write_fingervision_footage
from tactile_rig.rig.rehearsal.processes import DeviceProcess, child_argv, mock_serve_argv

BENCH_FILE = "bench.toml"
STATE_FILE = "rehearsal.json"
SENSORS = ("gelsight", "fingervision")
SYNTHETIC_FOOTAGE = "rendered"  # --camera NAME=rendered: a FingerVision video the rehearsal renders
REGISTRY_DIR = "v4l2"  # OUT/v4l2: the emulated cameras' registry, when its socket paths fit
# The bench file's [bench] keys naming the emulation (read by tactile_rig.cli.emulation and the loader).
REGISTRY_KEY, PRELOAD_KEY = "v4l2_registry", "v4l2_preload"


@dataclass
class RehearsalOptions:
    """What the rehearsal serves. ``cameras`` maps a camera name to footage (a video or
    ``FILE.mcap[#TOPIC]``) and ``camera_sensors`` a camera name to its sensor (default fingervision);
    ``homing`` enables GRBL homing (the jig boots locked and ``$H`` takes ~20 s, as on a real jig);
    ``calibration`` makes the GelSight calibration when it is missing; ``gelsight_fourcc`` the pixel
    format the bench asks of the GelSight camera (``MJPG``, as a GelSight Mini streams, or ``YUYV``:
    uncompressed, V4L2 only) and ``gelsight_jpeg_quality`` the camera's JPEG quality for MJPG;
    ``camera_transport`` is ``"v4l2"`` (emulated V4L2 devices, default) or ``"http"`` (MJPEG over
    HTTP); ``camera_models`` maps a camera name (``gelsight``, ``fingervision``, a footage name) to its
    camera model (default ``c310``: every mode the rehearsal uses is one a C310 offers); ``stage_scene`` is what lies
    on the jig's stage (``jig_accuracy``: the object of the accuracy run; ``gelsight_ball_presses``:
    the calibration ball); ``press`` serves the gripper, the scale and a FingerVision camera
    (``camera_fingervision``) from one process and one world, the fingertip pressed on the scale by
    the gripper (:mod:`.child` ``press``: what a force-map collection needs)."""

    cameras: Mapping[str, str] = field(default_factory=dict)
    camera_sensors: Mapping[str, str] = field(default_factory=dict)
    seed: int = 0
    homing: bool = False
    gelsight_fps: float = 25.0
    calibration: bool = True
    scale_rate_sps: int = 80
    gelsight_jpeg_quality: int = 95
    stage_scene: str = STAGE_SCENE
    press: bool = False
    camera_transport: str = DEFAULT_TRANSPORT
    gelsight_fourcc: str = "MJPG"
    camera_models: Mapping[str, str] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.camera_transport not in TRANSPORTS:
            raise ValueError(f"camera_transport={self.camera_transport!r} must be one of {', '.join(TRANSPORTS)}")
        if self.gelsight_fourcc not in FOURCCS:
            raise ValueError(f"gelsight_fourcc={self.gelsight_fourcc!r} must be one of {', '.join(FOURCCS)}")
        if self.camera_transport == "http" and self.gelsight_fourcc != "MJPG":
            raise ValueError(f"gelsight_fourcc={self.gelsight_fourcc!r}: the HTTP cameras stream MJPG only "
                             "(YUYV needs camera_transport='v4l2')")
        names = {"gelsight", *self.cameras, *(["fingervision"] if self.press else [])}
        for name, key in self.camera_models.items():
            if name not in names:
                raise ValueError(f"camera_models names {name!r}, which is not a camera of this rehearsal "
                                 f"({', '.join(sorted(names))})")
            camera_model(key)  # ValueError naming the known models
        for name, sensor in self.camera_sensors.items():
            if sensor not in SENSORS:
                raise ValueError(f"camera {name!r}: sensor {sensor!r} must be one of {', '.join(SENSORS)}")
        if self.press and "fingervision" in self.cameras:
            raise ValueError("camera name 'fingervision' is the pressed fingertip's camera with press=True")
        for name in self.cameras:
            if not name.replace("_", "").isalnum() or name == "gelsight":
                raise ValueError(f"camera name {name!r} must be letters, digits and _ (and not 'gelsight', "
                                 "the stage's camera)")
        if not 0 < self.gelsight_fps <= 60:
            raise ValueError(f"gelsight_fps={self.gelsight_fps!r} must be in (0, 60] frames per second")
        check_mode(camera_model(self.model("gelsight")), self.gelsight_fourcc, *CAMERA_SIZE, self.gelsight_fps,
                   what="the GelSight camera (gelsight_fps, gelsight_fourcc)")
        if not 1 <= self.gelsight_jpeg_quality <= 100:
            raise ValueError(f"gelsight_jpeg_quality={self.gelsight_jpeg_quality!r} must be in 1..100")
        if self.scale_rate_sps not in (10, 80):
            raise ValueError(f"scale_rate_sps={self.scale_rate_sps!r} must be 10 or 80 (the HX711 RATE pin)")

    def model(self, camera: str) -> str:
        """The camera model key of rehearsal camera ``camera`` (``gelsight``, ``fingervision``, a footage name)."""
        return self.camera_models.get(camera, DEFAULT_MODEL)


class RehearsalBench:
    """Start with :meth:`start` (or ``with``); :attr:`bench_path` is the bench file; :meth:`stop` ends
    every process. ``out`` holds the bench file, the device links, the calibration, a state file and
    (when its socket paths fit, else a short folder in the temporary directory) the emulated
    cameras' registry (:attr:`registry`). :attr:`env` is what a process opening the cameras needs."""

    def __init__(self, out: str | Path, options: RehearsalOptions | None = None) -> None:
        self.out = Path(out)
        self.options = options or RehearsalOptions()
        self.processes: dict[str, DeviceProcess] = {}
        self.devices: list[RehearsalDevice] = []
        self.bench_path = self.out / BENCH_FILE
        self.registry: Path | None = None
        self.library: Path | None = None

    @property
    def env(self) -> dict[str, str]:
        """The environment (``LD_PRELOAD``, ``TACTILE_RIG_V4L2_DIR``) a process must be started with to
        open the emulated cameras; empty with HTTP cameras."""
        if self.registry is None or self.library is None:
            return {}
        return preload_env(self.library, self.registry)

    def start(self) -> "RehearsalBench":
        """Start every device process (in parallel), wait for their ports, write the bench file.

        On Linux the device processes end when the thread that started them ends (they must not
        outlive a killed rehearsal): call this from a thread that lives as long as the rehearsal."""
        o = self.options
        self.out.mkdir(parents=True, exist_ok=True)
        cal = self.out / "calib" / "gelsight.json"
        cameras = ["gelsight", *(["fingervision"] if o.press else []), *o.cameras]
        nodes = self._prepare_cameras(cameras)

        def camera_opts(name: str, fourcc: str = "MJPG", quality: int = 95) -> list[str]:
            opts = ["--transport", o.camera_transport, "--model", o.model(name), "--fourcc", fourcc,
                    "--jpeg-quality", str(quality), "--seed", str(o.seed)]
            if self.registry is not None:
                node, serial = nodes[name]
                opts += ["--registry", str(self.registry), "--node", str(node), "--serial", serial]
            return opts

        stage_opts = ["--scene", o.stage_scene, "--fps", repr(float(o.gelsight_fps)),
                      *camera_opts("gelsight", o.gelsight_fourcc, o.gelsight_jpeg_quality)] + \
            (["--homing"] if o.homing else [])
        procs: dict[str, DeviceProcess] = {}
        if o.press:
            procs["press"] = DeviceProcess("press", child_argv("press", ["--rate", str(o.scale_rate_sps),
                                                                          *camera_opts("fingervision")]))
        else:
            procs["gripper"] = DeviceProcess("gripper", mock_serve_argv(
                "dynamixel", ["--protocol", "2", "--id", "1", "--baud", "57600"]))
            procs["scale"] = DeviceProcess("scale", mock_serve_argv(
                "scale", ["--rate", str(o.scale_rate_sps), "--seed", str(o.seed)]))
        procs["stage"] = DeviceProcess("jig", child_argv("stage", stage_opts))
        for name, source in o.cameras.items():
            if source == SYNTHETIC_FOOTAGE:
                source = str(write_fingervision_footage(self.out / "footage" / f"{name}.avi", seed=o.seed))
            procs[f"camera_{name}"] = DeviceProcess(f"camera_{name}", child_argv(
                "camera", ["--source", str(source), "--name", name, *camera_opts(name)]))
        self.processes = procs
        try:
            for p in procs.values():
                p.start(self.out / "logs")
            if o.calibration and not cal.is_file():
                mock_gelsight_calibration(cal.with_suffix(""), seed=o.seed)  # while the processes boot
            for p in procs.values():
                p.wait_ready()
            self._write(cal if cal.is_file() else None)
        except BaseException:
            self.stop()
            raise
        return self

    def _prepare_cameras(self, cameras: list[str]) -> dict[str, tuple[int, str]]:
        """For V4L2 cameras: build the preload library, make a fresh registry and number the nodes
        (from 42 up, skipping nodes this machine has). Returns camera name -> (node number, USB
        serial number): the first camera of a model has the model's serial, the others one ending in
        their node number, so each has its own ``/dev/v4l/by-id`` link, the same on every start."""
        if self.options.camera_transport != "v4l2":
            self.registry = self.library = None
            return {}
        try:
            self.library = v4l2_build.build()
        except PreloadUnavailable as exc:
            raise PreloadUnavailable(f"{exc}; or rehearse with the cameras over HTTP (--camera-transport http)",
                                     device="rehearsal cameras") from None
        self.registry = _registry_for(self.out)
        _fresh_registry(self.registry)
        free = (n for n in range(FIRST_NODE, FIRST_NODE + 1000) if not os.path.exists(f"/dev/video{n}"))
        out: dict[str, tuple[int, str]] = {}
        for name in cameras:
            node, model = next(free), camera_model(self.options.model(name))
            first = all(self.options.model(other) != model.key for other in out)
            out[name] = (node, model.serial if first else f"{model.serial[:-3]}{node % 1000:03d}")
        return out

    def _camera_keys(self, info: dict[str, Any], sensor: str) -> dict[str, Any]:
        return {"port": info["port"], "sensor": sensor, "model": info["model"], "width": info["width"],
                "height": info["height"], "fps": float(info["fps"]), "fourcc": info["fourcc"]}

    @staticmethod
    def _camera_comment(info: dict[str, Any], what: str, pid: int | None) -> str:
        if info.get("transport") == "v4l2":
            how = f"emulated {camera_model(info['model']).title} ({info['by_id']})"
        else:
            how = f"{camera_model(info['model']).title} as MJPEG over HTTP"
        return f"{what}: {how}, pid {pid}"

    def _write(self, calibration: Path | None) -> None:
        o, links = self.options, self.out / "dev"
        st = self.processes["stage"].info
        pids = {k: p.pid for k, p in self.processes.items()}
        if o.press:
            press = self.processes["press"].info
            g, s = press["gripper"], press["scale"]
            pids["gripper"] = pids["scale"] = pids["press"]
        else:
            g, s = self.processes["gripper"].info, self.processes["scale"].info
        self.devices = [
            RehearsalDevice("gripper", {"port": str(link_device(links, "gripper", g["port"])), "baud": 57600,
                                        "ids": [1], "protocol": 2, "current_limit_frac": 0.5},
                            f"MX-64 mock, pid {pids['gripper']}, {g['port']}"),
            RehearsalDevice("scale", {"port": str(link_device(links, "scale", s["port"])), "baud": 57600,
                                      "rate_hz": float(o.scale_rate_sps)},
                            f"HX711 sketch mock, pid {pids['scale']}, {s['port']}"),
            RehearsalDevice("jig", {"port": str(link_device(links, "jig", st["port"])), "baud": 115200,
                                    "x_limits_mm": [-20.0, 20.0], "y_limits_mm": [-20.0, 20.0],
                                    "theta_limits_deg": [-90.0, 90.0]},
                            f"GRBL 1.1h mock, pid {pids['stage']}, {st['port']}"),
        ]
        cam = st["camera"]
        keys = self._camera_keys(cam, "gelsight")
        keys.update({"mm_per_px_x": 0.0634, "mm_per_px_y": 0.0634})
        if calibration is not None:
            keys["calibration"] = os.path.relpath(calibration, self.out)
        self.devices.append(RehearsalDevice("camera_gelsight", keys, self._camera_comment(
            cam, "GelSight rendering the jig's stage", pids["stage"])))
        if o.press:
            c = self.processes["press"].info["camera"]
            keys = self._camera_keys(c, "fingervision")
            # What earlier sessions on this rehearsal made, named as a lab's bench names them.
            if (self.out / "calib" / "fingervision.json").is_file():
                keys["calibration"] = "calib/fingervision.json"
            if any((self.out / "calib" / "force_map").glob("force_map*.json")):
                keys["force_map"] = "calib/force_map"
            self.devices.append(RehearsalDevice("camera_fingervision", keys, self._camera_comment(
                c, "FingerVision fingertip pressed on the scale by the gripper", pids["press"])))
        for name in o.cameras:
            c = self.processes[f"camera_{name}"].info
            fp = c["footage"]
            self.devices.append(RehearsalDevice(
                f"camera_{name}", self._camera_keys(c, o.camera_sensors.get(name, "fingervision")),
                self._camera_comment(c, f"footage {c['source']} ({c['frames']} frames, {fp['width']}x{fp['height']} "
                                        f"at {fp['fps']:g} fps)", pids[f"camera_{name}"])))
        for dev in self.devices:
            pid = pids.get(dev.table if dev.table in pids else _PROCESS_OF.get(dev.table, dev.table))
            dev.pids = [pid] if pid is not None else []
        head: dict[str, Any] = {}
        header = ("The rehearsal bench (tactile-rig bench rehearse): every device is a mock in its own\n"
                  "process; valid while that command runs. Ports are links in dev/ (as /dev/serial/by-path).")
        if self.registry is not None and self.library is not None:
            head = {REGISTRY_KEY: _relative(self.registry, self.out), PRELOAD_KEY: str(self.library)}
            header += ("\nThe cameras are emulated V4L2 devices: a process opens them when started with\n"
                       f"LD_PRELOAD set to {PRELOAD_KEY} and TACTILE_RIG_V4L2_DIR to {REGISTRY_KEY} below\n"
                       "(tactile-rig does so by itself; 'tactile-rig bench env' prints them for other programs).")
        self.bench_path.write_text(bench_toml("rehearsal", self.devices, header=header, head=head),
                                   encoding="utf-8")
        (self.out / STATE_FILE).write_text(json.dumps(self.describe(), indent=2) + "\n", encoding="utf-8")

    def describe(self) -> dict[str, Any]:
        """The bench file, the environment its cameras need, and each device process's pid and what it printed."""
        return {"bench": str(self.bench_path), "env": self.env,
                "processes": {k: {"pid": p.pid, **p.info} for k, p in self.processes.items()}}

    def problems(self) -> list[str]:
        """Device processes that have exited (a rehearsal with any is broken)."""
        return [f"{k} (pid {p.pid}) exited with {p.proc.returncode if p.proc else None}"
                for k, p in self.processes.items() if not p.running]

    def stop(self) -> None:
        """Stop every device process (idempotent)."""
        for p in self.processes.values():
            p.stop()

    def __enter__(self) -> "RehearsalBench":
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()


_PROCESS_OF = {"jig": "stage", "camera_gelsight": "stage", "camera_fingervision": "press"}  # else its own name
_NODE_SUFFIX = "/root/dev/video" + "9" * 4  # the longest socket path below a registry


def _registry_for(out: Path) -> Path:
    """``OUT/v4l2`` when its sockets' paths fit a Unix socket address, else a folder in the
    temporary directory named after ``OUT`` (the same one on every start)."""
    here = out.resolve() / REGISTRY_DIR
    if len(str(here)) + len(_NODE_SUFFIX) <= MAX_SOCKET_PATH:
        return here
    tag = hashlib.sha256(str(out.resolve()).encode()).hexdigest()[:12]
    return Path(tempfile.gettempdir()) / f"tactile-rig-v4l2-{os.getuid()}-{tag}"


def _alive(sock: Path) -> bool:
    s = socket.socket(socket.AF_UNIX, socket.SOCK_SEQPACKET)
    try:
        s.settimeout(1.0)
        s.connect(str(sock))
        return True
    except OSError:
        return False
    finally:
        s.close()


def _fresh_registry(registry: Path) -> None:
    """Empty the registry a previous rehearsal left (its nodes would still be listed), unless one of
    its cameras is still served: then another rehearsal runs on this folder."""
    dev = registry / "root" / "dev"
    live = [p.name for p in sorted(dev.glob("video*")) if p.is_socket() and _alive(p)] if dev.is_dir() else []
    if live:
        raise ValueError(f"the emulated cameras' registry {registry} is in use ({', '.join(live)} served): "
                         "another rehearsal runs on this folder; stop it or use another --out")
    shutil.rmtree(registry, ignore_errors=True)
    registry.mkdir(parents=True, exist_ok=True)


def _relative(path: Path, base: Path) -> str:
    """``path`` relative to ``base`` when inside it (the bench file moves with its folder), else absolute."""
    try:
        return str(path.resolve().relative_to(base.resolve()))
    except ValueError:
        return str(path)
