"""The one conversion from a camera's settings to its lens set-up (pbrt's camera `Create`).

`resolve_camera(settings)` decides, in this order and for every caller alike:
  lens       the file, loaded once per content (camera.lenses);
  f-number   Blender's F-Stop, clamped to the lens's widest N_0 (core.aperture.clamp_f_number:
             a stored 0.9499999 is f/0.95), the stop radius R = R_0 N_0 / N;
  focus      Blender's focus distance (or focus object / bone), measured from the sensor,
             clamped to the closest focus (camera.focusing);
  aperture   circle, blades (count, rotation, curvature) or image mask (a missing mask is a
             circle, with a warning);
  model      AUTO: the cheapest model within the scene's error budget (camera.model_choice);
             LEARNED: the lens's model among the candidates (exact when none, or without
             onnxruntime); an explicitly named model directory must belong to the lens;
             a lens whose groups stand at a tabulated focus (or zoom) position uses a model
             trained for that position, found by the moved lens's content hash; elsewhere
             a model of the lens at infinity gives way to the exact trace;
  sensor     z_s(D) of the exact lens at the stop radius used (breathing is real); 0 for the
             thin lens; a learned model trained for a narrower stop or other sensor positions
             gives way to the exact trace;
  film       core.film from the sensor and render settings.
Whatever it changes is said in LensSetup.messages; what leaves no lens raises the project's
error (LensError, ModelError, FocusError, FilmError) naming what is wrong.
"""

from __future__ import annotations

import dataclasses
import math

from ..core.aperture import CircularAperture, PolygonAperture, clamp_f_number, stop_radius_of
from ..core.errors import FocusError, ModelError
from ..core.film import FULL_FRAME, FilmError, film_from_settings
from .focusing import clamp_focus_mm, focus_group_position, focus_sensor_z_mm
from ..core.variable_gaps import TABULATED_REL_TOL
from .lenses import grouped_entry, load_lens_entry, zoomed_entry
from .model_choice import EXACT_NAME, ModelChoice, choose_for_scene
from .models import find_model, models_of_lens, onnxruntime_status, read_header
from .settings import COATINGS, MODELS, CameraSettings

#: the most ghosts a camera renders (the brightest first)
MAX_GHOSTS = 64
#: the largest multiplier of the ghosts' light: 10^4 makes a 1e-4 ghost as bright as its
#: source; more only overflows the film (a stored 3.4e38 made pixels of 1e35)
MAX_GHOST_INTENSITY = 1e4
from .setup import INFO, WARNING, FocusFollow, LensSetup

def usable_f_number(requested: float, widest: float) -> tuple[float, str | None]:
    """(f-number, message or None) for a requested f-number on a lens opening to `widest`
    (core.aperture.clamp_f_number, and the widest for a value that is no f-number)."""
    n = float(requested)
    if not (math.isfinite(n) and n > 0.0):
        return widest, (f"f-number {requested:g} is not usable; using the lens's widest "
                        f"aperture f/{widest:g}")
    return clamp_f_number(n, widest)


def build_aperture(a, say):
    """The core aperture of ApertureSettings; a mask that cannot be used is a circle."""
    if a.shape == "mask":
        if a.mask is not None:
            return a.mask
        say(WARNING, f"{a.mask_problem or 'Aperture mask: no image chosen'}; using a round "
                     "aperture")
    elif a.shape == "blades" and int(a.blades) >= 3:
        return PolygonAperture(int(a.blades), float(a.rotation_deg), float(a.curvature))
    return CircularAperture()


def _learned_model(s: CameraSettings, entry, say, zoom_mm: float | None = None):
    """The ModelHeader of the model LEARNED uses, or None (exact) with a warning saying why."""
    ok, msg = onnxruntime_status()
    if s.model_dir:
        info = read_header(s.model_dir)      # ModelError: not a model
        if info.lens_content_hash != entry.content_hash:
            raise ModelError(f"this model was trained for another lens (hash "
                             f"{info.lens_content_hash}), not '{entry.name}' (hash "
                             f"{entry.content_hash})", path=str(s.model_dir))
        if ok:
            return info
    elif ok:
        info = find_model(entry.content_hash, s.model_candidates)
        if info is not None:
            return info
        where = f" in {s.models_folder}" if s.models_folder else ""
        msg = (f"No trained NeuroLens model for '{entry.name}' (lens hash "
               f"{entry.content_hash}){where}: train one with 'python -m trainer fit LENS "
               f"{'' if zoom_mm is None else f'--zoom {zoom_mm:g} '}--out FOLDER/NAME'; "
               "using the exact trace")
    say(WARNING, msg)
    return None


