"""docs/presets.md's table and docs/lenses/ pictures are what scripts/presets_doc.py makes of
the preset files now (a generated document kept current, like the generated OSL)."""

from pathlib import Path
from testdata.scripts import load_script

ROOT = Path(__file__).resolve().parents[2]


def _script():
    return load_script("presets_doc")


def test_the_presets_table_and_pictures_are_current(capsys):
    """Regenerating changes nothing: run `python scripts/presets_doc.py` after editing a
    preset."""
    doc = _script()
    assert doc.main(["--check"]) == 0, capsys.readouterr().out
    stems = {p.stem for p in (ROOT / "presets" / "lenses").glob("*.toml")}
    text = (ROOT / "docs" / "presets.md").read_text(encoding="utf-8")
    assert all(f"`{s}`" in text and (ROOT / "docs" / "lenses" / f"{s}.png").is_file()
               for s in stems)
