"""GRBL 1.1h, emulated: the firmware of the x-y-θ jig (θ on the Z channel, or A on grblHAL).

The package splits the firmware along its own seams: :mod:`.gcode` (the parser, pure),
:mod:`.report` (everything GRBL prints, pure), :mod:`.planner` and :mod:`.homing` (motion
planning, pure numerics), :mod:`.system` (``$`` commands), :mod:`.motion_control` (G-code
execution, homing and probing as jobs of the protocol loop), :mod:`.stepper` (the executing block
in time), :mod:`.machine` (the jig's settings, machine and stage coordinates, switches, probe) and
:mod:`.firmware` (bytes, the protocol loop, alarms, resets, reports, time).
``rigsim://jig?...`` builds a :class:`GrblMock`.
"""

from __future__ import annotations

from typing import Any

from tactile_rig.core.clock import Clock
from tactile_rig.devices import grbl as gp
from tactile_rig.mocks.grbl.firmware import GrblMock, default_settings
from tactile_rig.mocks.registry import Params, register_kind

__all__ = ["GrblMock", "default_settings"]


def _factory(params: Params, *, clock: Clock, world: Any = None) -> GrblMock:
    stage_name = params.text("stage", "stage") or "stage"
    stage = world.require(stage_name, who="the jig mock") if world is not None else None
    firmware = params.text("firmware", "grbl") or "grbl"
    axes = params.integer("axes", 4 if firmware == "grblhal" else 3)
    return GrblMock(
        clock=clock, stage=stage, axes=axes,
        theta_axis=params.text("theta_axis", "A" if axes == 4 else "Z") or "Z",
        firmware=firmware, baud=params.integer("baud", gp.BAUD), timing=params.flag("timing", True),
        seed=params.integer("seed", 0), homing=params.flag("homing", True), boot_s=params.number("boot_s", 0.0),
        work_origin=params.text("work_origin", None),
    )


register_kind("jig", _factory, default_baud=gp.BAUD,
              description="GRBL 1.1h x-y-theta jig (theta on Z; A with firmware=grblhal)")