def _named_model_fits(s: CameraSettings, entry, say) -> bool:
    """False (with a warning) when the named model learned this lens at another of its
    tabulated zoom or focus positions: the exact trace then renders this one."""
    from ..core.variable_gaps import position_lenses
    try:
        trained = read_header(s.model_dir).lens_content_hash
    except ModelError:
        return True                          # _learned_model says what is wrong with it
    if trained == entry.content_hash:
        return True
    base = load_lens_entry(s.lens_path).lens
    if base.content_hash() == trained:
        say(WARNING, "This model was trained for the lens focused at infinity (and at its "
                     "first focal length); using the exact trace")
        return False
    for key, k, moved in position_lenses(base):
        if moved.content_hash() == trained:
            table = base.zoom_gaps if key == "zoom" else base.focus_gaps
            say(WARNING, f"This model was trained for the lens at another {key} position "
                         f"({table.positions[k]:g} mm); using the exact trace")
            return False
    return True


def _auto_model(s: CameraSettings, entry, say):
    """(ModelHeader or None, ModelChoice) of model AUTO."""
    choice = choose_for_scene(entry, s.needs, s.model_candidates, needs_error=s.needs_error,
                              pixel_fraction=s.pixel_fraction, renderer=s.renderer)
    if choice.kind != "learned":
        return None, choice
    ok, msg = onnxruntime_status()
    if ok:
        try:
            return read_header(choice.path), choice
        except ModelError as exc:
            msg = f"the chosen model cannot be read ({exc})"
    say(WARNING, msg)
    return None, choice.instead_exact(f"{choice.name} meets the budget, but {msg}: the exact "
                                      "trace is used")


def _learned_misfit(info, n, stop_r, focus_mm, sensor_z):
    """(warning, what the model was trained for) when a learned model cannot render this
    aperture or focus, else None."""
    widest = info.domain.get("stop_radius_mm")
    if widest is not None and stop_r > float(widest) * (1.0 + 1e-9):
        return (f"f/{n:g} opens the stop to {stop_r:.3f} mm, wider than the learned model was "
                f"trained for ({float(widest):.3f} mm)", "a narrower aperture")
    lo, hi = info.sensor_z_range
    if not (lo - 1e-6 <= sensor_z <= hi + 1e-6):
        return (f"Focus at {focus_mm / 1000.0:.3f} m puts the sensor at z = {sensor_z:.3f} mm, "
                f"outside the learned model's range [{lo:.3f}, {hi:.3f}] mm",
                "other focus settings")
    return None


def _remade_per_frame(s: CameraSettings, entry) -> str | None:
    """Why an animated camera cannot read its focus and f-number in the shader (a follow
    camera: one shader for every frame) and is re-made per frame instead, or None: groups that
    move with focus, an anamorphic lens (its camera aims over the rear element, whose
    normalisation is baked per focus), and ghosts (their plan, the share of light each takes,
    is solved per focus and stop)."""
    if entry.lens.focus_gaps is not None:
        return "This lens focuses by moving groups"
    if entry.lens.anamorphic:
        return "This lens is anamorphic"
    if s.ghosts.enabled:
        return "Ghosts are on"
    return None


def _follow(s: CameraSettings, entry, focus_mm: float, n: float) -> FocusFollow | None:
    """The range of an animated focus or f-number, clamped as each frame clamps its value
    (nearer than the closest focus: the closest focus; wider than the lens: its widest);
    None for a camera whose values do not change."""
    focus = [focus_mm] + [clamp_focus_mm(entry, d)[0] for d in s.animated_focus_mm]
    fs = [n] + [clamp_f_number(v, entry.f_number)[0] for v in s.animated_f_numbers
                if v > 0 and math.isfinite(v)]
    if max(focus) == min(focus) and max(fs) == min(fs):
        return None
    return FocusFollow((min(focus), max(focus)), (min(fs), max(fs)))


