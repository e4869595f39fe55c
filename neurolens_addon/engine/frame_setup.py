"""Everything one frame of the NEUROLENS engine needs, set up once from a resolved lens.

`build_renderer(scene, depsgraph, camera_obj, setup, settings, sink)`: the camera-ray generator
(the set-up through camera.traced, the thin lens traced exactly, and its derived camera:
camera.derived), the scene caster, materials, lights, emissive meshes and world, the film and
the progressive renderer. Before any of it, the render's memory is estimated (engine.memory:
the frame, its passes, the bundles, the denoiser and diffraction) and a render that would not
fit is refused with the figure (core.errors.ResourceError); the film is streamed (tile by tile)
when engine.memory.streamed_film says so. Blender objects come in as arguments; nothing here
imports bpy.
"""

from __future__ import annotations

import os
import time

from ..camera import traced
from ..core.errors import NeuroLensError
from . import memory
from .camera_rays import CameraRayGenerator, make_evaluator
from .emitters import scene_emitters
from .flare import traces_emitters, traces_world
from .film import Film
from .kernel_warmup import warm_up
from .lights import scene_lights, scene_world
from .materials import SceneMaterials
from .renderer import FrameRenderer, RenderStats
from .casters import make_caster
from .data_passes import VECTOR_NOTE, DataLayout, FirstHitData
from .unsupported import scene_notes
from .shading import Shader


def plan_memory(setup, settings, *, viewport: bool = False, data_passes=()):
    """(streamed film?, memory.Estimate) of rendering the traced `setup` with `settings`; a
    viewport keeps a frame film (it shows the frame as it refines) and has no Blender result
    and no denoiser."""
    from . import denoise
    w, h = setup.film.width_px, setup.film.height_px
    rays = 3 if settings.dispersion and setup.dispersion and settings.colour_rays == 3 else 1
    streamed = False if viewport else memory.streamed_film(w, h, settings, rays)
    den = bool(settings.denoise) and not viewport and denoise.available()
    # before the caster exists: as many workers as the settings allow (an upper bound)
    workers = max(1, min(int(settings.workers or (os.cpu_count() or 1)), 16))
    est = memory.estimate(w, h, settings, rays_per_sample=rays, workers=workers,
                          streamed=streamed, denoise=den,
                          diffraction_radius=None if viewport else setup.diffraction_radius_px,
                          blender_result=not viewport,
                          data=DataLayout(tuple(data_passes)) if data_passes else None)
    return streamed, est


#: how far beyond the film's corner (a multiple of its radius) the Vector pass places points
PLACED_FIELD = 3.0
#: an anamorphic lens's grid: how far beyond the frame's edges (a multiple of each half side)
PLACED_GRID = 1.5


def first_hit_data(setup, gen, passes, steps, notes: list):
    """The data passes' FirstHitData of a frame (None without data passes): the Vector pass
    places points by the lens's chief ray (core.projection) where the lens has one, and
    otherwise is left at 0 with a note saying why."""
    if not passes:
        return None
    layout = DataLayout(tuple(passes))
    placement = None
    if "Vector" in passes:
        try:
            placement = film_placement(setup)
        except NeuroLensError as exc:
            notes.append(VECTOR_NOTE.format(why=getattr(exc, "message", str(exc))))
    return FirstHitData(layout, placement=placement, camera_matrix=gen.matrix, steps=steps,
                        mm_per_unit=gen.mm_per_unit, sensor_z_mm=setup.sensor_z_mm)


def film_placement(setup):
    """The core.projection placement of a traced set-up's lens as focused on its film: a
    lens of revolution's chief-ray table out to PLACED_FIELD times the film's corner or as far
    as the lens images, an anamorphic lens's chief-ray grid over PLACED_GRID times the frame
    (a point that moves in from off the frame has a vector too), a lens known only from a
    ray table's chief-ray table through its model; the project's error where
    the lens has no chief rays to place by."""
    from ..core.chief_grid import chief_ray_grid
    from ..core.projection import FilmPlacement, GridPlacement
    from ..core.stmap import chief_ray_table
    f = setup.film
    if setup.entry.table:            # its chief rays through its model (camera.table_lens)
        return FilmPlacement(setup.lens.chief_ray_table(PLACED_FIELD * f.radius_mm), f)
    if setup.lens.anamorphic:
        k = float(setup.squeeze)
        hx = PLACED_GRID * (0.5 * f.width_mm + abs(f.shift_x_mm)) / k
        hy = PLACED_GRID * (0.5 * f.height_mm + abs(f.shift_y_mm))
        grid = chief_ray_grid(setup.lens, setup.sensor_z_mm, hx, hy, squeeze=k)
        return GridPlacement(grid, f)
    table = chief_ray_table(setup.lens, setup.sensor_z_mm, PLACED_FIELD * f.radius_mm)
    return FilmPlacement(table, f)


def build_renderer(scene, depsgraph, camera_obj, setup, settings, sink, *,
                   viewport: bool = False, data_passes=(), motion_steps=None):
    """(FrameRenderer, the LensSetup rendered, SceneMaterials) for one frame; ResourceError
    (one line, with the figure) when its memory estimate exceeds what the machine has.
    data_passes: the data passes asked for (data_passes.DATA_PASSES' names); motion_steps:
    the data_passes.MotionSteps one frame before and after (the Vector pass)."""
    t0 = time.perf_counter()
    stats = RenderStats()
    setup = traced(setup)
    film_geo = setup.film
    data_passes = tuple(data_passes or ())
    streamed, est = plan_memory(setup, settings, viewport=viewport, data_passes=data_passes)
    memory.check(est, settings.memory_limit_gb)
    kernels = warm_up()              # before the frame: the first bundle pays no compile
    evaluator = make_evaluator(setup.derived, providers=settings.providers(),
                               threads=settings.threads or None)
    cam_eval = camera_obj.evaluated_get(depsgraph)
    gen = CameraRayGenerator(evaluator, cam_eval.matrix_world, setup.mm_per_unit,
                             seed=settings.seed,
                             dispersion=settings.dispersion and setup.dispersion,
                             colour_rays=settings.colour_rays)
    caster = make_caster(scene, depsgraph, settings.intersector, should_stop=sink.should_stop,
                         notes=stats.notes)
    materials = SceneMaterials(depsgraph)
    world = scene_world(scene, stats.notes)
    stats.notes.extend(scene_notes(scene, depsgraph))
    emitters = scene_emitters(depsgraph, materials)
    shader = Shader(caster, materials, scene_lights(depsgraph), world,
                    emitters=emitters, settings=settings,
                    camera_position=gen.position, view_axis=gen.view_axis,
                    transparent=scene.render.film_transparent,
                    flare_traces_emitters=traces_emitters(gen.camera, emitters,
                                                          gen.position),
                    flare_traces_world=traces_world(gen.camera, world),
                    data=first_hit_data(setup, gen, data_passes, motion_steps, stats.notes))
    keep = memory.kept_passes(settings.denoise, setup.diffraction) if streamed else ()
    film = Film(film_geo.width_px, film_geo.height_px, transparent=scene.render.film_transparent,
                streamed=streamed, keep=keep,
                data=DataLayout(data_passes) if data_passes else None)
    stats.memory_estimate = est.total
    stats.lens = setup.describe()
    stats.provider = evaluator.provider
    stats.intersector = caster.backend
    if kernels is not None:
        stats.kernels = kernels.describe()
        stats.seconds["kernels"] = kernels.seconds
    stats.seconds["setup"] = time.perf_counter() - t0
    return FrameRenderer(gen, shader, film, settings, sink, stats), setup, materials
