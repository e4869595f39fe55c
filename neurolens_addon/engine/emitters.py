"""Emissive meshes as a light: their triangles, sampled in proportion to emitted power.

Every triangle t of an instance whose material emits (materials.SceneMaterials: emission E_t,
constant over the material) joins one table, chosen with probability proportional to its
power weight  w_t = A_t lum(E_t)  (A_t its world area, lum the Rec.709 luminance), and a point
uniformly on it (u, v -> barycentrics (1 - sqrt u, sqrt u (1 - v), sqrt u v)). The density of
a point x on t is then, per unit area, p_A(x) = lum(E_t) / sum_s w_s, so a ray that meets an
emissive surface knows the density of light sampling from its material alone:
    p_w = p_A d^2 / |cos theta_l|       (per solid angle at the shading point)
and a light sample brings  Li / p_w = E |cos theta_l| / (p_A d^2)  (emission is two-sided).
"""

from __future__ import annotations

import numpy as np

from .mesh_tables import GEOMETRY_TYPES, instance_triangles
from .vec import norm

LUMINANCE = np.array([0.2126, 0.7152, 0.0722])


class Emitters:
    """The emissive triangles of a frame."""

    def __init__(self, corners: np.ndarray, emission: np.ndarray):
        self.corners = np.asarray(corners, dtype=np.float64).reshape(-1, 3, 3)
        self.emission = np.asarray(emission, dtype=np.float64).reshape(-1, 3)
        e1 = self.corners[:, 1] - self.corners[:, 0]
        e2 = self.corners[:, 2] - self.corners[:, 0]
        area = 0.5 * norm(np.cross(e1, e2))
        w = area * np.maximum(self.emission @ LUMINANCE, 0.0)
        keep = w > 0
        self.corners, self.emission, w = self.corners[keep], self.emission[keep], w[keep]
        self.total = float(w.sum())
        self.cdf = np.concatenate([[0.0], np.cumsum(w)]) / max(self.total, 1e-300)

    @property
    def count(self) -> int:
        return self.emission.shape[0]

    def __bool__(self) -> bool:
        return self.count > 0

    def solid_angle_at(self, p: np.ndarray) -> float:
        """The solid angle (sr) the emissive triangles subtend at the point p, summed
        (sum A_t |cos t_t| / d_t^2 at their centroids: small, far triangles)."""
        c = self.corners.mean(axis=1) - p
        d2 = np.maximum(np.einsum("ij,ij->i", c, c), 1e-300)
        n = 0.5 * np.cross(self.corners[:, 1] - self.corners[:, 0],
                           self.corners[:, 2] - self.corners[:, 0])
        return float(np.sum(np.abs(np.einsum("ij,ij->i", n, c)) / d2 ** 1.5))

    def area_density(self, emission: np.ndarray) -> np.ndarray:
        """p_A of points whose surfaces emit `emission` (N, 3)."""
        return np.maximum(emission @ LUMINANCE, 0.0) / max(self.total, 1e-300)

    def sample(self, p: np.ndarray, u1: np.ndarray, u2: np.ndarray):
        """(wi (N, 3), distance (N,), Li / p (N, 3), p (N,) per solid angle) for shading
        points p; the reference of light_kernels.emitters_sample."""
        t = np.clip(np.searchsorted(self.cdf, u1, side="right") - 1, 0, self.count - 1)
        # reuse u1's place within the triangle's CDF step as the first barycentric number
        f = np.clip((u1 - self.cdf[t]) / np.maximum(self.cdf[t + 1] - self.cdf[t], 1e-300),
                    0.0, 1.0)
        s = np.sqrt(f)
        c = self.corners[t]
        q = ((1.0 - s)[:, None] * c[:, 0] + (s * (1.0 - u2))[:, None] * c[:, 1]
             + (s * u2)[:, None] * c[:, 2])
        v = q - p
        d2 = np.einsum("ij,ij->i", v, v)
        dist = np.sqrt(d2)
        wi = v / np.maximum(dist, 1e-12)[:, None]
        nrm = np.cross(c[:, 1] - c[:, 0], c[:, 2] - c[:, 0])
        nrm /= np.maximum(norm(nrm)[:, None], 1e-300)
        cos_l = np.abs(np.einsum("ij,ij->i", wi, nrm))
        e = self.emission[t]
        p_a = self.area_density(e)
        pdf = p_a * d2 / np.maximum(cos_l, 1e-12)
        ok = (cos_l > 1e-9) & (p_a > 0)
        li = np.where(ok[:, None], e / np.where(ok, pdf, 1.0)[:, None], 0.0)
        return wi, dist, li, np.where(ok, pdf, 0.0)


def scene_emitters(depsgraph, materials) -> Emitters:
    """The emissive triangles of every instance in the evaluated depsgraph, with the
    materials' emission (materials: SceneMaterials, whose rows it reads)."""
    corners, emission = [], []
    for inst in depsgraph.object_instances:
        ob = inst.object
        if ob.type not in GEOMETRY_TYPES:
            continue
        rows = [materials.row(s.material) for s in ob.material_slots] or [0]
        emis = materials.arrays()["emission"][rows]
        if not (emis @ LUMINANCE > 0).any():
            continue
        read = instance_triangles(inst, material_index=True)
        if read is None:
            continue
        world, poly, mi = read
        tri_emis = emis[np.clip(mi[poly], 0, len(rows) - 1)]
        lit = np.flatnonzero(tri_emis @ LUMINANCE > 0)
        corners.append(world[lit])
        emission.append(tri_emis[lit])
    if not corners:
        return Emitters(np.zeros((0, 3, 3)), np.zeros((0, 3)))
    return Emitters(np.concatenate(corners), np.concatenate(emission))
