"""Robustness counts (issues 7, 14 and 27): what bad input, full disks and extreme rays do.

* Lens files: FUZZ_EXAMPLES documents from testdata.lens_documents.fuzz_documents (random
  edits of a valid prescription: wrong types, missing and unknown keys, NaN and infinite
  numbers, damaged TOML text), each loaded by core.lensfile.loads_lens. Counted: loaded lenses,
  LensErrors, any other exception (a crash), and the slowest document (a hang would show).
* Hostile lens files (issue 27): testdata.hostile_lens_files's corpus (huge counts, deep JSON
  and TOML, 20- and 5000-digit numbers, NUL and control characters, non-ASCII digits, duplicate
  keys, booleans as numbers, NaN and infinities, tables crossing at a later position, rows over
  the caps, and the good files they are made from), every file through every reader a lens
  file meets (TOML, .zmx, .dat, .zmx system lines, gap tables, model.json, model header, the
  library's entry), each case under a HOSTILE_DEADLINE_S deadline. Counted: cases tried,
  loaded, refused cleanly (the project's own error), tracebacks (any other exception), hangs,
  hostile files a format's own reader loaded and good files it refused.
* Model files: MODEL_FUZZ_EXAMPLES damaged model.json files (testdata.model_documents) read
  by neural.modelfile.read_model_json with a deadline: read, refused naming the file, crashes
  and hangs.
* Full disks (issue 27): benchmarks.full_disk_writes, every writer of a user's file under
  file-size caps: written complete, refused cleanly, tracebacks, hangs, lost files.
* Extreme rays: RAYS_PER_MODEL rays per lens model in total (exact and learned, spread over
  every preset) from testdata.extreme_rays (grazing, at every semi-diameter, beyond the
  field, toward the rear element, on the axis, tiny direction components; 380 and 780 nm; infinity
  and closest focus; half through the stop closed to f/64). Counted: valid rays with a NaN or
  infinite component (must be 0), and the valid fraction.
"""

from __future__ import annotations

import time

import numpy as np

from neurolens_addon.core.lensfile import load_lens

from . import full_disk_writes
from .common import ROOT, md_table, preset_paths

FUZZ_EXAMPLES = 10_000
MODEL_FUZZ_EXAMPLES = 2_000
MODEL_HANG_S = 10.0
HOSTILE_DEADLINE_S = 20.0
RAYS_PER_MODEL = 10_000_000
CHUNK = 400_000


def fuzz_lens_files(examples: int = FUZZ_EXAMPLES) -> dict:
    from hypothesis import HealthCheck, given, settings

    from neurolens_addon.core.errors import LensError
    from neurolens_addon.core.lensfile import loads_lens
    from testdata.lens_documents import fuzz_documents
    counts = {"documents": 0, "lenses": 0, "lens_errors": 0, "crashes": 0, "slowest_s": 0.0}
    crashes = []

    @settings(max_examples=examples, deadline=None, database=None,
              suppress_health_check=list(HealthCheck))
    @given(text=fuzz_documents())
    def one(text):
        counts["documents"] += 1
        t0 = time.perf_counter()
        try:
            loads_lens(text, path="fuzz.toml")
            counts["lenses"] += 1
        except LensError:
            counts["lens_errors"] += 1
        except Exception as exc:  # noqa: BLE001 - counting crashes is the point
            counts["crashes"] += 1
            crashes.append(f"{type(exc).__name__}: {exc}"[:200])
        counts["slowest_s"] = max(counts["slowest_s"], time.perf_counter() - t0)
    one()
    counts["crash_examples"] = crashes[:5]
    return counts


def hostile_lens_files(limit: int | None = None,
                       deadline_s: float = HOSTILE_DEADLINE_S) -> dict:
    """The hostile corpus through every reader (module docstring); `limit`: only the first
    `limit` files (by name), for a quick check."""
    import json
    import tempfile
    from pathlib import Path

    from testdata.hostile_lens_files import OWN_READER, READERS, read_one, write_corpus
    counts = {"files": 0, "cases": 0, "loaded": 0, "refused": 0, "tracebacks": 0, "hangs": 0,
              "hostile_loaded": 0, "good_refused": 0, "slowest_s": 0.0}
    problems = []
    with tempfile.TemporaryDirectory() as tmp:
        folder, scratch = Path(tmp) / "corpus", Path(tmp) / "scratch"
        scratch.mkdir()
        write_corpus(folder)
        expect = json.loads((folder / "expect.json").read_text())
        names = sorted(expect)[:limit]
        counts["files"] = len(names)
        for name in names:
            for reader in READERS:
                row = read_one(reader, folder / name, scratch, deadline_s)
                counts["cases"] += 1
                counts["slowest_s"] = max(counts["slowest_s"], row["seconds"])
                outcome = {"crash": "tracebacks", "hang": "hangs"}.get(row["outcome"],
                                                                       row["outcome"])
                counts[outcome] += 1
                if outcome in ("tracebacks", "hangs"):
                    problems.append(f"{name} / {reader}: {row['message']}"[:200])
                if reader == OWN_READER[Path(name).suffix]:
                    if expect[name] == "refuse" and row["outcome"] == "loaded":
                        counts["hostile_loaded"] += 1
                        problems.append(f"{name}: loaded, but it is hostile")
                    elif expect[name] == "load" and row["outcome"] != "loaded":
                        counts["good_refused"] += 1
                        problems.append(f"{name}: refused: {row['message']}"[:200])
    counts["problem_examples"] = problems[:5]
    return counts


