# `make demo` runs the main job on embedded defaults; `make test` runs lint and
# the tests. Both create .venv and install into it on a fresh machine; the
# stamp files make a second run skip the install when nothing changed.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
DEMO_DIR := build/demo

.PHONY: demo test bench clean

$(BIN)/python:
	$(PYTHON) -m venv $(VENV)

$(VENV)/.run-installed: pyproject.toml constraints.txt | $(BIN)/python
	$(BIN)/python -m pip install -q --disable-pip-version-check -c constraints.txt -e .
	touch $@

$(VENV)/.test-installed: pyproject.toml constraints.txt $(VENV)/.run-installed
	$(BIN)/python -m pip install -q --disable-pip-version-check -c constraints.txt -e '.[test,build]'
	touch $@

demo: $(VENV)/.run-installed
	$(BIN)/tracker demo --out $(DEMO_DIR)

test: $(VENV)/.test-installed
	$(BIN)/ruff check tracker tests tools
	$(BIN)/pytest

bench: $(VENV)/.test-installed
	$(BIN)/tracker bench all --out build/bench

clean:
	rm -rf $(VENV) build
