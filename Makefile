# The two set-up commands of the README:
#   make run    install everything into .venv and start the console with the simulator
#   make test   install everything (incl. test tools and Chromium) and run the whole suite
# For the edit loop:
#   make test-fast   the unit tests without the slow ones (under a minute)
#   make lint        ruff (lint and format) and mypy, as CI runs them
PY ?= $(shell command -v python3.11 || command -v python3)
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
HOST ?= 127.0.0.1
PORT ?= 8000
# pytest-xdist workers: one per logical CPU (on a 2-core machine: 2). --dist loadgroup is
# tests/conftest.py's scheduling: each test its own work unit, except a module with a
# module-scoped fixture, whose tests share one worker (the fixture built once). Before it, each
# test alone ran pytest in 315-356 s in CI, --dist load in 368-381 s, loadfile 342 s. A third
# worker on two cores does not fill the waits: -n 3 took 394 s (just before 7584db5; the slow tests 1.5-2x
# slower each) against 357 s for -n 2 in the CI run before it (not back to back); back to back on a
# quiet machine (at 191ffcc) 275.1 s against 283.7 s, with 6% more CPU: within noise, so two stay.
WORKERS ?= logical
# Bytecode (and pytest's rewritten test modules) cached in the venv, outside the sources, even
# where PYTHONDONTWRITEBYTECODE is set: without it every worker rewrites and compiles the ~100
# test modules and the packages on each run (collection 15.9 s CPU; 4.2-4.9 s once cached).
PYTEST := env -u PYTHONDONTWRITEBYTECODE PYTHONPYCACHEPREFIX=$(CURDIR)/$(VENV)/pycache $(BIN)/python -m pytest
LINT_PATHS := agent sim robot console benchmarks tests

.PHONY: run test test-fast lint install chromium bench

$(STAMP): pyproject.toml
	test -x $(BIN)/python || $(PY) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip
	# torch first, pinned to the CPU build (see pyproject.toml)
	$(BIN)/pip install --quiet torch==2.13.0
	$(BIN)/pip install --quiet -e '.[test]'
	touch $(STAMP)

install: $(STAMP)

chromium:
	@command -v chromium >/dev/null 2>&1 || { \
	  SUDO=$$( [ "$$(id -u)" = 0 ] || echo sudo ); \
	  $$SUDO apt-get update -qq && DEBIAN_FRONTEND=noninteractive $$SUDO apt-get install -y -qq chromium >/dev/null; }

run: $(STAMP)
	$(BIN)/imgnav console --host $(HOST) --port $(PORT)

# the Python packages and Chromium install side by side (neither waits for the other)
test:
	@$(MAKE) --no-print-directory -j2 $(STAMP) chromium
	$(PYTEST) -q -n $(WORKERS) --dist loadgroup --durations=15

test-fast: $(STAMP)
	$(PYTEST) -q -n $(WORKERS) -m "not slow" tests/unit

lint: $(STAMP)
	$(BIN)/ruff check $(LINT_PATHS)
	$(BIN)/ruff format --check $(LINT_PATHS)
	$(BIN)/mypy

bench: $(STAMP)
	for f in benchmarks/bench_*.py; do $(BIN)/python $$f || exit 1; done