def fuzz_model_files(examples: int = MODEL_FUZZ_EXAMPLES,
                     hang_s: float = MODEL_HANG_S) -> dict:
    """MODEL_FUZZ_EXAMPLES damaged model.json files (testdata.model_documents) read by
    neural.modelfile.read_model_json, each on a thread with a deadline: models read, clean
    refusals (ModelError naming model.json), other exceptions (crashes) and reads still running
    after `hang_s` (hangs)."""
    import tempfile
    from pathlib import Path

    from hypothesis import HealthCheck, given, settings

    from neurolens_addon.core.errors import ModelError
    from neurolens_addon.neural.modelfile import read_model_json
    from testdata.deadline import run_with_deadline
    from testdata.model_documents import fuzz_model_documents, write_model
    counts = {"documents": 0, "models": 0, "model_errors": 0, "unnamed_errors": 0,
              "crashes": 0, "hangs": 0, "slowest_s": 0.0}
    crashes = []
    with tempfile.TemporaryDirectory() as tmp:
        folder = write_model(Path(tmp) / "fuzz.neurolens", "{}")

        @settings(max_examples=examples, deadline=None, database=None,
                  suppress_health_check=list(HealthCheck))
        @given(text=fuzz_model_documents())
        def one(text):
            counts["documents"] += 1
            (folder / "model.json").write_text(text)
            t0 = time.perf_counter()
            done, _value, exc = run_with_deadline(lambda: read_model_json(folder), hang_s)
            counts["slowest_s"] = max(counts["slowest_s"], time.perf_counter() - t0)
            if not done:
                counts["hangs"] += 1
            elif exc is None:
                counts["models"] += 1
            elif isinstance(exc, ModelError):
                counts["model_errors" if "model.json" in str(exc) else "unnamed_errors"] += 1
            else:
                counts["crashes"] += 1
                crashes.append(f"{type(exc).__name__}: {exc}"[:200])
        one()
    counts["crash_examples"] = crashes[:5]
    return counts


def extreme_rays_counts(per_model: int = RAYS_PER_MODEL) -> dict:
    from neurolens_addon.core.trace import trace
    from neurolens_addon.neural.model import LearnedLens

    from testdata.extreme_rays import count_bad, extreme_rays
    presets = preset_paths()
    per_lens = per_model // len(presets)
    out = {}
    for path in presets:
        lens = load_lens(path)
        mdir = ROOT / "presets" / "models" / f"{path.stem}.neurolens"
        model = LearnedLens.load(mdir, lens=lens) if (mdir / "model.json").exists() else None
        row = {"rays": 0, "exact_bad": 0, "exact_valid": 0, "learned_bad": 0,
               "learned_valid": 0}
        for i in range(0, per_lens, CHUNK):
            n = min(CHUNK, per_lens - i)
            rays, zs, _ = extreme_rays(lens, n, seed=i)
            m = rays.o.shape[1]
            closed = np.arange(m) % 2 == 1
            r64 = lens.stop_radius_mm * lens.f_number / 64.0
            for sel, stop in ((~closed, None), (closed, r64)):
                sub = type(rays)(rays.o[:, sel], rays.d[:, sel], rays.wavelength[sel])
                ex = trace(lens, sub, sensor_z=None, stop_radius=stop)
                row["exact_bad"] += count_bad(ex.rays, ex.valid)
                row["exact_valid"] += int(ex.valid.sum())
                if model is not None:
                    lr = model.trace_from_sensor(sub, sensor_z=zs[sel], stop_radius=stop)
                    row["learned_bad"] += count_bad(lr.rays, lr.valid)
                    row["learned_valid"] += int(lr.valid.sum())
            row["rays"] += m
        out[path.stem] = row
        print(f"  {path.stem}: {row}", flush=True)
    return out


