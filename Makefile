# mixcount: `make demo` sets up and runs the main job on the generated demo library;
# `make test` sets up and runs the test suite. Both create .venv when missing.
PYTHON ?= python3.11
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed
DEMO_DB := catalog/catalog.db
DEMO_OUT := out/demo
MIX := $(VENV)/bin/mixcount --db $(DEMO_DB)

.PHONY: setup test demo browser clean-demo bench

setup: $(STAMP)

$(STAMP): pyproject.toml
	@test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e '.[dev]'
	@touch $(STAMP)

# Debian's Chromium for the HTML contact-sheet tests (we run as root on the dev/CI machines).
browser:
	@command -v chromium >/dev/null 2>&1 || (apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium >/dev/null)

test: $(STAMP) browser
	$(PY) -m pytest -q

demo: $(STAMP)
	$(MIX) demo-library catalog/demo
	$(MIX) catalog ingest catalog/demo
	$(MIX) catalog list --summary

clean-demo:
	rm -rf catalog/demo catalog/catalog.db* catalog/collision catalog/renders catalog/usd_assets $(DEMO_OUT)
