"""The run's devices: :class:`DeviceJigRig` over a GRBL jig driver and a camera driver, and the
connectors that give it the mocks of a scene or the devices of a bench."""

from __future__ import annotations

from typing import Any, Callable

import numpy as np

from tactile_rig.core.clock import VirtualClock
from tactile_rig.core.errors import DeviceTimeout, RigError
from tactile_rig.core.geometry import Pose
from tactile_rig.drivers.camera import CameraConfig, FingertipCamera
from tactile_rig.mocks.camera import SimulatedCamera
from tactile_rig.rig.bench import Bench, connect_bench, load_bench, mock_bench_path
from tactile_rig.sim.scenes import JIG_ACCURACY_SCENE

MOCK_SCENE = JIG_ACCURACY_SCENE  # the world of a run on mocks
STALE_FRAMES_MAX = 30  # frames from before the settle that a touch skips before giving up (1 s at 30 fps)


class DeviceJigRig:
    """A :class:`JigRig` over drivers: a GRBL ``Jig`` and a ``FingertipCamera`` on one clock.

    ``world`` (mocks only) supplies the truth: the stage model's pose after the world is advanced to
    now. Without a world the truth is the commanded pose (a bench). ``recorder`` (optional, a
    :class:`~tactile_rig.rig.recording.Recorder`) receives every move, pose and frame.
    """

    def __init__(self, jig: Any, camera: Any, clock: Any, *, world: Any = None, stage: str = "stage",
                 feed_mm_per_min: float | None = None, settle_s: float = 0.1, move_timeout_s: float = 120.0,
                 frame_timeout_s: float = 2.0, description: dict[str, Any] | None = None,
                 recorder: Any = None, camera_name: str = "gelsight") -> None:
        self.jig, self.camera, self.clock, self.world = jig, camera, clock, world
        self.stage_name = stage
        self.feed_mm_per_min = None if feed_mm_per_min is None else float(feed_mm_per_min)
        self.settle_s = float(settle_s)
        self.move_timeout_s = float(move_timeout_s)
        self.frame_timeout_s = float(frame_timeout_s)
        self.description = dict(description or {"kind": "mock" if world is not None else "bench"})
        self.recorder = recorder
        self.camera_name = camera_name
        self._primed = False
        self._settled_at_s: float | None = None  # when the last move had settled (the clock's time)

    def now_s(self) -> float:
        return float(self.clock.now_s())

    def move_to(self, pose: Pose) -> None:
        if self.recorder is not None:
            self.recorder.write_command("jig", "move_to", **pose.as_dict(), feed_mm_per_min=self.feed_mm_per_min)
        self.jig.move_to(pose.x_mm, pose.y_mm, pose.theta_deg, feed_mm_per_min=self.feed_mm_per_min)
        self.jig.wait_idle(timeout_s=self.move_timeout_s)
        self.clock.sleep(self.settle_s)
        self._settled_at_s = self.now_s()
        if self.recorder is not None:
            extra = {}
            if self.world is not None:
                extra = {"true_" + k: v for k, v in self.truth(pose).as_dict().items()}
            self.recorder.write_jig_pose({**pose.as_dict(), "z_mm": 0.0}, **extra)

    def touch(self) -> np.ndarray:
        """A frame taken after the last move settled (frames a camera queued before are skipped)."""
        frame = self.camera.read(timeout_s=self.frame_timeout_s)
        # V4L2 buffers and network streams hand over frames exposed earlier: one that arrived before
        # the stage settled shows the old pose and would be localized as the new one.
        skipped = 0
        while (self._settled_at_s is not None and getattr(frame, "t_host_s", None) is not None
               and frame.t_host_s < self._settled_at_s):
            skipped += 1
            if skipped > STALE_FRAMES_MAX:
                raise DeviceTimeout(f"{skipped} frames in a row arrived from before the stage settled at "
                                    f"t={self._settled_at_s:.3f} s (expected a fresh frame)", device=self.camera_name)
            frame = self.camera.read(timeout_s=self.frame_timeout_s)
        image = getattr(frame, "image", frame)
        if self.recorder is not None:
            self.recorder.write_frame(self.camera_name, image, compress="png")
        return image

    def truth(self, commanded: Pose) -> Pose:
        if self.world is None:
            return commanded
        self.world.advance_to()
        st = self.world.require(self.stage_name, "the jig accuracy run")
        return Pose(float(st.x_mm), float(st.y_mm), theta_deg=float(st.theta_deg))

    def describe(self) -> dict[str, Any]:
        return dict(self.description)

    def begin_step(self, step: int) -> None:
        """Mocks: reseed every noise source (the world's models, the simulated camera) from
        ``(world seed, step, source)``: step 0 is the map, step i + 1 point i. The noise a point
        sees then depends on nothing before it, so a run interrupted and resumed at any point gives
        the same results as one that ran straight through. A bench has no noise to seed."""
        if self.world is None:
            return
        if not self._primed:
            # The camera driver drops its warm-up frames at the first read after opening: let that
            # happen before any step's noise is seeded, whichever step an attempt starts at.
            self.camera.read(timeout_s=self.frame_timeout_s)
            self._primed = True
        seed = int(getattr(self.world, "seed", 0))
        sources: list[tuple[str, Any]] = [(name, self.world.get(name)) for name in self.world]
        sources.append(("camera", getattr(self.camera, "source", None)))
        for k, (name, obj) in enumerate(sources):
            reseed = getattr(obj, "reseed", None)
            if callable(reseed):
                key = int.from_bytes(name.encode()[:8].ljust(8, b"\0"), "little")
                reseed(np.random.default_rng(np.random.SeedSequence([seed, int(step), key])))


