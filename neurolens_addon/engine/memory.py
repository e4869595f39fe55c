"""The memory a render needs, estimated before it starts, and the memory the machine has.

Estimate. For a W x H frame (P = W H pixels) the render allocates, beyond what the process
already holds (the scene, the lens, its model):
  result       4 C P          Blender's render result: C = 20 float channels (film.PASSES:
                              Combined 4, Depth 1, Normal 3, Vignetting 1, Lens Uncertainty 1,
                              Noisy Image 4, Denoising Albedo 3, Denoising Normal 3, and the
                              data passes asked for: Vector 4, Position 3, UV 3), held by
                              Blender for the frame (none for the viewport)
  film         64 P           the film's sums on a frame film (film.SUM_BYTES a pixel, and 4
                              a data column: Vector 5, Position 3, UV 2), or, on
                              a streamed one, 64 T for the tile in progress (T its pixels)
                              plus 4 c P for the c channels it keeps for post-processing
                              (Combined 4 and the guides 3 + 3 with the denoiser, Combined with
                              diffraction)
  bundles      B (w b + (w + 1) h)   the bundles in flight: w worker threads each shading
                              B lens rays (max_bundle_rays, or fewer when the largest tile at
                              every sample has fewer rays; with dispersion a sample is 3 lens
                              rays, so B bounds rays, not samples) at b = BYTES_PER_LENS_RAY at
                              its peak, and w + 1 finished bundles of h = BYTES_HELD_PER_RAY
                              waiting for the film
  denoise      P (16 + 12 + 12 + 16 + o) + O   the colour, albedo and normal read from a
                              frame film (a streamed film holds them already: not counted
                              again), the denoised Combined, and OIDN's scratch at its
                              OIDN_MAX_MEMORY_MB: O + o P (measured: OIDN_FIXED, OIDN_PER_PIXEL)
  diffraction  24 (2r+1)^2 + 32 S + 16 P + K   the kernels (3 channels and one wavelength's,
                              float64) of radius r, the strip FFTs (S = FFT rows x columns of
                              core.diffraction.strip_rows, ~32 bytes a point), a new Combined
                              when nothing was denoised, and the aperture's Fraunhofer pattern
                              and its kernel blocks K (DIFFRACTION_FIXED)
The constants are measured (tracemalloc over bundles of the demo scene: 1.37-1.43 KB a lens
ray at its peak for the exact and learned double Gauss, 0.2 KB held; OIDN's scratch at its
limit from RSS at 1280 x 720 to 7680 x 4320) and rounded up. The estimate leaves out what
does not grow with the frame (the scene's triangles, onnxruntime's arenas) and Blender's
image writer after the render.

Available. Linux: MemAvailable from /proc/meminfo (what can be allocated without swapping),
lowered to what the process's cgroup still allows (memory.max - memory.current + inactive
file pages, or cgroup v1's limit_in_bytes - usage_in_bytes + total_inactive_file) when it has
a limit; Windows: GlobalMemoryStatusEx's ullAvailPhys; elsewhere os.sysconf's available pages,
or the physical memory when only that is known; None when nothing says (no refusal then).

Refusal. A render whose estimate exceeds the memory available (or the user's limit, the
render settings' Memory Limit, 0 = the machine's) is refused before anything frame-sized is
allocated, with one line: "WxH at S samples needs about X GB, this machine has Y GB available".

Streaming. The film is streamed (tile by tile order, plan.bundles tile_major) when the tile
order setting says so, or in Auto when the frame has one pass (the two orders then coincide)
or its frame film would exceed FRAME_FILM_BUDGET.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field

from . import plan
from .film import CHANNELS, PASSES, SUM_BYTES

#: float channels of Blender's render result for the engine's passes
RESULT_CHANNELS = sum(channels for _name, channels, _chan in PASSES)
#: peak bytes of one bundle's camera samples, lens, casts and shading, a lens ray (measured
#: 1.37-1.43 KB; onnxruntime's and Embree's own buffers are not traced: rounded up)
BYTES_PER_LENS_RAY = 2048
#: bytes a finished bundle holds a lens ray until the film takes it (measured 0.2 KB)
BYTES_HELD_PER_RAY = 256
#: OIDN at OIDN_MAX_MEMORY_MB: fixed scratch, libraries and weights, and per pixel (measured
#: RSS over its inputs: +0.6 GB at 3840 x 2160, +1.2 GB at 7680 x 4320)
OIDN_FIXED = 420 << 20
OIDN_PER_PIXEL = 26
#: the aperture's two 2048^2 Fraunhofer grids, their FFTs, and the kernel's blocks
DIFFRACTION_FIXED = 300 << 20
#: bytes a point of a strip's FFT takes in core.diffraction.convolve (input, spectrum,
#: kernel spectrum, inverse)
DIFFRACTION_PER_FFT_POINT = 32
#: Auto streams a frame whose film sums would take more than this
FRAME_FILM_BUDGET = 256 << 20
GB = 1e9


def streamed_film(width: int, height: int, settings, rays_per_sample: int) -> bool:
    """Whether the film is streamed (module docstring)."""
    order = getattr(settings, "tile_order", "AUTO")
    if order == "TILES":
        return True
    if order == "PROGRESSIVE":
        return False
    max_samples = max(1, settings.max_bundle_rays // rays_per_sample)
    passes = plan.passes_of(width, height, settings.samples, settings.tile_size, max_samples)
    return len(passes) == 1 or SUM_BYTES * width * height > FRAME_FILM_BUDGET


def kept_passes(denoise: bool, diffraction: bool) -> tuple:
    """The passes a streamed film keeps for the frame's post-processing."""
    if denoise:
        return ("Combined", "Denoising Albedo", "Denoising Normal")
    return ("Combined",) if diffraction else ()


