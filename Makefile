# The two commands of the README. Both run the idempotent set-up first (venv + drivers).
VENV ?= .venv
PY := $(VENV)/bin/python

.PHONY: setup demo test test-fast lint

setup:
	@bash scripts/setup.sh

demo: setup
	$(VENV)/bin/rsb demo

# Test files run in parallel (pytest-xdist), a worker a core plus one, at most 4: each worker holds
# torch, SAPIEN and a renderer, and memory runs out before cores do. The extra worker fills the
# time tests wait on the processes they start (signals, limits, venv builds): on 2 cores the suite
# took 1,224 s with 3 workers, 1,370 s with 2 (peak 6 GB). A file's tests stay in one worker
# (loadfile: module fixtures are built once), the costliest files first (tests/conftest.py, by the
# seconds each file took in a measured run: tests/durations.json, written by scripts/test_durations.py;
# xdist's own reorder, by test count, would start the long few-test files last). The run ends with
# its wall time ("rsb: suite wall time ..."). JOBS=0: one process.
JOBS ?= $(shell python3 -c "import os; print(len(os.sched_getaffinity(0)) + 1)" 2>/dev/null || echo auto)
XDIST := -n $(JOBS) --maxprocesses 4 --dist loadfile --no-loadscope-reorder
# each test's seconds, for scripts/test_durations.py (the order above and README's suite time)
JUNIT ?= .cache/junit.xml

test: setup
	$(PY) -m pytest -ra $(XDIST) --junitxml=$(JUNIT)

test-fast: setup
	$(PY) -m pytest -ra $(XDIST) -m "not slow"

lint: setup
	$(VENV)/bin/ruff check .
	$(VENV)/bin/lint-imports  # the layer contracts of pyproject.toml (docs/architecture.md)
