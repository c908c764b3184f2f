"""The rehearsal bench: every device in its own process, a bench file naming them, one object to stop it.

    with RehearsalBench("rehearsal") as rb:          # or: tactile-rig bench rehearse --out rehearsal
        bench = load_bench(rb.bench_path)            # the --bench path, exactly as on hardware

Devices (each its own process, real time):

* ``gripper``: the MX-64 mock on a pty (``tactile-rig mock serve dynamixel``), Protocol 2.0, ID 1, 57600 baud;
* ``scale``: the HX711 sketch's mock on a pty (``tactile-rig mock serve scale``), 57600 baud, 80 samples/s;
* ``jig`` + ``camera_gelsight``: the GRBL mock on a pty and the GelSight camera rendering the object on
  its stage, served as MJPEG over HTTP (:mod:`.child` ``stage``: one process, one world);
* ``camera_<name>`` for each recorded footage given (``cameras={"fingervision": "run.mcap#/camera_x/image/compressed"}``):
  the footage played at its recorded rate as MJPEG over HTTP (:mod:`.child` ``camera``); the source
  ``"rendered"`` is a FingerVision video the rehearsal writes first to ``OUT/footage/<name>.avi``.

The serial devices are named in the bench file through links in ``OUT/dev/`` (``OUT/dev/gripper`` →
``/dev/pts/N``), as a lab names USB adapters through ``/dev/serial/by-path`` links; each process's
stderr is ``OUT/logs/<device>.log``. A GelSight
calibration made on the mocks (the ball-press session) is written to ``OUT/calib/gelsight.json`` and
named by the camera, so ``run jig-accuracy --bench`` runs at once. With ``press``, a force map or a
marker baseline made earlier in ``OUT/calib/`` (``force_map/``, ``fingervision.json``) is named by
``camera_fingervision`` on the next start.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

from tactile_rig.rig.jig_accuracy import mock_gelsight_calibration
from tactile_rig.rig.rehearsal.child import STAGE_SCENE
from tactile_rig.rig.rehearsal.bench_file import RehearsalDevice, bench_toml, link_device
from tactile_rig.rig.rehearsal.frames import write_fingervision_footage
from tactile_rig.rig.rehearsal.processes import DeviceProcess, child_argv, mock_serve_argv

BENCH_FILE = "bench.toml"
STATE_FILE = "rehearsal.json"
SENSORS = ("gelsight", "fingervision")
SYNTHETIC_FOOTAGE = "rendered"  # --camera NAME=rendered: a FingerVision video the rehearsal renders


@dataclass
class RehearsalOptions:
    """What the rehearsal serves. ``cameras`` maps a camera name to footage (a video or
    ``FILE.mcap[#TOPIC]``) and ``camera_sensors`` a camera name to its sensor (default fingervision);
    ``homing`` enables GRBL homing (the jig boots locked and ``$H`` takes ~20 s, as on a real jig);
    ``calibration`` makes the GelSight calibration when it is missing; ``gelsight_jpeg_quality`` is
    the GelSight stream's JPEG quality (a GelSight Mini streams MJPG too); ``stage_scene`` is what lies
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

    def __post_init__(self) -> None:
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
        if not 1 <= self.gelsight_jpeg_quality <= 100:
            raise ValueError(f"gelsight_jpeg_quality={self.gelsight_jpeg_quality!r} must be in 1..100")
        if self.scale_rate_sps not in (10, 80):
            raise ValueError(f"scale_rate_sps={self.scale_rate_sps!r} must be 10 or 80 (the HX711 RATE pin)")


class RehearsalBench:
    """Start with :meth:`start` (or ``with``); :attr:`bench_path` is the bench file; :meth:`stop` ends
    every process. ``out`` holds the bench file, the device links, the calibration and a state file."""

    def __init__(self, out: str | Path, options: RehearsalOptions | None = None) -> None:
        self.out = Path(out)
        self.options = options or RehearsalOptions()
        self.processes: dict[str, DeviceProcess] = {}
        self.devices: list[RehearsalDevice] = []
        self.bench_path = self.out / BENCH_FILE

    def start(self) -> "RehearsalBench":
        """Start every device process (in parallel), wait for their ports, write the bench file.

        On Linux the device processes end when the thread that started them ends (they must not
        outlive a killed rehearsal): call this from a thread that lives as long as the rehearsal."""
        o = self.options
        self.out.mkdir(parents=True, exist_ok=True)
        cal = self.out / "calib" / "gelsight.json"
        stage_opts = ["--scene", o.stage_scene, "--seed", str(o.seed), "--fps", repr(float(o.gelsight_fps)),
                      "--jpeg-quality", str(o.gelsight_jpeg_quality)] + (["--homing"] if o.homing else [])
        procs: dict[str, DeviceProcess] = {}
        if o.press:
            procs["press"] = DeviceProcess("press", child_argv("press", ["--seed", str(o.seed),
                                                                          "--rate", str(o.scale_rate_sps)]))
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
                "camera", ["--source", str(source), "--name", name, "--seed", str(o.seed)]))
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
        keys: dict[str, Any] = {"port": cam["url"], "sensor": "gelsight", "mm_per_px_x": 0.0634,
                                "mm_per_px_y": 0.0634, "width": cam["width"], "height": cam["height"],
                                "fps": float(cam["fps"]), "fourcc": cam["fourcc"]}
        if calibration is not None:
            keys["calibration"] = os.path.relpath(calibration, self.out)
        self.devices.append(RehearsalDevice("camera_gelsight", keys,
                                            f"GelSight rendering the jig's stage, pid {pids['stage']}"))
        if o.press:
            c = self.processes["press"].info["camera"]
            keys = {"port": c["url"], "sensor": "fingervision", "width": c["width"], "height": c["height"],
                    "fps": float(c["fps"]), "fourcc": c["fourcc"]}
            # What earlier sessions on this rehearsal made, named as a lab's bench names them.
            if (self.out / "calib" / "fingervision.json").is_file():
                keys["calibration"] = "calib/fingervision.json"
            if any((self.out / "calib" / "force_map").glob("force_map*.json")):
                keys["force_map"] = "calib/force_map"
            self.devices.append(RehearsalDevice("camera_fingervision", keys,
                                                f"FingerVision fingertip pressed on the scale by the gripper, "
                                                f"pid {pids['press']}"))
        for name in o.cameras:
            c = self.processes[f"camera_{name}"].info
            self.devices.append(RehearsalDevice(f"camera_{name}", {
                "port": c["url"], "sensor": o.camera_sensors.get(name, "fingervision"), "width": c["width"],
                "height": c["height"], "fps": float(c["fps"]), "fourcc": c["fourcc"]},
                f"footage {c['source']} ({c['frames']} frames at {c['fps']} fps), pid {pids[f'camera_{name}']}"))
        header = ("The rehearsal bench (tactile-rig bench rehearse): every device is a mock in its own\n"
                  "process; valid while that command runs. Ports are links in dev/ (as /dev/serial/by-path).")
        self.bench_path.write_text(bench_toml("rehearsal", self.devices, header=header), encoding="utf-8")
        (self.out / STATE_FILE).write_text(json.dumps(self.describe(), indent=2) + "\n", encoding="utf-8")

    def describe(self) -> dict[str, Any]:
        """The bench file, and each device process's pid and what it printed."""
        return {"bench": str(self.bench_path),
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
