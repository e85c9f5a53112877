# The two entry points of the project: `make demo` and `make test`.
# Each one creates .venv in the checkout and installs everything it needs first.
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
OUT ?= outputs/demo

.PHONY: demo test lint setup clean browser

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

# The report's browser test renders pages in Debian's chromium: installed here when missing and
# run as root (CI); otherwise that test skips with the reason (and fails when CI is set).
browser:
	@if [ ! -x /usr/bin/chromium ]; then \
	  if [ "$$(id -u)" = 0 ]; then \
	    apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium; \
	  else echo "chromium missing: the browser test will skip (as root, make test installs it)"; fi; \
	fi

test: $(VENV)/.installed lint browser
	$(PY) -m pytest -q tests

clean:
	rm -rf $(VENV) outputs .pytest_cache .ruff_cache