def _zoom(s: CameraSettings, entry, say, say_cycles) -> float | None:
    """A zoom lens's focal length: Blender's focal length clamped to the lens's range (with a
    message); None for a lens that does not zoom."""
    table = entry.lens.zoom_gaps
    if table is None:
        return None
    lo, hi = table.positions[0], table.positions[-1]
    if s.zoom_animated:
        say_cycles(WARNING, "The focal length of this zoom lens is animated: it is followed "
                            "by re-making the Cycles camera every frame while the add-on runs "
                            "(Render > Lock Interface on); a farm without the add-on renders "
                            "this set-up's focal length on every frame")
    f = s.zoom_mm
    if not math.isfinite(f):
        say(WARNING, f"No focal length set: this zoom lens is used at {lo:g} mm")
        return lo
    if not lo * (1.0 - TABULATED_REL_TOL) <= f <= hi * (1.0 + TABULATED_REL_TOL):
        clamped = min(max(f, lo), hi)
        say(WARNING, f"This lens zooms from {lo:g} to {hi:g} mm: {f:g} mm is used as "
                     f"{clamped:g} mm")
        return clamped
    return f


def resolve_camera(s: CameraSettings) -> LensSetup:
    """The LensSetup of a camera's settings (module docstring)."""
    messages, cycles_messages = list(s.notes), []

    def say(level: str, text: str) -> None:
        messages.append((level, text))

    def say_cycles(level: str, text: str) -> None:
        cycles_messages.append((level, text))

    if s.model not in MODELS:
        raise ModelError(f"camera '{s.camera}': the lens model must be one of "
                         f"{', '.join(MODELS)}, got {s.model!r}")
    entry = load_lens_entry(s.lens_path)
    if entry.table:
        return _table_setup(s, entry, messages, cycles_messages)
    zoom = _zoom(s, entry, say, say_cycles)
    if zoom is not None:
        entry = zoomed_entry(entry, zoom)

    n, f_msg = usable_f_number(s.f_number, entry.f_number)
    if f_msg:
        say(WARNING, f_msg)
    stop_r = stop_radius_of(entry.lens, n)

    focus_mm, msg = clamp_focus_mm(entry, s.focus_distance_mm)
    if msg:
        say(WARNING, msg)

    aperture = build_aperture(s.aperture, say)

    group = 0.0 if s.model == "thin" else focus_group_position(entry, focus_mm)
    # at a tabulated focus the groups stand where a model may have been trained for them
    model_entry = entry
    if group != 0.0 and float(group).is_integer() and s.model in ("auto", "learned"):
        held = grouped_entry(entry, int(group))
        if s.model_dir:
            try:
                mine = read_header(s.model_dir).lens_content_hash == held.content_hash
            except ModelError:
                mine = False                 # _learned_model says what is wrong with it
        else:
            mine = bool(models_of_lens(held.content_hash, s.model_candidates))
        if mine:
            model_entry = held

    model, info, choice, dispersion = s.model, None, None, bool(s.dispersion)
    if model == "learned" and s.model_dir and not _named_model_fits(s, model_entry, say):
        model = "exact"
    if model == "auto":
        info, choice = _auto_model(s, model_entry, say)
        model = "learned" if info is not None else "exact"
    elif model == "learned":
        info = _learned_model(s, model_entry, say, zoom)
        model = "learned" if info is not None else "exact"

    sensor_z = 0.0 if model == "thin" else focus_sensor_z_mm(entry, focus_mm, stop_r)
    follow = _follow(s, entry, focus_mm, n)
    remade = _remade_per_frame(s, entry) if model in ("exact", "learned") else None
    if follow is not None and remade is not None:
        say_cycles(WARNING, f"{remade}: an animated focus or f-number is followed by "
                            "re-making the Cycles camera every frame while the add-on runs "
                            "(Render > Lock Interface on); a farm without the add-on renders "
                            "this set-up's focus and f-number on every frame")
        follow = None
    misfit = None
    if info is not None and group != 0.0 and model_entry is entry:
        misfit = (f"Focus at {focus_mm / 1000.0:.3f} m moves this lens's focusing groups; "
                  "the learned model knows the lens focused at infinity", "infinity focus")
    if info is not None:
        # a camera that follows its animation must fit the model at both ends of its range
        ends = [(n, focus_mm)] if follow is None else [
            (f, d) for f in follow.f_numbers for d in follow.focus_mm]
        for f, d in ends:
            r = stop_radius_of(entry.lens, f)
            misfit = misfit or _learned_misfit(info, f, r, d, focus_sensor_z_mm(entry, d, r))
    if misfit is not None:
        warning, reason = misfit
        say(WARNING, warning + "; using the exact trace")
        model, info = "exact", None
        if choice is not None:
            # a model of the lens focused at infinity knows none of its groups' positions
            choice = choice.instead_exact(f"{choice.name} was trained for {reason}: the exact "
                                          "trace is used", trainable=True,
                                          unfit=f"trained for {reason}",
                                          all_unfit=reason == "infinity focus")
    elif info is not None and dispersion and not info.dispersion:
        say(INFO, "This learned model was trained without dispersion: no chromatic "
                  "aberration (the exact trace has it)")
        dispersion = False

    if s.ghosts.enabled and model == "thin":
        say(INFO, "Cycles renders ghosts with the exact or learned lens; the NeuroLens engine "
                  "renders them with any")
    ghosts = _ghosts(s.ghosts, say)     # before the messages are frozen: it may warn
    film = _film(s, say)
    lens_film = film.on_lens(entry.squeeze)
    if info is not None and lens_film.radius_mm > info.film_radius_mm * (1.0 + 1e-6):
        say(WARNING, f"The frame's corners ({lens_film.radius_mm:.1f} mm from the axis) lie "
                     f"beyond the learned model's film radius {info.film_radius_mm:.1f} mm: "
                     "those rays are outside its domain and stay dark")
    return LensSetup(settings=s, entry=entry, model=model, model_info=info, choice=choice,
                     f_number=float(n), stop_radius_mm=float(stop_r), focus_mm=float(focus_mm),
                     sensor_z_mm=float(sensor_z), aperture=aperture,
                     dispersion=dispersion, film=film, messages=tuple(messages),
                     cycles_messages=tuple(cycles_messages),
                     f_number_clamped=f_msg is not None,
                     follow=follow if model in ("exact", "learned") else None,
                     focus_group=float(group), diffraction=bool(s.diffraction),
                     ghosts=ghosts)


