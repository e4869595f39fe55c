"""Material parameters from node trees, as plain arrays, read once per render.

Each material becomes one row of (base colour, metallic, roughness, emission, texture):
  Principled BSDF   Base Color, Metallic, Roughness, Emission Color x Emission Strength
  Diffuse BSDF      Color (metallic 0, roughness 1)
  Glossy BSDF       Color (metallic 1), Roughness
  Emission          Color x Strength (black base)
  Mix Shader        the two inputs' parameters mixed by an unconnected Fac
  anything else     the material's viewport display colour, metallic and roughness
Base Color may come from an Image Texture node (looked up through the mesh's UVs: the active
render UV map, or the one a UV Map node names) or an RGB node; any other link keeps the
socket's own value. Images are read once into linear float arrays (8-bit sRGB images decoded
with the sRGB transfer function, as Blender's colour management does); Closest and Linear
(bilinear; also used for Cubic and Smart) interpolation, Repeat / Extend / Clip / Mirror
extension. Objects without a material get a grey Principled default.

Per object (built the first time a ray hits it): the material row of each polygon of the
evaluated mesh (material_index -> material slot -> row), and, when one of its materials is
textured, the mesh's loop triangles in world space with their UVs. The UV of a hit on polygon
P is interpolated with the barycentric coordinates of the hit point in the triangle of P that
contains it (the one whose smallest barycentric coordinate is largest).
The same barycentric coordinates interpolate the mesh's corner normals on polygons shaded
smooth (ray_cast itself gives face normals); the shading normal is turned to the face
normal's side. Not supported: procedural textures, normal and bump maps, Mapping nodes,
textures and smooth normals on instanced geometry (found on the instanced object's own
placement only).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

DEFAULT = {"base": (0.8, 0.8, 0.8), "metallic": 0.0, "roughness": 0.5,
           "emission": (0.0, 0.0, 0.0), "texture": None}


def srgb_to_linear(c: np.ndarray) -> np.ndarray:
    c = np.asarray(c, dtype=np.float32)
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4).astype(np.float32)


class Texture:
    """An image as a linear (H, W, 3) float32 array, row 0 at the bottom (Blender's order)."""

    def __init__(self, pixels: np.ndarray, interpolation: str = "Linear",
                 extension: str = "REPEAT", name: str = ""):
        self.pixels = np.ascontiguousarray(pixels, dtype=np.float32)
        self.h, self.w = self.pixels.shape[:2]
        self.closest = interpolation == "Closest"
        self.extension = extension
        self.name = name

    @classmethod
    def from_image(cls, image, interpolation="Linear", extension="REPEAT"):
        w, h = (int(s) for s in image.size)
        if w == 0 or h == 0:
            return None
        buf = np.empty(w * h * image.channels, dtype=np.float32)
        image.pixels.foreach_get(buf)
        px = buf.reshape(h, w, image.channels)
        rgb = px[..., :3] if image.channels >= 3 else np.repeat(px[..., :1], 3, axis=2)
        space = image.colorspace_settings.name
        if not image.is_float and space in ("sRGB", "sRGB EOTF"):
            rgb = srgb_to_linear(rgb)
        return cls(rgb, interpolation, extension, image.name)

    def _wrap(self, x: np.ndarray, n: int):
        """Integer texel indices under the extension mode, and an inside mask (Clip)."""
        inside = np.ones(x.shape, dtype=bool)
        if self.extension == "REPEAT":
            x = np.mod(x, n)
        elif self.extension == "MIRROR":
            x = np.mod(x, 2 * n)
            x = np.where(x >= n, 2 * n - 1 - x, x)
        else:
            if self.extension == "CLIP":
                inside = (x >= 0) & (x < n)
            x = np.clip(x, 0, n - 1)
        return x, inside

    def lookup(self, uv: np.ndarray) -> np.ndarray:
        """(N, 2) UVs -> (N, 3) linear RGB."""
        u = uv[:, 0] * self.w
        v = uv[:, 1] * self.h
        if self.closest:
            x, okx = self._wrap(np.floor(u).astype(np.int64), self.w)
            y, oky = self._wrap(np.floor(v).astype(np.int64), self.h)
            return np.where((okx & oky)[:, None], self.pixels[y, x], 0.0)
        u, v = u - 0.5, v - 0.5
        x0, y0 = np.floor(u), np.floor(v)
        fx, fy = (u - x0)[:, None], (v - y0)[:, None]
        x0, y0 = x0.astype(np.int64), y0.astype(np.int64)
        xa, oka = self._wrap(x0, self.w)
        xb, okb = self._wrap(x0 + 1, self.w)
        ya, okc = self._wrap(y0, self.h)
        yb, okd = self._wrap(y0 + 1, self.h)
        p = self.pixels
        return ((1 - fy) * ((1 - fx) * p[ya, xa] * (oka & okc)[:, None]
                            + fx * p[ya, xb] * (okb & okc)[:, None])
                + fy * ((1 - fx) * p[yb, xa] * (oka & okd)[:, None]
                        + fx * p[yb, xb] * (okb & okd)[:, None]))


# ---------------------------------------------------------------- node trees

def _rgb(value) -> tuple:
    return tuple(float(c) for c in tuple(value)[:3])


def _linked_node(socket):
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
    src = _linked_node(s)
    if src is None:
        return _rgb(s.default_value), None
    if src.type == "TEX_IMAGE" and src.image is not None:
        uv_name = None
        vec = _linked_node(src.inputs["Vector"]) if "Vector" in src.inputs else None
        if vec is not None and vec.type == "UVMAP":
            uv_name = vec.uv_map or None
        elif vec is not None and vec.type != "TEX_COORD":
            notes.append(f"material '{mat_name}': texture coordinates from a '{vec.name}' node "
                         "are not supported; using the UV map")
        return _rgb(s.default_value), (src.image, src.interpolation, src.extension, uv_name)
    if src.type == "RGB":
        return _rgb(src.outputs[0].default_value), None
    notes.append(f"material '{mat_name}': '{s.name}' from a '{src.name}' node is not "
                 "supported; using the socket's value")
    return _rgb(s.default_value), None


def _value_input(node, name, default):
    s = _socket(node, name)
    return float(s.default_value) if s is not None else default


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
    elif t == "BSDF_DIFFUSE":
        p["base"], p["texture"] = _colour_input(node, ("Color",), notes, mat_name)
        p["roughness"] = 1.0
    elif t in ("BSDF_GLOSSY", "BSDF_ANISOTROPIC"):
        p["base"], p["texture"] = _colour_input(node, ("Color",), notes, mat_name)
        p["metallic"] = 1.0
        p["roughness"] = _value_input(node, "Roughness", 0.5)
    elif t == "EMISSION":
        em, _ = _colour_input(node, ("Color",), notes, mat_name)
        strength = _value_input(node, "Strength", 1.0)
        p["base"] = (0.0, 0.0, 0.0)
        p["emission"] = tuple(c * strength for c in em)
    elif t == "MIX_SHADER" and depth < 8:
        fac = float(node.inputs[0].default_value)
        a = _shader_params(_linked_node(node.inputs[1]), notes, mat_name, depth + 1)
        b = _shader_params(_linked_node(node.inputs[2]), notes, mat_name, depth + 1)
        for k in ("metallic", "roughness"):
            p[k] = (1 - fac) * a[k] + fac * b[k]
        for k in ("base", "emission"):
            p[k] = tuple((1 - fac) * x + fac * y for x, y in zip(a[k], b[k]))
        p["texture"] = a["texture"] if fac < 0.5 else b["texture"]
    else:
        notes.append(f"material '{mat_name}': shader '{node.name}' is not supported; using the "
                     "viewport display colour")
        return None
    return p


def material_params(material, notes: list) -> dict:
    """The parameter row of one material (module docstring)."""
    if material is None:
        return dict(DEFAULT)
    fallback = {"base": _rgb(material.diffuse_color), "metallic": float(material.metallic),
                "roughness": float(material.roughness), "emission": (0.0, 0.0, 0.0),
                "texture": None}
    tree = material.node_tree          # Blender 5: materials always use their node tree
    if tree is None:
        return fallback
    outs = [n for n in tree.nodes if n.type == "OUTPUT_MATERIAL"]
    if not outs:
        return fallback
    active = [n for n in outs if n.is_active_output and n.target in ("ALL", "CYCLES")]
    out = (active or outs)[0]
    p = _shader_params(_linked_node(out.inputs["Surface"]), notes, material.name)
    return fallback if p is None else p


# ---------------------------------------------------------------- per-object tables

class _ObjectTable:
    """One object's evaluated mesh as arrays: polygon -> material row and smooth flag, and on
    demand its loop triangles in world space, world corner normals and UV maps."""

    def __init__(self, mesh, matrix: np.ndarray, poly_material: np.ndarray):
        self.mesh = mesh
        self.matrix = matrix
        self.poly_material = poly_material
        npoly = poly_material.size
        self.smooth = np.zeros(npoly, dtype=bool)
        if npoly:
            mesh.polygons.foreach_get("use_smooth", self.smooth)
        self._tris = None
        self._normals = None
        self._uv = {}

    def triangles(self):
        """(first triangle of each polygon (P,), count (P,), world corners (T, 3, 3),
        corner loop indices (T, 3)), triangles sorted by polygon."""
        if self._tris is None:
            mesh, m = self.mesh, self.matrix
            tris = mesh.loop_triangles
            t = len(tris)
            loops = np.empty(3 * t, np.int32)
            verts = np.empty(3 * t, np.int32)
            tpoly = np.empty(t, np.int32)
            tris.foreach_get("loops", loops)
            tris.foreach_get("vertices", verts)
            tris.foreach_get("polygon_index", tpoly)
            co = np.empty(3 * len(mesh.vertices), np.float64)
            mesh.vertices.foreach_get("co", co)
            co = co.reshape(-1, 3) @ m[:3, :3].T + m[:3, 3]
            order = np.argsort(tpoly, kind="stable")
            npoly = self.poly_material.size
            first = np.searchsorted(tpoly[order], np.arange(npoly))
            count = np.bincount(tpoly, minlength=npoly)
            self._tris = (first, count, co[verts.reshape(-1, 3)[order]],
                          loops.reshape(-1, 3)[order])
        return self._tris

    def corner_normals(self) -> np.ndarray:
        """(L, 3) unit world-space corner normals (normals transform by the inverse
        transpose of the object's matrix)."""
        if self._normals is None:
            n = np.empty(3 * len(self.mesh.loops), np.float64)
            self.mesh.corner_normals.foreach_get("vector", n)
            n = n.reshape(-1, 3) @ np.linalg.inv(self.matrix[:3, :3])
            n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
            self._normals = n
        return self._normals

    def uv(self, name):
        """(L, 2) corner UVs of the named map (None: the active render map), or None."""
        if name not in self._uv:
            layers = self.mesh.uv_layers
            layer = layers.get(name) if name else None
            if layer is None:
                layer = next((lay for lay in layers if lay.active_render), None) or layers.active
            if layer is None:
                self._uv[name] = None
            else:
                uv = np.empty(2 * len(self.mesh.loops), np.float64)
                layer.data.foreach_get("uv", uv)
                self._uv[name] = uv.reshape(-1, 2)
        return self._uv[name]

    def locate(self, poly: np.ndarray, p: np.ndarray):
        """(triangle (K,), barycentrics (K, 3)) of hit points p on polygons poly: of the
        polygon's triangles, the one whose smallest barycentric coordinate is largest."""
        first, count, corners, _ = self.triangles()
        best = np.full(poly.size, -np.inf)
        tri = np.zeros(poly.size, np.int64)
        bary = np.zeros((poly.size, 3))
        for j in range(int(count[poly].max(initial=0))):
            has = j < count[poly]
            t = np.where(has, first[poly] + j, 0)
            c = corners[t]
            b = _barycentric(p, c[:, 0], c[:, 1], c[:, 2])
            score = np.where(has, b.min(axis=1), -np.inf)
            better = score > best
            best = np.where(better, score, best)
            tri = np.where(better, t, tri)
            bary = np.where(better[:, None], b, bary)
        return tri, bary


def _barycentric(p, a, b, c):
    v0, v1, v2 = b - a, c - a, p - a
    d00 = np.einsum("ij,ij->i", v0, v0)
    d01 = np.einsum("ij,ij->i", v0, v1)
    d11 = np.einsum("ij,ij->i", v1, v1)
    d20 = np.einsum("ij,ij->i", v2, v0)
    d21 = np.einsum("ij,ij->i", v2, v1)
    den = d00 * d11 - d01 * d01
    den = np.where(np.abs(den) > 1e-30, den, 1e-30)
    v = (d11 * d20 - d01 * d21) / den
    w = (d00 * d21 - d01 * d20) / den
    return np.stack([1.0 - v - w, v, w], axis=1)


@dataclass
class SurfacePoint:
    """Per hit: material parameters and the shading normal (smooth where the mesh is)."""

    base: np.ndarray        # (K, 3)
    metallic: np.ndarray    # (K,)
    roughness: np.ndarray   # (K,)
    emission: np.ndarray    # (K, 3)
    normal: np.ndarray      # (K, 3) unit shading normal, same side as the face normal


class SceneMaterials:
    """Every material's parameters as arrays (row 0: the default material) and per-object
    tables, built lazily as objects are first hit."""

    def __init__(self, depsgraph):
        self.depsgraph = depsgraph
        self.notes: list[str] = []
        self._rows: dict = {}
        self._params: list[dict] = [{**DEFAULT, "texture": -1, "uv": None}]
        self._textures: list[Texture] = []
        self._tex_keys: dict = {}
        self._objects: list = []          # by caster object id
        self._to_clear: list = []
        self._arrays = None

    # -- materials

    def row(self, material) -> int:
        if material is None:
            return 0
        key = material.name_full
        r = self._rows.get(key)
        if r is None:
            p = material_params(material, self.notes)
            tex = p.pop("texture")
            p["texture"] = -1
            p["uv"] = None
            if tex is not None:
                image, interp, ext, uv_name = tex
                tkey = (image.name_full, interp, ext)
                ti = self._tex_keys.get(tkey)
                if ti is None:
                    t = Texture.from_image(image, interp, ext)
                    if t is None:
                        self.notes.append(f"image '{image.name}' has no pixels (missing file?)")
                        ti = -1
                    else:
                        ti = len(self._textures)
                        self._textures.append(t)
                    self._tex_keys[tkey] = ti
                p["texture"], p["uv"] = ti, uv_name
            r = self._rows[key] = len(self._params)
            self._params.append(p)
            self._arrays = None
        return r

    def arrays(self):
        """(base (M, 3), metallic (M,), roughness (M,), emission (M, 3), texture (M,))."""
        if self._arrays is None:
            ps = self._params
            self._arrays = (np.array([p["base"] for p in ps], np.float64),
                            np.array([p["metallic"] for p in ps], np.float64),
                            np.array([p["roughness"] for p in ps], np.float64),
                            np.array([p["emission"] for p in ps], np.float64),
                            np.array([p["texture"] for p in ps], np.int64))
        return self._arrays

    # -- objects

    def _table(self, obj_id: int, obj) -> _ObjectTable:
        while len(self._objects) <= obj_id:
            self._objects.append(None)
        tab = self._objects[obj_id]
        if tab is not None:
            return tab
        ob = obj.evaluated_get(self.depsgraph)
        if ob.type == "MESH":
            mesh = ob.data
        else:
            mesh = ob.to_mesh()
            self._to_clear.append(ob)
        npoly = len(mesh.polygons)
        mi = np.zeros(npoly, np.int32)
        if npoly:
            mesh.polygons.foreach_get("material_index", mi)
        slots = [self.row(s.material) for s in ob.material_slots] or [0]
        poly_material = np.asarray(slots, np.int64)[np.clip(mi, 0, len(slots) - 1)]
        tab = _ObjectTable(mesh, np.array(ob.matrix_world, dtype=np.float64), poly_material)
        self._objects[obj_id] = tab
        return tab

    def lookup(self, hits, objects: list) -> SurfacePoint:
        """Material parameters and shading normals of scene_cast.Hits."""
        k = hits.ray.size
        mat = np.zeros(k, np.int64)
        normal = hits.normal / np.maximum(np.linalg.norm(hits.normal, axis=1, keepdims=True),
                                          1e-12)
        groups = []
        for oid in np.unique(hits.object):
            sel = np.flatnonzero(hits.object == oid)
            tab = self._table(int(oid), objects[oid])
            npoly = tab.poly_material.size
            poly = np.clip(hits.polygon[sel], 0, max(npoly - 1, 0))
            mat[sel] = tab.poly_material[poly] if npoly else 0
            groups.append((sel, tab, poly))
        base_a, met_a, rough_a, emis_a, tex_a = self.arrays()   # rows may have been added
        base = base_a[mat]
        tex = tex_a[mat]
        for sel, tab, poly in groups:
            if not tab.poly_material.size:
                continue
            smooth = tab.smooth[poly]
            textured = tex[sel] >= 0
            need = smooth | textured
            if not need.any():
                continue
            ns = np.flatnonzero(need)
            tri, bary = tab.locate(poly[ns], hits.location[sel[ns]])
            loops = tab.triangles()[3][tri]                   # (K, 3) corner loop indices
            sm = smooth[ns]
            if sm.any():
                cn = tab.corner_normals()
                n = np.einsum("ij,ijk->ik", bary[sm], cn[loops[sm]])
                n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
                g = normal[sel[ns[sm]]]
                n = np.where((np.einsum("ij,ij->i", n, g) < 0)[:, None], -n, n)
                normal[sel[ns[sm]]] = n
            tx = textured[ns]
            for ti in np.unique(tex[sel[ns[tx]]]):
                pick = tx & (tex[sel[ns]] == ti)
                rows = sel[ns[pick]]
                uv_name = self._params[int(mat[rows[0]])]["uv"]
                uv = tab.uv(uv_name)
                if uv is None:
                    continue
                huv = np.einsum("ij,ijk->ik", bary[pick], uv[loops[pick]])
                base[rows] = self._textures[int(ti)].lookup(huv)
        return SurfacePoint(base, met_a[mat], rough_a[mat], emis_a[mat], normal)

    def close(self):
        for ob in self._to_clear:
            try:
                ob.to_mesh_clear()
            except (RuntimeError, ReferenceError):
                pass
        self._to_clear.clear()
