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
from .unsupported import scene_notes
from .shading import Shader


def plan_memory(setup, settings, *, viewport: bool = False):
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
                          blender_result=not viewport)
    return streamed, est


def build_renderer(scene, depsgraph, camera_obj, setup, settings, sink, *,
                   viewport: bool = False):
    """(FrameRenderer, the LensSetup rendered, SceneMaterials) for one frame; ResourceError
    (one line, with the figure) when its memory estimate exceeds what the machine has."""
    t0 = time.perf_counter()
    stats = RenderStats()
    setup = traced(setup)
    film_geo = setup.film
    streamed, est = plan_memory(setup, settings, viewport=viewport)
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
                    flare_traces_world=traces_world(gen.camera, world))
    keep = memory.kept_passes(settings.denoise, setup.diffraction) if streamed else ()
    film = Film(film_geo.width_px, film_geo.height_px, transparent=scene.render.film_transparent,
                streamed=streamed, keep=keep)
    stats.memory_estimate = est.total
    stats.lens = setup.describe()
    stats.provider = evaluator.provider
    stats.intersector = caster.backend
    if kernels is not None:
        stats.kernels = kernels.describe()
        stats.seconds["kernels"] = kernels.seconds
    stats.seconds["setup"] = time.perf_counter() - t0
    return FrameRenderer(gen, shader, film, settings, sink, stats), setup, materials
