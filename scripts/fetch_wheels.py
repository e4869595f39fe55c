#!/usr/bin/env python3
"""Download the platform wheels the extension bundles: onnxruntime (the learned lens), embreex
(the engine's Embree ray casts), pyoidn (its Open Image Denoise) and numba (the compiled
lens trace and shading; llvmlite comes as its dependency) with their runtime dependencies,
never numpy (Blender ships its own), into wheels/ (git-ignored).

    python scripts/fetch_wheels.py                 # onnxruntime as installed here, 3 platforms
    python scripts/fetch_wheels.py --version 1.31.1 --dest wheels
    python scripts/fetch_wheels.py --platform linux-x64 --python 3.13
    python scripts/fetch_wheels.py --dry-run       # print the pip commands only

For each Blender platform (linux-x64, windows-x64, macos-arm64) and each Python the supported
Blenders run (3.11: Blender 5.0; 3.13: Blender 5.1 and 5.2 LTS) it runs `pip download --no-deps
--only-binary=:all: --platform TAG --python-version X.Y`, reads each wheel's Requires-Dist
(markers evaluated for that platform and Python, extras skipped) and fetches those the same
way, recursively, skipping numpy. Pure and abi3 wheels serve both Pythons and are fetched once.
It then writes wheels/wheels.toml: the manifest lines (`platforms = [...]`, `wheels = [...]`)
that scripts/build_extension.py puts into the release manifest, and the Pythons fetched for
(`pythons`, which the build checks every bundled package covers). One zip per platform then
holds the wheels of both Pythons; Blender installs those of its own Python. The add-on works
without these wheels: exact and thin lenses need only numpy, the engine casts rays through
Blender's BVH without embreex and leaves frames noisy without pyoidn.
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
#: the Python of each supported Blender line (its wheels are cpXY or abi3 ones)
PYTHON_VERSIONS = {"3.11": "Blender 5.0", "3.13": "Blender 5.1 and 5.2 LTS"}
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
EXTRA_PACKAGES = ("embreex", "pyoidn", "numba")


def canonical(name: str) -> str:
    return re.sub(r"[-_.]+", "-", name).lower()


def wheel_project(filename: str) -> str:
    """The project name of a wheel file name (PEP 427: name-version-...)."""
    return canonical(Path(filename).name.split("-", 1)[0])


def pip_download_command(requirement: str, platform: str, dest: Path,
                         python: str) -> list[str]:
    cmd = [sys.executable, "-m", "pip", "download", "--no-deps", "--only-binary=:all:",
           "--python-version", python, "--implementation", "cp", "--dest", str(dest),
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


def runtime_requirements(wheel: Path, platform: str, python: str) -> list[str]:
    """Requires-Dist of a wheel that apply on `platform` with Python `python` (no extras)."""
    Requirement = _requirement_parser()
    with zipfile.ZipFile(wheel) as zf:
        meta = next(n for n in zf.namelist() if n.endswith(".dist-info/METADATA"))
        headers = Parser().parsestr(zf.read(meta).decode("utf-8"))
    env = dict(_MARKER_ENV[platform], python_version=python,
               python_full_version=python + ".0", implementation_name="cpython",
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


def wheel_pythons(filename: str) -> set[str] | None:
    """The Pythons of PYTHON_VERSIONS a wheel installs in ("3.11", "3.13"), from its tags
    (PEP 425: a cpXY wheel, an abi3 wheel from its version on, a py3 / none wheel on all);
    None when its name does not follow the wheel naming spec."""
    parts = Path(filename).name[:-4].split("-")
    if not filename.endswith(".whl") or not 5 <= len(parts) <= 6:
        return None
    python_tags, abi_tags = parts[-3].split("."), parts[-2].split(".")
    out = set()
    for version in PYTHON_VERSIONS:
        minor = int(version.split(".")[1])
        for tag in python_tags:
            m = re.fullmatch(r"(cp|py)3(\d*)", tag)
            if m is None:
                continue
            if not m.group(2):                       # py3: any Python 3
                out.add(version)
            elif int(m.group(2)) == minor or ("abi3" in abi_tags and int(m.group(2)) <= minor):
                out.add(version)
    return out


def wheel_platform(filename: str) -> str | None:
    """The Blender platform a wheel is built for (a key of PLATFORMS; "other" for none of
    them), or None for a pure one (platform tag "any"). The same matching as Blender's
    installer: any glibc version, any macOS version, arm64 or universal2 on macOS."""
    tag = Path(filename).name[:-4].split("-")[-1]
    if tag == "any":
        return None
    if tag.startswith("manylinux") and tag.endswith("_x86_64"):
        return "linux-x64"
    if tag == "win_amd64":
        return "windows-x64"
    if tag.startswith("macosx_") and tag.endswith(("_arm64", "_universal2")):
        return "macos-arm64"
    return "other"


def missing_pythons(files, pythons, platform: str | None = None) -> dict[str, set[str]]:
    """{project: the Pythons of `pythons` none of its wheels among `files` installs in} (with
    `platform`: among the pure wheels and that platform's): the Blenders a release built from
    them would leave without that package."""
    covered: dict[str, set[str]] = {}
    for f in files:
        name = Path(f).name
        if platform is not None and wheel_platform(name) not in (None, platform):
            continue
        covered.setdefault(wheel_project(name), set()).update(wheel_pythons(name) or ())
    return {p: set(pythons) - got for p, got in covered.items() if set(pythons) - got}


def manifest_lines(files, platforms) -> str:
    """The `platforms` and `wheels` manifest entries for wheels under ./wheels/."""
    check_no_numpy(files)
    names = sorted({Path(f).name for f in files})
    wheels = ",\n".join(f'  "./wheels/{n}"' for n in names)
    plats = ", ".join(f'"{p}"' for p in platforms)
    return f"platforms = [{plats}]\nwheels = [\n{wheels},\n]\n"


def fetch(version: str, dest: Path, platforms, dry_run: bool = False,
          extra: tuple = (), pythons=tuple(PYTHON_VERSIONS)) -> list[Path]:
    """onnxruntime `version` and the `extra` requirements ("name==version"), with their
    dependencies, for each platform and each Python of `pythons`."""
    dest.mkdir(parents=True, exist_ok=True)
    got: set[Path] = set()
    for platform in platforms:
        for python in pythons:
            queue = [f"{PACKAGE}=={version}", *extra]
            seen: set[str] = set()
            while queue:
                requirement = queue.pop(0)
                name = canonical(_requirement_parser()(requirement).name)
                if name in seen or name in NEVER_BUNDLE:
                    continue
                seen.add(name)
                with tempfile.TemporaryDirectory(prefix="neurolens-wheels-") as tmp:
                    cmd = pip_download_command(requirement, platform, Path(tmp), python)
                    print("$", " ".join(cmd))
                    if dry_run:
                        continue
                    subprocess.run(cmd, check=True)
                    (wheel,) = Path(tmp).glob("*.whl")     # --no-deps: exactly one
                    target = dest / wheel.name
                    shutil.move(str(wheel), target)
                got.add(target)
                queue += runtime_requirements(target, platform, python)
    files = sorted(got)
    check_no_numpy(files)
    if not dry_run:
        listed = ", ".join(f'"{p}"' for p in pythons)
        (dest / "wheels.toml").write_text(
            "# written by scripts/fetch_wheels.py; build_extension.py adds `platforms` and "
            "`wheels` to the release manifest\n" + f"pythons = [{listed}]\n"
            + manifest_lines(files, platforms), encoding="utf-8")
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
    ap.add_argument("--python", action="append", choices=sorted(PYTHON_VERSIONS),
                    help="a Blender Python: " + ", ".join(
                        f"{p} ({b})" for p, b in PYTHON_VERSIONS.items())
                    + " (repeatable; default: all)")
    ap.add_argument("--dry-run", action="store_true", help="print the pip commands only")
    args = ap.parse_args(argv)
    if not args.version:
        ap.error("onnxruntime is not installed here: give --version")
    extra = () if args.no_extras else tuple(
        f"{p}=={v}" for p in EXTRA_PACKAGES if (v := _installed_version(p)))
    files = fetch(args.version, args.dest, args.platform or list(PLATFORMS), args.dry_run,
                  extra=extra, pythons=tuple(args.python or PYTHON_VERSIONS))
    for f in files:
        print(f"{f.name}  ({f.stat().st_size / 1e6:.1f} MB)")
    if not args.dry_run:
        print(f"wrote {args.dest / 'wheels.toml'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
