"""Imports every built-in world model module so their kinds are registered.

Add a line here when a new model module is written (one small module per model).
"""

from __future__ import annotations

import importlib

_BUILTIN = (
    "tactile_rig.mocks.world.stage",
    "tactile_rig.mocks.world.load_cell",
    "tactile_rig.mocks.world.fingers",
    "tactile_rig.mocks.world.objects",
    "tactile_rig.mocks.world.gelsight_render",
    "tactile_rig.mocks.world.fingervision_render",
    "tactile_rig.mocks.world.arm",
    "tactile_rig.mocks.world.table",
    "tactile_rig.mocks.world.hand",
    "tactile_rig.mocks.world.friction",
    "tactile_rig.mocks.world.sim_gripper",
    "tactile_rig.mocks.world.part",
    "tactile_rig.mocks.world.torsion",
    "tactile_rig.mocks.world.stick",
)

for _name in _BUILTIN:
    try:
        importlib.import_module(_name)
    except ModuleNotFoundError as _exc:  # a model module not written yet
        if _exc.name != _name:
            raise
