"""Float OpenEXR images written whole or not at all, through the OpenEXR library.

`write_exr(path, channels, attributes)`: channels {name: (H, W) array, row 0 at the bottom
(as Blender and Nuke's STMap count y)}, stored as 32-bit float scanlines (ZIP compression,
top row first as the format has it), with string and number attributes in the header; the
file is written beside its target and renamed onto it (core.atomic), so a failed write leaves
the old file. OpenEXR is the project's Python's (requirements.txt), not the add-on's bundle:
inside Blender, images are written by Blender.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .errors import NeuroLensError


def write_exr(path, channels: dict, attributes: dict | None = None) -> Path:
    """Write `channels` to the EXR at `path` (module docstring); the path written."""
    try:
        import OpenEXR
    except ImportError as exc:
        raise NeuroLensError(f"writing EXR needs the OpenEXR package ({exc}); install the "
                             "project's requirements (make test does)") from None
    from .atomic import atomic_path
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    for key, value in (attributes or {}).items():
        header[str(key)] = value if isinstance(value, str) else float(value)
    data = {name: np.ascontiguousarray(np.asarray(a, dtype=np.float32)[::-1])
            for name, a in channels.items()}
    with atomic_path(path) as tmp:
        with OpenEXR.File(header, data) as f:
            f.write(str(tmp))
    return Path(path)


def read_exr(path) -> tuple[dict, dict]:
    """(channels {name: (H, W) float32, row 0 at the bottom}, header) of an EXR."""
    import OpenEXR
    with OpenEXR.File(str(path)) as f:
        chans = {name: np.asarray(c.pixels, dtype=np.float32)[::-1].copy()
                 for name, c in f.channels().items()}
        return chans, dict(f.header())