@dataclass
class Estimate:
    width: int
    height: int
    samples: int
    parts: dict = field(default_factory=dict)     # name -> bytes

    @property
    def total(self) -> int:
        return int(sum(self.parts.values()))

    def describe(self) -> str:
        parts = ", ".join(f"{k} {v / GB:.2f}" for k, v in self.parts.items() if v)
        return f"about {self.total / GB:.1f} GB ({parts} GB)"


def estimate(width: int, height: int, settings, *, rays_per_sample: int = 1, workers: int = 1,
             streamed: bool = False, denoise: bool = False, diffraction_radius: int | None = None,
             blender_result: bool = True, data=None) -> Estimate:
    """The bytes a render of W x H pixels needs beyond what is allocated already (module
    docstring), by part."""
    p = int(width) * int(height)
    e = Estimate(int(width), int(height), int(settings.samples))
    channels = RESULT_CHANNELS + (data.channels if data is not None else 0)
    e.parts["result"] = 4 * channels * p if blender_result else 0
    keep = kept_passes(denoise, diffraction_radius is not None) if streamed else ()
    sums = SUM_BYTES + (4 * data.width if data is not None else 0)
    if streamed:
        tile = min(settings.tile_size, width) * min(settings.tile_size, height)
        e.parts["film"] = sums * tile + 4 * sum(CHANNELS[k] for k in keep) * p
    else:
        e.parts["film"] = sums * p
    # a bundle is (part of) one pass of one tile: no more rays than the bound, nor than the
    # largest tile's samples (a small frame's bundles are small)
    tile_px = min(settings.tile_size, width) * min(settings.tile_size, height)
    b = min(int(settings.max_bundle_rays), rays_per_sample * int(settings.samples) * tile_px)
    w = max(1, int(workers))
    e.parts["bundles"] = b * (w * BYTES_PER_LENS_RAY + (w + 1) * BYTES_HELD_PER_RAY)
    if denoise:
        inputs = 0 if streamed else 4 * (4 + 3 + 3) * p
        e.parts["denoise"] = inputs + 16 * p + OIDN_FIXED + OIDN_PER_PIXEL * p
    if diffraction_radius is not None:
        from ..core.diffraction import strip_rows
        r = int(diffraction_radius)
        _rows, fh, fw = strip_rows(int(height), int(width), r)
        combined = 0 if denoise else 16 * p
        if not denoise and not streamed:
            combined += 16 * p              # the frame film's Combined, read for it
        e.parts["diffraction"] = (24 * (2 * r + 1) ** 2 + DIFFRACTION_PER_FFT_POINT * fh * fw
                                  + combined + DIFFRACTION_FIXED)
    return e


# ---------------------------------------------------------------- what the machine has

def _read_int(path: str):
    try:
        with open(path, encoding="ascii") as f:
            text = f.read().strip()
    except (OSError, UnicodeDecodeError):
        return None
    return int(text) if text.isdigit() else None


def _inactive_file(path: str, key: str) -> int:
    try:
        with open(path, encoding="ascii") as f:
            for line in f:
                name, _, value = line.partition(" ")
                if name == key and value.strip().isdigit():
                    return int(value)
    except (OSError, UnicodeDecodeError):
        pass
    return 0


