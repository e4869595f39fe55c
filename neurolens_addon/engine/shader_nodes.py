"""Material parameters from shader node trees: one parameter row per material.

A material's row is (base colour, metallic, roughness, emission, transmission, ior, f0,
alpha, multiscatter, texture), read from the shader linked to its Material Output (the active
one for All or Cycles, else the first):
  Principled BSDF   Base Color, Metallic, Roughness, Emission Color x Emission Strength,
                    Transmission Weight (x (1 - Metallic)), IOR, Alpha, the dielectric
                    reflectance f0 = ((IOR - 1) / (IOR + 1))^2 x 2 Specular IOR Level, and
                    multiscatter 1 for the Multiscatter GGX distribution (the default), 0 for
                    GGX (bsdf.py: the lobe's multiple-scattering compensation)
  Diffuse BSDF      Color (metallic 0, roughness 1, f0 0: Lambertian alone)
  Glossy BSDF       Color (metallic 1), Roughness, multiscatter as Principled's
  Glass BSDF        Color (the tint of its refraction and reflection), Roughness, IOR;
                    transmission 1 (Principled's transmission tints its refraction only)
  Refraction BSDF   as Glass (its reflection is kept: a small difference from Cycles)
  Transparent BSDF  alpha 0 (light passes straight through, untinted)
  Emission          Color x Strength (black base)
  Mix Shader        the two inputs' parameters mixed by an unconnected Fac f: emission and
                    alpha as p = (1 - f) p_a + f p_b, the scattering parameters by each
                    side's opaque share w_a = (1 - f) alpha_a, w_b = f alpha_b:
                    p = (w_a p_a + w_b p_b) / (w_a + w_b); the texture of the larger share
  Principled Alpha  scales its emission too (it mixes the whole BSDF with transparency)
  anything else     the material's viewport display colour, metallic and roughness
An unconnected Surface renders black; no material gives the grey Principled DEFAULT.
Base Color may come from an Image Texture node (its image, interpolation and extension, and
the UV map a UV Map node names: None for the active render map) or an RGB node; any other link
keeps the socket's own value, with a note. Reroute nodes are followed.
"""

from __future__ import annotations

DEFAULT = {"base": (0.8, 0.8, 0.8), "metallic": 0.0, "roughness": 0.5,
           "emission": (0.0, 0.0, 0.0), "transmission": 0.0, "ior": 1.5, "f0": 0.04,
           "alpha": 1.0, "tint_reflection": 0.0, "multiscatter": 1.0, "texture": None}
#: the parameters a Mix Shader blends linearly (colours and numbers)
MIXED = ("base", "emission", "metallic", "roughness", "transmission", "ior", "f0", "alpha",
         "tint_reflection", "multiscatter")


def rgb(value) -> tuple:
    """The first three components of a colour socket value, as floats."""
    return tuple(float(c) for c in tuple(value)[:3])


def linked_node(socket):
    """The node feeding `socket` (Reroute nodes followed), or None."""
    if not socket.is_linked:
        return None
    node = socket.links[0].from_node
    while node is not None and node.type == "REROUTE":
        node = node.inputs[0].links[0].from_node if node.inputs[0].is_linked else None
    return node


def _socket(node, *names):
    for n in names:
        s = node.inputs.get(n)
        if s is not None:
            return s
    return None


def _colour_input(node, names, notes, mat_name):
    """(rgb, texture spec or None) of a colour socket."""
    s = _socket(node, *names)
    if s is None:
        return (0.0, 0.0, 0.0), None
    src = linked_node(s)
    if src is None:
        return rgb(s.default_value), None
    if src.type == "TEX_IMAGE" and src.image is not None:
        uv_name = None
        vec = linked_node(src.inputs["Vector"]) if "Vector" in src.inputs else None
        if vec is not None and vec.type == "UVMAP":
            uv_name = vec.uv_map or None
        elif vec is not None and vec.type != "TEX_COORD":
            notes.append(f"material '{mat_name}': texture coordinates from a '{vec.name}' node "
                         "are not supported; using the UV map")
        return rgb(s.default_value), (src.image, src.interpolation, src.extension, uv_name)
    if src.type == "RGB":
        return rgb(src.outputs[0].default_value), None
    notes.append(f"material '{mat_name}': '{s.name}' from a '{src.name}' node is not "
                 "supported; using the socket's value")
    return rgb(s.default_value), None


def _value_input(node, name, default):
    s = _socket(node, name)
    return float(s.default_value) if s is not None else default


#: Principled BSDF lobes the engine does not shade yet: (input, default, what the user gets)
UNSHADED_LOBES = (("Coat Weight", 0.0, "its clear coat is left out"),
                  ("Subsurface Weight", 0.0, "subsurface scattering is left out"),
                  ("Sheen Weight", 0.0, "its sheen is left out"))


def dielectric_f0(ior: float, level: float = 0.5) -> float:
    """Principled's reflectance at normal incidence for its IOR and Specular IOR Level."""
    r = (ior - 1.0) / (ior + 1.0)
    return min(max(r * r * 2.0 * level, 0.0), 1.0)


def _multiscatter(node) -> float:
    """1 where the node's distribution compensates GGX's multiple scattering (Cycles'
    Multiscatter GGX), else 0."""
    return 1.0 if getattr(node, "distribution", "MULTI_GGX") == "MULTI_GGX" else 0.0