def run() -> tuple[str, dict]:
    t0 = time.perf_counter()
    hostile = hostile_lens_files()
    t_hostile = time.perf_counter() - t0
    print(f"  hostile lens files: {hostile}", flush=True)
    t0 = time.perf_counter()
    fuzz = fuzz_lens_files()
    t_fuzz = time.perf_counter() - t0
    print(f"  fuzz: {fuzz}", flush=True)
    t0 = time.perf_counter()
    models = fuzz_model_files()
    t_models = time.perf_counter() - t0
    print(f"  model fuzz: {models}", flush=True)
    t0 = time.perf_counter()
    disk = full_disk_writes.run_cases()
    t_disk = time.perf_counter() - t0
    rays = extreme_rays_counts()
    total = sum(r["rays"] for r in rays.values())
    bad_e = sum(r["exact_bad"] for r in rays.values())
    bad_l = sum(r["learned_bad"] for r in rays.values())
    rows = [[k, f"{r['rays']:,}", f"{r['exact_valid'] / r['rays']:.3f}", r["exact_bad"],
             f"{r['learned_valid'] / r['rays']:.3f}", r["learned_bad"]] for k, r in rays.items()]
    text = "\n".join([
        "## Robustness: bad lens and model files, full disks, extreme rays",
        "",
        f"Lens-file fuzzer: {fuzz['documents']:,} generated documents in {t_fuzz:.0f} s: "
        f"{fuzz['lenses']:,} loaded, {fuzz['lens_errors']:,} refused with a LensError naming "
        f"the file, **{fuzz['crashes']} crashes of other kinds**; slowest document "
        f"{fuzz['slowest_s'] * 1000:.0f} ms (no hang).",
        "",
        f"Hostile lens files (issue 27, testdata/hostile_lens_files.py: huge counts, deep "
        f"JSON and TOML, 20- and 5000-digit numbers, NUL and control characters, non-ASCII "
        f"digits, duplicate keys, booleans as numbers, NaN, tables crossing at a later "
        f"position, rows over the caps): {hostile['files']} files through "
        f"{hostile['cases'] // max(hostile['files'], 1)} readers each, {hostile['cases']:,} "
        f"cases in {t_hostile:.0f} s: {hostile['loaded']:,} loaded, {hostile['refused']:,} "
        f"refused cleanly (the project's own error), **{hostile['tracebacks']} tracebacks, "
        f"{hostile['hangs']} hangs** (cases still running after {HOSTILE_DEADLINE_S:g} s); "
        f"by each file's own reader {hostile['hostile_loaded']} hostile files loaded and "
        f"{hostile['good_refused']} good ones refused; slowest case "
        f"{hostile['slowest_s'] * 1000:.0f} ms.",
        "",
        f"Writes on a nearly full disk (issue 27, benchmarks/full_disk_writes.py: every "
        f"file a command writes capped at {', '.join(f'{c:,}' for c in full_disk_writes.CAPS[:-1])}"
        f" bytes and uncapped, over an old file): {disk['cases']} cases in {t_disk:.0f} s: "
        f"{disk['written']} written complete, {disk['refused']} refused cleanly (non-zero exit, "
        f"one line, the old file byte for byte, no temporary file), "
        f"{disk['refused without a line']} refused without a line, **{disk['traceback']} "
        f"tracebacks, {disk['hang']} hangs, {disk['lost']} lost files**.",
        "",
        md_table(["writer"] + [f"{c:,} B" if c < (1 << 30) else "no cap"
                               for c in full_disk_writes.CAPS], _disk_rows(disk["rows"])),
        "",
        f"Model-file fuzzer: {models['documents']:,} damaged model.json files (random edits of "
        f"a shipped model at random key paths: wrong types and ranges, deleted keys, lists "
        f"emptied or grown, 1000-deep nesting; NaN and Infinity literals, cuts, stray bytes) "
        f"in {t_models:.0f} s: {models['models']:,} read, {models['model_errors']:,} refused "
        f"with a ModelError naming model.json, {models['unnamed_errors']} refused without "
        f"naming it, **{models['crashes']} crashes (tracebacks), {models['hangs']} hangs** "
        f"(reads still running after {MODEL_HANG_S:g} s); slowest "
        f"{models['slowest_s'] * 1000:.0f} ms.",
        "",
        f"Extreme rays: {total:,} through the exact trace and the same {total:,} through the "
        f"learned models (every preset; grazing, every semi-diameter, 1.5x the field, rear element, "
        f"axis, tiny components; 380/780 nm; infinity and closest focus; half at f/64): "
        f"**{bad_e} NaN/infinite valid rays exact, {bad_l} learned**.",
        "",
        md_table(["preset", "rays", "exact valid", "exact NaN/inf", "learned valid",
                  "learned NaN/inf"], rows)])
    return text, {"hostile_lens_files": hostile, "hostile_seconds": t_hostile,
                  "fuzz": fuzz, "fuzz_seconds": t_fuzz, "model_fuzz": models,
                  "model_fuzz_seconds": t_models, "full_disk": disk, "full_disk_seconds": t_disk,
                  "extreme_rays": rays}


def _disk_rows(rows) -> list[list[str]]:
    """One row per writer, a verdict per cap."""
    table: dict[str, dict[int, str]] = {}
    for name, cap, verdict in rows:
        table.setdefault(name, {})[cap] = verdict
    return [[name] + [by_cap.get(c, "") for c in full_disk_writes.CAPS]
            for name, by_cap in table.items()]
