"""Moved: the GRBL mock's motion profiles live in :mod:`tactile_rig.mocks.grbl.planner`.

This module re-exports them for one release and warns on import.
"""

from __future__ import annotations

import warnings

from tactile_rig.mocks.grbl.planner import Profile, block_phases, stop_phases

warnings.warn("tactile_rig.mocks.grbl_motion moved to tactile_rig.mocks.grbl.planner", DeprecationWarning,
              stacklevel=2)

__all__ = ["Profile", "block_phases", "stop_phases"]
