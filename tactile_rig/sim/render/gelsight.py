"""GelSight renderer: an indentation height field → the BGR frame a photometric fingertip sees.

The renderer (:class:`GelSightRenderer`: the gel's range, the elastomer's smoothing, the normals, the
four LEDs' lighting, the composite on a real no-contact frame with noise) is
:mod:`tactile_rig.sim.render.gelsight_renderer`, where its physics is told step by step; the surface
numerics are :mod:`.gel_surface`, the read noise :mod:`.noise`, and the ball-press data sets (the
lighting fitted on real presses, rendered presses with exact labels) :mod:`.ball_presses`. Every public
name of those is importable from here.

This module adds :class:`GelSightRendererModel` (kind ``gelsight_renderer``), which reads the object
and the stage from a scene and renders what the gel sees of them.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from tactile_rig.sim.base import register_model
from tactile_rig.sim.render.ball_presses import (
    ball_press_height_mm,
    fit_lighting,
    read_labels,
    render_ball_press_dataset,
)
from tactile_rig.sim.render.gel_surface import downsample_factor, gaussian_smooth, surface_gradients
from tactile_rig.sim.render.gelsight_renderer import (
    ASSETS,
    BACKGROUNDS,
    TAXIM_LIGHTING,
    TAXIM_NOISE_SIGMA,
    GelSightRenderer,
    LightingModel,
    lighting_from_leds,
    load_background,
    load_background_array_resized,
)
from tactile_rig.sim.render.noise import SensorNoise
from tactile_rig.sim.world.objects import HeightField, ObjectModel

__all__ = [
    "ASSETS",
    "BACKGROUNDS",
    "LightingModel",
    "TAXIM_LIGHTING",
    "TAXIM_NOISE_SIGMA",
    "lighting_from_leds",
    "fit_lighting",
    "load_background",
    "load_background_array_resized",
    "GelSightRenderer",
    "SensorNoise",
    "render_ball_press_dataset",
    "ball_press_height_mm",
    "read_labels",
    "surface_gradients",
    "gaussian_smooth",
    "downsample_factor",
    "GelSightRendererModel",
]


class GelSightRendererModel:
    """Scene model (kind ``gelsight_renderer``): renders what the gel sees of the scene's object.

    Reads, only if present: the object model named ``object`` (an :class:`ObjectModel`: shape,
    ``press_depth_mm`` and its own pose) and the stage named ``stage`` (attributes ``x_mm, y_mm,
    theta_deg`` and, if it has one, ``press_depth_mm`` or ``z_mm`` overriding the object's depth).
    The stage pose is added to the object's pose.
    """

    def __init__(self, world: Any, rng: np.random.Generator, *, background: str = "taxim",
                 shape_px: tuple[int, int] | list[int] | None = None, mm_per_px: float | None = None,
                 object: str = "object", stage: str = "stage", smoothing_mm: float = 0.6,  # noqa: A002
                 max_protrusion_mm: float = 1.0,
                 noise_sigma: float | tuple[float, float, float] | list[float] = TAXIM_NOISE_SIGMA,
                 flicker_sigma: float = 0.0) -> None:
        native = BACKGROUNDS.get(background)
        bg = load_background(background)
        shape = (int(shape_px[0]), int(shape_px[1])) if shape_px is not None else (bg.shape[0], bg.shape[1])
        if mm_per_px is None:
            if native is None:
                raise ValueError(f"gelsight_renderer: mm_per_px is required for background {background!r}")
            mm_per_px = native[1] * bg.shape[0] / shape[0]
        self.world = world
        self.object_name, self.stage_name = object, stage
        self.renderer = GelSightRenderer(bg, float(mm_per_px), shape_px=shape, smoothing_mm=smoothing_mm,
                                         max_protrusion_mm=max_protrusion_mm, noise_sigma=noise_sigma,
                                         flicker_sigma=flicker_sigma, seed=rng)
        self.t_s = 0.0
        self.last_truth: dict[str, Any] = {}

    def advance_to(self, t_s: float) -> None:
        self.t_s = max(self.t_s, float(t_s))

    def reseed(self, rng: np.random.Generator) -> None:
        """The renderer's per-frame noise from ``rng`` from now on (:meth:`GelSightRenderer.reseed`)."""
        self.renderer.reseed(rng)

    def contact_state(self) -> tuple[HeightField | None, float, float, float, float]:
        """(shape, press_depth_mm, x_mm, y_mm, theta_deg) from the scene (shape None: nothing to touch)."""
        obj = self.world.get(self.object_name) if self.world is not None else None
        if not isinstance(obj, ObjectModel):
            return None, 0.0, 0.0, 0.0, 0.0
        depth, x, y, th = obj.press_depth_mm, obj.x_mm, obj.y_mm, obj.theta_deg
        stage = self.world.get(self.stage_name)
        if stage is not None:
            x += float(getattr(stage, "x_mm", 0.0))
            y += float(getattr(stage, "y_mm", 0.0))
            th += float(getattr(stage, "theta_deg", 0.0))
            for attr in ("press_depth_mm", "z_mm"):
                if getattr(stage, attr, None) is not None:
                    depth = float(getattr(stage, attr))
                    break
        return obj.shape, depth, x, y, th

    def render_now(self) -> np.ndarray:
        """Advance the world to its clock's now and render; ground truth goes to ``last_truth``."""
        if self.world is not None:
            self.world.advance_to()
        shape, depth, x, y, th = self.contact_state()
        if shape is None:
            frame, ind = self.renderer.render(None), None
        else:
            frame, ind = self.renderer.render_object(shape, depth, x, y, th)
        self.last_truth = {"indentation_mm": ind, "press_depth_mm": depth, "x_mm": x, "y_mm": y,
                           "theta_deg": th, "t_s": self.t_s}
        return frame


register_model("gelsight_renderer")(GelSightRendererModel)