def _unshaded(node, notes, mat_name) -> None:
    """Say once per material what of a Principled BSDF the engine does not shade."""
    for name, default, what in UNSHADED_LOBES:
        sock = _socket(node, name)
        if sock is not None and (sock.is_linked or float(sock.default_value) != default):
            notes.append(f"material '{mat_name}': {what} (the NEUROLENS engine does not shade "
                         f"'{name}' yet; Cycles does)")


def _shader_params(node, notes, mat_name, depth=0) -> dict:
    p = dict(DEFAULT)
    if node is None:
        return {**p, "base": (0.0, 0.0, 0.0)}        # an unconnected surface renders black
    t = node.type
    if t == "BSDF_PRINCIPLED":
        p["base"], p["texture"] = _colour_input(node, ("Base Color",), notes, mat_name)
        p["metallic"] = _value_input(node, "Metallic", 0.0)
        p["roughness"] = _value_input(node, "Roughness", 0.5)
        em, _ = _colour_input(node, ("Emission Color", "Emission"), notes, mat_name)
        strength = _value_input(node, "Emission Strength", 1.0)
        p["emission"] = tuple(c * strength for c in em)
        p["ior"] = max(_value_input(node, "IOR", 1.5), 1.0)
        p["f0"] = dielectric_f0(p["ior"], _value_input(node, "Specular IOR Level", 0.5))
        p["transmission"] = (min(max(_value_input(node, "Transmission Weight", 0.0), 0.0), 1.0)
                             * (1.0 - min(max(p["metallic"], 0.0), 1.0)))
        p["alpha"] = min(max(_value_input(node, "Alpha", 1.0), 0.0), 1.0)
        p["multiscatter"] = _multiscatter(node)
        # Alpha mixes the whole BSDF, emission included, with transparency (as Cycles does)
        p["emission"] = tuple(c * p["alpha"] for c in p["emission"])
        _unshaded(node, notes, mat_name)
    elif t == "BSDF_DIFFUSE":
        p["base"], p["texture"] = _colour_input(node, ("Color",), notes, mat_name)
        p["roughness"] = 1.0
        p["f0"] = 0.0                                 # Lambert alone: no specular layer
    elif t in ("BSDF_GLOSSY", "BSDF_ANISOTROPIC"):
        p["base"], p["texture"] = _colour_input(node, ("Color",), notes, mat_name)
        p["metallic"] = 1.0
        p["roughness"] = _value_input(node, "Roughness", 0.5)
        p["multiscatter"] = _multiscatter(node)
    elif t in ("BSDF_GLASS", "BSDF_REFRACTION"):
        p["base"], p["texture"] = _colour_input(node, ("Color",), notes, mat_name)
        p["roughness"] = _value_input(node, "Roughness", 0.0)
        p["ior"] = max(_value_input(node, "IOR", 1.5), 1.0)
        p["f0"] = dielectric_f0(p["ior"])
        p["transmission"] = 1.0
        p["tint_reflection"] = 1.0                    # Glass BSDF tints its reflection too
    elif t == "BSDF_TRANSPARENT":
        p["base"] = (0.0, 0.0, 0.0)
        p["alpha"] = 0.0
    elif t == "EMISSION":
        em, _ = _colour_input(node, ("Color",), notes, mat_name)
        strength = _value_input(node, "Strength", 1.0)
        p["base"] = (0.0, 0.0, 0.0)
        p["emission"] = tuple(c * strength for c in em)
    elif t == "MIX_SHADER" and depth < 8:
        fac = float(node.inputs[0].default_value)
        a = _shader_params(linked_node(node.inputs[1]), notes, mat_name, depth + 1) or p
        b = _shader_params(linked_node(node.inputs[2]), notes, mat_name, depth + 1) or p
        # emission and opacity mix linearly; the surface's scattering parameters mix by each
        # side's share of the opaque part, so a Transparent side only makes it see-through
        wa, wb = (1 - fac) * a["alpha"], fac * b["alpha"]
        ta, tb = (wa / (wa + wb), wb / (wa + wb)) if wa + wb > 0 else (1 - fac, fac)
        for k in MIXED:
            u, v = (1 - fac, fac) if k in ("emission", "alpha") else (ta, tb)
            if isinstance(a[k], tuple):
                p[k] = tuple(u * x + v * y for x, y in zip(a[k], b[k]))
            else:
                p[k] = u * a[k] + v * b[k]
        p["texture"] = a["texture"] if ta >= tb else b["texture"]
    else:
        notes.append(f"material '{mat_name}': shader '{node.name}' is not supported; using the "
                     "viewport display colour")
        return None
    return p


def material_params(material, notes: list) -> dict:
    """The parameter row of one material (module docstring)."""
    if material is None:
        return dict(DEFAULT)
    fallback = {**DEFAULT, "base": rgb(material.diffuse_color),
                "metallic": float(material.metallic), "roughness": float(material.roughness)}
    tree = material.node_tree          # Blender 5: materials always use their node tree
    if tree is None:
        return fallback
    outs = [n for n in tree.nodes if n.type == "OUTPUT_MATERIAL"]
    if not outs:
        return fallback
    active = [n for n in outs if n.is_active_output and n.target in ("ALL", "CYCLES")]
    out = (active or outs)[0]
    if out.inputs["Volume"].is_linked:
        notes.append(f"material '{material.name}': its volume is left out (the NEUROLENS engine "
                     "does not shade volumes yet; Cycles does)")
    p = _shader_params(linked_node(out.inputs["Surface"]), notes, material.name)
    return fallback if p is None else p
