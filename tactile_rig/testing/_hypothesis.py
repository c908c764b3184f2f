"""hypothesis, which the strategies modules need, is a test dependency: ``pip install 'tactile-rig[test]'``."""

from __future__ import annotations

try:
    from hypothesis import strategies as st
except ModuleNotFoundError as exc:  # pragma: no cover - depends on the install
    raise ModuleNotFoundError(
        "tactile_rig.testing.strategies* need hypothesis, a test dependency: pip install 'tactile-rig[test]'",
        name=exc.name,
    ) from exc

__all__ = ["st"]
