"""The engine's render settings: a plain dataclass, read from `scene.neurolens_engine` (the
property group blender/engine_registration.py adds) when it exists, else the defaults; the
light-path limits from the scene's own Light Paths settings (`scene.cycles`), so the engine
and Cycles bounce light alike."""

from __future__ import annotations

from dataclasses import dataclass, fields

from .plan import DEFAULT_MAX_RAYS, HARD_MAX_RAYS


@dataclass
class RenderSettings:
    samples: int = 16               # camera samples per pixel
    bounces: int = 12               # Light Paths > Max Bounces: Total (Cycles' default)
    diffuse_bounces: int = 4        # ... Diffuse
    glossy_bounces: int = 4         # ... Glossy
    transmission_bounces: int = 12  # ... Transmission
    transparent_bounces: int = 8    # ... Transparent (alpha)
    min_light_bounces: int = 0      # Russian roulette only after this many bounces
    tile_size: int = 64             # pixels
    max_bundle_rays: int = DEFAULT_MAX_RAYS   # camera samples per bundle (<= HARD_MAX_RAYS)
    uncertainty_samples: int = 2    # samples per pixel that compute the ensemble spread
    seed: int = 0
    clamp_direct: float = 0.0       # Cycles' Clamp Direct: 0 off, else the largest r+g+b
    clamp_indirect: float = 10.0    # Cycles' Clamp Indirect (its default): after a bounce
    dispersion: bool = True         # sample wavelengths (else the d line, white weights)
    colour_rays: int = 3            # lens rays a sample with dispersion: 3 (R, G, B) or 1
    device: str = "AUTO"            # onnxruntime providers: AUTO (CUDA when present) or CPU
    intersector: str = "AUTO"       # ray casts: AUTO (Embree when installed), EMBREE, BLENDER
    denoise: bool = True            # Open Image Denoise on the finished frame (denoise.py)
    threads: int = 0                # onnxruntime worker threads, 0: one per core
    workers: int = 0                # threads shading bundles at once, 0: one per core
    tile_order: str = "AUTO"        # AUTO, PROGRESSIVE or TILES (engine.memory.streamed_film)
    memory_limit_gb: float = 0.0    # refuse renders estimated above it; 0: what is available

    def checked(self) -> "RenderSettings":
        if self.samples < 1:
            raise ValueError(f"samples must be >= 1, got {self.samples}")
        for name in ("clamp_direct", "clamp_indirect"):
            v = getattr(self, name)
            if not (v >= 0.0 and v < float("inf")):
                raise ValueError(f"{name} must be >= 0 (0: no clamp), got {v}")
        for name in ("bounces", "diffuse_bounces", "glossy_bounces", "transmission_bounces",
                     "transparent_bounces", "min_light_bounces"):
            if getattr(self, name) < 0:
                raise ValueError(f"{name} must be >= 0, got {getattr(self, name)}")
        if self.tile_size < 1:
            raise ValueError(f"tile size must be >= 1, got {self.tile_size}")
        if not 1 <= self.max_bundle_rays <= HARD_MAX_RAYS:
            raise ValueError(f"max_bundle_rays must be in 1..{HARD_MAX_RAYS}, got "
                             f"{self.max_bundle_rays}")
        if self.colour_rays not in (1, 3):
            raise ValueError(f"colour_rays must be 1 or 3, got {self.colour_rays}")
        if self.tile_order not in ("AUTO", "PROGRESSIVE", "TILES"):
            raise ValueError(f"tile_order must be AUTO, PROGRESSIVE or TILES, got "
                             f"{self.tile_order!r}")
        if not (self.memory_limit_gb >= 0.0 and self.memory_limit_gb < float("inf")):
            raise ValueError(f"memory_limit_gb must be >= 0 (0: what the machine has "
                             f"available), got {self.memory_limit_gb}")
        return self

    def providers(self):
        return ["CPUExecutionProvider"] if self.device == "CPU" else None


#: RenderSettings field <- the scene's Light Paths property (scene.cycles)
LIGHT_PATHS = {"bounces": "max_bounces", "diffuse_bounces": "diffuse_bounces",
               "glossy_bounces": "glossy_bounces",
               "transmission_bounces": "transmission_bounces",
               "transparent_bounces": "transparent_max_bounces",
               "min_light_bounces": "min_light_bounces",
               "clamp_direct": "sample_clamp_direct", "clamp_indirect": "sample_clamp_indirect"}


def from_scene(scene) -> RenderSettings:
    props = getattr(scene, "neurolens_engine", None)
    s = RenderSettings()
    paths = getattr(scene, "cycles", None)
    if paths is not None:
        for name, prop in LIGHT_PATHS.items():
            if hasattr(paths, prop):
                setattr(s, name, type(getattr(s, name))(getattr(paths, prop)))
    if props is not None:
        for f in fields(RenderSettings):
            if hasattr(props, f.name):
                setattr(s, f.name, type(getattr(s, f.name))(getattr(props, f.name)))
    return s.checked()
