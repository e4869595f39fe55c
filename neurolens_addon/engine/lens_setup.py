"""The lens a camera renders through: prescription, evaluator, f-number, focus, aperture shape.

`lens_from_camera(camera_obj, scene)` answers from, in order:
  1. the add-on's camera properties when they are registered and enabled
     (`camera.data.neurolens.enabled`): `neurolens_addon.blender.sync.camera_spec(camera_obj,
     scene)` gives the lens, model, f-number (clamped), focus (clamped to the closest focus),
     sensor position and aperture shape; a "thin" camera is traced exactly here;
  2. otherwise custom properties on the camera data (what the command line sets):
       camera.data["neurolens_lens"]   a preset name ("double_gauss_50mm_f2") or a .toml path
       camera.data["neurolens_model"]  "learned" (default: the preset's shipped model),
                                       "exact", or the path of a NAME.neurolens directory
Either way Blender's own depth-of-field settings are the truth for the rest (the add-on reads
them the same way):
  f-number   camera.data.dof.aperture_fstop (clamped to the lens's widest, with a note);
             the stop radius is R = R_design N_design / N;
  focus      camera.data.dof.focus_object when set (its distance along the camera's view axis),
             else dof.focus_distance; measured from the camera origin, which the engine puts
             at the sensor plane, as a camera's distance scale is;
  iris       dof.aperture_blades >= 3 gives a polygonal stop rotated by dof.aperture_rotation.
The sensor position that focuses the distance D is core.focus.focus_sensor_z(lens, D) (exact
rays, least RMS spot). Scene units: metres times scene.unit_settings.scale_length.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..core.aperture import PolygonAperture, clamp_f_number, stop_radius_for_f_number
from ..core.errors import NeuroLensError

ROOT = Path(__file__).resolve().parents[2]
PRESET_LENSES = ROOT / "presets" / "lenses"
PRESET_MODELS = ROOT / "presets" / "models"
LENS_PROP = "neurolens_lens"
MODEL_PROP = "neurolens_model"


class LensSetupError(NeuroLensError, ValueError):
    """The camera names no lens, a lens or model that cannot be found, or a focus it cannot
    reach; the message says which and what was expected."""


@dataclass
class LensConfig:
    lens: object                      # core.prescription.Lens
    lens_path: str
    mode: str                         # "exact" or "learned"
    model_path: str | None
    f_number: float
    stop_radius_mm: float
    focus_distance_mm: float          # object distance from the sensor plane
    sensor_z_mm: float                # lens-space sensor plane that focuses it
    aperture: object | None           # core.aperture shape, None: circular
    notes: list[str] = field(default_factory=list)

    def describe(self) -> str:
        what = "learned" if self.mode == "learned" else "exact"
        return (f"{self.lens.name} ({what}), f/{self.f_number:g}, focus "
                f"{self.focus_distance_mm / 1000.0:.3g} m")


def preset_names() -> list[str]:
    return sorted(p.stem for p in PRESET_LENSES.glob("*.toml"))


def resolve_lens_path(name_or_path: str) -> Path:
    """A preset name or a lens-file path -> the file; LensSetupError when neither exists."""
    s = str(name_or_path).strip()
    if not s:
        raise LensSetupError("no lens given: expected a preset name or a .toml / .dat path")
    p = Path(s).expanduser()
    if p.is_file():
        return p
    preset = PRESET_LENSES / (s if s.endswith(".toml") else s + ".toml")
    if preset.is_file():
        return preset
    raise LensSetupError(f"lens '{s}' not found: expected a preset name "
                         f"({', '.join(preset_names())}) or the path of a lens file")


def default_model_path(lens_path: Path) -> Path:
    return PRESET_MODELS / (lens_path.stem + ".neurolens")


def _load_lens(path: Path):
    from ..core.lensfile import load_lens, load_pbrt_dat
    return load_pbrt_dat(path) if path.suffix.lower() == ".dat" else load_lens(path)


def _view_distance(camera_obj, target_obj) -> float:
    """Distance of target's origin along the camera's view axis (-Z), in scene units."""
    m = np.array(camera_obj.matrix_world, dtype=np.float64)
    t = np.array(target_obj.matrix_world, dtype=np.float64)[:3, 3]
    view = -m[:3, 2] / np.linalg.norm(m[:3, 2])
    return float(np.dot(t - m[:3, 3], view))


def _mm_per_unit(scene) -> float:
    scale = float(getattr(getattr(scene, "unit_settings", None), "scale_length", 1.0) or 1.0)
    return 1000.0 * scale


def lens_from_camera(camera_obj, scene) -> LensConfig:
    """The LensConfig of a camera object (module docstring: where each setting comes from)."""
    if camera_obj is None or getattr(camera_obj, "type", None) != "CAMERA":
        raise LensSetupError("the scene has no active camera (set scene.camera to a camera "
                             "object)")
    props = getattr(camera_obj.data, "neurolens", None)
    if props is not None and getattr(props, "enabled", False):
        from ..blender.sync import camera_spec
        return _from_spec(camera_spec(camera_obj, scene), camera_obj, scene)
    return _from_custom_properties(camera_obj, scene)


def _from_spec(spec, camera_obj, scene) -> LensConfig:
    """From the add-on's CameraSpec (neurolens_addon.cycles.spec: model, lens, model_dir,
    sensor_z_mm, f_number, aperture, focus_distance_m), already clamped and focused."""
    lens = spec.lens
    if lens is None:
        raise LensSetupError(f"camera '{camera_obj.name}': its lens settings name no lens")
    notes = []
    mode, sensor_z = spec.model, float(spec.sensor_z_mm)
    focus_mm = float(spec.focus_distance_m) * 1000.0
    f_number = float(spec.f_number) if spec.f_number else float(lens.f_number)
    stop_r = stop_radius_for_f_number(lens.stop_radius_mm, lens.f_number, f_number)
    if mode == "thin":
        notes.append("the camera asks for the thin lens; the NEUROLENS engine renders real "
                     "lenses, so it traces this lens exactly")
        mode = "exact"
        sensor_z = _focus(lens, focus_mm, stop_r, camera_obj)
    model_path = spec.model_dir if mode == "learned" else None
    if mode == "learned" and not model_path:
        raise LensSetupError(f"camera '{camera_obj.name}': a learned lens without a model")
    return LensConfig(lens, str(lens.path or lens.name), mode, model_path, f_number, stop_r,
                      focus_mm, sensor_z, spec.aperture, notes)


def _focus(lens, focus_mm: float, stop_r: float, camera_obj) -> float:
    from ..core.errors import FocusError
    from ..core.focus import closest_focus_mm, focus_sensor_z
    try:
        return focus_sensor_z(lens, focus_mm, stop_radius=stop_r)
    except FocusError as e:
        near = closest_focus_mm(lens)
        raise LensSetupError(f"camera '{camera_obj.name}': {e} (closest focus "
                             f"{near / 1000.0:.3f} m)") from None


def _from_custom_properties(camera_obj, scene) -> LensConfig:
    cam = camera_obj.data
    name = cam.get(LENS_PROP) if hasattr(cam, "get") else None
    if not name:
        raise LensSetupError(f"camera '{camera_obj.name}' names no lens: set its "
                             f"'{LENS_PROP}' custom property to a preset name "
                             f"({', '.join(preset_names()[:3])}, ...) or a lens file path")
    path = resolve_lens_path(str(name))
    lens, lens_path = _load_lens(path), str(path)
    choice = str(cam.get(MODEL_PROP, "learned") or "learned")
    if choice.lower() in ("exact", "learned"):
        mode, model_path = choice.lower(), None
    else:
        mode, model_path = "learned", choice
    if mode == "learned":
        mp = Path(model_path) if model_path else default_model_path(Path(lens_path))
        if not (mp / "model.json").is_file():
            raise LensSetupError(f"no learned model for lens '{lens.name}' at {mp} (train one "
                                 f"with `python -m trainer fit`, or use the exact lens)")
        model_path = str(mp)

    notes = []
    dof = cam.dof
    f_number, msg = clamp_f_number(float(dof.aperture_fstop), lens.f_number)
    if msg:
        notes.append(msg)
    stop_r = stop_radius_for_f_number(lens.stop_radius_mm, lens.f_number, f_number)
    mm = _mm_per_unit(scene)
    if dof.focus_object is not None:
        focus_mm = _view_distance(camera_obj, dof.focus_object) * mm
    else:
        focus_mm = float(dof.focus_distance) * mm
    if not (focus_mm > 0 and math.isfinite(focus_mm)):
        raise LensSetupError(f"camera '{camera_obj.name}': focus distance must be positive, "
                             f"got {focus_mm / 1000.0:g} m")
    sensor_z = _focus(lens, focus_mm, stop_r, camera_obj)
    aperture = None
    blades = int(getattr(dof, "aperture_blades", 0) or 0)
    if blades >= 3:
        aperture = PolygonAperture(blades, math.degrees(float(dof.aperture_rotation)))
    return LensConfig(lens, lens_path, mode, model_path, f_number, stop_r, focus_mm,
                      sensor_z, aperture, notes)
