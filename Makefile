# Quickstart: `make demo`, `make test`. Both create .venv on first use.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
TEST_STAMP := $(VENV)/.installed-test
BENCH_STAMP := $(VENV)/.installed-bench
# OpenWInD (GPL-3): the benchmarks' independent simulator, never a dependency of the package
OPENWIND := openwind==0.12.4

.PHONY: demo test lint bench clean

$(BIN)/python:
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip

# the numba kernels compile once at install (about 25 s; cache=True keeps them): the first
# `make demo` then starts with them; without it they compile in the background of the
# demo's first stages (mpipe/pipeline/warmup.py)
WARMUP := $(BIN)/python -m mpipe.pipeline.warmup || echo "kernels not compiled now: they compile on first use"

$(STAMP): pyproject.toml | $(BIN)/python
	$(BIN)/python -m pip install --quiet -e .
	$(WARMUP)
	touch $@

$(TEST_STAMP): pyproject.toml | $(BIN)/python
	$(BIN)/python -m pip install --quiet -e ".[test]"
	$(WARMUP)
	touch $@ $(STAMP)

demo: $(STAMP)
	$(BIN)/python -m mpipe.cli.demo

lint: $(TEST_STAMP)
	$(BIN)/ruff check mpipe tests benchmarks
	$(BIN)/ruff format --check mpipe tests benchmarks

test: lint
	# two processes: the suite's tests are independent (tmp_path each), and CI has 2 cores
	$(BIN)/python -m pytest -n 2

$(BENCH_STAMP): $(TEST_STAMP)
	$(BIN)/python -m pip install --quiet "$(OPENWIND)"
	touch $@

bench: $(BENCH_STAMP)
	$(BIN)/python benchmarks/run_all.py

clean:
	rm -rf $(VENV) build *.egg-info demo_output