#: why a lens known only from a ray table renders through its learned model
TABLE_WHY = ("this lens is known only from a ray table: its learned model renders it whatever "
             "its cost (there is no prescription to trace exactly)")


def _table_setup(s: CameraSettings, entry, messages: list, cycles_messages: list) -> LensSetup:
    """The LensSetup of a lens known only from a ray table (camera.table_lens): its model
    at the table's own focus and aperture, whatever the camera asks, saying so."""
    def say(level: str, text: str) -> None:
        messages.append((level, text))

    lens = entry.lens
    ok, msg = onnxruntime_status()
    if not ok:
        raise ModelError(f"lens '{lens.name}' is known only from a ray table and renders "
                         f"through its learned model, which needs onnxruntime ({msg})",
                         path=lens.path)
    info = read_header(lens.path)
    if s.model in ("exact", "thin"):
        say(WARNING, f"Lens model {s.model}: {TABLE_WHY}")
    n = float(lens.f_number)
    if math.isfinite(s.f_number) and abs(s.f_number - n) > 0.01 * n:
        say(INFO, f"f/{n:.3g} is the ray table's aperture: the camera's F-Stop "
                  f"(f/{s.f_number:g}) does not change it")
    focus = float(lens.focus_mm)
    asked = s.focus_distance_mm
    if math.isfinite(asked) and not (asked > 1e6 if math.isinf(focus)
                                     else abs(asked - focus) <= 0.01 * focus):
        where = "infinity" if math.isinf(focus) else f"{focus / 1000.0:.3g} m"
        say(INFO, f"The ray table was taken focused at {where}: the camera's focus distance "
                  "does not change it")
    if s.aperture.shape != "circle":
        say(INFO, "The aperture's shape is the ray table's: the camera's blades or mask do "
                  "not apply")
    if s.ghosts.enabled:
        say(WARNING, "Ghosts follow the lens's surfaces, which a ray table does not give: "
                     "no ghosts or flare")
    dispersion = bool(s.dispersion) and info.dispersion
    if s.dispersion and not info.dispersion:
        say(INFO, "The ray table holds one wavelength: no chromatic aberration")
    film = _film(s, say)
    if film.radius_mm > info.film_radius_mm * (1.0 + 1e-6):
        say(WARNING, f"The frame's corners ({film.radius_mm:.1f} mm from the axis) lie beyond "
                     f"the ray table's film radius {info.film_radius_mm:.1f} mm: those rays "
                     "are outside what it holds and stay dark")
    cost = info.ray_cost_us(s.renderer)
    choice = ModelChoice(kind="learned", name=f"learned model {info.name}",
                         path=str(info.directory),
                         error_um_p99=info.image_error_um_p99 or math.nan,
                         budget_um=math.nan, pixel_fraction=float(s.pixel_fraction),
                         reason=TABLE_WHY[0].upper() + TABLE_WHY[1:], renderer=s.renderer,
                         cost_us=None if cost is None else cost[1])
    return LensSetup(settings=s, entry=entry, model="learned", model_info=info, choice=choice,
                     f_number=n, stop_radius_mm=math.inf, focus_mm=focus,
                     sensor_z_mm=float(lens.sensor_z), aperture=CircularAperture(),
                     dispersion=dispersion, film=film, messages=tuple(messages),
                     cycles_messages=tuple(cycles_messages), diffraction=bool(s.diffraction))


