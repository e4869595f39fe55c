"""Digests of every generated artifact: the ONNX graphs each preset model exports and the OSL
camera source of every preset (exact, learned where a model ships, thin; round, bladed and
masked stops). `python scripts/generated_digests.py > digests.json` before and after a change
shows whether a refactor left them byte-identical (`--compare OLD.json`)."""

from __future__ import annotations

import argparse
import hashlib
import json
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def _sha(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def onnx_digests() -> dict:
    from onnx_export import write_onnx_files
    out = {}
    for d in sorted((ROOT / "presets" / "models").glob("*.neurolens")):
        model = json.loads((d / "model.json").read_text())
        with tempfile.TemporaryDirectory() as tmp:
            for name, digest in write_onnx_files(model, tmp).items():
                out[f"{d.name}/{name}"] = digest
    return out


def osl_digests() -> dict:
    import numpy as np

    from neurolens_addon.core.aperture import ImageMaskAperture, PolygonAperture
    from neurolens_addon.core.lensfile import load_lens
    from neurolens_addon.cycles import CameraSpec, generate_osl
    yy, xx = np.mgrid[-1:1:32j, -1:1:32j]
    mask = ImageMaskAperture(((xx ** 2 + yy ** 2) < 0.8).astype(float), source="disc")
    apertures = {"round": None, "blades": PolygonAperture(6, 15.0), "mask": mask}
    out = {}
    for path in sorted((ROOT / "presets" / "lenses").glob("*.toml")):
        lens = load_lens(path)
        for ap_name, ap in apertures.items():
            for disp in (False, True):
                spec = CameraSpec("exact", lens, sensor_z_mm=0.05, f_number=lens.f_number * 2,
                                  aperture=ap, dispersion=disp)
                out[f"{path.stem}/exact/{ap_name}/{disp}"] = _sha(generate_osl(spec).encode())
        model = ROOT / "presets" / "models" / f"{path.stem}.neurolens"
        if model.is_dir():
            spec = CameraSpec("learned", lens, model_dir=str(model), sensor_z_mm=0.0,
                              f_number=lens.f_number * 2, dispersion=True)
            try:
                out[f"{path.stem}/learned"] = _sha(generate_osl(spec).encode())
            except Exception as exc:  # noqa: BLE001 - recorded, compared like a digest
                out[f"{path.stem}/learned"] = f"error: {type(exc).__name__}"
        spec = CameraSpec("thin", lens, f_number=2.8, focus_distance_m=2.0)
        out[f"{path.stem}/thin"] = _sha(generate_osl(spec).encode())
    return out


def main() -> int:
    p = argparse.ArgumentParser()
    p.add_argument("--compare", help="an earlier output of this script")
    args = p.parse_args()
    now = {"onnx": onnx_digests(), "osl": osl_digests()}
    if not args.compare:
        print(json.dumps(now, indent=1, sort_keys=True))
        return 0
    old = json.loads(Path(args.compare).read_text())
    bad = [f"{kind}:{k}" for kind in old for k in sorted(set(old[kind]) | set(now[kind]))
           if old[kind].get(k) != now[kind].get(k)]
    for k in bad:
        print("differs:", k)
    print(f"{sum(len(v) for v in now.values())} artifacts, {len(bad)} differ")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
