"""The MX-64 mock: firmware emulation of Dynamixel servos on one bus (Protocol 2.0 or 1.0).

``rigsim://dynamixel?protocol=2&ids=1,2&baud=1000000`` or ``tactile-rig mock serve dynamixel``.
Parameters (URL query or ``--param KEY=VALUE``):

==================  ========================================================================
protocol            1 or 2 (default 2)
ids                 servo IDs, comma-separated (default 1)
baud                line rate in bit/s (default 1000000 for Protocol 2.0, 57600 for 1.0; the
                    servos' Baud Rate register is set to match)
timing              1: replies take the wire time plus the Return Delay Time; 0: instant
return_delay_us     initial Return Delay Time of every servo (default 500, the factory value)
model               ``mx64`` (default), or the model number 311 / 310 (must match the protocol)
boot_ms             time a servo is deaf after Reboot / Factory Reset (default 50)
fingers             name of the ``fingers`` model in the scene that the first ID drives
                    (default ``fingers``; without a scene or that model, a default plant)
object_width_mm     width of an object between the fingers of the default plant (none by default)
object_stiffness_npm  its stiffness (default 100 000 N/m: a rigid part between rubber pads)
position            initial shaft position in ticks of the default plant (default mid-range)
==================  ========================================================================
"""

from __future__ import annotations

from typing import Any

from tactile_rig.mocks.dynamixel.device import DynamixelBusDevice, nominal_baud
from tactile_rig.mocks.dynamixel.firmware import Servo
from tactile_rig.mocks.registry import Params, register_kind
from tactile_rig.sim.world.fingers import OBJECT_STIFFNESS_NPM, Fingers

__all__ = ["DynamixelBusDevice", "Servo", "make_bus"]

_MODELS = {"mx64": None, "311": 2, "310": 1}


def make_bus(
    *,
    protocol: int = 2,
    ids: list[int] | tuple[int, ...] = (1,),
    baud: int | None = None,
    timing: bool = True,
    return_delay_us: int = 500,
    boot_s: float = 0.05,
    plants: dict[int, Fingers] | None = None,
    t_s: float = 0.0,
) -> DynamixelBusDevice:
    """Build a bus of MX-64s; ``plants`` maps an ID to its plant (default: a free gripper each)."""
    if protocol not in (1, 2):
        raise ValueError(f"dynamixel: protocol={protocol!r} must be 1 or 2")
    baud = baud or (1_000_000 if protocol == 2 else 57600)
    if not ids:
        raise ValueError("dynamixel: ids must name at least one servo")
    for i in ids:
        if not 0 <= i <= (252 if protocol == 2 else 253):
            raise ValueError(f"dynamixel: id={i} is outside 0-{252 if protocol == 2 else 253}")
    plants = plants or {}
    servos = [Servo(i, protocol, plants.get(i) or Fingers(t_s=t_s), return_delay_us=return_delay_us, baud=baud,
                    t_s=t_s)
              for i in ids]
    return DynamixelBusDevice(servos, protocol=protocol, baud=nominal_baud(baud), timing=timing, boot_s=boot_s)


def _factory(params: Params, *, clock: Any, world: Any = None) -> DynamixelBusDevice:
    protocol = params.integer("protocol", 2)
    model = (params.text("model", "mx64") or "mx64").lower().replace("-", "")
    if model not in _MODELS:
        raise ValueError(f"{params.source}: model={model!r} must be mx64, 311 or 310")
    if _MODELS[model] is not None and _MODELS[model] != protocol:
        raise ValueError(f"{params.source}: model {model} speaks Protocol {_MODELS[model]}, not {protocol}")
    ids = params.integers("ids", [1])
    t0 = clock.now_s()
    fingers_name = params.text("fingers", "fingers")
    width_mm = params.number("object_width_mm")
    stiffness = params.number("object_stiffness_npm", OBJECT_STIFFNESS_NPM)
    position = params.integer("position")
    plant = world.get(fingers_name) if world is not None else None
    if plant is not None and not isinstance(plant, Fingers):
        raise ValueError(f"{params.source}: world model {fingers_name!r} is not a fingers model")
    if plant is None:
        plant = Fingers(object_width_m=None if width_mm is None else width_mm / 1000,
                        object_stiffness_npm=stiffness, position_ticks=position, t_s=t0)
    return make_bus(
        protocol=protocol,
        ids=ids,
        baud=params.integer("baud"),
        timing=params.flag("timing", True),
        return_delay_us=params.integer("return_delay_us", 500),
        boot_s=params.number("boot_ms", 50.0) / 1000,
        plants={ids[0]: plant} if ids else None,
        t_s=t0,
    )


register_kind("dynamixel", _factory, default_baud=1_000_000,
              description="MX-64 servos (Protocol 2.0 or 1.0) on one bus, with the gripper plant")
