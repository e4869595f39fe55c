"""What one Cycles custom camera is: `CameraSpec`, checked before any source is generated.

A spec names the lens model ("exact": the full sequential trace; "learned": a trained
NeuroLens model evaluated in the shader; "thin": an ideal thin lens, Blender's own model), the
sensor position that sets focus (lens space, mm; from core.focus), the f-number and aperture
shape, whether wavelength is sampled per ray, and the film (sensor size in mm as Cycles uses
it, after sensor fit). The generated shader maps the film to Cycles' camera space:

    camera space = (lens space - (0, 0, sensor_z_mm)) * mm_per_unit^-1,

i.e. the camera object sits on the sensor plane looking down +Z (Cycles custom-camera space,
+Y up), so Blender's focus distance (from the camera) is the core's object distance (from the
sensor). The thin lens keeps Blender's convention instead: its lens is at the camera origin.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from ..core.errors import ApertureError, LensError, ModelError, NeuroLensError
from .shader_range import FLOAT32_SAFE, FLOAT32_TINY, check_shader_range

MODELS = ("exact", "learned", "thin")
PROBES = ("direction", "position", "weight")


class CameraSpecError(NeuroLensError, ValueError):
    """A camera description that cannot be turned into a shader (names the field)."""

    def __init__(self, field: str, message: str):
        self.field = field
        super().__init__(f"camera spec field '{field}': {message}")


@dataclass(frozen=True)
class CameraSpec:
    """One Cycles custom camera. Units: mm for the lens and sensor, metres for focus.

    model: "exact" | "learned" | "thin".
    lens: the core Lens (exact, learned; optional for thin, where it gives the focal length).
    model_dir: the trained model directory (learned).
    sensor_z_mm: sensor plane in lens space (core.focus.focus_sensor_z; 0 = design focus).
    f_number: None = the lens's widest (design) aperture; thin lens: required.
    aperture: a core.aperture shape (None = circular).
    dispersion: sample a wavelength per ray and weight it to RGB (else 587.56 nm, weight 1).
    focal_mm, focus_distance_m: the thin lens (focal_mm defaults to the lens's paraxial EFL).
    sensor_width_mm, sensor_height_mm: the film as Cycles frames it (after sensor fit).
    metres_per_unit: the scene's unit scale (scene.unit_settings.scale_length).
    follow: a cycles.follow.FocusFollow (exact and learned): the shader reads Blender's focus
    distance and f-number every frame within that range instead of baking sensor_z_mm and
    f_number (an animated camera renders without the add-on).
    squeeze: an anamorphic lens's f_y / f_x; the film's x is divided by it (desqueezed).
    ghosts: a core.ghosts.GhostPlan (exact and learned still cameras): a share of the
    samples follows the ghosts (cycles.ghosts).
    stop_radius_mm, lens_film_radius_mm, derived: from_setup copies the derived camera's stop
    radius and lens film radius, gives the shader's stop shape as `aperture`, and keeps the
    camera.derived.DerivedCamera itself for what costs rays to derive (the E_0 and slab pupil
    of that shape, a following camera's tables), read when the shader is written (a sync
    that finds the camera unchanged writes none). A spec written by hand (tests, benchmarks),
    or changed since (dataclasses.replace), takes those from the same functions the derived
    camera uses. cycles/ writes them; it derives nothing itself.
    probe: diagnostics for tests — "direction" / "position" write the exit ray (camera space)
    into throughput, "weight" the sampling weight; rays use the fixed sample probe_sample (the
    aperture's two uniforms, then optionally the ghost choice's two: cycles.ghosts) and
    the pixel centre instead of random numbers.
    """

    model: str
    lens: object = None
    model_dir: str | None = None
    sensor_z_mm: float = 0.0
    f_number: float | None = None
    aperture: object = None
    dispersion: bool = False
    focal_mm: float | None = None
    focus_distance_m: float | None = None
    sensor_width_mm: float = 36.0
    sensor_height_mm: float = 24.0
    metres_per_unit: float = 1.0
    probe: str | None = None
    probe_sample: tuple = (0.5, 0.5)
    follow: object = None
    ghosts: object = None
    squeeze: float = 1.0
    stop_radius_mm: float | None = None
    lens_film_radius_mm: float | None = None
    derived: object = field(default=None, compare=False, repr=False)

    @classmethod
    def from_setup(cls, setup, **probe) -> "CameraSpec":
        """The Cycles camera of a resolved lens set-up (camera.LensSetup): the only way the
        add-on builds one. `probe`: the diagnostic fields (probe, probe_sample) for tests.
        An anamorphic lens's learned model (cartesian frame) has no shader: Cycles traces
        that lens exactly (the NeuroLens engine uses the model)."""
        model, model_dir = setup.model, setup.model_dir
        if model == "learned" and getattr(setup.lens, "anamorphic", False):
            model, model_dir = "exact", None
        traced = setup.model in ("exact", "learned")
        c = setup.derived
        follow = setup.follow if traced else None
        return cls(model=model, lens=c.lens, model_dir=model_dir,
                   sensor_z_mm=c.sensor_z_mm, f_number=c.f_number,
                   aperture=c.shader_aperture if traced else c.aperture,
                   dispersion=c.dispersion,
                   focal_mm=float(setup.entry.efl_mm),
                   focus_distance_m=float(setup.focus_m),
                   sensor_width_mm=float(c.film.width_mm),
                   sensor_height_mm=float(c.film.height_mm),
                   metres_per_unit=float(setup.metres_per_unit),
                   follow=follow,
                   ghosts=c.ghost_plan if traced and follow is None else None,
                   squeeze=c.squeeze,
                   stop_radius_mm=c.stop_radius_mm if traced else None,
                   lens_film_radius_mm=c.film_radius_mm,
                   derived=c if traced else None,
                   **probe)

    @property
    def mm_to_units(self) -> float:
        """Scene units per millimetre."""
        return 1e-3 / self.metres_per_unit

    @property
    def film_radius_mm(self) -> float:
        """The radius the lens images onto: the derived camera's lens film (an anamorphic
        lens's is 1 / squeeze as wide as the frame: core.film.Film.on_lens)."""
        if self.lens_film_radius_mm is not None:
            return float(self.lens_film_radius_mm)
        from ..core.film import Film
        return Film(1, 1, self.sensor_width_mm, self.sensor_height_mm).on_lens(
            self.squeeze).radius_mm

    @property
    def stop_radius(self) -> float:
        """The stop radius (mm): the derived camera's, or the lens's own at f_number (its
        widest when None) by core.aperture.stop_radius_of."""
        if self.stop_radius_mm is not None:
            return float(self.stop_radius_mm)
        from ..core.aperture import stop_radius_of
        return stop_radius_of(self.lens, self.lens.f_number if self.f_number is None
                              else self.f_number)

    @property
    def _camera(self):
        """The derived camera when this spec still describes it (not changed since)."""
        c = self.derived
        if c is None or c.lens is not self.lens or c.sensor_z_mm != self.sensor_z_mm \
                or c.stop_radius_mm != self.stop_radius or c.shader_aperture is not \
                self.aperture or (c.setup.follow if self.follow is not None else None) \
                != self.follow:
            return None
        return c

    @property
    def normalisation(self) -> float:
        """E_0, the film centre's irradiance every weight is divided by: the derived camera's,
        or core.pupil.centre_irradiance at the spec's sensor plane, stop and shape."""
        if self._camera is not None:
            return float(self._camera.shader_centre_irradiance)
        from ..core.aperture import shader_shape
        from ..core.pupil import cached_centre_irradiance
        return cached_centre_irradiance(self.lens, sensor_z=float(self.sensor_z_mm),
                                        stop_radius=self.stop_radius,
                                        aperture=shader_shape(self.aperture))

    @property
    def tables(self):
        """A following camera's camera.derived.FollowTables (the derived camera's, or
        follow_tables of the spec's lens, range and shape)."""
        if self._camera is not None:
            return self._camera.follow_tables
        from ..camera.derived import follow_tables
        from ..core.aperture import shader_shape
        return follow_tables(self.lens, self.follow, shader_shape(self.aperture))

    @property
    def slabs(self):
        """The slab pupil the shader samples (core.pupil_slabs): the derived camera's, or the
        same function's at the spec's sensor plane and stop (a following camera: over its
        tables' planes at the widest stop)."""
        if self._camera is not None:
            return self._camera.slab_pupil
        from ..core.aperture import shader_shape
        from ..core.pupil_slabs import slab_pupil
        shape = shader_shape(self.aperture)
        if self.follow is None:
            return slab_pupil(self.lens, float(self.sensor_z_mm), self.film_radius_mm,
                              self.stop_radius, shape)
        tab = self.tables
        return slab_pupil(self.lens, tab.slab_planes[0], self.film_radius_mm,
                          float(tab.stop_radii[0]), shape, also_sensor_z=tab.slab_planes[1:])


def _positive(spec, name: str) -> float:
    v = getattr(spec, name)
    try:
        x = float(v)
    except (TypeError, ValueError):
        raise CameraSpecError(name, f"expected a positive number, got {v!r}") from None
    if not (math.isfinite(x) and x > 0.0):
        raise CameraSpecError(name, f"expected a positive number, got {v!r}")
    if not FLOAT32_TINY <= x <= FLOAT32_SAFE:
        raise CameraSpecError(name, f"{v!r} is beyond what Cycles' float32 camera can hold")
    return x


def _check_follow(spec) -> None:
    """A follow range: exact or learned, focus 0 < near <= far (far may be inf), f-numbers
    no wider than the lens, lo <= hi."""
    from ..camera.setup import FocusFollow
    f = spec.follow
    if not isinstance(f, FocusFollow):
        raise CameraSpecError("follow", f"expected a cycles.follow.FocusFollow, got "
                                        f"{type(f).__name__}")
    if spec.model not in ("exact", "learned"):
        raise CameraSpecError("follow", f"the {spec.model} camera cannot follow Blender's "
                                        "focus and f-number")
    near, far = (float(v) for v in f.focus_mm)
    if not (math.isfinite(near) and 0.0 < near <= far):
        raise CameraSpecError("follow", f"focus range must satisfy 0 < near <= far (mm), got "
                                        f"{f.focus_mm!r}")
    lo, hi = (float(v) for v in f.f_numbers)
    design = float(spec.lens.f_number)
    if not (math.isfinite(hi) and lo <= hi and lo >= design * (1.0 - 1e-6)):
        raise CameraSpecError("follow", f"f-number range must satisfy f/{design:g} <= lo <= hi, "
                                        f"got {f.f_numbers!r}")


def validate(spec: CameraSpec) -> None:
    """Raise the project's error for anything generate_osl cannot honour."""
    from ..core.aperture import Aperture
    from ..core.prescription import Lens

    if not isinstance(spec, CameraSpec):
        raise CameraSpecError("spec", f"expected a CameraSpec, got {type(spec).__name__}")
    if spec.model not in MODELS:
        raise CameraSpecError("model", f"expected one of {', '.join(MODELS)}, got {spec.model!r}")
    for name in ("sensor_width_mm", "sensor_height_mm", "metres_per_unit"):
        _positive(spec, name)
    z = spec.sensor_z_mm
    if (isinstance(z, bool) or not isinstance(z, (int, float)) or not math.isfinite(z)
            or abs(z) > FLOAT32_SAFE):
        raise CameraSpecError("sensor_z_mm", f"expected a finite number (mm), got {z!r}")
    if spec.aperture is not None and not isinstance(spec.aperture, Aperture):
        raise ApertureError(f"camera spec field 'aperture': expected a core.aperture shape "
                            f"(CircularAperture, PolygonAperture, ImageMaskAperture), got "
                            f"{type(spec.aperture).__name__}")
    if spec.f_number is not None:
        _positive(spec, "f_number")
    if not isinstance(spec.dispersion, bool):
        raise CameraSpecError("dispersion", f"expected True or False, got {spec.dispersion!r}")
    _positive(spec, "squeeze")
    if spec.lens is not None and getattr(spec.lens, "anamorphic", False) and (
            spec.model == "learned" or spec.follow is not None):
        raise CameraSpecError("lens", "an anamorphic lens renders in the exact (or thin), "
                                      "still camera only")
    if spec.ghosts is not None:
        from ..core.ghosts import GhostPlan
        if not isinstance(spec.ghosts, GhostPlan):
            raise CameraSpecError("ghosts", f"expected a core.ghosts.GhostPlan, got "
                                            f"{type(spec.ghosts).__name__}")
        if spec.model not in ("exact", "learned") or spec.follow is not None:
            raise CameraSpecError("ghosts", "ghosts render in the exact and learned still "
                                            "cameras only")
    if spec.probe is not None and spec.probe not in PROBES:
        raise CameraSpecError("probe", f"expected None or one of {', '.join(PROBES)}, "
                                       f"got {spec.probe!r}")
    u = spec.probe_sample
    if (not isinstance(u, tuple) or len(u) not in (2, 4)
            or not all(isinstance(c, (int, float)) and 0.0 <= c < 1.0 for c in u)):
        raise CameraSpecError("probe_sample", f"expected two (or four) numbers in [0, 1), got "
                                              f"{u!r}")

    table = bool(getattr(spec.lens, "table", False))    # known only from a ray table
    if table and spec.model != "learned":
        raise LensError(f"lens '{spec.lens.name}' is known only from a ray table: the "
                        f"{spec.model} camera needs a prescription; its learned model renders "
                        "it", path=spec.lens.path)
    if spec.model in ("exact", "learned") and not table:
        if not isinstance(spec.lens, Lens):
            raise LensError(f"camera spec field 'lens': the {spec.model} camera needs a core "
                            f"Lens, got {type(spec.lens).__name__}")
        if not any(s.stop for s in spec.lens.surfaces):
            raise LensError(f"lens '{spec.lens.name}' has no aperture stop",
                            path=spec.lens.path, field="stop")
        if spec.model == "exact" or spec.ghosts is not None:
            # the exact camera (and the ghosts') writes the surfaces into float32 shader text
            check_shader_range(spec.lens)
    if spec.follow is not None:
        _check_follow(spec)
    elif spec.stop_radius_mm is not None and spec.model in ("exact", "learned") and not table:
        # a spec copied from the derived camera, then changed (dataclasses.replace), must not
        # keep the old stop: its f-number's stop on the same lens
        from ..core.aperture import stop_radius_of
        want = stop_radius_of(spec.lens, spec.lens.f_number if spec.f_number is None
                              else spec.f_number)
        if not math.isclose(float(spec.stop_radius_mm), want, rel_tol=1e-9):
            raise CameraSpecError("stop_radius_mm", f"{spec.stop_radius_mm:g} mm is not the "
                                                    f"stop of f/{spec.f_number:g} on this lens "
                                                    f"({want:g} mm)")
    if spec.model == "learned" and (spec.model_dir is None or not str(spec.model_dir).strip()):
        raise ModelError("the learned camera needs the trained model directory",
                         field="model_dir")
    if spec.model == "thin":
        if spec.lens is not None and not isinstance(spec.lens, Lens):
            raise LensError(f"camera spec field 'lens': expected a core Lens or None, got "
                            f"{type(spec.lens).__name__}")
        if spec.focal_mm is None and spec.lens is None:
            raise CameraSpecError("focal_mm", "the thin lens needs a focal length (or a lens "
                                              "to take it from)")
        if spec.focal_mm is not None:
            _positive(spec, "focal_mm")
        if spec.f_number is None:
            raise CameraSpecError("f_number", "the thin lens needs an f-number")
        d = spec.focus_distance_m
        if (d is None or isinstance(d, bool) or not isinstance(d, (int, float))
                or math.isnan(d) or d <= 0.0):
            raise CameraSpecError("focus_distance_m", f"the thin lens needs a focus distance "
                                                      f"> 0 (metres, inf allowed), got {d!r}")
