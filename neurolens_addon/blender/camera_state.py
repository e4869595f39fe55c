"""What one camera's settings amount to, for the panel: `evaluate_camera`.

The camera's lens set-up comes from the one reader and the one resolver
(camera_reader.lens_setup); a camera whose settings leave no lens keeps the error, so the
panel can say why. With `with_fov` the panel's field of view is added: the full angles the
focused lens images onto its film's half width, half height and half diagonal, and its image
circle (camera.field_of_view.frame_field_of_view: an anamorphic lens's own film).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from ..camera.setup import ERROR, INFO, WARNING, LensSetup
from ..core.errors import NeuroLensError
from . import camera_reader

__all__ = ["ERROR", "INFO", "WARNING", "CameraState", "evaluate_camera"]


@dataclass
class CameraState:
    """A camera's lens set-up (or the error that leaves it without one) and the messages the
    panel shows."""

    enabled: bool
    setup: LensSetup | None = None
    error: NeuroLensError | None = None
    messages: list = field(default_factory=list)        # [(level, text)]
    fov_deg: tuple | None = None                        # (horizontal, vertical, diagonal)
    image_circle_mm: float | None = None

    def say(self, level: str, text: str) -> None:
        self.messages.append((level, text))

    # what the panel reads, from the set-up
    def _get(self, name: str, default=None):
        return getattr(self.setup, name) if self.setup is not None else default

    entry = property(lambda self: self._get("entry"))
    model = property(lambda self: self._get("model"))
    model_info = property(lambda self: self._get("model_info"))
    choice = property(lambda self: self._get("choice"))
    f_number = property(lambda self: self._get("f_number", math.nan))
    stop_radius_mm = property(lambda self: self._get("stop_radius_mm", math.nan))
    focus_m = property(lambda self: self._get("focus_m", math.nan))
    sensor_z_mm = property(lambda self: self._get("sensor_z_mm", math.nan))
    lens_id = property(lambda self: self._get("lens_id"))

    @property
    def frame_mm(self) -> tuple | None:
        return self.setup.film.size_mm if self.setup is not None else None

    @property
    def closest_focus_m(self) -> float:
        return self.entry.closest_focus_mm / 1000.0 if self.entry else math.nan


def evaluate_camera(camera_obj, scene, depsgraph=None, *, with_fov: bool = False) -> CameraState:
    """The CameraState of a camera object (module docstring). Never raises for bad settings."""
    obj = camera_obj.evaluated_get(depsgraph) if depsgraph is not None else camera_obj
    cam = obj.data
    state = CameraState(enabled=camera_reader.uses_panel(cam))
    try:
        state.setup = camera_reader.lens_setup(camera_obj, scene, depsgraph,
                                                  include_disabled=True)
    except NeuroLensError as exc:
        state.error = exc
        state.say(ERROR, str(exc))
        return state
    state.messages.extend(state.setup.messages)
    if scene.render.engine == "CYCLES":
        state.messages.extend(state.setup.cycles_messages)
    if with_fov:
        _field_of_view(state)
    return state


def _field_of_view(state: CameraState) -> None:
    from ..camera.field_of_view import frame_field_of_view
    state.fov_deg, state.image_circle_mm = frame_field_of_view(state.setup)
    if state.fov_deg[2] is None:
        state.say(INFO, f"The frame's corners lie outside the lens's image circle "
                        f"({state.image_circle_mm:.1f} mm across): they stay dark")
