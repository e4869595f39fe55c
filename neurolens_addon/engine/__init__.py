"""The NEUROLENS render engine: the paper's pipeline inside Blender.

For each tile, a *bundle* of camera samples (pixel jitter x aperture x wavelength) goes through
the lens in one batch (learned with onnxruntime, or exact with the core), is moved to world
space with the camera's transform, intersected with `scene.ray_cast`, shaded, and accumulated
on the film; the image refreshes tile by tile.

Modules, each with one responsibility (lights, materials, shader_nodes, textures, mesh_tables,
scene_cast and frame_setup read Blender objects handed to them):
  plan          tiles, progressive sample passes and bounded ray bundles
  camera_rays   film sampling, pupil-aware aperture samples, wavelengths, lens evaluation,
                lens space -> Blender camera space -> world space
  film          per-pass accumulation buffers, sample counts, vignetting and uncertainty
  bsdf          the surface model (Lambert + GGX microfacet), pure numpy
  lights        Blender lights and the world, as arrays; light sampling
  materials     SceneMaterials: the scene's material rows and the surface at each hit
  shader_nodes  material parameters read from node trees
  textures      image textures: lookup, interpolation, extension modes
  mesh_tables   one object's mesh as arrays (materials, triangles, normals, UVs)
  shading       a bundle's paths: direct lighting with shadow rays, diffuse bounces
  scene_cast    the only caller of scene.ray_cast
  settings      the render settings (samples, bounces, tiles, bundle bound, ...)
  renderer      the progressive tile loop, timing, cancellation (no bpy types)
  frame_setup   one frame's generator, caster, shader and film from a camera.LensSetup

The lens set-up comes from neurolens_addon.camera (the one resolver every renderer uses); the
RenderEngine subclass, its settings panel and registration are bpy glue and live in
neurolens_addon.blender (render_engine, engine_registration). Nothing here imports bpy: the
modules take Blender objects as arguments. docs/render-engine.md is the user's view.
"""
