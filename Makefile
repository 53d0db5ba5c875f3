# Two commands on a fresh machine: `make run` and `make test`. Both set everything up first and
# are idempotent: the virtual environment is rebuilt only when pyproject.toml changes, the CAD
# library only when its sources or settings change.
SHELL := /bin/bash
VENV ?= .venv
PY := $(VENV)/bin/python
CADNERF := $(VENV)/bin/cadnerf
STAMP := .make
LIBRARY_DIR ?= library_data/build
QUICK ?=

.PHONY: setup library run test lint typecheck pytest bench clean

setup: $(STAMP)/venv

# torch goes in first, from the local CPU wheel: anything that depends on torch installed before
# it would pull a multi-gigabyte CUDA build from the registry.
$(STAMP)/venv: pyproject.toml
	@mkdir -p $(STAMP)
	@test -x $(PY) || python3 -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip setuptools wheel
	$(PY) -m pip install -q torch==2.13.0
	$(PY) -m pip install -q -e '.[dev]'
	@touch $@

library: setup
	$(CADNERF) library build --out $(LIBRARY_DIR) --if-stale

run: setup library
	$(CADNERF) serve --demo

lint: setup
	$(VENV)/bin/ruff check .

typecheck: setup
	$(VENV)/bin/mypy app worker cadnerf_core cadnerf_cli library_data

pytest: setup
	$(VENV)/bin/pytest -q

test: lint typecheck pytest

bench: setup library
	$(PY) -m benchmarks.run $(if $(QUICK),--quick,) --out docs/benchmarks.md

clean:
	rm -rf $(STAMP) $(VENV) $(LIBRARY_DIR)
