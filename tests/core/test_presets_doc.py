"""docs/presets.md's table and docs/lenses/ pictures are what scripts/presets_doc.py makes of
the preset files now (a generated document kept current, like the generated OSL)."""

import importlib.util
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def _script():
    spec = importlib.util.spec_from_file_location("presets_doc", ROOT / "scripts" / "presets_doc.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_the_presets_table_and_pictures_are_current(capsys):
    """Regenerating changes nothing: run `python scripts/presets_doc.py` after editing a
    preset."""
    doc = _script()
    assert doc.main(["--check"]) == 0, capsys.readouterr().out
    stems = {p.stem for p in (ROOT / "presets" / "lenses").glob("*.toml")}
    text = (ROOT / "docs" / "presets.md").read_text(encoding="utf-8")
    assert all(f"`{s}`" in text and (ROOT / "docs" / "lenses" / f"{s}.png").is_file()
               for s in stems)
