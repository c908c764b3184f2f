"""Scene files: which world models a scene needs, with their parameters and seed.

A scene is a TOML file::

    [scene]
    name = "jig-rotation-sweep"
    description = "GelSight touches of a part on the x-y-theta jig"
    seed = 0

    [models.stage]          # model name
    type = "stage"          # registered model kind
    x_range_mm = [-20, 20]  # the model's own parameters

Models are built in file order, so a model may look up the ones above it. Built-in scenes live in
this folder; :func:`load_scene` accepts a path or a built-in name.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import tomllib

from tactile_rig.core.clock import Clock
from tactile_rig.sim import World

SCENE_DIR = Path(__file__).resolve().parent

# Built-in scenes that the rig's sessions and the rehearsal bench name (each a file of this folder).
JIG_ACCURACY_SCENE = "jig_accuracy"  # a textured part on the jig's stage under the GelSight camera
GELSIGHT_BALL_PRESS_SCENE = "gelsight_ball_presses"  # the calibration ball on the stage: GelSight calibration
FORCE_MAP_PRESS_SCENE = "force_map_press"  # the gripper presses a FingerVision fingertip on the scale: force map


@dataclass
class Scene:
    """A loaded scene: its world plus the non-model sections of the file (e.g. ``[controller]``)."""

    name: str
    description: str
    world: World
    path: Path | None
    sections: dict[str, Any] = field(default_factory=dict)


def builtin_scenes() -> dict[str, Path]:
    """Built-in scene names → files."""
    return {p.stem: p for p in sorted(SCENE_DIR.glob("*.toml"))}


def resolve_scene_path(name_or_path: str | Path) -> Path:
    p = Path(name_or_path)
    if p.suffix == ".toml" and p.is_file():
        return p
    scenes = builtin_scenes()
    key = str(name_or_path)
    if key in scenes:
        return scenes[key]
    raise FileNotFoundError(
        f"scene {key!r} is neither a .toml file nor a built-in scene; built-in scenes: "
        f"{', '.join(scenes) or '(none)'}"
    )


def load_scene(
    name_or_path: str | Path,
    *,
    clock: Clock | None = None,
    seed: int | None = None,
    overrides: dict[str, dict[str, Any]] | None = None,
) -> Scene:
    """Load a scene by built-in name or path and build its world.

    ``seed`` overrides the file's seed; ``overrides`` maps model name → parameters to replace.
    Errors name the file and the offending model.
    """
    path = resolve_scene_path(name_or_path)
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except tomllib.TOMLDecodeError as exc:
        raise ValueError(f"scene file {path}: {exc}") from None
    head = data.get("scene", {})
    name = str(head.get("name", path.stem))
    world = World(clock, seed=int(seed if seed is not None else head.get("seed", 0)), name=name)
    models = data.get("models", {})
    if not isinstance(models, dict):
        raise ValueError(f"scene file {path}: [models] must be a table of model tables")
    for model_name, spec in models.items():
        spec = dict(spec)
        if overrides and model_name in overrides:
            spec.update(overrides[model_name])
        kind = spec.pop("type", None)
        if kind is None:
            raise ValueError(f"scene file {path}: model {model_name!r} has no 'type' key")
        try:
            world.build(model_name, kind, **spec)
        except TypeError as exc:
            raise ValueError(f"scene file {path}: model {model_name!r} ({kind}): {exc}") from None
    sections = {k: v for k, v in data.items() if k not in ("scene", "models")}
    return Scene(name=name, description=str(head.get("description", "")), world=world, path=path,
                 sections=sections)