def _cgroup_room() -> int | None:
    """What this process's memory cgroup still allows, None without a limit."""
    try:
        with open("/proc/self/cgroup", encoding="ascii") as f:
            lines = f.read().splitlines()
    except (OSError, UnicodeDecodeError):
        return None
    rooms = []
    for line in lines:
        parts = line.split(":", 2)
        if len(parts) != 3:
            continue
        _id, controllers, path = parts
        path = path.lstrip("/")
        if controllers == "":                                   # cgroup v2
            base = os.path.join("/sys/fs/cgroup", path)
            limit = _read_int(os.path.join(base, "memory.max"))
            used = _read_int(os.path.join(base, "memory.current"))
            cache = _inactive_file(os.path.join(base, "memory.stat"), "inactive_file")
        elif "memory" in controllers.split(","):               # cgroup v1
            for base in (os.path.join("/sys/fs/cgroup/memory", path), "/sys/fs/cgroup/memory"):
                limit = _read_int(os.path.join(base, "memory.limit_in_bytes"))
                if limit is not None:
                    break
            used = _read_int(os.path.join(base, "memory.usage_in_bytes"))
            cache = _inactive_file(os.path.join(base, "memory.stat"), "total_inactive_file")
        else:
            continue
        # "max", or v1's page-rounded 2^63: no limit
        if limit is not None and used is not None and limit < (1 << 60):
            rooms.append(max(0, limit - used + cache))
    return min(rooms) if rooms else None


def available_bytes() -> tuple[int | None, str]:
    """(bytes that can be allocated now, where the figure comes from) (module docstring)."""
    try:
        with open("/proc/meminfo", encoding="ascii") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    avail = int(line.split()[1]) * 1024
                    room = _cgroup_room()
                    if room is not None and room < avail:
                        return room, "cgroup memory limit"
                    return avail, "MemAvailable"
    except (OSError, ValueError, UnicodeDecodeError):
        pass
    if os.name == "nt":
        try:
            import ctypes

            class _Status(ctypes.Structure):
                _fields_ = [("dwLength", ctypes.c_ulong), ("dwMemoryLoad", ctypes.c_ulong),
                            ("ullTotalPhys", ctypes.c_ulonglong),
                            ("ullAvailPhys", ctypes.c_ulonglong),
                            ("ullTotalPageFile", ctypes.c_ulonglong),
                            ("ullAvailPageFile", ctypes.c_ulonglong),
                            ("ullTotalVirtual", ctypes.c_ulonglong),
                            ("ullAvailVirtual", ctypes.c_ulonglong),
                            ("ullAvailExtendedVirtual", ctypes.c_ulonglong)]
            st = _Status()
            st.dwLength = ctypes.sizeof(_Status)
            if ctypes.windll.kernel32.GlobalMemoryStatusEx(ctypes.byref(st)):
                return int(st.ullAvailPhys), "GlobalMemoryStatusEx"
        except (OSError, AttributeError, ValueError):
            pass
    for names, source in ((("SC_AVPHYS_PAGES", "SC_PAGE_SIZE"), "sysconf available pages"),
                          (("SC_PHYS_PAGES", "SC_PAGE_SIZE"), "physical memory")):
        try:
            pages, size = (os.sysconf(n) for n in names)
        except (ValueError, OSError, AttributeError):
            continue
        if pages > 0 and size > 0:
            return pages * size, source
    return None, "unknown"


def check(e: Estimate, limit_gb: float = 0.0, available: int | None = None) -> None:
    """Refuse (ResourceError, one line) a render whose estimate exceeds the limit set in the
    render settings (limit_gb > 0) or else the memory available."""
    from ..core.errors import ResourceError
    what = f"{e.width}x{e.height} at {e.samples} sample{'s' if e.samples != 1 else ''}"
    if limit_gb and limit_gb > 0:
        if e.total > limit_gb * GB:
            raise ResourceError(f"{what} needs about {e.total / GB:.1f} GB, over the Memory "
                                f"Limit of {limit_gb:g} GB set in the NeuroLens render "
                                f"settings or --memory-limit (lower the resolution or raise "
                                f"the limit)")
        return
    if available is None:
        available, _source = available_bytes()
    if available is not None and e.total > available:
        raise ResourceError(f"{what} needs about {e.total / GB:.1f} GB, this machine has "
                            f"{available / GB:.1f} GB available (lower the resolution, or set "
                            f"a higher Memory Limit in the NeuroLens render settings or "
                            f"--memory-limit to try anyway)")
