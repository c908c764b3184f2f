"""Episode wirings, one module per controller kind: build the controller from a scene, run it,
and judge the episode against the controller's property using the world's ground truth.

Each module exposes ``run_episode(ctx: EpisodeContext) -> EpisodeReport``.
"""

from __future__ import annotations

from typing import Any

from tactile_rig.control.common import ControllerResult, Outcome


def expected_outcome(controller: dict[str, Any]) -> str:
    """The outcome a scene expects (``expect`` in ``[controller]``, default ``success``)."""
    return str(controller.get("expect", "success"))


def params_for(cls: type, section: dict[str, Any]) -> Any:
    """Instantiate the params dataclass ``cls`` from the keys of ``section`` it knows."""
    import dataclasses

    names = {f.name for f in dataclasses.fields(cls)}
    return cls(**{k: v for k, v in section.items() if k in names})


def outcome_matches(result: ControllerResult, controller: dict[str, Any]) -> bool:
    exp = expected_outcome(controller)
    if exp == "fault":
        return result.outcome is Outcome.FAULT
    return result.outcome.value == exp
