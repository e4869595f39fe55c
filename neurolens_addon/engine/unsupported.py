"""What a scene asks for that the engine does not render, said once per render.

Materials report their own unshaded lobes (shader_nodes.py); this looks at the rest of the
scene: motion blur, hair (Curves objects and hair particle systems), volume and point-cloud
objects, light nodes and IES profiles, light linking. Each kind gives one note naming the
first few objects, so a farm log says what differs from Cycles without repeating itself.
A light's node tree counts only when it changes the light (blender_compat: from Blender 5.1
every light has a default tree, which renders as the plain light the engine renders).
"""

from __future__ import annotations

from .blender_compat import light_nodes_change_light

#: objects named in a note, at most
NAMED = 3


def _names(objects: list) -> str:
    shown = ", ".join(f"'{o}'" for o in objects[:NAMED])
    more = len(objects) - NAMED
    return shown + (f" and {more} more" if more > 0 else "")


def scene_notes(scene, depsgraph) -> list[str]:
    """One note per kind of unsupported feature the evaluated scene uses."""
    notes = []
    if getattr(scene.render, "use_motion_blur", False):
        notes.append("motion blur is not rendered by the NEUROLENS engine (every object is "
                     "at the frame's time); Cycles renders it")
    kinds = {"hair": [], "volume": [], "point cloud": [], "light nodes": [],
             "light linking": []}
    seen = set()
    for inst in depsgraph.object_instances:
        ob = inst.object.original
        if ob.name in seen:
            continue
        seen.add(ob.name)
        if ob.type == "CURVES" or any(ps.settings.type == "HAIR"
                                      for ps in getattr(ob, "particle_systems", ())):
            kinds["hair"].append(ob.name)
        elif ob.type == "VOLUME":
            kinds["volume"].append(ob.name)
        elif ob.type == "POINTCLOUD":
            kinds["point cloud"].append(ob.name)
        elif ob.type == "LIGHT" and light_nodes_change_light(ob.data):
            kinds["light nodes"].append(ob.name)
        link = getattr(ob, "light_linking", None)
        if link is not None and (getattr(link, "receiver_collection", None) is not None
                                 or getattr(link, "blocker_collection", None) is not None):
            kinds["light linking"].append(ob.name)
    what = {"hair": "hair is not rendered",
            "volume": "volume objects are not rendered",
            "point cloud": "point clouds are not rendered",
            "light nodes": "light nodes (and IES profiles) are ignored: plain lights",
            "light linking": "light linking is ignored: every light lights everything"}
    for kind, names in kinds.items():
        if names:
            notes.append(f"{what[kind]} by the NEUROLENS engine ({_names(names)}); Cycles "
                         "renders it")
    return notes
