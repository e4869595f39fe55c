"""Blender's lights and world as arrays, and light sampling for direct lighting.

Radiometry follows Cycles' conventions (power P in watts, colour c, distances in scene units):
  point   intensity I = P c / (4 pi) W/sr; a radius r > 0 makes it a disc of radius r facing
          the shading point, sampled uniformly (soft shadows)
  spot    a point light masked by its cone: smoothstep(0, (1 - cos h) b, cos t - cos h), h half
          the spot size, b the blend, t the angle to the spot's axis (its local -Z)
  sun     irradiance E = S c W/m^2 from its local +Z, over a cone of its angular diameter
  area    a one-sided Lambertian emitter of radiance L = P c / (pi A) facing its local -Z
          (square, rectangle, disk or ellipse, scaled with the object), sampled uniformly by
          area: the estimate of its irradiance is  L cos(t_l) cos(t_s) / d^2 * A
A sample returns the direction wi to the light, the distance to shadow-test, the incident
radiance already divided by the sampling density, and that density per solid angle (inf for a
light without size), so that the shading point receives  f(wo, wi) (n.wi) Li / p  when the
shadow ray is clear. Lights with size (area, point and spot with a radius, sun with an angle)
are also met by bounce rays (`Light.hit`: distance, radiance and the density with which
`sample` would have chosen that direction), so the shader weighs the two strategies by
multiple importance sampling. Lights are not visible to camera rays (Blender's default for
lights: an emissive mesh makes a visible source), nor do they block rays; light linking,
light groups, IES profiles, nodes on lights and the spot's non-uniform scale are ignored.
A point light's disc of radius r carries radiance L = I / (pi r^2), so that it delivers the
point light's intensity; a sun of angular radius h carries L = E / (2 pi (1 - cos h)).

World: the Background node's Color x Strength, or an Environment Texture (equirectangular,
u = 0.5 - atan2(y, x) / 2 pi, v = 0.5 + atan2(z, hypot(x, y)) / pi) feeding it; else
world.color. It is sampled as a light: a flat colour uniformly over the sphere (p = 1 / 4 pi),
an environment image in proportion to luminance x cos(elevation) over a grid of at most
256 x 512 cells, p(w) = p_cell(u, v) / (2 pi^2 cos(elevation)) per solid angle.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from . import light_kernels
from .bsdf import basis
from .shader_nodes import linked_node, rgb
from .textures import Texture
from .vec import norm


@dataclass
class Light:
    kind: str                 # POINT, SPOT, SUN, AREA
    colour: np.ndarray        # (3,) P c for point/spot/area, S c for the sun
    position: np.ndarray      # (3,)
    axis_x: np.ndarray        # (3,) local X in world (scaled, area size)
    axis_y: np.ndarray
    forward: np.ndarray       # (3,) unit local -Z (emission direction)
    radius: float = 0.0
    cos_half: float = -1.0    # spot
    smooth: float = 0.0       # spot
    cos_sun: float = 1.0      # cos of the sun's angular radius
    shape: str = "SQUARE"
    size_x: float = 1.0
    size_y: float = 1.0
    shadow: bool = True
    visible: bool = True      # seen by bounce rays (the light's Diffuse/Glossy visibility)

    # -- the light's extent

    @property
    def is_delta(self) -> bool:
        """A point, spot or sun without size: reachable by light sampling only."""
        if self.kind == "SUN":
            return not self.cos_sun < 1.0
        return self.kind != "AREA" and not self.radius > 0.0

    def _extent(self):
        sx = self.size_x
        sy = self.size_x if self.shape in ("SQUARE", "DISK") else self.size_y
        return sx, sy

    @property
    def area(self) -> float:
        sx, sy = self._extent()
        a = sx * sy * float(np.linalg.norm(np.cross(self.axis_x, self.axis_y)))
        return a * (np.pi / 4.0 if self.shape in ("DISK", "ELLIPSE") else 1.0)

    @property
    def plane_normal(self) -> np.ndarray:
        """An area light's unit normal, on its emitting side (its local -Z when unsheared)."""
        n = np.cross(self.axis_x, self.axis_y)
        n = n / max(float(np.linalg.norm(n)), 1e-300)
        return n if n @ self.forward >= 0 else -n

    @property
    def sun_solid_angle(self) -> float:
        return 2.0 * np.pi * (1.0 - self.cos_sun)

    def _spot_mask(self, towards_light: np.ndarray) -> np.ndarray:
        """The spot's cone falloff for unit directions from shading points to the light."""
        if self.kind != "SPOT":
            return np.ones(towards_light.shape[0])
        x = -(towards_light @ self.forward) - self.cos_half
        if self.smooth > 0:
            s = np.clip(x / self.smooth, 0.0, 1.0)
            mask = s * s * (3.0 - 2.0 * s)
        else:
            mask = (x > 0).astype(np.float64)
        return np.where(x > 0, mask, 0.0)

    # -- light sampling

    @cached_property
    def row(self) -> np.ndarray:
        """The light as the compiled kernels read it (light_kernels.light_row)."""
        return light_kernels.light_row(self)

    def sample(self, p: np.ndarray, u1: np.ndarray, u2: np.ndarray):
        """(wi (N, 3) unit, distance (N,), Li / pdf (N, 3), pdf (N,) per solid angle, inf for
        a delta light) for shading points p (N, 3); the reference of light_kernels.sample."""
        n = p.shape[0]
        if self.kind == "SUN":
            axis = -self.forward
            if self.cos_sun < 1.0:
                cos_t = 1.0 - u1 * (1.0 - self.cos_sun)
                sin_t = np.sqrt(np.maximum(0.0, 1.0 - cos_t * cos_t))
                t, b = basis(np.broadcast_to(axis, (n, 3)).copy())
                phi = 2.0 * np.pi * u2
                wi = ((sin_t * np.cos(phi))[:, None] * t + (sin_t * np.sin(phi))[:, None] * b
                      + cos_t[:, None] * axis)
                pdf = np.full(n, 1.0 / self.sun_solid_angle)
            else:
                wi = np.broadcast_to(axis, (n, 3)).copy()
                pdf = np.full(n, np.inf)
            return wi, np.full(n, np.inf), np.broadcast_to(self.colour, (n, 3)).copy(), pdf
        if self.kind == "AREA":
            if self.shape in ("DISK", "ELLIPSE"):
                r = np.sqrt(u1)
                a = 0.5 * r * np.cos(2 * np.pi * u2)
                b = 0.5 * r * np.sin(2 * np.pi * u2)
            else:
                a, b = u1 - 0.5, u2 - 0.5
            sx, sy = self._extent()
            q = self.position + (a * sx)[:, None] * self.axis_x + (b * sy)[:, None] * self.axis_y
            v = q - p
            d2 = np.einsum("ij,ij->i", v, v)
            dist = np.sqrt(d2)
            wi = v / np.maximum(dist, 1e-12)[:, None]
            cos_l = np.maximum(0.0, -(wi @ self.plane_normal))
            li = self.colour[None, :] * (cos_l / (np.pi * np.maximum(d2, 1e-12)))[:, None]
            pdf = np.where(cos_l > 0, d2 / (self.area * np.maximum(cos_l, 1e-12)), 0.0)
            return wi, dist, li, pdf
        # point and spot: a disc of the light's radius facing the shading point
        q = np.broadcast_to(self.position, (n, 3))
        if self.radius > 0:
            to_p = p - self.position
            nrm = to_p / np.maximum(norm(to_p)[:, None], 1e-12)
            t, b = basis(nrm)
            r = self.radius * np.sqrt(u1)
            phi = 2.0 * np.pi * u2
            q = q + (r * np.cos(phi))[:, None] * t + (r * np.sin(phi))[:, None] * b
        v = q - p
        d2 = np.einsum("ij,ij->i", v, v)
        dist = np.sqrt(d2)
        wi = v / np.maximum(dist, 1e-12)[:, None]
        fall = self._spot_mask(wi) / (4.0 * np.pi * np.maximum(d2, 1e-12))
        if self.radius > 0:
            # uniform on the disc: Li / pdf = L cos_l (pi r^2) / d^2 with L = I / (pi r^2)
            to_c = self.position - p
            cos_l = np.abs(np.einsum("ij,ij->i", wi, to_c)) / np.maximum(
                norm(to_c), 1e-12)
            fall = fall * cos_l
            pdf = d2 / (np.pi * self.radius ** 2 * np.maximum(cos_l, 1e-12))
        else:
            pdf = np.full(n, np.inf)
        return wi, dist, self.colour[None, :] * fall[:, None], pdf

    # -- rays that meet the light (bounce rays, for multiple importance sampling)

    def hit(self, o: np.ndarray, d: np.ndarray, escaped: np.ndarray | None = None):
        """(distance (N,), radiance (N, 3), pdf (N,) of `sample` choosing d from o) of rays
        (o, d) that meet the light; distance inf where they miss it. A sun is met by rays that
        escape the scene (`escaped`)."""
        n = o.shape[0]
        if self.is_delta or not self.visible:
            return np.full(n, np.inf), np.zeros((n, 3)), np.zeros(n)
        return self._hit_with_size(o, d, escaped)

    def _hit_with_size(self, o: np.ndarray, d: np.ndarray, escaped: np.ndarray | None):
        """`hit` of a visible light with size: the reference of light_kernels.hit."""
        if self.kind == "SUN":
            inside = (d @ -self.forward) >= self.cos_sun
            if escaped is not None:
                inside &= escaped
            omega = self.sun_solid_angle
            rad = np.where(inside[:, None], self.colour[None, :] / omega, 0.0)
            return np.where(inside, 1e30, np.inf), rad, np.where(inside, 1.0 / omega, 0.0)
        if self.kind == "AREA":
            nrm = self.plane_normal
            den = d @ nrm                                   # < 0: the ray faces the emitter
            t = ((self.position - o) @ nrm) / np.where(den < 0, den, -1.0)
            q = o + t[:, None] * d - self.position
            sx, sy = self._extent()
            a = (q @ self.axis_x) / (self.axis_x @ self.axis_x) / sx
            b = (q @ self.axis_y) / (self.axis_y @ self.axis_y) / sy
            if self.shape in ("DISK", "ELLIPSE"):
                inside = a * a + b * b <= 0.25
            else:
                inside = (np.abs(a) <= 0.5) & (np.abs(b) <= 0.5)
            ok = (den < 0) & (t > 0) & inside
            area = self.area
            rad = np.where(ok[:, None], self.colour[None, :] / (np.pi * area), 0.0)
            pdf = np.where(ok, t * t / (area * np.maximum(-den, 1e-12)), 0.0)
            return np.where(ok, t, np.inf), rad, pdf
        # the disc of the point light facing the ray's origin
        to_o = o - self.position
        dist_o = np.maximum(norm(to_o), 1e-12)
        nrm = to_o / dist_o[:, None]
        den = np.einsum("ij,ij->i", d, nrm)
        t = dist_o / np.maximum(-den, 1e-12)
        q = o + t[:, None] * d - self.position
        ok = (den < 0) & (np.einsum("ij,ij->i", q, q) <= self.radius ** 2)
        disc = np.pi * self.radius ** 2
        rad = (self.colour[None, :] / (4.0 * np.pi * disc)
               * self._spot_mask(d)[:, None])
        rad = np.where(ok[:, None], rad, 0.0)
        pdf = np.where(ok, t * t / (disc * np.maximum(-den, 1e-12)), 0.0)
        return np.where(ok, t, np.inf), rad, pdf


