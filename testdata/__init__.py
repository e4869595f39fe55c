"""Generators of test inputs that tests/ and benchmarks/ both use (lens-file documents, extreme
camera rays). A neutral place: it imports neither tests nor benchmarks, and, like every
top-level folder but the add-on's own, it is not shipped in the extension (blender_manifest.toml
[build] excludes "/*" and re-includes only the add-on)."""
