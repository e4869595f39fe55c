#!/usr/bin/env python3
"""Validate the manifest and build the extension zip with Blender's own extension tool.

    python scripts/build_extension.py --out build/extension          # no wheels: offline
    python scripts/fetch_wheels.py && \\
    python scripts/build_extension.py --out dist --wheels wheels --split-platforms   # release

Blender's tool (`blender_ext.py`, shipped inside the bpy package) runs as plain Python: no
Blender needed; the tool of the bpy this Python has (5.0.1 in .venv, 5.2.3 in .venv-5.2)
validates and builds. Without wheels the repository itself is the source (its manifest's
[build] section decides what ships). With wheels, the tool's own no-wheel zip is unpacked into a
staging folder, the wheels are copied beside it and the manifest there gets the `platforms` and
`wheels` lines of wheels/wheels.toml (written by fetch_wheels.py): the repository's manifest is
never edited, and a build never needs the network. Each platform's wheels must serve every
Python listed there (3.11 for Blender 5.0, 3.13 for 5.1 and 5.2 LTS), so one zip per platform
installs in all of them, and every zip built is validated again by the tool. numpy is never
bundled.
"""

from __future__ import annotations

import argparse
import importlib.util
import re
import shutil
import subprocess
import sys
import tempfile
import tomllib
import zipfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
MANIFEST = "blender_manifest.toml"


def blender_ext_tool() -> Path:
    """Path of blender_ext.py inside the installed bpy package (found without importing bpy)."""
    spec = importlib.util.find_spec("bpy")
    if spec is None or not spec.submodule_search_locations:
        raise SystemExit("the bpy package is not installed: pip install bpy==5.0.1 (Blender "
                         "5.0, Python 3.11) or bpy==5.2.3 (Blender 5.2 LTS, Python 3.13)")
    base = Path(next(iter(spec.submodule_search_locations)))
    found = sorted(base.glob("[0-9]*.[0-9]*/scripts/addons_core/bl_pkg/cli/blender_ext.py"))
    if not found:
        raise SystemExit(f"no blender_ext.py under {base}")
    return found[-1]


def tool_name() -> str:
    """Which Blender's extension tool this is: "blender_ext of bpy 5.2.3"."""
    from importlib.metadata import PackageNotFoundError, version
    try:
        return f"blender_ext of bpy {version('bpy')}"
    except PackageNotFoundError:
        return f"blender_ext at {blender_ext_tool()}"


def run_tool(*args: str) -> str:
    cmd = [sys.executable, str(blender_ext_tool()), *args]
    proc = subprocess.run(cmd, capture_output=True, text=True, check=False)
    out = (proc.stdout + proc.stderr).strip()
    if proc.returncode != 0 or "FATAL_ERROR" in out:
        raise SystemExit(f"{' '.join(args[:1])} failed:\n{out}")
    return out


def validate(source: Path = ROOT) -> str:
    return run_tool("validate", str(source))


def _built_zips(output: str, out_dir: Path) -> list[Path]:
    # one "building: NAME.zip" line per archive (with --split-platforms: one per platform)
    return [out_dir / name for name in re.findall(r"^building: (\S+\.zip)$", output, re.MULTILINE)]


def build(source: Path, out_dir: Path, split_platforms: bool = False) -> list[Path]:
    out_dir.mkdir(parents=True, exist_ok=True)
    args = ["build", "--source-dir", str(source), "--output-dir", str(out_dir)]
    if split_platforms:
        args.append("--split-platforms")
    zips = _built_zips(run_tool(*args), out_dir)
    if not zips or not all(z.is_file() for z in zips):
        raise SystemExit("the extension tool reported no zip")
    return zips


def release_manifest(text: str, wheel_lines: str) -> str:
    """The manifest with `platforms` / `wheels` added before its first table."""
    data = tomllib.loads(text)
    if "wheels" in data or "platforms" in data:
        raise SystemExit("the repository manifest already lists wheels or platforms")
    m = re.search(r"^\[", text, flags=re.MULTILINE)
    at = m.start() if m else len(text)
    merged = text[:at] + wheel_lines.rstrip() + "\n\n" + text[at:]
    tomllib.loads(merged)   # still valid TOML
    return merged


def wheel_lines(wheels_dir: Path) -> str:
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from fetch_wheels import (PLATFORMS, PYTHON_VERSIONS, check_no_numpy, manifest_lines,
                              missing_pythons)

    listed = wheels_dir / "wheels.toml"
    if listed.is_file():
        data = tomllib.loads(listed.read_text(encoding="utf-8"))
        files = [wheels_dir / Path(w).name for w in data["wheels"]]
        platforms = data["platforms"]
        pythons = data.get("pythons", list(PYTHON_VERSIONS))
    else:
        files = sorted(wheels_dir.glob("*.whl"))
        platforms = list(PLATFORMS)
        pythons = list(PYTHON_VERSIONS)
    missing = [f.name for f in files if not f.is_file()]
    if missing:
        raise SystemExit(f"wheels listed in {listed} are missing: {', '.join(missing)}")
    check_no_numpy(files)
    gaps = [f"{platform}: {project} for Python {', '.join(sorted(need))}"
            for platform in platforms
            for project, need in sorted(missing_pythons(files, pythons, platform).items())]
    if gaps:
        raise SystemExit("the wheels leave a Blender without a package (fetch_wheels.py "
                         f"--python ...): {'; '.join(gaps)}")
    return manifest_lines(files, platforms)


def build_with_wheels(wheels_dir: Path, out_dir: Path, split_platforms: bool) -> list[Path]:
    lines = wheel_lines(wheels_dir)
    with tempfile.TemporaryDirectory(prefix="neurolens-ext-") as tmp:
        tmp = Path(tmp)
        (base,) = build(ROOT, tmp / "base")
        stage = tmp / "stage"
        with zipfile.ZipFile(base) as zf:
            zf.extractall(stage)
        (stage / "wheels").mkdir()
        for line in re.findall(r'"\./wheels/([^"]+)"', lines):
            shutil.copy2(wheels_dir / line, stage / "wheels" / line)
        text = (ROOT / MANIFEST).read_text(encoding="utf-8")
        (stage / MANIFEST).write_text(release_manifest(text, lines), encoding="utf-8")
        validate(stage)
        return build(stage, out_dir, split_platforms)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, default=ROOT / "build" / "extension",
                    help="output folder for the zip(s)")
    ap.add_argument("--wheels", type=Path, default=None,
                    help="folder of wheels from fetch_wheels.py (default: none, offline build)")
    ap.add_argument("--split-platforms", action="store_true",
                    help="one zip per platform (with --wheels)")
    args = ap.parse_args(argv)
    print(validate())
    if args.wheels is not None and any(args.wheels.glob("*.whl")):
        zips = build_with_wheels(args.wheels, args.out, args.split_platforms)
    else:
        if args.wheels is not None:
            print(f"no wheels in {args.wheels}: building without them (learned lens needs "
                  "onnxruntime installed separately)")
        zips = build(ROOT, args.out)
    for z in zips:
        with zipfile.ZipFile(z) as zf:
            bad = [n for n in zf.namelist() if Path(n).name.lower().startswith("numpy")]
        if bad:
            raise SystemExit(f"{z} bundles numpy: {bad}")
        validate(z)                  # the archive itself, as Blender will read it
        print(f"built {z} ({z.stat().st_size / 1e6:.1f} MB), validated by {tool_name()}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
