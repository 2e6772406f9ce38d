# distnav — set-up and checks. A fresh machine needs only Python 3.11, pip and make.
#   make demo   create .venv (first time), install distnav with what the demo needs (numpy, scipy, matplotlib:
#               the `plot` extra), run `distnav demo` (its experiments in 2 processes)
#   make test   install every extra and the checkers (`.[dev]`), then ruff + mypy + the whole pytest suite (on every
#               core: pytest-xdist, see the pytest target)
#   make dist   build the sdist and the wheel into dist/ (python -m build) and check them (twine check)
# Two stamps: .venv/.demo-stamp (the `plot` extra) and .venv/.dev-stamp (`.[dev]`, which includes it).
PYTHON ?= python3
VENV   ?= .venv
BIN     = $(VENV)/bin
DEMO_STAMP = $(VENV)/.demo-stamp
DEV_STAMP  = $(VENV)/.dev-stamp
DEMO_OUT ?= distnav-demo
DEMO_JOBS ?= 2
# --no-compile: no byte-compiling of every installed module (scipy alone is seconds); Python compiles what it
# imports, once. Not --quiet: pip's lines are the progress of the install.
PIP_FLAGS = --no-compile --progress-bar off

.PHONY: demo test lint typecheck pytest bench dist clean env demo-env

env: $(DEV_STAMP)
demo-env: $(DEMO_STAMP)

# The venv is made without pip (`ensurepip` byte-compiles pip and setuptools: seconds) when the pip of $(PYTHON)
# can install into it (`pip --python`, pip 22.3 or later); the first install then puts pip into the venv, so
# `.venv/bin/pip` works as usual. An older pip: the venv gets its pip from ensurepip.
$(BIN)/python:
	$(PYTHON) -m venv --without-pip $(VENV)
	$(PYTHON) -m pip --python $(BIN)/python --version >/dev/null 2>&1 || $(BIN)/python -m ensurepip --default-pip

# pip: the venv's own once it has one, else the outer pip installing into the venv (and pip with it)
PIP_INSTALL = if $(BIN)/python -m pip --version >/dev/null 2>&1; then $(BIN)/python -m pip install $(PIP_FLAGS) $(1); \
	else $(PYTHON) -m pip --python $(BIN)/python install $(PIP_FLAGS) pip $(1); fi

$(DEMO_STAMP): pyproject.toml | $(BIN)/python
	@echo "installing distnav with the plot extra into $(VENV) (numpy, scipy, matplotlib)"
	$(call PIP_INSTALL,-e '.[plot]')
	touch $(DEMO_STAMP)

$(DEV_STAMP): pyproject.toml | $(BIN)/python
	@echo "installing distnav with every extra and the checkers into $(VENV) (.[dev])"
	$(call PIP_INSTALL,-e '.[dev]')
	touch $(DEV_STAMP) $(DEMO_STAMP)

demo: $(DEMO_STAMP)
	$(BIN)/distnav demo --out $(DEMO_OUT) --jobs $(DEMO_JOBS)

lint: $(DEV_STAMP)
	$(BIN)/ruff check src tests benchmarks scripts
	$(BIN)/ruff format --check src tests benchmarks scripts

typecheck: $(DEV_STAMP)
	$(BIN)/mypy

# -n auto --dist loadscope: every core (pytest-xdist), each module's tests on one worker (its fixtures built once);
# the slowest 15 tests are listed at the end
pytest: $(DEV_STAMP)
	$(BIN)/python -m pytest -q -n auto --dist loadscope --durations=15

test: lint typecheck pytest

# --no-isolation: setuptools comes with .[dev], so the build needs no download
dist: $(DEV_STAMP)
	rm -rf dist
	$(BIN)/python -m build --no-isolation --outdir dist .
	$(BIN)/python -m twine check dist/*
	rm -rf build src/*.egg-info

bench: $(DEV_STAMP)
	$(BIN)/python benchmarks/run.py

clean:
	rm -rf $(VENV) $(DEMO_OUT) .pytest_cache .mypy_cache .ruff_cache dist build
