# One word per job on a fresh machine with Python 3.11+: each target creates the virtual
# environment it needs (./.venv) on first use.
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed

.PHONY: setup demo test test-slow test-all lint bench docs blender clean

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[test,plot,bench]'
	touch $(STAMP)

setup: $(STAMP)

# Blender's Python module (bpy 4.5 LTS) for the Cycles parity tests and .blend exports: it needs
# Python 3.11 exactly and NumPy < 2, so it lives in an environment of its own (.venv-blender),
# which brdf_fit.convert.blender finds; without it those tests skip with one line
BLENDER_PYTHON ?= python3.11
BLENDER_VENV   := .venv-blender
BLENDER_STAMP  := $(BLENDER_VENV)/.installed

$(BLENDER_STAMP):
	$(BLENDER_PYTHON) -m venv $(BLENDER_VENV)
	$(BLENDER_VENV)/bin/python -m pip install --quiet 'bpy==4.5.*'
	touch $(BLENDER_STAMP)

blender: $(BLENDER_STAMP)   ## Blender 4.5's Python module in ./.venv-blender (Cycles parity tests)

demo: $(STAMP)          ## the main job on its embedded default
	$(BIN)/brdf-fit demo

# the suite runs in parallel, one process per core (pytest-xdist; whole files per worker, so a
# file's tests share their compilations; 81% of the summed test time is tracing, lowering and
# compiling: benchmarks/results/compiles_tests.md). The default set: 6:00-9:49 for 1975-1976
# tests on 2 Intel Xeon cores (AVX-512) from fresh clones of e227241, 43ea94b, 792fb36
# (2026-12-07) and bfc0f6f (2026-12-08, with make blender), 7:48 for 1913 on 2 AMD EPYC cores
# (898d200); the slow set (`test-slow`, which CI runs too): 20:32-38:10 for 1878-1879 on the
# Xeon (fresh clones of e227241, 792fb36 and bfc0f6f: the same machine type varies that much),
# 28:30 for 1698 on the EPYC (CI in all, blender + setup + test + docs + test-slow: 29-57
# minutes on the Xeon, ~40 on the EPYC).
# On an AVX2 machine, or to check a bound for one: XLA_FLAGS=--xla_cpu_max_isa=AVX2 make test
XDIST  := -n auto --maxprocesses=4 --dist loadfile

test: $(STAMP)          ## the default test suite (what CI runs)
	$(BIN)/python -m pytest -q $(XDIST)

test-slow: $(STAMP)     ## the tests marked slow only (CI runs them after `test`; tests/conftest.py)
	$(BIN)/python -m pytest -q $(XDIST) -m slow

test-all: $(STAMP)      ## both sets in one run
	$(BIN)/python -m pytest -q $(XDIST) -m "slow or not slow"

DOCS_STAMP := $(VENV)/.docs-installed

$(DOCS_STAMP): $(STAMP) pyproject.toml
	$(BIN)/python -m pip install --quiet -e '.[docs]'
	touch $(DOCS_STAMP)

docs: $(DOCS_STAMP)     ## the documentation site in ./site (warnings are errors; tutorials run)
	$(BIN)/python docs/_prepare.py
	PATH="$(abspath $(BIN)):$$PATH" $(BIN)/mkdocs build --strict

lint: $(STAMP)
	$(BIN)/ruff check brdf_fit data_synth tests benchmarks

bench: $(STAMP)         ## re-run the committed benchmarks (results in benchmarks/results/)
	$(BIN)/python benchmarks/bench_eval.py
	$(BIN)/python benchmarks/bench_albedo_quadrature.py
	$(BIN)/python benchmarks/bench_phong_normaliser.py
	$(BIN)/python benchmarks/bench_catalogue_cost.py
	$(BIN)/python benchmarks/bench_fit_batch.py
	$(BIN)/python benchmarks/bench_coverage.py
	$(BIN)/python benchmarks/bench_select.py
	$(BIN)/python benchmarks/bench_latency.py
	$(BIN)/python benchmarks/bench_render.py
	$(BIN)/python benchmarks/report.py   # results/REPORT.md + results/report/*.png

clean:
	rm -rf $(VENV) build site *.egg-info .pytest_cache
