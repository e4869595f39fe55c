"""What a scene asks of a lens model: the error it can afford and the part of the input space
it uses, derived from the render settings alone (no bpy here; neurolens_addon.blender reads
the settings and builds a RenderNeeds).

The film (pixel counts, sensor fit, pixel aspect, shift, render region) is core.film's, the
one conversion every renderer uses; p is its pixel pitch (the finer of the two axes).

Error budget:  e = pixel_fraction * p  (micrometres on the sensor), compared with a model's
image-space error (trainer evaluate: where the learned ray meets the plane in focus, against
the exact ray, divided by the magnification). Doubling the resolution halves p and so e.

Input space the scene uses:
  film     the radii [r_min, r_max] of the rendered rectangle's points from the axis, on the
           lens's own film (an anamorphic lens's is the frame narrowed by its squeeze); a
           region is a ring, or a disc when it holds the centre (the radial frame's input; a
           cartesian stage's box holds that disc);
  focus    the sensor positions focus_sensor_z(d) over the focus distances the frames use,
           and those of the extreme (distance, f-number) pairs focused at each f-number's own
           stop radius, as the render focuses (best focus moves with the aperture: about 1 mm
           for the bi-convex singlet between f/4 and f/8);
  stop     the stop radius of the widest f-number the frames use;
  spectrum the visible range with dispersion on, the d line without it.
"""

from __future__ import annotations

import hashlib
import json
import math
from dataclasses import asdict, dataclass, field

from .errors import NeuroLensError
from .film import SENSOR_FITS, FilmError, FilmSettings, film_from_settings
from .prescription import Lens

SENSOR_PAD_MM = 1e-3
VISIBLE_NM = (380.0, 780.0)
D_LINE_NM = 587.5618


class SceneNeedsError(NeuroLensError):
    """Render settings that describe no image (zero resolution, an empty border, ...)."""


def _positive(name: str, value) -> float:
    v = float(value)
    if not (math.isfinite(v) and v > 0):
        raise SceneNeedsError(f"{name} must be a positive number, got {value!r}")
    return v


@dataclass(frozen=True)
class RenderNeeds:
    """The render settings that decide what a lens model must do."""

    resolution_x: int
    resolution_y: int
    sensor_width_mm: float
    sensor_height_mm: float
    sensor_fit: str = "AUTO"
    resolution_percentage: float = 100.0
    border: tuple[float, float, float, float] = (0.0, 0.0, 1.0, 1.0)   # x0, y0, x1, y1
    f_numbers: tuple[float, ...] = ()             # every f-number the frames use
    focus_distances_m: tuple[float, ...] = ()     # every focus distance the frames use
    dispersion: bool = True
    pixel_fraction: float = 0.5                   # allowed error, in pixels
    pixel_aspect_x: float = 1.0
    pixel_aspect_y: float = 1.0
    shift_x: float = 0.0                          # Blender's lens shift (larger film side)
    shift_y: float = 0.0
    squeeze: float = 1.0                          # the lens's: its film is 1 / squeeze as wide
    extras: dict = field(default_factory=dict, compare=False)

    def __post_init__(self):
        for name in ("resolution_x", "resolution_y"):
            v = getattr(self, name)
            if not (isinstance(v, int) and v > 0):
                raise SceneNeedsError(f"{name} must be a positive integer, got {v!r}")
        for name in ("sensor_width_mm", "sensor_height_mm", "resolution_percentage",
                     "pixel_fraction", "squeeze"):
            _positive(name, getattr(self, name))
        if self.sensor_fit not in SENSOR_FITS:
            raise SceneNeedsError(f"sensor_fit must be one of {SENSOR_FITS}, got "
                                  f"{self.sensor_fit!r}")
        x0, y0, x1, y1 = (float(v) for v in self.border)
        if not (0.0 <= x0 < x1 <= 1.0 and 0.0 <= y0 < y1 <= 1.0):
            raise SceneNeedsError(f"border must satisfy 0 <= x0 < x1 <= 1 and 0 <= y0 < y1 <= 1, "
                                  f"got {self.border}")
        for f in self.f_numbers:
            _positive("f-number", f)
        for d in self.focus_distances_m:
            _positive("focus distance", d)

    # -- the film -------------------------------------------------------------------------
    @classmethod
    def from_film(cls, film: FilmSettings, **lens_settings) -> "RenderNeeds":
        """The needs of a film (core.film.FilmSettings) and the lens settings the frames use
        (f_numbers, focus_distances_m, dispersion, pixel_fraction, extras)."""
        return cls(resolution_x=film.resolution_x, resolution_y=film.resolution_y,
                   sensor_width_mm=film.sensor_width, sensor_height_mm=film.sensor_height,
                   sensor_fit=film.sensor_fit, resolution_percentage=film.percentage,
                   border=tuple(film.border), pixel_aspect_x=film.pixel_aspect_x,
                   pixel_aspect_y=film.pixel_aspect_y, shift_x=film.shift_x,
                   shift_y=film.shift_y, **lens_settings)

    def film_settings(self) -> FilmSettings:
        return FilmSettings(self.sensor_width_mm, self.sensor_height_mm, self.sensor_fit,
                            self.resolution_x, self.resolution_y, self.resolution_percentage,
                            self.pixel_aspect_x, self.pixel_aspect_y, self.shift_x,
                            self.shift_y, tuple(self.border))

    def film(self):
        """The rendered frame on the lens's sensor (core.film.Film; an anamorphic lens's film
        is the frame narrowed by its squeeze: Film.on_lens)."""
        try:
            return film_from_settings(self.film_settings()).on_lens(self.squeeze)
        except FilmError as exc:
            raise SceneNeedsError(str(exc)) from None

    def pixel_pitch_mm(self) -> float:
        return self.film().pixel_pitch_mm

    def error_budget_um(self) -> float:
        return 1000.0 * self.pixel_fraction * self.pixel_pitch_mm()

    def film_rect_mm(self) -> tuple[float, float, float, float]:
        """(x0, y0, x1, y1) of the rendered film in mm, axis at 0 (image x right, y up)."""
        return self.film().rect_mm()

    def film_radii_mm(self) -> tuple[float, float]:
        """[r_min, r_max]: the distances from the axis the rendered rectangle covers."""
        return self.film().radii_mm()

    # -- the lens settings ----------------------------------------------------------------
    def widest_f_number(self) -> float | None:
        return min(self.f_numbers) if self.f_numbers else None

    def wavelength_range_nm(self) -> tuple[float, float]:
        return VISIBLE_NM if self.dispersion else (D_LINE_NM, D_LINE_NM)

    def as_dict(self) -> dict:
        d = asdict(self)
        d.pop("extras")
        d["border"] = list(d["border"])
        d["f_numbers"] = sorted(set(d["f_numbers"]))
        d["focus_distances_m"] = sorted(set(d["focus_distances_m"]))
        return d


