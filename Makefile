# The two entry points of the project: `make demo` and `make test`.
# Each one creates .venv in the checkout and installs everything it needs first.
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
OUT ?= outputs/demo

.PHONY: demo test lint setup clean

$(VENV)/.installed: setup.py
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	# torch first, exactly this version: it resolves to the local CPU build.
	$(PY) -m pip install -q torch==2.13.0
	$(PY) -m pip install -q -e ".[dev,depth,fleet]"
	touch $@

setup: $(VENV)/.installed

demo: $(VENV)/.installed
	$(VENV)/bin/hybrid-calib demo --out $(OUT)

lint: $(VENV)/.installed
	$(VENV)/bin/ruff check hybrid_calib factors learned tests examples benchmarks

test: $(VENV)/.installed lint
	$(PY) -m pytest -q tests

clean:
	rm -rf $(VENV) outputs .pytest_cache .ruff_cache
