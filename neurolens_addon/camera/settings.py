"""The plain settings a camera holds for its lens (no bpy): what the one bpy reader
(neurolens_addon.blender.camera_reader) produces and the one resolver (camera.resolve) reads.

Values are as the user set them, before any clamping: the resolver decides what the lens can
do with them and says why when it changes one.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from ..core.film import FilmSettings
from ..core.scene_needs import RenderNeeds

MODELS = ("auto", "exact", "learned", "thin")
SHAPES = ("circle", "blades", "mask")


@dataclass(frozen=True)
class ApertureSettings:
    """The stop's shape: a circle, an iris of `blades` blades (rotation, curvature 0 straight
    .. 1 round), or an image mask (a core.aperture.ImageMaskAperture the reader built, or
    None with `mask_problem` saying why there is none)."""

    shape: str = "circle"
    blades: int = 0
    rotation_deg: float = 0.0
    curvature: float = 0.0
    mask: object = field(default=None, compare=False)
    mask_key: tuple = ()            # identifies the mask's pixels (equality, caching)
    mask_problem: str | None = None


COATINGS = ("bare", "single", "multi")


@dataclass(frozen=True)
class GhostSettings:
    """Ghosts and flare (core.ghosts), off unless `enabled`: the coating of every air-glass
    surface ("bare", "single": quarter-wave MgF2, "multi": a broadband stack), a multiplier of
    the ghosts' light (1: as the optics give it), how many of the brightest ghosts are
    rendered, and the share of camera samples spent on them."""

    enabled: bool = False
    coating: str = "single"
    intensity: float = 1.0
    count: int = 8
    share: float = 0.25


@dataclass(frozen=True)
class CameraSettings:
    """Everything a camera says about its lens (module docstring)."""

    camera: str                               # the camera's name, for messages
    lens_path: str                            # the lens file
    lens_id: str | None = None                # the library identifier, when from the library
    model: str = "auto"                       # one of MODELS
    model_dir: str | None = None              # a model the camera names explicitly (learned)
    model_candidates: tuple = ()              # where the lens's learned models are looked for
    models_folder: str | None = None          # the user's models folder (for messages)
    f_number: float = math.nan                # Blender's F-Stop as set
    focus_distance_mm: float = math.nan       # from the sensor, as set (focus object included)
    zoom_mm: float = math.nan                 # Blender's focal length: a zoom lens's setting
    zoom_animated: bool = False               # an F-curve animates that focal length
    animated_focus_mm: tuple = ()             # every focus the frames use (0: the closest the
                                              # lens focuses, inf allowed); () not animated
    animated_f_numbers: tuple = ()            # every f-number the frames use; () not animated
    aperture: ApertureSettings = ApertureSettings()
    dispersion: bool = True
    diffraction: bool = False                 # the stop's Fraunhofer pattern (core.diffraction)
    ghosts: GhostSettings = GhostSettings()   # ghosts and flare (core.ghosts)
    film: FilmSettings = FilmSettings()
    metres_per_unit: float = 1.0              # the scene's unit scale
    needs: RenderNeeds | None = field(default=None, compare=False)   # model AUTO
    needs_error: str | None = None            # why there are no needs (no image)
    pixel_fraction: float = 0.5               # the scene's error budget in pixels
    renderer: str = "neurolens"               # what renders the frame: "neurolens" or "cycles"
                                              # (model AUTO picks the cheapest there)
    notes: tuple = ()                         # ((level, text), ...) the reader noticed