def scene_lights(depsgraph) -> list[Light]:
    """Every light instance of the evaluated scene (instanced lights included)."""
    out = []
    for inst in depsgraph.object_instances:
        ob = inst.object
        if ob.type != "LIGHT":
            continue
        li = ob.data
        m = np.array(inst.matrix_world, dtype=np.float64)
        colour = np.array(rgb(li.color)) * float(li.energy)
        if not colour.any():
            continue
        fwd = -m[:3, 2] / max(np.linalg.norm(m[:3, 2]), 1e-12)
        kw = dict(kind=li.type, colour=colour, position=m[:3, 3].copy(), axis_x=m[:3, 0].copy(),
                  axis_y=m[:3, 1].copy(), forward=fwd,
                  shadow=bool(getattr(li, "use_shadow", True)),
                  visible=bool(getattr(ob, "visible_diffuse", True)
                               or getattr(ob, "visible_glossy", True)))
        if li.type in ("POINT", "SPOT"):
            kw["radius"] = float(li.shadow_soft_size)
            if li.type == "SPOT":
                ch = math.cos(0.5 * float(li.spot_size))
                kw["cos_half"] = ch
                kw["smooth"] = (1.0 - ch) * float(li.spot_blend)
        elif li.type == "SUN":
            kw["cos_sun"] = math.cos(0.5 * float(li.angle))
        elif li.type == "AREA":
            kw["shape"] = li.shape
            kw["size_x"] = float(li.size)
            kw["size_y"] = float(li.size_y)
        else:
            continue
        out.append(Light(**kw))
    return out