def _ghosts(g, say):
    """The ghost settings a render can use (None when off): the count within 1..MAX_GHOSTS,
    the share of samples within [0.02, 0.9], the intensity within [0, MAX_GHOST_INTENSITY];
    what is changed is said."""
    if not g.enabled:
        return None
    if g.coating not in COATINGS:
        say(WARNING, f"Ghosts: coating {g.coating!r} is not one of {', '.join(COATINGS)}; "
                     "using the single MgF2 layer")
        g = dataclasses.replace(g, coating="single")
    fixed = dataclasses.replace(
        g, count=min(max(int(g.count), 1), MAX_GHOSTS),
        share=min(max(float(g.share), 0.02), 0.9) if math.isfinite(g.share) else 0.25,
        intensity=(min(max(float(g.intensity), 0.0), MAX_GHOST_INTENSITY)
                   if math.isfinite(g.intensity) else 1.0))
    if fixed != g:
        say(WARNING, f"Ghosts: {g.count} ghosts, share {g.share:g}, intensity {g.intensity:g} "
                     f"are used as {fixed.count}, {fixed.share:g}, {fixed.intensity:g}")
    return fixed


def _film(s: CameraSettings, say):
    """The film; a render region that holds no pixel is the whole frame (renderers render the
    whole frame; the region only narrows what model AUTO must cover)."""
    try:
        return film_from_settings(s.film)
    except FilmError as exc:
        if tuple(s.film.border) == FULL_FRAME:
            raise
        say(WARNING, f"{exc}: the whole frame is used")
        return film_from_settings(dataclasses.replace(s.film, border=FULL_FRAME))


def traced(setup: LensSetup) -> LensSetup:
    """The set-up a ray-traced render uses: the thin lens becomes the exact lens, focused
    (the NEUROLENS engine renders real lenses only)."""
    if setup.model != "thin":
        return setup
    z = focus_sensor_z_mm(setup.entry, setup.focus_mm, setup.stop_radius_mm)
    group = focus_group_position(setup.entry, setup.focus_mm)
    return dataclasses.replace(setup, model="exact", sensor_z_mm=z,
                               focus_group=group).with_message(
        INFO, "the camera asks for the thin lens; the NEUROLENS engine renders real lenses, "
              "so it traces this lens exactly")


__all__ = ["EXACT_NAME", "FocusError", "build_aperture", "resolve_camera", "traced",
           "usable_f_number"]
