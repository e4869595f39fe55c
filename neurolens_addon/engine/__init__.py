"""The NEUROLENS render engine: the paper's pipeline inside Blender.

For each tile, a *bundle* of camera samples (pixel jitter x aperture x wavelength) goes through
the lens in one batch (learned with onnxruntime, or exact with the core), is moved to world
space with the camera's transform, path traced against the scene (Embree or scene.ray_cast),
and accumulated on the film; the image refreshes tile by tile, then is denoised.

Modules, each with one responsibility (lights, emitters, materials, shader_nodes, textures,
mesh_tables, scene_cast, embree_cast, unsupported, blender_compat and frame_setup read Blender
objects handed to them):
  plan          tiles, progressive sample passes and bounded ray bundles
  camera_rays   film sampling, pupil-aware aperture samples, wavelengths, lens evaluation,
                lens space -> Blender camera space -> world space
  film          per-pass accumulation buffers, sample counts, vignetting and uncertainty
  vec           row-wise operations on (N, 3) vector arrays
  bsdf          the opaque surface model (Lambert under a GGX layer), pure numpy
  dielectric    glass: rough dielectric reflection and refraction, pure numpy
  lights        Blender lights and the world, as arrays; their sampling and ray hits
  emitters      emissive meshes' triangles as a light, sampled by power
  materials     SceneMaterials: the scene's material rows and the surface at each hit
  shader_nodes  material parameters read from node trees
  textures      image textures: lookup, interpolation, extension modes
  mesh_tables   one object's mesh as arrays (materials, triangles, normals, UVs)
  shading       a bundle's paths: light samples, bounces, multiple importance sampling
  scene_cast    the caster interface, and the only caller of scene.ray_cast
  embree_cast   the Embree caster (embreex) over the frame's triangles
  denoise       Open Image Denoise on the finished frame
  viewport      the rendered viewport's progressive session
  unsupported   what a scene uses that the engine does not render, said once
  blender_compat  what differs between Blender 5.0 and 5.2 LTS (lights' node trees)
  settings      the render settings (samples, light paths, tiles, bundle bound, ...)
  renderer      the progressive tile loop, worker threads, timing, cancellation (no bpy)
  frame_setup   one frame's generator, caster, shader and film from a camera.LensSetup

The lens set-up comes from neurolens_addon.camera (the one resolver every renderer uses); the
RenderEngine subclass, its settings panel and registration are bpy glue and live in
neurolens_addon.blender (render_engine, engine_registration). Nothing here imports bpy: the
modules take Blender objects as arguments. docs/render-engine.md is the user's view.
"""