class World:
    """Radiance arriving from the environment along world directions, and its importance
    sampling (a piecewise-constant density over the environment image's texels, weighted by
    luminance and by the solid angle of each row, cos(elevation); a flat colour is sampled
    uniformly over the sphere)."""

    #: largest sampling grid (the environment is averaged down to it)
    GRID = (256, 512)

    def __init__(self, colour=(0.0, 0.0, 0.0), texture: Texture | None = None,
                 strength: float = 1.0):
        self.colour = np.asarray(colour, dtype=np.float64)
        self.texture = texture
        self.strength = float(strength)
        self._table = None

    @property
    def is_black(self) -> bool:
        if self.texture is None:
            return not self.colour.any()
        return not self.strength or not self.texture.pixels.any()

    def radiance(self, d: np.ndarray) -> np.ndarray:
        if self.texture is None:
            return np.broadcast_to(self.colour, d.shape).copy()
        u = 0.5 - np.arctan2(d[:, 1], d[:, 0]) / (2.0 * np.pi)
        v = 0.5 + np.arctan2(d[:, 2], np.hypot(d[:, 0], d[:, 1])) / np.pi
        return self.texture.lookup(np.stack([u, v], axis=1)) * self.strength

    # -- importance sampling

    def _grid(self):
        """(rows, cols, CDF over the cells in row-major order (R C + 1,), cell pdf (R, C)) of
        the environment; the cell pdf is per unit of (u, v)."""
        if self._table is None:
            th, tw = self.texture.h, self.texture.w
            rows, cols = min(th, self.GRID[0]), min(tw, self.GRID[1])
            # the texels averaged into the grid's cells (blocks of whole texels)
            px = self.texture.pixels.astype(np.float64)
            ys = (np.arange(rows + 1) * th) // rows
            xs = (np.arange(cols + 1) * tw) // cols
            csum = np.cumsum(np.cumsum(np.pad(px, ((1, 0), (1, 0), (0, 0))), 0), 1)
            block = (csum[ys[1:]][:, xs[1:]] - csum[ys[:-1]][:, xs[1:]]
                     - csum[ys[1:]][:, xs[:-1]] + csum[ys[:-1]][:, xs[:-1]])
            count = np.outer(ys[1:] - ys[:-1], xs[1:] - xs[:-1])[..., None]
            lum = (block / np.maximum(count, 1)) @ np.array([0.2126, 0.7152, 0.0722])
            elev = np.pi * ((np.arange(rows) + 0.5) / rows - 0.5)
            w = np.maximum(lum, 0.0) * np.cos(elev)[:, None] + 1e-12
            cdf = np.concatenate([[0.0], np.cumsum(w.ravel())])
            cdf /= cdf[-1]
            self._table = (rows, cols, cdf, w / w.sum() * rows * cols)
        return self._table

    def sample(self, n: int, u1: np.ndarray, u2: np.ndarray):
        """(wi (N, 3), Li / pdf (N, 3), pdf (N,) per solid angle) of N environment samples."""
        if self.texture is None:
            z = 1.0 - 2.0 * u1
            r = np.sqrt(np.maximum(0.0, 1.0 - z * z))
            phi = 2.0 * np.pi * u2
            wi = np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)
            pdf = np.full(n, 1.0 / (4.0 * np.pi))
            return wi, np.broadcast_to(self.colour * (4.0 * np.pi), (n, 3)).copy(), pdf
        rows, cols, cdf, cell = self._grid()
        k = np.clip(np.searchsorted(cdf, u1, side="right") - 1, 0, rows * cols - 1)
        y, x = np.divmod(k, cols)
        # u1's position within its cell's CDF step places the sample along the row
        fx = np.clip((u1 - cdf[k]) / np.maximum(cdf[k + 1] - cdf[k], 1e-300), 0.0, 1.0)
        u = (x + fx) / cols
        v = (y + u2) / rows
        elev = np.pi * (v - 0.5)
        phi = 2.0 * np.pi * (0.5 - u)
        ce = np.cos(elev)
        wi = np.stack([ce * np.cos(phi), ce * np.sin(phi), np.sin(elev)], axis=1)
        pdf = cell[y, x] / (2.0 * np.pi * np.pi * np.maximum(ce, 1e-12))
        li = self.radiance(wi) / np.maximum(pdf, 1e-300)[:, None]
        return wi, np.where((pdf > 0)[:, None], li, 0.0), pdf

    def pdf(self, d: np.ndarray) -> np.ndarray:
        """Density per solid angle with which `sample` picks the unit directions d."""
        if self.texture is None:
            return np.full(d.shape[0], 1.0 / (4.0 * np.pi))
        rows, cols, _, cell = self._grid()
        u = np.mod(0.5 - np.arctan2(d[:, 1], d[:, 0]) / (2.0 * np.pi), 1.0)
        elev = np.arctan2(d[:, 2], np.hypot(d[:, 0], d[:, 1]))
        v = 0.5 + elev / np.pi
        x = np.clip((u * cols).astype(np.int64), 0, cols - 1)
        y = np.clip((v * rows).astype(np.int64), 0, rows - 1)
        return cell[y, x] / (2.0 * np.pi * np.pi * np.maximum(np.cos(elev), 1e-12))


def scene_world(scene, notes: list | None = None) -> World:
    w = scene.world
    if w is None:
        return World()
    tree = w.node_tree
    if tree is not None:
        outs = [n for n in tree.nodes if n.type == "OUTPUT_WORLD"]
        active = [n for n in outs if n.is_active_output] or outs
        if active:
            bg = linked_node(active[0].inputs["Surface"])
            if bg is None:
                return World()
            if bg.type == "BACKGROUND":
                strength = float(bg.inputs["Strength"].default_value)
                src = linked_node(bg.inputs["Color"])
                if src is not None and src.type == "TEX_ENVIRONMENT" and src.image is not None:
                    tex = Texture.from_image(src.image, src.interpolation, "REPEAT",
                                             notes)
                    if tex is not None:
                        return World(texture=tex, strength=strength)
                colour = rgb(bg.inputs["Color"].default_value)
                return World(np.array(colour) * strength)
            if notes is not None:
                notes.append(f"world shader '{bg.name}' is not supported; using world colour")
    return World(rgb(w.color))
