"""Hostile settings in the add-on: a folder that is a file, a folder that cannot be written.
The preference falls back to the default folder and says why; nothing raises."""

import os

import pytest


@pytest.mark.parametrize("kind", ["lenses", "models"])
def test_01_a_folder_that_is_a_file_falls_back_with_a_reason(addon, tmp_path, kind):
    prefs = addon.preferences
    ap = prefs.addon_preferences()
    not_a_folder = tmp_path / "a-file"
    not_a_folder.write_text("x")
    setattr(ap, f"{kind}_directory", str(not_a_folder))
    try:
        got = prefs.user_directory(kind)
        assert got == prefs.default_directory(kind)
        assert "is a file, not a folder" in prefs.DIRECTORY_PROBLEMS[kind]
    finally:
        setattr(ap, f"{kind}_directory", "")
    assert prefs.user_directory(kind) == prefs.default_directory(kind)
    assert kind not in prefs.DIRECTORY_PROBLEMS


@pytest.mark.skipif(not os.path.isdir("/proc/self"), reason="no /proc here")
def test_02_a_folder_that_cannot_be_created_falls_back_with_a_reason(addon):
    """A folder under /proc cannot be created, not even by root: the default is used and the
    reason kept for the preferences to show."""
    prefs = addon.preferences
    ap = prefs.addon_preferences()
    ap.lenses_directory = "/proc/neurolens-cannot-exist/lenses"
    try:
        assert prefs.user_directory("lenses") == prefs.default_directory("lenses")
        assert "cannot be created" in prefs.DIRECTORY_PROBLEMS["lenses"]
    finally:
        ap.lenses_directory = ""
