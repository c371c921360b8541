# trafficlearn: `make demo` builds everything on the bundled real data, `make test` runs the test suite.
SHELL := /bin/bash
PYTHON ?= $(shell command -v python3.11 || command -v python3)
VENV := .venv
PY := $(VENV)/bin/python
export TRAFFICLEARN_HOME ?= $(CURDIR)/var
export DAGSTER_HOME := $(TRAFFICLEARN_HOME)/dagster
export PYTHONUNBUFFERED := 1
export TRAFFICLEARN_PROFILE ?= $(or $(PROFILE),demo)
# asset groups `make demo` materialises, in order
DEMO_GROUPS := aviation trajectory urban dcb

.PHONY: demo test bench dev tables clean

$(VENV)/.installed: pyproject.toml
	@$(PYTHON) -c "import sys; sys.exit(sys.version_info[:2] != (3, 11))" 2>/dev/null || { echo "error: trafficlearn needs Python 3.11 (set PYTHON=/path/to/python3.11)"; exit 1; }
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet -e '.[dev]'
	touch $@

$(DAGSTER_HOME)/dagster.yaml: dagster.yaml
	mkdir -p $(DAGSTER_HOME)
	cp dagster.yaml $@

demo: $(VENV)/.installed $(DAGSTER_HOME)/dagster.yaml
	$(PY) -m pipelines.materialize $(DEMO_GROUPS)
	$(PY) -m warehouse tables

test: $(VENV)/.installed
	$(PY) -m pytest tests --ignore=tests/bench -q

# `traffic` (the comparison baseline) pins pandas/numpy versions of its own, so it gets a venv of its own.
.venv-bench/.installed:
	$(PYTHON) -m venv .venv-bench
	.venv-bench/bin/python -m pip install --quiet 'traffic==2.13' 'pandas>=2.2,<3'
	touch $@

bench: $(VENV)/.installed .venv-bench/.installed
	TRAFFICLEARN_BENCH_TRAFFIC_PYTHON=$(CURDIR)/.venv-bench/bin/python $(PY) -m pytest tests/bench -q -s

dev: $(VENV)/.installed $(DAGSTER_HOME)/dagster.yaml
	$(PY) -m pipelines.dev

tables: $(VENV)/.installed
	$(PY) -m warehouse tables

clean:
	rm -rf $(TRAFFICLEARN_HOME)
