"""Everything one frame of the NEUROLENS engine needs, set up once from a resolved lens.

`build_renderer(scene, depsgraph, camera_obj, setup, settings, sink)`: the camera-ray generator
(the set-up through camera.traced, the thin lens traced exactly, and its derived camera:
camera.derived), the scene caster,
materials, lights, emissive meshes and world, the film and the progressive renderer. Blender objects come in as
arguments; nothing here imports bpy.
"""

from __future__ import annotations

import time

from ..camera import traced
from .camera_rays import CameraRayGenerator, make_evaluator
from .emitters import scene_emitters
from .film import Film
from .lights import scene_lights, scene_world
from .materials import SceneMaterials
from .renderer import FrameRenderer, RenderStats
from .casters import make_caster
from .unsupported import scene_notes
from .shading import Shader


def build_renderer(scene, depsgraph, camera_obj, setup, settings, sink):
    """(FrameRenderer, the LensSetup rendered, SceneMaterials) for one frame."""
    t0 = time.perf_counter()
    stats = RenderStats()
    setup = traced(setup)
    film_geo = setup.film
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
    shader = Shader(caster, materials, scene_lights(depsgraph), world,
                    emitters=scene_emitters(depsgraph, materials), settings=settings,
                    camera_position=gen.position, view_axis=gen.view_axis,
                    transparent=scene.render.film_transparent)
    film = Film(film_geo.width_px, film_geo.height_px, transparent=scene.render.film_transparent)
    stats.lens = setup.describe()
    stats.provider = evaluator.provider
    stats.intersector = caster.backend
    stats.seconds["setup"] = time.perf_counter() - t0
    return FrameRenderer(gen, shader, film, settings, sink, stats), setup, materials
