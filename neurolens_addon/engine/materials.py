"""The scene's materials as arrays, and the surface at each ray hit: parameters and normal.

Every material the rays meet becomes one parameter row (shader_nodes.py: base colour,
metallic, roughness, emission, texture), read once per render; row 0 is the grey default for
objects without a material. An image texture is read once per (image, interpolation,
extension) (textures.py) and shared by the rows that use it. Each object hit gets an
ObjectTable (mesh_tables.py) the first time a ray hits it.
For a hit on polygon P of an object, the material row is the object's row of P; where that row
is textured or P is shaded smooth, the hit is located in its triangle of P with barycentric
coordinates (b_0, b_1, b_2), and
    uv        = sum_i b_i uv_i              (the row's UV map, or the active render map)
    base      = texture(uv)                 (replaces the row's base colour)
    n_shading = normalise(sum_i b_i n_i),   turned to the face normal's side (n.g >= 0)
with uv_i and n_i the triangle's corner UVs and world corner normals; elsewhere the shading
normal is the face normal. Not supported: procedural textures, normal and bump maps, Mapping
nodes, textures and smooth normals on instanced geometry (found on the instanced object's own
placement only).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from . import mesh_kernels, shading_kernels
from .mesh_tables import BPY_READS, ObjectTable
from .shader_nodes import DEFAULT, MIXED, material_params
from .textures import Texture
from .vec import norm

#: the parameters gathered per hit (shader_nodes.MIXED): numbers, and colours (R, G, B)
_VECTORS = ("base", "emission")
_SCALARS = tuple(k for k in MIXED if k not in _VECTORS)


@dataclass
class SurfacePoint:
    """Per hit: material parameters and the shading normal (smooth where the mesh is)."""

    base: np.ndarray          # (K, 3)
    metallic: np.ndarray      # (K,)
    roughness: np.ndarray     # (K,)
    emission: np.ndarray      # (K, 3)
    normal: np.ndarray        # (K, 3) unit shading normal, same side as the face normal
    transmission: np.ndarray  # (K,) share of the glass lobe (dielectric.py)
    ior: np.ndarray           # (K,)
    f0: np.ndarray            # (K,) dielectric reflectance at normal incidence
    alpha: np.ndarray         # (K,) opacity
    tint_reflection: np.ndarray  # (K,) share of the glass reflection tinted by the base
    multiscatter: np.ndarray  # (K,) 1: the GGX lobes compensate multiple scattering (bsdf.py)


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
        self._flat = None                   # _flat_tables' arrays

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
                    t = Texture.from_image(image, interp, ext, self.notes)
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

    def arrays(self) -> dict:
        """Per parameter (shader_nodes.MIXED, and "texture"), its array over the rows (M, ...)."""
        arrays = self._arrays
        # rows only grow (another thread may add one meanwhile): arrays cover every row there
        # is at the time of the call
        if arrays is None or arrays["texture"].size != len(self._params):
            ps = list(self._params)
            arrays = {k: np.array([p[k] for p in ps], np.float64) for k in MIXED}
            arrays["texture"] = np.array([p["texture"] for p in ps], np.int64)
            self._arrays = arrays
        return arrays

    # -- objects

    def _table(self, obj_id: int, obj) -> ObjectTable:
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
        tab = ObjectTable(mesh, np.array(ob.matrix_world, dtype=np.float64), poly_material)
        self._objects[obj_id] = tab
        return tab

    def _flat_tables(self, object_ids: np.ndarray, objects: list):
        """The object tables of every object hit as flat arrays, built for the objects not
        seen before: (offset of each object's polygons (O,), their count (O,), the polygons'
        material rows and smooth flags, each ending in a default entry that objects without
        polygons point to)."""
        flat = self._flat
        if flat is not None and object_ids.size and object_ids.max() < flat[0].size \
                and flat[4][object_ids].all():
            return flat
        with BPY_READS:                       # tables and rows grow as the render goes
            for oid in np.unique(object_ids):
                self._table(int(oid), objects[oid])
            tabs = self._objects
            npoly = np.array([t.poly_material.size if t is not None else 0 for t in tabs],
                             np.int64)
            offset = np.concatenate([[0], np.cumsum(npoly)[:-1]]).astype(np.int64)
            end = int(npoly.sum())
            offset = np.where(npoly > 0, offset, end)     # the default entry
            parts = [t for t in tabs if t is not None and t.poly_material.size]
            material = np.concatenate([t.poly_material for t in parts] + [np.zeros(1, np.int64)])
            smooth = np.concatenate([t.smooth for t in parts] + [np.zeros(1, bool)])
            built = np.array([t is not None for t in tabs], bool)
            self._flat = flat = (offset, npoly, material, smooth, built)
            self.arrays()                     # after the tables: rows may have been added
        return flat

    def object_table(self, obj_id: int):
        """The ObjectTable of an object `lookup` has met (None before)."""
        tabs = self._objects
        return tabs[obj_id] if obj_id < len(tabs) else None

    def lookup(self, hits, objects: list) -> SurfacePoint:
        """Material parameters and shading normals of scene_cast.Hits."""
        obj = np.asarray(hits.object, np.int64)
        offset, npoly, flat_material, flat_smooth, _built = self._flat_tables(obj, objects)
        table = self.arrays()
        if shading_kernels.active():      # the rows and their gathers in one pass
            mat, need, normal, scalars, vectors = mesh_kernels.run_surface_rows(
                obj, hits.polygon, hits.normal, offset, npoly, flat_material, flat_smooth,
                table["texture"], tuple(table[k] for k in _SCALARS),
                tuple(table[k] for k in _VECTORS))
            values = dict(zip(_SCALARS, scalars)) | dict(zip(_VECTORS, vectors))
        else:
            normal = hits.normal / np.maximum(norm(hits.normal)[:, None], 1e-12)
            count = npoly[obj]
            at = offset[obj] + np.clip(hits.polygon, 0, np.maximum(count - 1, 0))
            mat = flat_material[at]
            need = flat_smooth[at] | (table["texture"][mat] >= 0)
            values = {k: table[k][mat] for k in MIXED}
        base = values["base"]
        if need.any():
            tex = table["texture"][mat]
            rows_needing = np.flatnonzero(need)
            for oid in np.unique(obj[rows_needing]):
                rows = rows_needing[obj[rows_needing] == oid]
                tab = self._objects[oid]
                poly = np.clip(hits.polygon[rows], 0, tab.poly_material.size - 1)
                tri, bary, normal[rows] = tab.locate_smooth(poly, hits.location[rows],
                                                            normal[rows])
                tx = tex[rows] >= 0
                if not tx.any():                # smooth only: no corner UVs to interpolate
                    continue
                loops = tab.triangles()[4][tri]                   # (K, 3) corner loop indices
                for ti in np.unique(tex[rows[tx]]):
                    pick = tx & (tex[rows] == ti)
                    uv_name = self._params[int(mat[rows[pick][0]])]["uv"]
                    uv = tab.uv(uv_name)
                    if uv is None:
                        continue
                    huv = np.einsum("ij,ijk->ik", bary[pick], uv[loops[pick]])
                    base[rows[pick]] = self._textures[int(ti)].lookup(huv)
        return SurfacePoint(base, values["metallic"], values["roughness"], values["emission"],
                            normal, values["transmission"], values["ior"], values["f0"],
                            values["alpha"], values["tint_reflection"], values["multiscatter"])

    def close(self):
        for ob in self._to_clear:
            try:
                ob.to_mesh_clear()
            except (RuntimeError, ReferenceError):
                pass
        self._to_clear.clear()
