"""Old import paths of modules that moved in 0.2, kept working for one release.

Importing an old path (``tactile_rig.errors``, ``tactile_rig.mocks.world.stage``, ...) returns the
module at its new place and warns once with a :class:`DeprecationWarning` naming the new path.
A meta-path finder does it, so the old names need no stub files.
"""

from __future__ import annotations

import importlib
import importlib.abc
import importlib.util
import sys
import warnings
from types import ModuleType
from typing import Sequence

# Old module (or package prefix) -> new module. Longest prefix wins.
MOVED: dict[str, str] = {
    "tactile_rig.errors": "tactile_rig.core.errors",
    "tactile_rig.clock": "tactile_rig.core.clock",
    "tactile_rig.rig.poses": "tactile_rig.core.geometry",
    "tactile_rig.drivers.dynamixel.control_table": "tactile_rig.devices.dynamixel.control_table",
    "tactile_rig.drivers.dynamixel.errors": "tactile_rig.devices.dynamixel.error_codes",
    "tactile_rig.drivers.scale_protocol": "tactile_rig.devices.scale",
    "tactile_rig.drivers.grbl_protocol": "tactile_rig.devices.grbl",
    "tactile_rig.mocks.world.gelsight_render": "tactile_rig.sim.render.gelsight",
    "tactile_rig.mocks.world.fingervision_render": "tactile_rig.sim.render.fingervision",
    "tactile_rig.mocks.world.sim_gripper": "tactile_rig.sim.fakes.gripper",
    "tactile_rig.mocks.world.arm": "tactile_rig.sim.fakes.arm",
    "tactile_rig.mocks.world.models": "tactile_rig.sim",
    "tactile_rig.mocks.world": "tactile_rig.sim.world",
    "tactile_rig.mocks.scenes": "tactile_rig.sim.scenes",
    "tactile_rig.mocks.sensors": "tactile_rig.sim.fakes.sensors",
    "tactile_rig.rig.stirring": "tactile_rig.sim.world.stirring",
    "tactile_rig.rig.stick_press": "tactile_rig.sim.world.stick_press",
    "tactile_rig.mocks.grbl_motion": "tactile_rig.mocks.grbl.planner",
    "tactile_rig.drivers.jig": "tactile_rig.drivers.grbl",
    "tactile_rig.drivers.jig_limits": "tactile_rig.drivers.grbl.limits",
}


def new_name(old: str) -> str | None:
    """The new module name for ``old``, or None when ``old`` did not move."""
    for prefix in sorted(MOVED, key=len, reverse=True):
        if old == prefix or old.startswith(prefix + "."):
            return MOVED[prefix] + old[len(prefix):]
    return None


class _AliasLoader(importlib.abc.Loader):
    def __init__(self, old: str, new: str) -> None:
        self.old, self.new = old, new

    def create_module(self, spec: importlib.machinery.ModuleSpec) -> ModuleType:
        warnings.warn(f"{self.old} moved to {self.new}; the old path goes away in the next release",
                      DeprecationWarning, stacklevel=6)
        module = importlib.import_module(self.new)
        sys.modules[self.old] = module
        return module

    def exec_module(self, module: ModuleType) -> None:
        """The module is the new one, already executed."""


class _MovedFinder(importlib.abc.MetaPathFinder):
    def find_spec(self, fullname: str, path: Sequence[str] | None = None,
                  target: ModuleType | None = None) -> importlib.machinery.ModuleSpec | None:
        new = new_name(fullname)
        if new is None:
            return None
        return importlib.util.spec_from_loader(fullname, _AliasLoader(fullname, new))


def install() -> None:
    """Put the finder first on ``sys.meta_path`` (once)."""
    if not any(isinstance(f, _MovedFinder) for f in sys.meta_path):
        sys.meta_path.insert(0, _MovedFinder())
