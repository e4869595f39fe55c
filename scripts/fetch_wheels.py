#!/usr/bin/env python3
"""Download the platform wheels the extension bundles: onnxruntime (the learned lens), embreex
(the engine's Embree ray casts) and pyoidn (its Open Image Denoise) with their runtime
dependencies, never numpy (Blender ships its own), into wheels/ (git-ignored).

    python scripts/fetch_wheels.py                 # onnxruntime as installed here, 3 platforms
    python scripts/fetch_wheels.py --version 1.31.1 --dest wheels
    python scripts/fetch_wheels.py --dry-run       # print the pip commands only

For each Blender platform (linux-x64, windows-x64, macos-arm64) and Python 3.11 (Blender 5.0's)
it runs `pip download --no-deps --only-binary=:all: --platform TAG --python-version 3.11`, reads
each wheel's Requires-Dist (markers evaluated for that platform, extras skipped) and fetches those
the same way, recursively, skipping numpy. It then writes wheels/wheels.toml: the manifest lines
(`platforms = [...]`, `wheels = [...]`) that scripts/build_extension.py puts into the release
manifest. The add-on works without these wheels: exact and thin lenses need only numpy, the
engine casts rays through Blender's BVH without embreex and leaves frames noisy without pyoidn.
"""

from __future__ import annotations

import argparse
import re
import shutil
import subprocess
import sys
import tempfile
import zipfile
from email.parser import Parser
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PYTHON_VERSION = "3.11"
#: Blender platform -> pip platform tags (pip also accepts older manylinux / macOS versions)
PLATFORMS = {
    "linux-x64": ["manylinux_2_28_x86_64", "manylinux_2_17_x86_64", "manylinux2014_x86_64"],
    "windows-x64": ["win_amd64"],
    "macos-arm64": ["macosx_14_0_arm64", "macosx_11_0_arm64"],
}
#: marker environments of each platform (PEP 508), for the dependencies' markers
_MARKER_ENV = {
    "linux-x64": {"sys_platform": "linux", "platform_system": "Linux", "os_name": "posix",
                  "platform_machine": "x86_64"},
    "windows-x64": {"sys_platform": "win32", "platform_system": "Windows", "os_name": "nt",
                    "platform_machine": "AMD64"},
    "macos-arm64": {"sys_platform": "darwin", "platform_system": "Darwin", "os_name": "posix",
                    "platform_machine": "arm64"},
}
#: never bundled: Blender ships numpy (bundling another would break Blender's own)
NEVER_BUNDLE = frozenset({"numpy"})
PACKAGE = "onnxruntime"
#: bundled beside onnxruntime (default: the versions installed here)
EXTRA_PACKAGES = ("embreex", "pyoidn")


def canonical(name: str) -> str:
    return re.sub(r"[-_.]+", "-", name).lower()


def wheel_project(filename: str) -> str:
    """The project name of a wheel file name (PEP 427: name-version-...)."""
    return canonical(Path(filename).name.split("-", 1)[0])


def pip_download_command(requirement: str, platform: str, dest: Path) -> list[str]:
    cmd = [sys.executable, "-m", "pip", "download", "--no-deps", "--only-binary=:all:",
           "--python-version", PYTHON_VERSION, "--implementation", "cp", "--dest", str(dest),
           "--disable-pip-version-check", "--quiet"]
    for tag in PLATFORMS[platform]:
        cmd += ["--platform", tag]
    return cmd + [requirement]


def _requirement_parser():
    try:
        from packaging.requirements import Requirement
    except ImportError:                         # pip vendors it
        from pip._vendor.packaging.requirements import Requirement
    return Requirement


