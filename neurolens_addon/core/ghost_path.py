"""A ghost's path through a lens: light reflected at two surfaces a < b (core.ghosts).

Surfaces are numbered 0 (front) to N - 1 (rear); medium k lies in front of surface k (medium 0
is the scene's air, medium N the air before the sensor). Light of the ghost (a, b) enters at
surface 0, is reflected back at surface b, forward again at surface a, and reaches the sensor.
A camera traces it backwards (sensor -> scene):
    surfaces N-1 .. a+1   refract                      (media k+1 -> k)
    surface a             reflect, staying in medium a+1
    surfaces a+1 .. b-1   refract, travelling -z       (media k -> k+1)
    surface b             reflect, staying in medium b
    surfaces b-1 .. 0     refract                      (media k+1 -> k)
core.trace follows it (trace(..., ghost=Ghost(a, b))), and the light's own way, scene -> sensor,
the same steps in reverse (ghost_steps_from_scene: trace(..., from_sensor=False, ghost=...)).
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Ghost:
    """The ghost reflected at surfaces a < b (0-based, front to back)."""

    a: int
    b: int

    def __str__(self) -> str:
        return f"{self.a + 1}-{self.b + 1}"        # 1-based, as a prescription numbers them


def ghost_steps(n_surfaces: int, ghost: Ghost):
    """(order, media pairs, reflect flags) of the camera-side path (module docstring)."""
    a, b = ghost.a, ghost.b
    if not 0 <= a < b < n_surfaces:
        raise ValueError(f"ghost {a}-{b}: surfaces must satisfy 0 <= a < b < {n_surfaces}")
    order, pairs, refl = [], [], []
    for k in range(n_surfaces - 1, a, -1):
        order.append(k), pairs.append((k + 1, k)), refl.append(False)
    order.append(a), pairs.append((a + 1, a)), refl.append(True)
    for k in range(a + 1, b):
        order.append(k), pairs.append((k, k + 1)), refl.append(False)
    order.append(b), pairs.append((b, b + 1)), refl.append(True)
    for k in range(b - 1, -1, -1):
        order.append(k), pairs.append((k + 1, k)), refl.append(False)
    return order, pairs, refl


def ghost_steps_from_scene(n_surfaces: int, ghost: Ghost):
    """(order, media pairs, reflect flags) of the light's path, scene -> sensor: the camera's
    steps in reverse order, each refraction's media swapped (a reflection keeps its pair: the
    medium it stays in, then the one beyond the surface)."""
    order, pairs, refl = ghost_steps(n_surfaces, ghost)
    return (order[::-1], [p if r else (p[1], p[0]) for p, r in zip(pairs[::-1], refl[::-1])],
            refl[::-1])
