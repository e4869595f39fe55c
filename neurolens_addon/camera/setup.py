"""`LensSetup`: everything a render needs from a camera, resolved once (camera.resolve).

The panel, the Cycles camera, the NEUROLENS engine, the command line and the focus picker all
read this one record: the lens, the model used (and the learned model's header), the
f-number and stop radius, the focus distance and the sensor position that focuses it, the
aperture shape, dispersion, diffraction and the film. Messages (level, text) say what was
changed and why; `cycles_messages` those that concern the Cycles camera alone (shown and
printed where Cycles renders, never by the NeuroLens engine).
"""

from __future__ import annotations

import dataclasses
import functools
from dataclasses import dataclass

from ..core.film import Film
from .lenses import LensEntry
from .model_choice import ModelChoice
from .models import ModelHeader
from .settings import CameraSettings

INFO, WARNING, ERROR = "INFO", "WARNING", "ERROR"


@dataclass(frozen=True)
class FocusFollow:
    """The range of Blender's animated focus and f-number over the frames a camera renders:
    the Cycles camera reads each frame's values within it (cycles.follow)."""

    focus_mm: tuple[float, float]       # nearest, farthest focus distance from the sensor (mm)
    f_numbers: tuple[float, float]      # widest, narrowest f-number


@dataclass(frozen=True)
class LensSetup:
    settings: CameraSettings
    entry: LensEntry
    model: str                          # "exact" | "learned" | "thin": the model used
    model_info: ModelHeader | None      # the learned model's header (learned only)
    choice: ModelChoice | None          # model AUTO: what it chose and why
    f_number: float                     # clamped to the lens's widest
    stop_radius_mm: float               # R = R_design N_design / N
    focus_mm: float                     # from the sensor, not nearer than the closest focus
    sensor_z_mm: float                  # lens-space sensor plane that focuses it (thin: 0)
    aperture: object                    # core.aperture shape
    dispersion: bool                    # wavelength sampled per ray
    film: Film
    messages: tuple = ()                # ((level, text), ...)
    cycles_messages: tuple = ()         # ((level, text), ...) about the Cycles camera only
    f_number_clamped: bool = False      # the f-number asked for is wider than the lens opens
    follow: FocusFollow | None = None   # animated focus or f-number: their range (else None)
    focus_group: float = 0.0            # focusing groups' position (core.variable_gaps; 0: inf)
    diffraction: bool = False           # the frame convolved with the stop's Fraunhofer pattern
    ghosts: object = None               # camera.settings.GhostSettings when ghosts are on

    @functools.cached_property
    def derived(self):
        """The camera.derived.DerivedCamera of this set-up: every optical value the renderers
        use (stop radius, sensor plane, lens film, centre irradiance, samplers, ghost plan),
        derived once."""
        from .derived import DerivedCamera
        return DerivedCamera(self)

    @property
    def aperture_key(self) -> tuple:
        """The stop shape's value key (core.aperture.aperture_key)."""
        from ..core.aperture import aperture_key
        return aperture_key(self.aperture)

    @property
    def squeeze(self) -> float:
        """The squeeze the frame is desqueezed by (the film's x divided by it): the lens's
        nominal one, f_y / f_x as its file stands (LensEntry.squeeze: at infinity for a lens
        with focusing groups), as footage is desqueezed by the lens's stated factor whatever
        the focus. A front anamorphic's squeeze falls as it focuses closer, so its close-ups
        come out wider (its 'mumps'), as on film; 1 for the thin lens."""
        return 1.0 if self.model == "thin" else float(self.entry.squeeze)

    @functools.cached_property
    def working_f_number(self) -> float:
        """The paraxial working f-number at this focus and stop (the thin lens: N (1 + m),
        its image distance over the aperture's diameter)."""
        if self.model == "thin":
            f, d = self.entry.efl_mm, self.focus_mm
            return self.f_number * (d / (d - f) if d > f else 1.0)
        if self.entry.table:             # a ray table's f-number is its working f-number
            return self.f_number
        from ..core.diffraction import lens_working_f_number
        return lens_working_f_number(self.lens, self.focus_mm, self.sensor_z_mm,
                                     self.stop_radius_mm)

    def _kernel_args(self) -> dict:
        f = self.film
        pixel = (f.width_mm * f.height_mm / (f.width_px * f.height_px)) ** 0.5
        return dict(pixel_mm=pixel, working_f_number=self.working_f_number,
                    dispersion=self.dispersion, max_radius_px=max(f.width_px, f.height_px))

    @functools.cached_property
    def diffraction_kernel(self):
        """The film's diffraction kernel (core.diffraction.film_kernel), None when off."""
        if not self.diffraction:
            return None
        from ..core.diffraction import kernel_for
        return kernel_for(self.aperture, **self._kernel_args())

    @property
    def diffraction_radius_px(self) -> int | None:
        """The diffraction kernel's radius in pixels, without computing the kernel (the
        render's memory estimate), None when off."""
        if not self.diffraction:
            return None
        from ..core.diffraction import kernel_radius
        return kernel_radius(**self._kernel_args())

    @functools.cached_property
    def lens(self):
        """The lens as focused: the file's lens with its focusing groups moved to
        `focus_group` (the file's lens itself for unit focusing)."""
        if self.focus_group == 0.0 or self.entry.lens.focus_gaps is None:
            return self.entry.lens
        from ..core.variable_gaps import lens_at
        return lens_at(self.entry.lens, focus=self.focus_group)

    @property
    def camera(self) -> str:
        return self.settings.camera

    @property
    def lens_id(self) -> str | None:
        return self.settings.lens_id

    @property
    def model_dir(self) -> str | None:
        return str(self.model_info.directory) if self.model_info is not None else None

    @property
    def metres_per_unit(self) -> float:
        return self.settings.metres_per_unit

    @property
    def mm_per_unit(self) -> float:
        return 1000.0 * self.settings.metres_per_unit

    @property
    def focus_m(self) -> float:
        return self.focus_mm / 1000.0

    @property
    def key(self) -> tuple:
        """Equal for set-ups that render the same (what the Cycles glue compares)."""
        f = self.film
        return (self.model, self.entry.content_hash, self.entry.path, self.model_dir,
                round(self.sensor_z_mm, 9), round(self.f_number, 9), self.aperture_key,
                self.dispersion, round(self.entry.efl_mm, 9), round(self.focus_mm, 6),
                self.follow, self.diffraction, self.ghosts,
                round(f.width_mm, 9), round(f.height_mm, 9), self.metres_per_unit)

    def as_dict(self) -> dict:
        """Every resolved field as plain JSON values (what `render --show-setup` prints)."""
        f = self.film
        return {
            "camera": self.camera, "lens": self.lens.name, "lens_file": self.entry.path,
            "lens_content_hash": self.entry.content_hash, "model": self.model,
            "model_dir": self.model_dir, "f_number": self.f_number,
            "stop_radius_mm": self.stop_radius_mm, "focus_mm": self.focus_mm,
            "sensor_z_mm": self.sensor_z_mm, "aperture": [str(k) for k in self.aperture_key],
            "dispersion": self.dispersion, "diffraction": self.diffraction,
            "ghosts": (None if self.ghosts is None else
                       dataclasses.asdict(self.ghosts)),
            "metres_per_unit": self.metres_per_unit,
            "film": {"width_px": f.width_px, "height_px": f.height_px, "width_mm": f.width_mm,
                     "height_mm": f.height_mm, "shift_x_mm": f.shift_x_mm,
                     "shift_y_mm": f.shift_y_mm, "border": list(f.border)},
            "choice": self.choice.name if self.choice is not None else None,
            "choice_why": self.choice.reason if self.choice is not None else None,
            "choice_considered": ([] if self.choice is None else
                                  [list(c) for c in self.choice.considered]),
            "choice_cost": (None if self.choice is None else
                            {"renderer": self.choice.renderer,
                             "us_per_camera_ray": self.choice.cost_us,
                             "exact_us_per_camera_ray": self.choice.exact_cost_us}),
            "follow": (None if self.follow is None else
                       {"focus_mm": list(self.follow.focus_mm),
                        "f_numbers": list(self.follow.f_numbers)}),
            "messages": [list(m) for m in self.messages],
            "cycles_messages": [list(m) for m in self.cycles_messages],
        }

    def describe(self) -> str:
        return (f"{self.lens.name} ({self.model}), f/{self.f_number:g}, focus "
                f"{self.focus_m:.3g} m")

    def with_message(self, level: str, text: str) -> "LensSetup":
        return dataclasses.replace(self, messages=self.messages + ((level, text),))
