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
.PHONY: help env test figures reproduce baseline bench clean distclean povray

help:
	@echo "make figures   reproduce the paper's figures and result tables (results/)"
	@echo "make reproduce regenerate every result from scratch"
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

# --- results and figures -----------------------------------------------------------------
NUMERICS  := $(wildcard estimator/*.py generators/*.py) gridflow/metrics.py gridflow/sweep.py \
             gridflow/cli.py
SWEEP_CSV := results/sweep_paper.csv
FIGDIR    := results/figures
FIGS      := $(FIGDIR)/fig1.png $(FIGDIR)/fig2.png $(FIGDIR)/fig3.png $(FIGDIR)/fig4.png
OUTPUTS   := $(FIGS) results/claims.csv results/cube.csv
CUBE_SRC  := $(wildcard estimator/*.py scenes/*.py) gridflow/render.py gridflow/loader.py \
             gridflow/cube.py gridflow/figures.py gridflow/metrics.py gridflow/cli.py

figures: $(STAMP)
	@t0=$$(date +%s); $(MAKE) --no-print-directory $(OUTPUTS) && \
	  echo "make figures: up to date after $$(( $$(date +%s) - t0 )) s"

# Everything from scratch: delete the generated results, then rebuild them.
reproduce: $(STAMP)
	rm -rf $(OUTPUTS) $(SWEEP_CSV) work/cube
	@$(MAKE) --no-print-directory figures

$(SWEEP_CSV): bench/sweeps/paper.toml $(NUMERICS) | $(STAMP)
	$(BIN)/gridflow sweep $< -o $@

$(FIGDIR)/fig3.png $(FIGDIR)/fig4.png &: $(SWEEP_CSV) gridflow/figures.py gridflow/cli.py | $(STAMP)
	$(BIN)/gridflow figures --sweep $< --out $(FIGDIR)

$(FIGDIR)/fig2.png: gridflow/figures.py generators/sinusoid.py gridflow/cli.py | $(STAMP)
	$(BIN)/gridflow figures --fig2 --out $(FIGDIR)

# The cube: rendered with POV-Ray into work/cube/ (cached, not committed), then estimated.
$(FIGDIR)/fig1.png results/cube.csv &: $(CUBE_SRC) | $(STAMP) povray
	$(BIN)/gridflow cube --csv results/cube.csv --fig-dir $(FIGDIR)

# POV-Ray (Debian's povray) is installed where missing.
povray:
	@command -v povray >/dev/null 2>&1 || { \
	  echo "installing POV-Ray (apt-get install povray)"; \
	  SUDO=""; [ "$$(id -u)" = 0 ] || SUDO=sudo; \
	  $$SUDO apt-get update -qq && DEBIAN_FRONTEND=noninteractive $$SUDO apt-get install -y -qq povray >/dev/null; }

results/claims.csv: $(SWEEP_CSV) gridflow/claims.py gridflow/cli.py | $(STAMP)
	$(BIN)/gridflow claims $< --write-csv $@ --write-doc docs/reproduction.md

# Regenerate the stored error curves on purpose (the tests compare fresh runs with them).
bench: $(STAMP)
	$(PY) -m bench.throughput

baseline: $(STAMP)
	$(BIN)/gridflow sweep bench/sweeps/paper.toml -o $(SWEEP_CSV)
	$(BIN)/gridflow claims $(SWEEP_CSV) --write-csv results/claims.csv --write-doc docs/reproduction.md

test: $(STAMP)
	$(PY) -m pytest

clean:
	rm -rf .pytest_cache build *.egg-info
	find . -name __pycache__ -not -path "./$(VENV)/*" -prune -exec rm -rf {} +

distclean: clean
	rm -rf $(VENV)