@dataclass(frozen=True)
class TrainingRegion:
    """The part of a lens's input space a scene uses (what a scene model is trained on)."""

    film_radius_mm: float
    film_radius_min_mm: float
    sensor_z_range: tuple[float, float]
    stop_radius_mm: float
    wavelength_range_nm: tuple[float, float]
    dispersion: bool

    def as_dict(self) -> dict:
        return {k: (list(v) if isinstance(v, tuple) else v) for k, v in asdict(self).items()}

    def key(self, lens: Lens, config: dict) -> str:
        """Content hash naming a model trained on this region: the lens prescription, the
        region (rounded to 1e-6 so float noise does not retrain) and the trainer config."""
        region = {k: (round(v, 6) if isinstance(v, float) else
                      [round(x, 6) for x in v] if isinstance(v, list) else v)
                  for k, v in self.as_dict().items()}
        blob = json.dumps({"lens": lens.content_hash(), "region": region, "config": config},
                          sort_keys=True)
        return hashlib.sha256(blob.encode()).hexdigest()[:24]


def used_sensor_z(lens: Lens, needs: RenderNeeds, focus_z=None) -> list[float]:
    """The sensor positions of the extreme (focus distance, f-number) pairs `needs` uses, each
    focused at its own stop radius (as the render focuses). `focus_z(lens, distance_mm,
    stop_radius_mm)` defaults to core.focus.focus_sensor_z (a caller may pass a cached one)."""
    from .aperture import clamp_f_number, stop_radius_of
    if focus_z is None:
        from .focus import focus_sensor_z

        def focus_z(lens, d_mm, stop):
            return focus_sensor_z(lens, d_mm, stop_radius=stop)
    fs = sorted({clamp_f_number(f, lens.f_number)[0] for f in needs.f_numbers})
    stops = [stop_radius_of(lens, f)
             for f in ((fs[0], fs[-1]) if fs else ())] or [lens.stop_radius_mm]
    ds = sorted(needs.focus_distances_m)
    ds = (ds[0], ds[-1]) if ds else ()
    return [float(focus_z(lens, 1000.0 * d, s)) for d in ds for s in stops]


def training_region(lens: Lens, needs: RenderNeeds, *, margin: float = 0.02,
                    focus_z=None) -> TrainingRegion:
    """The region of `needs` on `lens`, grown by `margin` (relative) so samples at its edge are
    fitted as well as inside it; its sensor range also holds used_sensor_z (padded by
    SENSOR_PAD_MM), so a model trained on it covers the camera it was trained for. The film
    radius stops at the lens's image circle (core.field: the widest over the sensor range),
    beyond which no light reaches the film: a fisheye on a full-frame camera needs no model
    of its dark corners. `focus_z`: as in used_sensor_z."""
    from .aperture import clamp_f_number, stop_radius_of
    from .focus import closest_focus_mm, focus_sensor_z
    r_min, r_max = needs.film_radii_mm()
    r_max *= 1.0 + margin
    r_min = max(0.0, r_min * (1.0 - margin) - margin * r_max)
    if needs.focus_distances_m:
        nearest = closest_focus_mm(lens)
        zs = []
        for d in needs.focus_distances_m:
            if 1000.0 * d < nearest:
                raise SceneNeedsError(f"focus distance {d} m is nearer than the lens's closest "
                                      f"focus {nearest / 1000.0:.3f} m")
            zs.append(focus_sensor_z(lens, 1000.0 * d))
    else:
        zs = [focus_sensor_z(lens, math.inf), focus_sensor_z(lens, closest_focus_mm(lens))]
    z_lo, z_hi = min(zs), max(zs)
    pad = max(1e-3, margin * (z_hi - z_lo))
    f = needs.widest_f_number()
    if f is None:
        stop = lens.stop_radius_mm
    else:
        f, _ = clamp_f_number(f, lens.f_number)
        stop = min(lens.stop_radius_mm, stop_radius_of(lens, f) * (1.0 + margin))
    lo, hi = z_lo - pad, z_hi + pad
    used = used_sensor_z(lens, needs, focus_z)
    if used:
        lo, hi = min(lo, min(used) - SENSOR_PAD_MM), max(hi, max(used) + SENSOR_PAD_MM)
    from .field import image_circle_radius_mm
    circle = max(image_circle_radius_mm(lens, z) for z in (lo, hi))
    if circle > 0.0:
        r_max = min(r_max, circle)
        r_min = min(r_min, r_max)
    return TrainingRegion(r_max, r_min, (lo, hi), stop,
                          needs.wavelength_range_nm(), needs.dispersion)
