"""A camera's lens set-up, resolved once for every caller (no bpy).

    blender.camera_reader  camera object -> CameraSettings   (the one bpy reader)
    camera.resolve         CameraSettings -> LensSetup        (the one resolver)
    users                  the panel, the Cycles camera (cycles.spec.CameraSpec.from_setup),
                           the NEUROLENS engine, the render command line, the focus picker,
                           the scene-needs model choice.

Modules: settings (the plain input record), setup (the LensSetup record), resolve (the
decisions), lenses (finding and loading lens files), focusing (reachable focus, sensor
position), models (learned models of a lens), model_choice (model AUTO), field_of_view (what
the panel shows), lru (the shared caches).
"""

from .resolve import resolve_camera, traced
from .settings import ApertureSettings, CameraSettings, GhostSettings
from .setup import ERROR, INFO, WARNING, LensSetup

__all__ = ["ERROR", "INFO", "WARNING", "ApertureSettings", "CameraSettings", "GhostSettings",
           "LensSetup",
           "resolve_camera", "traced"]
