"""What is simulated rather than emulated: the world a mock bench lives in.

- :mod:`tactile_rig.sim.world`: small physics models, one module each (stage, load cell, fingers,
  objects, hand, friction, table, part, stick, torsion, stirring, stick press), composed per scene;
- :mod:`tactile_rig.sim.render`: the GelSight and FingerVision renderers (frames from a world);
- :mod:`tactile_rig.sim.scenes`: TOML scene files naming only the models a scene needs;
- :mod:`tactile_rig.sim.fakes`: byte-free stand-ins that satisfy the controllers' protocols directly
  (a simulated gripper, a simulated arm, model and rendered tactile sensors).

Firmware emulations that speak a device's bytes live in :mod:`tactile_rig.mocks` and read their
state from these models. Nothing here imports a driver, a mock or the rig.
"""

from tactile_rig.sim.base import World, WorldModel, model_kinds, register_model
from tactile_rig.sim.fakes import arm as _arm  # noqa: E402,F401
from tactile_rig.sim.fakes import gripper as _gripper  # noqa: E402,F401
from tactile_rig.sim.render import fingervision as _fingervision_render  # noqa: E402,F401
from tactile_rig.sim.render import gelsight as _gelsight_render  # noqa: E402,F401

# Every built-in model kind registers on import; a new model module adds its line here.
from tactile_rig.sim.world import (  # noqa: E402,F401  (registration side effect)
    fingers,
    friction,
    hand,
    load_cell,
    objects,
    part,
    scale_press,
    stage,
    stick,
    table,
    torsion,
)

__all__ = ["World", "WorldModel", "model_kinds", "register_model"]