def sim_camera_connector(sensor_model: str) -> Callable[[Any, Any], Any]:
    """A bench connector that renders a scene's sensor model through the simulated UVC camera."""

    def connect(cfg: Any, ctx: Any) -> Any:
        if ctx.world is None:
            raise RigError("a simulated GelSight camera needs a scene with a renderer", device=cfg.name)
        renderer = ctx.world.require(sensor_model, f"camera [{cfg.name}]")
        sim = SimulatedCamera(renderer, clock=ctx.clock, name=cfg.name, fourcc=cfg.fourcc,
                              width=cfg.width, height=cfg.height, fps=cfg.fps)
        cam = FingertipCamera(sim, CameraConfig(fourcc=cfg.fourcc, width=cfg.width, height=cfg.height,
                                                fps=cfg.fps), clock=ctx.clock, name=cfg.name)
        return cam.open()

    return connect


def connect_mock_jig_rig(*, scene: str = "jig_accuracy", seed: int = 0, start_s: float = 0.0,
                         sensor_model: str = "gelsight") -> Any:
    """Connect the jig and camera drivers of the built-in mock bench to ``scene`` (one VirtualClock).

    Returns the connected :class:`~tactile_rig.rig.bench.Rig` (its ``world`` holds the scene); the
    jig driver talks to the GRBL mock over ``rigsim://@mock.jig`` and the camera renders
    ``sensor_model`` at the stage's pose. ``start_s`` starts the clock later (a resumed run).
    """
    base = load_bench(mock_bench_path(), check_files=False)
    missing = [d for d in ("jig", "camera") if d not in base.devices]
    if missing:
        raise RigError(f"the mock bench {base.source} lacks {', '.join(missing)}", device="jig_accuracy")
    bench = Bench(name=base.name, devices={k: base.devices[k] for k in ("jig", "camera")}, source=base.source,
                  path=base.path, text=base.text, scene=scene, seed=int(seed))
    return connect_bench(bench, connectors={"camera": sim_camera_connector(sensor_model)},
                         clock=VirtualClock(start_s))


def connect_bench_jig_rig(bench: Any, camera: str | None = None, *, start_s: float = 0.0) -> tuple[Any, str]:
    """Connect the jig and one GelSight camera of a bench; returns (Rig, camera name).

    A bench file made of mocks (every port ``rigsim://``) runs on its ``[bench] scene`` (default: the
    jig accuracy scene), with the simulated camera rendering the scene's ``gelsight`` model.
    """
    cams = [n for n, c in bench.cameras.items() if c.sensor == "gelsight"]
    name = camera or (cams[0] if cams else None)
    if name is None or name not in bench.devices:
        raise RigError(f"{bench.source}: a jig accuracy run needs a [camera] with sensor = \"gelsight\"",
                       device="jig_accuracy")
    sub = Bench(name=bench.name, devices={"jig": bench.device("jig"), name: bench.device(name)},
                source=bench.source, path=bench.path, text=bench.text, scene=bench.scene, seed=bench.seed)
    if not sub.is_mock:
        return connect_bench(sub), name
    sub.scene = sub.scene or MOCK_SCENE
    return connect_bench(sub, connectors={"camera": sim_camera_connector("gelsight")},
                         clock=VirtualClock(start_s)), name

def prepare_jig(jig: Any, timeout_s: float = 120.0) -> None:
    """Bring a GRBL jig to Idle and ``active``: home it when it is locked in Alarm (GRBL with homing
    enabled), clear a latched fault (:meth:`tactile_rig.drivers.grbl.Jig.activate`)."""
    jig.activate(home=True, timeout_s=timeout_s)