def runtime_requirements(wheel: Path, platform: str) -> list[str]:
    """Requires-Dist of a wheel that apply on `platform` with Python 3.11 (no extras)."""
    Requirement = _requirement_parser()
    with zipfile.ZipFile(wheel) as zf:
        meta = next(n for n in zf.namelist() if n.endswith(".dist-info/METADATA"))
        headers = Parser().parsestr(zf.read(meta).decode("utf-8"))
    env = dict(_MARKER_ENV[platform], python_version=PYTHON_VERSION,
               python_full_version=PYTHON_VERSION + ".0", implementation_name="cpython",
               platform_python_implementation="CPython", extra="")
    out = []
    for line in headers.get_all("Requires-Dist") or []:
        req = Requirement(line)
        if req.marker is not None and not req.marker.evaluate(env):
            continue
        out.append(str(Requirement(f"{req.name}{req.specifier}")))
    return out


def check_no_numpy(files) -> None:
    """Refuse a wheel list that would bundle numpy."""
    bad = [Path(f).name for f in files if wheel_project(Path(f).name) in NEVER_BUNDLE]
    if bad:
        raise SystemExit(f"refusing to bundle {', '.join(bad)}: Blender ships numpy")


def manifest_lines(files, platforms) -> str:
    """The `platforms` and `wheels` manifest entries for wheels under ./wheels/."""
    check_no_numpy(files)
    names = sorted({Path(f).name for f in files})
    wheels = ",\n".join(f'  "./wheels/{n}"' for n in names)
    plats = ", ".join(f'"{p}"' for p in platforms)
    return f"platforms = [{plats}]\nwheels = [\n{wheels},\n]\n"


def fetch(version: str, dest: Path, platforms, dry_run: bool = False,
          extra: tuple = ()) -> list[Path]:
    """onnxruntime `version` and the `extra` requirements ("name==version"), with their
    dependencies, for each platform."""
    dest.mkdir(parents=True, exist_ok=True)
    got: set[Path] = set()
    for platform in platforms:
        queue = [f"{PACKAGE}=={version}", *extra]
        seen: set[str] = set()
        while queue:
            requirement = queue.pop(0)
            name = canonical(_requirement_parser()(requirement).name)
            if name in seen or name in NEVER_BUNDLE:
                continue
            seen.add(name)
            with tempfile.TemporaryDirectory(prefix="neurolens-wheels-") as tmp:
                cmd = pip_download_command(requirement, platform, Path(tmp))
                print("$", " ".join(cmd))
                if dry_run:
                    continue
                subprocess.run(cmd, check=True)
                (wheel,) = Path(tmp).glob("*.whl")     # --no-deps: exactly one
                target = dest / wheel.name
                shutil.move(str(wheel), target)
            got.add(target)
            queue += runtime_requirements(target, platform)
    files = sorted(got)
    check_no_numpy(files)
    if not dry_run:
        (dest / "wheels.toml").write_text(
            "# written by scripts/fetch_wheels.py; build_extension.py adds these lines to the "
            "release manifest\n" + manifest_lines(files, platforms), encoding="utf-8")
    return files


def _installed_version(package: str = PACKAGE) -> str | None:
    from importlib.metadata import PackageNotFoundError, version
    try:
        return version(package)
    except PackageNotFoundError:
        return None


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--version", default=_installed_version(),
                    help="onnxruntime version (default: the one installed here)")
    ap.add_argument("--no-extras", action="store_true",
                    help=f"onnxruntime only (not {', '.join(EXTRA_PACKAGES)})")
    ap.add_argument("--dest", type=Path, default=ROOT / "wheels")
    ap.add_argument("--platform", action="append", choices=sorted(PLATFORMS),
                    help="a Blender platform (repeatable; default: all three)")
    ap.add_argument("--dry-run", action="store_true", help="print the pip commands only")
    args = ap.parse_args(argv)
    if not args.version:
        ap.error("onnxruntime is not installed here: give --version")
    extra = () if args.no_extras else tuple(
        f"{p}=={v}" for p in EXTRA_PACKAGES if (v := _installed_version(p)))
    files = fetch(args.version, args.dest, args.platform or list(PLATFORMS), args.dry_run,
                  extra=extra)
    for f in files:
        print(f"{f.name}  ({f.stat().st_size / 1e6:.1f} MB)")
    if not args.dry_run:
        print(f"wrote {args.dest / 'wheels.toml'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
