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
.PHONY: help env test figures reproduce baseline bench mutants clean distclean povray peers-env readings

help:
	@echo "make figures   reproduce the paper's figures and result tables (results/)"
	@echo "make reproduce regenerate every result from scratch"
	@echo "make test      run the test suite"
	@echo "make baseline  regenerate the stored error curves deliberately"
	@echo "make readings  the paper's observations under other readings (4 sweeps, ~12 min)"
	@echo "make bench     run the throughput benchmark"
	@echo "make mutants   run the hand-written mutants against the tests (about 5 min)"
	@echo "make peers-env set up depthy and plenpy (pinned) for gridflow peers --hci"
	@echo "make clean     remove caches (never results of long runs)"

# gridflow is installed in strict editable mode: a tree of links to the repository's files
# under build/ (static tools can follow it; the default mode's import hook they cannot).
# A module added or removed needs the tree made again: MODULES lists them, and the list
# is rewritten (re-triggering the install) only when it changes.
MODULES     := $(sort $(wildcard base/*.py estimator/*.py generators/*.py scenes/*.py \
                 pipeline/*.py bench/*.py bench/cli/*.py bench/sweeps/*.toml))
MODULE_LIST := build/.modules
$(shell mkdir -p build && echo "$(MODULES)" | cmp -s - $(MODULE_LIST) || echo "$(MODULES)" > $(MODULE_LIST))

$(STAMP): pyproject.toml requirements.lock $(MODULE_LIST)
	@echo "setting up $(VENV): the pinned dependencies of requirements.lock and gridflow (1-2 min the first time) ..."
	@test -x $(PY) || $(PYTHON) -m venv $(VENV)
	@$(PY) -m pip install -q --upgrade pip
	@$(PY) -m pip install -q -r requirements.lock
	@$(PY) -m pip install --no-deps --no-build-isolation -e . --config-settings editable_mode=strict \
	  > $(VENV)/install.log 2>&1 || { cat $(VENV)/install.log; exit 1; }
	@touch $@
	@echo "$(VENV) is ready"

# numba compiles the estimator's kernels on first use (20-40 s) and caches them on disk;
# paying that here, with a message, keeps the first estimate from a long silence.
KERNELS := $(VENV)/.kernels
# (numba caches them beside the linked sources, so a new link tree needs them again)
$(KERNELS): estimator/_kernels.py estimator/_solver.py $(STAMP)
	@$(PY) -m gridflow.estimator.warmup
	@touch $@

env: $(STAMP) $(KERNELS)

# --- results and figures -----------------------------------------------------------------
# what a sweep's rows depend on (the modules its resume key fingerprints); the CLI is not
# among them: it only parses and prints
NUMERICS  := $(wildcard estimator/*.py generators/*.py) base/volume.py base/io.py \
             base/errors.py base/metrics.py bench/spec.py bench/sweep.py pipeline/__init__.py \
             pipeline/executors.py bench/setups.py
SWEEP_CSV := results/sweep_paper.csv
SETUP_CSV := results/sweep_paper_setup.csv
GROWTH_CSV := results/sweep_growth.csv
ZOOM_CSV  := results/sweep_paper_setup_zoom.csv
FIGDIR    := results/figures
FIGS      := $(FIGDIR)/fig1.png $(FIGDIR)/fig2.png \
             $(FIGDIR)/fig3_gridflow_setup.png $(FIGDIR)/fig4_gridflow_setup.png \
             $(FIGDIR)/fig3_paper_setup.png $(FIGDIR)/fig4_paper_setup.png \
             $(FIGDIR)/fig_growth.png
OUTPUTS   := $(FIGS) results/claims.csv results/claims_paper_setup.csv results/cube.csv \
             results/peers_depth.csv results/claims_growth.csv results/leaf.csv \
             results/paper_terms.csv results/claims_paper_setup_zoom.csv \
             results/cube_variants.csv results/growth_maps.csv results/uneven_leaf.csv \
             results/leaderboard.csv
CUBE_SRC  := $(wildcard estimator/*.py scenes/*.py) base/loader.py base/errors.py \
             bench/cube_experiment.py bench/figures.py base/metrics.py bench/markdown.py

figures: $(STAMP) $(KERNELS)
	@t0=$$(date +%s); $(MAKE) --no-print-directory $(OUTPUTS) && \
	  echo "make figures: up to date after $$(( $$(date +%s) - t0 )) s"

# Everything from scratch: delete the generated results, then rebuild them.
reproduce: $(STAMP)
	rm -rf $(OUTPUTS) $(SWEEP_CSV) $(SETUP_CSV) $(GROWTH_CSV) $(ZOOM_CSV) work/cube
	@$(MAKE) --no-print-directory figures

$(SWEEP_CSV): bench/sweeps/paper.toml $(NUMERICS) | $(STAMP)
	$(BIN)/gridflow sweep $< -o $@

$(SETUP_CSV): bench/sweeps/paper_setup.toml $(NUMERICS) | $(STAMP)
	$(BIN)/gridflow sweep $< -o $@

$(GROWTH_CSV): bench/sweeps/growth.toml $(NUMERICS) | $(STAMP)
	$(BIN)/gridflow sweep $< -o $@

$(ZOOM_CSV): bench/sweeps/paper_setup_zoom.toml $(NUMERICS) | $(STAMP)
	$(BIN)/gridflow sweep $< -o $@

results/claims_paper_setup_zoom.csv: $(ZOOM_CSV) bench/claims.py bench/labels.py bench/markdown.py | $(STAMP)
	$(BIN)/gridflow claims $< --write-csv $@ --write-doc docs/reproduction.md

$(FIGDIR)/fig_growth.png: $(GROWTH_CSV) bench/figures.py bench/labels.py | $(STAMP)
	$(BIN)/gridflow figures --sweep $< --out $(FIGDIR)

results/claims_growth.csv: $(GROWTH_CSV) bench/claims.py bench/labels.py bench/markdown.py | $(STAMP)
	$(BIN)/gridflow claims $< --write-csv $@ --write-doc docs/reproduction.md

$(FIGDIR)/fig3_gridflow_setup.png $(FIGDIR)/fig4_gridflow_setup.png &: $(SWEEP_CSV) bench/figures.py bench/labels.py | $(STAMP)
	$(BIN)/gridflow figures --sweep $< --out $(FIGDIR)

$(FIGDIR)/fig3_paper_setup.png $(FIGDIR)/fig4_paper_setup.png &: $(SETUP_CSV) bench/figures.py bench/labels.py | $(STAMP)
	$(BIN)/gridflow figures --sweep $< --out $(FIGDIR)

$(FIGDIR)/fig2.png: bench/figures.py generators/sinusoid.py | $(STAMP)
	$(BIN)/gridflow figures --fig2 --out $(FIGDIR)

# The cube: rendered with POV-Ray into work/cube/ (cached, not committed), then estimated.
$(FIGDIR)/fig1.png results/cube.csv &: $(CUBE_SRC) | $(STAMP) povray
	$(BIN)/gridflow cube --csv results/cube.csv --fig-dir $(FIGDIR) --write-doc docs/reproduction.md

# What sets the cube's motion directions: five more renderings of the cube (cached in
# work/cube/, 1-5 min each the first time), the full model's directions on each.
results/cube_variants.csv: $(CUBE_SRC) bench/cube_variants.py | $(STAMP) povray
	$(BIN)/gridflow cube-variants --csv $@ --write-doc docs/reproduction.md

# The growing leaf: rendered with POV-Ray into work/cube/ (cached), growth maps per region.
LEAF_SRC := $(wildcard estimator/*.py scenes/*.py) base/loader.py base/errors.py \
            bench/leaf_experiment.py bench/figures.py
results/leaf.csv $(FIGDIR)/fig_leaf.png &: $(LEAF_SRC) | $(STAMP) povray
	$(BIN)/gridflow leaf --csv results/leaf.csv --fig-dir $(FIGDIR)

# growth maps on leaves that grow unevenly, gridflow beside the 2-D divergence (a few
# minutes); the table in bench/README.md is rewritten from the same rows
results/growth_maps.csv: $(wildcard estimator/*.py generators/*.py) bench/growth_maps.py \
                         bench/peers.py | $(STAMP)
	$(PY) -m gridflow.bench.growth_maps --csv results/growth_maps.csv --write-doc bench/README.md

# the leaderboard: per suite (bench/sweeps/leaderboard_*.toml) gridflow's models and the
# peers as methods, ranked (about ten seconds); its table in bench/README.md
results/leaderboard.csv $(FIGDIR)/fig_leaderboard.png &: $(wildcard estimator/*.py \
                         generators/*.py) bench/leaderboard.py bench/peer_methods.py \
                         bench/peers.py bench/methods.py bench/sweep.py bench/spec.py \
                         bench/sweeps/leaderboard_depth.toml \
                         bench/sweeps/leaderboard_growth.toml | $(STAMP)
	$(PY) -m gridflow.bench.leaderboard --csv results/leaderboard.csv --fig-dir $(FIGDIR) \
	  --write-doc bench/README.md

# the POV-Ray leaf growing unevenly, as a recording (625 renders, cached in work/cube/),
# estimated with the growth default: maps and kymograph against the truth, per region
results/uneven_leaf.csv $(FIGDIR)/fig_uneven_leaf.png &: $(LEAF_SRC) bench/uneven_leaf.py \
                          bench/recordings.py $(wildcard pipeline/*.py base/*.py) | $(STAMP) povray
	$(PY) -m gridflow.bench.uneven_leaf --csv results/uneven_leaf.csv --fig-dir $(FIGDIR) \
	  --write-doc bench/README.md

# gridflow and peer methods side by side: depth on the cube rendered as a light field with
# large disparities, motion on sinusoids and the cube.
results/peers_depth.csv results/peers_motion.csv $(FIGDIR)/peers_depth.png &: $(CUBE_SRC) bench/peers.py generators/sinusoid.py | $(STAMP) povray
	$(BIN)/gridflow peers --csv-depth results/peers_depth.csv --csv-motion results/peers_motion.csv --fig-dir $(FIGDIR)

# depthy and plenpy, the Python light-field peers, in an environment of their own with the
# versions they need (requirements-peers.lock); `gridflow peers --hci SCENE` runs them there.
PEERS_VENV ?= .venv-peers
peers-env: $(PEERS_VENV)/.done
$(PEERS_VENV)/.done: requirements-peers.lock
	@echo "setting up depthy and plenpy in $(PEERS_VENV) (pinned versions, once; about 30 s) ..."
	@test -x $(PEERS_VENV)/bin/python || $(PYTHON) -m venv $(PEERS_VENV)
	@$(PEERS_VENV)/bin/python -m pip install -q -c /dev/null -r requirements-peers.lock 2>&1 \
	  | grep -v "^WARNING: Location" || true
	@$(PEERS_VENV)/bin/python -c "import depthy.lightfield, plenpy.lightfields" 2>/dev/null \
	  || { echo "depthy or plenpy does not import in $(PEERS_VENV) (see pip's output above)" >&2; exit 1; }
	@touch $@

# POV-Ray (Debian's povray) renders the cube; installed where missing, or one line says how.
povray:
	@command -v povray >/dev/null 2>&1 || { \
	  if [ "$$(id -u)" = 0 ]; then SUDO=""; elif sudo -n true 2>/dev/null; then SUDO="sudo -n"; \
	  else echo "POV-Ray is missing and installing it needs root: run 'sudo apt-get install povray', then make again" >&2; exit 1; fi; \
	  command -v apt-get >/dev/null 2>&1 || { echo "POV-Ray is missing: install it with your system's package manager (Debian/Ubuntu: apt-get install povray), then make again" >&2; exit 1; }; \
	  echo "installing POV-Ray (apt-get install povray; once) ..."; \
	  $$SUDO apt-get update -qq && DEBIAN_FRONTEND=noninteractive $$SUDO apt-get install -y -qq povray >/dev/null && \
	  echo "POV-Ray installed"; }

results/claims.csv: $(SWEEP_CSV) bench/claims.py bench/labels.py bench/markdown.py | $(STAMP)
	$(BIN)/gridflow claims $< --write-csv $@ --write-doc docs/reproduction.md

results/claims_paper_setup.csv: $(SETUP_CSV) bench/claims.py bench/labels.py bench/markdown.py | $(STAMP)
	$(BIN)/gridflow claims $< --write-csv $@ --write-doc docs/reproduction.md

# the paper's quantitative statements, gridflow's number for each under both setups
results/paper_terms.csv: $(SWEEP_CSV) $(SETUP_CSV) bench/claims.py bench/labels.py bench/markdown.py | $(STAMP)
	$(BIN)/gridflow claims $(SWEEP_CSV) $(SETUP_CSV) --write-terms $@ --write-doc docs/reproduction.md

# Other readings of the paper's unstated parameters (bench/readings.py): four more sweeps
# (into work/sweeps/, not committed: megabytes each), then their verdicts and numbers
# beside the paper setup's in results/readings*.csv and docs/reproduction.md.
READINGS     := paper_setup_offset1 paper_setup_matched3 paper_setup_ivw paper_offset1
READING_CSVS := $(READINGS:%=work/sweeps/sweep_%.csv)
work/sweeps/sweep_%.csv: bench/sweeps/%.toml $(NUMERICS) | $(STAMP)
	$(BIN)/gridflow sweep $< -o $@
readings: results/readings.csv
results/readings.csv results/readings_verdicts.csv &: $(SETUP_CSV) $(READING_CSVS) bench/readings.py bench/claims.py | $(STAMP)
	$(BIN)/gridflow readings $(SETUP_CSV) $(READING_CSVS) --csv-verdicts results/readings_verdicts.csv \
	  --csv-terms results/readings.csv --write-doc docs/reproduction.md

# Regenerate the stored error curves on purpose (the tests compare fresh runs with them).
bench: $(STAMP) $(KERNELS)
	$(PY) -m gridflow.bench.throughput

baseline: $(STAMP)
	$(BIN)/gridflow sweep paper -o $(SWEEP_CSV)
	$(BIN)/gridflow claims $(SWEEP_CSV) --write-csv results/claims.csv --write-doc docs/reproduction.md
	$(BIN)/gridflow sweep paper_setup -o $(SETUP_CSV)
	$(BIN)/gridflow claims $(SETUP_CSV) --write-csv results/claims_paper_setup.csv --write-doc docs/reproduction.md
	$(BIN)/gridflow sweep growth -o $(GROWTH_CSV)
	$(BIN)/gridflow claims $(GROWTH_CSV) --write-csv results/claims_growth.csv --write-doc docs/reproduction.md
	$(BIN)/gridflow claims $(SWEEP_CSV) $(SETUP_CSV) --write-terms results/paper_terms.csv --write-doc docs/reproduction.md
	$(BIN)/gridflow sweep paper_setup_zoom -o $(ZOOM_CSV)
	$(BIN)/gridflow claims $(ZOOM_CSV) --write-csv results/claims_paper_setup_zoom.csv --write-doc docs/reproduction.md

# the test files shared among TEST_WORKERS processes (pytest-xdist; a file's tests stay in
# one process, so its module fixtures are made once): CI's machine has two cores, and
# most tests keep one busy.  TEST_WORKERS=0 runs them all in this process.
TEST_WORKERS ?= 2
test: $(STAMP) $(KERNELS) povray
	$(PY) -m pytest -n $(TEST_WORKERS) --dist loadfile

# plausible one-line bugs, each applied alone to a copy of the package, against the
# correctness tests that should catch it (tests/mutation.py; not part of make test)
mutants: $(STAMP) $(KERNELS)
	$(PY) tests/mutation.py

# build/ holds the editable install's link tree: removing it means installing again
clean:
	rm -rf .pytest_cache build *.egg-info $(STAMP) $(KERNELS)
	find . -name __pycache__ -not -path "./$(VENV)/*" -prune -exec rm -rf {} +

distclean: clean
	rm -rf $(VENV) $(PEERS_VENV)
