"""bpy glue for the Cycles custom camera: put a generated OSL camera on a Blender camera.

`apply_lens_camera(camera_data, spec)` writes neurolens_addon.cycles.generate_osl(spec) into an
internal text datablock (never a file in the add-on folder), sets the camera to Custom with it
and has Cycles compile it (cycles.osl.update_custom_camera_shader, the same call the Lens
panel's update makes), unless the source is unchanged since the last call. Cycles' camera-shader
update imports `oslquery`, which the PyPI bpy module keeps in its own site-packages:
`ensure_osl_query_path()` puts that on sys.path first.

OSL cameras run on the CPU device, or on OptiX GPUs (Blender manual, Custom Camera);
`OSL_DEVICE_NOTE` is the sentence the UI shows, `osl_camera_device_ok(scene)` the check.
"""

from __future__ import annotations

import os
import sys
import tempfile

import bpy

from ..core.errors import NeuroLensError
from ..cycles import CameraSpec, generate_osl, source_hash

OSL_DEVICE_NOTE = "OSL custom cameras render on the CPU, or on NVIDIA GPUs with OptiX, in Cycles"
TEXT_PREFIX = "NeuroLens camera"
HASH_KEY = "neurolens_osl_hash"


class OSLCompileError(NeuroLensError, RuntimeError):
    """Cycles' OSL compiler refused a generated camera shader (message: the compiler's log)."""


def osl_query_path() -> str:
    """The bpy module's bundled site-packages (where `oslquery` lives)."""
    return os.path.join(bpy.utils.resource_path("LOCAL"), "python", "lib",
                        f"python{sys.version_info.major}.{sys.version_info.minor}",
                        "site-packages")


def ensure_osl_query_path() -> str:
    """Make `import oslquery` work (needed by Cycles' camera-shader update); return the path.

    Inside Blender the module is already importable and nothing changes."""
    try:
        import oslquery
        return os.path.dirname(os.path.dirname(oslquery.__file__))
    except ImportError:
        pass
    path = osl_query_path()
    if not os.path.isdir(path):
        raise OSLCompileError(f"Blender's OSL query module folder is missing: {path}")
    if path not in sys.path:
        sys.path.append(path)
    return path


def use_cycles_cpu(scene, *, osl_shading: bool = False) -> None:
    """Render `scene` with Cycles on the CPU (where OSL cameras run). The camera shader does
    not need OSL shading; `osl_shading=True` also switches shading to OSL."""
    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    if osl_shading:
        scene.cycles.shading_system = True


def osl_camera_device_ok(scene) -> tuple[bool, str]:
    """(True, "") when Cycles can run an OSL camera for this scene, else (False, why)."""
    if scene.render.engine != "CYCLES":
        return False, "the render engine is not Cycles"
    if scene.cycles.device == "CPU":
        return True, ""
    try:
        prefs = bpy.context.preferences.addons["cycles"].preferences
        if prefs.compute_device_type == "OPTIX":
            return True, ""
    except (KeyError, AttributeError):
        pass
    return False, OSL_DEVICE_NOTE


def compile_osl(source: str) -> str:
    """Compile OSL source with Cycles' built-in compiler; the .oso text, or OSLCompileError
    carrying the compiler's messages."""
    import _cycles
    with tempfile.TemporaryDirectory(prefix="neurolens_osl_") as tmp:
        src = os.path.join(tmp, "camera.osl")
        oso = os.path.join(tmp, "camera.oso")
        log = os.path.join(tmp, "oslc.log")
        with open(src, "w", encoding="utf-8") as fh:
            fh.write(source)
        # oslc reports on the process's stderr / stdout: catch them at the descriptor level
        saved = [os.dup(1), os.dup(2)]
        with open(log, "w") as fh:
            os.dup2(fh.fileno(), 1)
            os.dup2(fh.fileno(), 2)
            try:
                ok = _cycles.osl_compile(src, oso)
            finally:
                os.dup2(saved[0], 1)
                os.dup2(saved[1], 2)
                for fd in saved:
                    os.close(fd)
        with open(log, encoding="utf-8", errors="replace") as fh:
            messages = fh.read().strip()
        if not ok or not os.path.isfile(oso):
            raise OSLCompileError("the generated camera shader does not compile:\n" +
                                  (messages or "(no compiler output)"))
        with open(oso, encoding="utf-8") as fh:
            return fh.read()


def _text_for(camera_data):
    name = f"{TEXT_PREFIX} {camera_data.name}.osl"
    text = bpy.data.texts.get(name)
    if text is None:
        text = bpy.data.texts.new(name)
    return text


def apply_lens_camera(camera_data, spec: CameraSpec) -> bool:
    """Make `camera_data` (a bpy.types.Camera) a Cycles Custom camera running the spec's
    shader. Returns False when nothing had to change (same source, already compiled)."""
    source = generate_osl(spec)
    digest = source_hash(source)
    text = camera_data.custom_shader
    if (camera_data.get(HASH_KEY) == digest and camera_data.type == "CUSTOM"
            and camera_data.custom_mode == "INTERNAL" and text is not None
            and text.as_string() == source and camera_data.custom_bytecode):
        return False
    ensure_osl_query_path()
    if text is None or not text.name.startswith(TEXT_PREFIX):
        text = _text_for(camera_data)
    if text.as_string() != source:
        text.clear()
        text.write(source)
    camera_data.type = "CUSTOM"
    camera_data.custom_mode = "INTERNAL"
    camera_data.custom_shader = text
    messages: list[str] = []
    import cycles.osl
    ok = cycles.osl.update_custom_camera_shader(
        camera_data, lambda kind, msg: messages.append(f"{min(kind)}: {msg}"))
    if not ok or not camera_data.custom_bytecode:
        compile_osl(source)     # raises with the compiler's own messages
        raise OSLCompileError("Cycles did not accept the camera shader: " + "; ".join(messages))
    camera_data[HASH_KEY] = digest
    return True


def clear_lens_camera(camera_data) -> None:
    """Back to Blender's perspective camera; the text datablock is removed when unused."""
    text = camera_data.custom_shader
    camera_data.type = "PERSP"
    camera_data.custom_shader = None
    if HASH_KEY in camera_data:
        del camera_data[HASH_KEY]
    if text is not None and text.name.startswith(TEXT_PREFIX) and text.users == 0:
        bpy.data.texts.remove(text)
