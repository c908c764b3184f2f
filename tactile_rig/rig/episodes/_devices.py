"""The real drivers on the device mocks, for scenes that run the bench path.

``[controller] gripper = "dynamixel"`` puts the MX-64 driver on the Dynamixel mock whose plant is
the scene's ``fingers`` model; ``motion = "jig"`` puts the GRBL jig driver on the GRBL mock that
moves the scene's ``stage``. ``transport = "rigsim"`` (default) serves the mock in process on the
scene's clock; ``"pty"`` serves it on a pseudo-terminal in real time (the scene must run on a
RealClock), exactly as the bench opens a USB adapter. Every opened thing is closed by
:meth:`Devices.close`.
"""

from __future__ import annotations

import itertools
from typing import Any, Callable

from tactile_rig.drivers.dynamixel.gripper import DynamixelGripper
from tactile_rig.drivers.grbl import Jig
from tactile_rig.drivers.scale import Scale
from tactile_rig.mocks.pty_server import PtyServer
from tactile_rig.mocks.registry import (
    Params,
    create_device,
    register_instance,
    unregister_instance,
)
from tactile_rig.rig.scene_runner import EpisodeContext
from tactile_rig.sim.world.timeline import Timeline

_names = itertools.count()


class Devices:
    """Opens drivers on mocks for one episode and closes them afterwards."""

    def __init__(self, ctx: EpisodeContext) -> None:
        self.ctx = ctx
        self.transport = str(ctx.controller.get("transport", "rigsim"))
        if self.transport not in ("rigsim", "pty"):
            raise ValueError(f"[controller] transport={self.transport!r} must be 'rigsim' or 'pty'")
        self._closers: list[Any] = []

    def _port(self, kind: str, params: dict[str, str]) -> str:
        device = create_device(kind, Params(params, source=f"scene {self.ctx.scene.name}: {kind}"),
                               clock=self.ctx.clock, world=self.ctx.world)
        if self.transport == "pty":

            server = PtyServer(device, clock=self.ctx.clock).start()
            self._closers.append(server.stop)
            return server.port
        name = f"scene-{kind}-{next(_names)}"
        url = register_instance(name, device, self.ctx.clock)
        self._closers.append(lambda: unregister_instance(name))
        return url

    def gripper(self, *, effort: float = 0.5) -> Any:
        """The MX-64 driver on the mock driving the scene's ``fingers`` (activated)."""

        g = DynamixelGripper(self._port("dynamixel", {"fingers": "fingers", "ids": "1"}), dxl_id=1, protocol=2)
        self._closers.insert(0, g.close)
        g.activate(effort)
        g.name = "gripper"  # type: ignore[attr-defined]
        return g

    def jig(self) -> tuple[Any, Timeline]:
        """The GRBL jig driver on the mock of the scene's ``stage``, and the stage's pose history."""

        stage = self.ctx.model("stage")
        history: Timeline = Timeline(keep_s=60.0)
        history.append(self.ctx.clock.now_s(), stage.pose())
        set_pose = stage.set_pose

        def recording_set_pose(x_mm: float, y_mm: float, theta_deg: float, t_s: float | None = None) -> None:
            set_pose(x_mm, y_mm, theta_deg, t_s)
            t = stage.t_s if t_s is None else t_s
            if t >= history.time_at(float("inf")):
                history.append(t, (x_mm, y_mm, theta_deg))

        stage.set_pose = recording_set_pose  # the sensor must see the stage where it was at capture
        jig = Jig(self._port("jig", {"stage": "stage", "homing": "0"}))
        self._closers.insert(0, jig.close)
        jig.name = "jig"  # type: ignore[attr-defined]
        return jig, history

    def scale(self) -> Any:
        """The HX711 scale driver on the mock of the scene's ``load_cell``, tared, as a ForceGauge."""

        scale = Scale(self._port("scale", {"load_cell": "load_cell"}))
        self._closers.insert(0, scale.close)
        scale.tare()
        return _ScaleGauge(scale)

    # -- what a scene asks for -----------------------------------------------------------------
    def pick_gripper(self) -> Any:
        """``[controller] gripper = "dynamixel"``: the driver; else the scene's ``gripper`` model."""
        c = self.ctx.controller
        if c.get("gripper") == "dynamixel":
            return self.gripper(effort=float(c.get("effort", 0.5)))
        return self.ctx.model("gripper")

    def pick_motion(self) -> tuple[Any, Any]:
        """(Motion, position(t) → (x, y, z mm, θ deg)): the jig driver or the scene's ``arm``."""
        if self.ctx.controller.get("motion") == "jig":
            jig, hist = self.jig()
            stage = self.ctx.model("stage")

            def pos_jig(t_s: float) -> Any:
                import numpy as np

                stage.advance_to(self.ctx.clock.now_s())
                x, y, th = hist.at(t_s)
                return np.array([x, y, 0.0, th])

            return jig, pos_jig
        arm = self.ctx.model("arm")
        return arm, arm.position_at

    def close(self) -> None:
        for fn in self._closers:
            try:
                fn()
            except Exception:  # closing must not hide the episode's own outcome
                pass
        self._closers.clear()


class _ScaleGauge:
    """The scale driver seen as a ForceGauge (newest reading, newtons)."""

    def __init__(self, scale: Any) -> None:
        self.scale = scale
        self.name = getattr(scale, "device", "scale")

    def read_force_n(self, timeout_s: float | None = 1.0) -> float:
        return float(self.scale.force_n(timeout_s))


def with_devices(run: "Callable[[EpisodeContext, Devices], Any]") -> "Callable[[EpisodeContext], Any]":
    """Make ``run_episode(ctx)`` from ``run(ctx, devices)``: the episode's drivers are always closed."""

    def run_episode(ctx: EpisodeContext) -> Any:
        devices = Devices(ctx)
        try:
            return run(ctx, devices)
        finally:
            devices.close()

    run_episode.__doc__ = run.__doc__
    return run_episode
