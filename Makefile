# Two entry points for a fresh machine: `make demo` and `make test`. Both build .venv themselves.
PYTHON ?= python3.11
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed
# Blender 5.2 LTS (bpy 5.2.3): Python 3.13 and numpy 2, the add-on's tests without the trainer.
PYTHON313 ?= python3.13
VENV52 := .venv-5.2
PY52 := $(VENV52)/bin/python
STAMP52 := $(VENV52)/.installed

.PHONY: venv venv-52 test test-52 test-fast demo bench models clean

venv: $(STAMP)

$(STAMP): requirements.txt
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -r requirements.txt
	touch $@

venv-52: $(STAMP52)

$(STAMP52): requirements-5.2.txt
	test -x $(PY52) || $(PYTHON313) -m venv $(VENV52)
	$(PY52) -m pip install --quiet --upgrade pip
	$(PY52) -m pip install --quiet -r requirements-5.2.txt
	touch $@

# The root's __init__.py is Blender's extension entry, not a test package: rooting pytest at
# tests/ keeps it out of collection, so a checkout in any folder (tmp.Xy1, wt-a) can test.
test: venv
	$(PY) scripts/build_extension.py --out build/extension
	$(PY) -m pytest -q --rootdir=tests -o pythonpath="$(CURDIR)" tests

# The add-on's tests under Blender 5.2 LTS (Python 3.13, numpy 2), all of them: Blender 5.2's
# own extension tool validates and builds the extension, and tests/trainer is skipped (one line
# per module: the trainer needs torch, which stays in .venv; when .venv is there, the panel's
# training tests train through it, as a user's Trainer Python preference would).
test-52: venv-52
	$(PY52) scripts/build_extension.py --out build/extension-5.2
	$(PY52) -m pytest -q --rootdir=tests -o pythonpath="$(CURDIR)" tests

# While working: everything but the tests marked slow (renders, training, per-preset sweeps).
test-fast: venv
	$(PY) scripts/build_extension.py --out build/extension
	$(PY) -m pytest -q --rootdir=tests -o pythonpath="$(CURDIR)" -m "not slow" tests

demo: venv
	mkdir -p out
	$(PY) -m neurolens_addon.core diagram presets/lenses/double_gauss_50mm_f2.toml --out out/demo_diagram.png
	$(PY) -m neurolens_addon.core spot presets/lenses/double_gauss_50mm_f2.toml --out out/demo_spot.png
	$(PY) -m neurolens_addon.render presets/scenes/demo.blend --lens double_gauss_50mm_f2 \
	  --model learned --focus 1.6 --fstop 2 --samples 16 --engine neurolens \
	  --out out/demo.exr --out out/demo.png
	@echo "wrote out/demo_diagram.png, out/demo_spot.png, out/demo.exr and out/demo.png"

bench: venv
	$(PY) -m benchmarks.run

# Train the learned model of every preset into presets/models (one per tabulated focal length
# of a zoom and per tabulated close distance of a lens with focusing groups), and record each
# model's measured error and speed and its engine cost a camera ray in its model.json
# (automatic model choice reads them). Long; resumable: models already trained are kept.
models: venv
	$(PY) scripts/train_presets.py

clean:
	rm -rf $(VENV) $(VENV52) out .pytest_cache
