"""A lens known only from a ray table: the test fixture testdata/models/measured_tessar.neurolens,
learned by `trainer fit-table` from the exact rays of the Tessar preset at infinity focus
(scripts/make_table_lens.py writes the table and trains it: real training on small data).
"""

from __future__ import annotations

from pathlib import Path

from neurolens_addon.core.lensfile import load_lens

ROOT = Path(__file__).resolve().parents[1]
LENS_FILE = ROOT / "presets" / "lenses" / "tessar_f4_5.toml"
MODEL = ROOT / "testdata" / "models" / "measured_tessar.neurolens"
NAME = "measured tessar"


def lens():
    """The Tessar the table was taken from."""
    return load_lens(LENS_FILE)
