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
A sample returns the direction wi to the light, the distance to shadow-test and the
incident radiance already divided by the sampling density, so that the shading point
receives  f(wo, wi) (n.wi) * Li  when the shadow ray is clear. Lights are not visible to
camera rays (use an emissive mesh for a visible source), and light linking, light groups,
IES profiles, nodes on lights and the spot's non-uniform scale are ignored.

World: the Background node's Color x Strength, or an Environment Texture (equirectangular,
u = 0.5 - atan2(y, x) / 2 pi, v = 0.5 + atan2(z, hypot(x, y)) / pi) feeding it; else
world.color. The world lights the scene only through rays that escape (bounces), not by
direct sampling.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .bsdf import basis
from .shader_nodes import linked_node, rgb
from .textures import Texture


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

    def sample(self, p: np.ndarray, u1: np.ndarray, u2: np.ndarray):
        """(wi (N, 3) unit, distance (N,), Li (N, 3)) for shading points p (N, 3)."""
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
            else:
                wi = np.broadcast_to(axis, (n, 3)).copy()
            return wi, np.full(n, np.inf), np.broadcast_to(self.colour, (n, 3)).copy()
        if self.kind == "AREA":
            if self.shape in ("DISK", "ELLIPSE"):
                r = np.sqrt(u1)
                a = 0.5 * r * np.cos(2 * np.pi * u2)
                b = 0.5 * r * np.sin(2 * np.pi * u2)
            else:
                a, b = u1 - 0.5, u2 - 0.5
            sx, sy = self.size_x, (self.size_x if self.shape in ("SQUARE", "DISK")
                                   else self.size_y)
            q = self.position + (a * sx)[:, None] * self.axis_x + (b * sy)[:, None] * self.axis_y
            v = q - p
            d2 = np.einsum("ij,ij->i", v, v)
            dist = np.sqrt(d2)
            wi = v / np.maximum(dist, 1e-12)[:, None]
            cos_l = np.maximum(0.0, -(wi @ self.forward))
            li = self.colour[None, :] * (cos_l / (np.pi * np.maximum(d2, 1e-12)))[:, None]
            return wi, dist, li
        # point and spot
        q = np.broadcast_to(self.position, (n, 3))
        if self.radius > 0:
            to_p = p - self.position
            nrm = to_p / np.maximum(np.linalg.norm(to_p, axis=1, keepdims=True), 1e-12)
            t, b = basis(nrm)
            r = self.radius * np.sqrt(u1)
            phi = 2.0 * np.pi * u2
            q = q + (r * np.cos(phi))[:, None] * t + (r * np.sin(phi))[:, None] * b
        v = q - p
        d2 = np.einsum("ij,ij->i", v, v)
        dist = np.sqrt(d2)
        wi = v / np.maximum(dist, 1e-12)[:, None]
        fall = 1.0 / (4.0 * np.pi * np.maximum(d2, 1e-12))
        if self.kind == "SPOT":
            cos_t = -(wi @ self.forward)
            x = cos_t - self.cos_half
            if self.smooth > 0:
                s = np.clip(x / self.smooth, 0.0, 1.0)
                mask = s * s * (3.0 - 2.0 * s)
            else:
                mask = (x > 0).astype(np.float64)
            fall = fall * np.where(x > 0, mask, 0.0)
        return wi, dist, self.colour[None, :] * fall[:, None]


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
                  shadow=bool(getattr(li, "use_shadow", True)))
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
    """Radiance arriving from the environment along world directions."""

    def __init__(self, colour=(0.0, 0.0, 0.0), texture: Texture | None = None,
                 strength: float = 1.0):
        self.colour = np.asarray(colour, dtype=np.float64)
        self.texture = texture
        self.strength = float(strength)

    def radiance(self, d: np.ndarray) -> np.ndarray:
        if self.texture is None:
            return np.broadcast_to(self.colour, d.shape).copy()
        u = 0.5 - np.arctan2(d[:, 1], d[:, 0]) / (2.0 * np.pi)
        v = 0.5 + np.arctan2(d[:, 2], np.hypot(d[:, 0], d[:, 1])) / np.pi
        return self.texture.lookup(np.stack([u, v], axis=1)) * self.strength


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
                    tex = Texture.from_image(src.image, src.interpolation, "REPEAT")
                    if tex is not None:
                        return World(texture=tex, strength=strength)
                colour = rgb(bg.inputs["Color"].default_value)
                return World(np.array(colour) * strength)
            if notes is not None:
                notes.append(f"world shader '{bg.name}' is not supported; using world colour")
    return World(rgb(w.color))
