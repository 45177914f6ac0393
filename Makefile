# mixcount: `make demo` sets up and runs the main job on the generated demo library;
# `make test` sets up and runs the test suite. Both create .venv when missing.
PYTHON ?= python3.11
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed
DEMO_DB := catalog/catalog.db
DEMO_OUT := out/demo
MIX := $(VENV)/bin/mixcount --db $(DEMO_DB)
DEMO_SCENES ?= 4

.PHONY: setup test test-fast lint demo browser clean-demo bench bench-smoke

setup: $(STAMP)

$(STAMP): pyproject.toml
	@test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e '.[dev,fiftyone]'
	@touch $(STAMP)

# Debian's Chromium for the HTML contact-sheet tests (we run as root on the dev/CI machines).
browser:
	@command -v chromium >/dev/null 2>&1 || (apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium >/dev/null)

# ruff and mypy (strict on scene/, annotate/, evaluate/, config.py; see pyproject.toml), then every test.
lint: $(STAMP)
	$(VENV)/bin/ruff check mixcount tests bench
	$(VENV)/bin/mypy

# Two pytest-xdist processes, each module's tests in one (--dist loadfile), the slowest modules first (tests/conftest.py,
# SLOWEST_MODULES_FIRST; --no-loadscope-reorder keeps that order); session fixtures are built once
# for both (tests/conftest.py). TEST_WORKERS=0 runs in one process.
TEST_WORKERS ?= 2
# One BLAS thread per test process: two processes on two cores already fill them, and OpenBLAS's own threads
# on the suite's small matrices only wait on each other (mixcount/threads.py has the figures).
# PYTHONDONTWRITEBYTECODE emptied for the run (this machine sets it): the suite starts ~300 Python processes
# (CLI commands, bpy workers, benches) and each compiled every mixcount module it imported from source, and
# each test process re-ran pytest's assertion rewrite of every test module: 39 CPU-seconds of the suite
# (py-spy, docs/testing.md). The caches go to the gitignored __pycache__ folders.
test: $(STAMP) browser lint
	PYTHONDONTWRITEBYTECODE= OPENBLAS_NUM_THREADS=1 $(PY) -m pytest -q -n $(TEST_WORKERS) --dist loadfile --no-loadscope-reorder

# Engine-free tests only (no bpy, Ray, browser or slow ones), in the same two processes: 80-90 s on 2 cores.
test-fast: $(STAMP)
	PYTHONDONTWRITEBYTECODE= OPENBLAS_NUM_THREADS=1 $(PY) -m pytest -q -n $(TEST_WORKERS) --dist loadfile --no-loadscope-reorder -m "not blender and not ray and not browser and not slow"

demo: $(STAMP)
	$(MIX) demo-library catalog/demo
	$(MIX) catalog ingest catalog/demo
	$(MIX) --set canonical_render.resolution=256 --set canonical_render.samples=8 catalog render
	$(MIX) catalog filter
	$(MIX) catalog caption --captioner stub
	$(MIX) catalog split
	$(MIX) catalog sheet --out $(DEMO_OUT)/sheets --only all
	$(MIX) catalog list --summary
	$(MIX) --config quick compose --n $(DEMO_SCENES) --out $(DEMO_OUT)/dataset --split train --resolution 256 --samples 8
	$(VENV)/bin/mixcount stats $(DEMO_OUT)/dataset
	$(VENV)/bin/mixcount baseline --gt $(DEMO_OUT)/dataset --split train --kind mean --out $(DEMO_OUT)/pred_mean.json
	$(VENV)/bin/mixcount evaluate --gt $(DEMO_OUT)/dataset --split train --pred $(DEMO_OUT)/pred_mean.json
	$(VENV)/bin/mixcount export $(DEMO_OUT)/dataset --format fsc147 --out $(DEMO_OUT)/export/fsc147
	$(VENV)/bin/mixcount export $(DEMO_OUT)/dataset --format countgd --out $(DEMO_OUT)/export/countgd
	@echo "demo done: contact sheets in $(DEMO_OUT)/sheets, dataset in $(DEMO_OUT)/dataset (preview.png, annotations/), exports in $(DEMO_OUT)/export"

# Benchmarks print their figures as one JSON line each (see docs/performance.md); minutes, not seconds.
bench: $(STAMP)
	$(PY) bench/ingest.py
	$(PY) bench/compose.py
	$(PY) bench/visibility.py
	$(PY) bench/throughput.py --scenes 24

# Every bench in its --smoke mode (tiny sizes, the same code path; what tests/test_benches.py runs): about 1.5 min.
bench-smoke: $(STAMP)
	$(PY) -m pytest -q tests/test_benches.py

clean-demo:
	rm -rf catalog/demo catalog/catalog.db* catalog/collision catalog/renders catalog/usd_assets $(DEMO_OUT)
