"""A lens folder holding hostile files (issue 27): the picker still lists every shipped preset
and every good file of the folder, and each bad file costs its own entry only, with a one-line
note naming it; Load Lens File refuses a bad file with one line (no traceback) and leaves the
camera as it was. The files are testdata/hostile_lens_files.py's corpus (its readers' own test,
tests/core/test_hostile_lens_files.py, reads all of them in a child process with bounded
memory; the three whose counts made the original code allocate without end are left out here,
where the add-on runs in the test's own process)."""

from __future__ import annotations

import pytest

from testdata.deadline import finishes

#: corpus files that made the original readers allocate gigabytes (or forever)
ALLOCATING = {"mnum_1e8.zmx", "mnum_1e9.zmx", "mnum_20_digits.zmx"}


@pytest.fixture
def hostile_folder(addon, tmp_path):
    """The user's lens folder set to a folder of the corpus's lens files: {name: expect}."""
    from testdata.hostile_lens_files import cases
    suffixes = addon.lenses.LENS_SUFFIXES
    expect = {}
    for case in cases():
        if case.name.endswith(suffixes) and case.name not in ALLOCATING:
            (tmp_path / case.name).write_bytes(case.data)
            expect[case.name] = case.expect
    ap = addon.preferences.addon_preferences()
    ap.lenses_directory = str(tmp_path)
    addon.library.clear_cache()
    try:
        yield tmp_path, expect
    finally:
        ap.lenses_directory = ""
        addon.library.clear_cache()


def test_01_bad_files_in_the_lens_folder_cost_their_own_entries_only(addon, hostile_folder):
    """Every shipped preset is listed with its lens; every good file of the folder too; each
    bad file is one entry without a lens whose note is one line naming the file."""
    folder, expect = hostile_folder
    assert addon.library.user_lenses_dir() == folder
    items = finishes(addon.library.items, 120.0)
    presets = {i.id: i for i in items if not i.is_user}
    assert sorted(presets) == addon.lenses.preset_names()
    assert all(i.entry is not None for i in presets.values())
    users = {i.id: i for i in items if i.is_user}
    assert sorted(users) == sorted("user:" + name for name in expect)
    wrong = []
    for name, want in expect.items():
        item = users["user:" + name]
        if want == "load" and item.entry is None:
            wrong.append(f"{name}: not listed as a lens: {item.error}")
        elif want == "refuse":
            note = item.summary
            if item.entry is not None:
                wrong.append(f"{name}: listed as a lens, but it is hostile")
            elif "\n" in note or name not in note or len(note) > 300:
                wrong.append(f"{name}: the note is not one line naming the file: {note!r}")
    assert not wrong, "\n".join(wrong)


@pytest.mark.parametrize("name", [
    "note_gaps_deep_list.zmx",          # RecursionError escaped the NOTE reader
    "note_f_number_20.zmx",             # TypeError
    "note_gaps_surface_infinite.zmx",   # OverflowError
    "focus_key_superscript.toml",       # ValueError from a "³" surface key
    "mnum_65.zmx",                      # loaded, configurations over the cap
    "control_nul.zmx",                  # loaded, two surfaces merged
])
def test_02_load_lens_file_refuses_a_bad_file_in_one_line(addon, scene, hostile_folder, name):
    """Load Lens File on a hostile file: cancelled, its report one line naming the file (never
    a Python traceback), the camera's lens settings unchanged."""
    import bpy
    folder, _expect = hostile_folder
    _sc, camera = scene
    obj = camera("Hostile", lens_id="tessar_f4_5")
    props = obj.data.neurolens
    before = (props.source, props.lens_id, props.lens_file, props.enabled)
    reports = []
    with bpy.context.temp_override(object=obj, active_object=obj):
        try:
            result = bpy.ops.neurolens.load_lens_file(filepath=str(folder / name))
        except RuntimeError as exc:       # bpy.ops raises ERROR reports in background mode
            reports.append(str(exc))
            result = {"CANCELLED"}
    assert result == {"CANCELLED"} and reports, result
    text = reports[0].removeprefix("Error: ").strip()
    assert "Traceback" not in text and "\n" not in text and name in text, text
    assert (props.source, props.lens_id, props.lens_file, props.enabled) == before
