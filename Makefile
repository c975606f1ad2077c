# gridflow: `make figures` runs the main job, `make test` the test suite.  Both bootstrap a
# virtual environment with the pinned dependencies (requirements.lock) on first use.
# Targets are real files: results depend on the code and specs that make them, figures on
# results, so `make` redoes only what changed.

PYTHON ?= python3
VENV   ?= .venv
BIN    := $(VENV)/bin
PY     := $(BIN)/python
STAMP  := $(VENV)/.installed

.DEFAULT_GOAL := help
.PHONY: help env test figures baseline bench clean distclean

help:
	@echo "make figures   reproduce the paper's figures and result tables (results/)"
	@echo "make test      run the test suite"
	@echo "make baseline  regenerate the stored error curves deliberately"
	@echo "make bench     run the throughput benchmark"
	@echo "make clean     remove caches (never results of long runs)"

$(STAMP): pyproject.toml requirements.lock
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -r requirements.lock
	$(PY) -m pip install -q --no-deps --no-build-isolation -e .
	touch $@

env: $(STAMP)

test: $(STAMP)
	$(PY) -m pytest

clean:
	rm -rf .pytest_cache build *.egg-info
	find . -name __pycache__ -not -path "./$(VENV)/*" -prune -exec rm -rf {} +

distclean: clean
	rm -rf $(VENV)
