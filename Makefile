# The two commands of the README. Both run the idempotent set-up first (venv + drivers).
VENV ?= .venv
PY := $(VENV)/bin/python

.PHONY: setup demo test test-fast lint

setup:
	@bash scripts/setup.sh

demo: setup
	$(VENV)/bin/rsb demo

test: setup
	$(PY) -m pytest -ra

test-fast: setup
	$(PY) -m pytest -ra -m "not slow"

lint: setup
	$(VENV)/bin/ruff check .
	$(VENV)/bin/lint-imports  # the layer contracts of pyproject.toml (docs/architecture.md)
