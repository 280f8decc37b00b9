# make run   : create the environment if needed, then run the default experiment (two-link arm)
# make test  : create the environment if needed, then ruff, mypy and the whole test suite
# make bench : benchmarks; figures go to bench/*.json and bench/*.md
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
# Our matrices are small: threaded BLAS only oversubscribes the cores that pytest -n 2 and the sweeps use.
export OPENBLAS_NUM_THREADS ?= 1
export OMP_NUM_THREADS ?= 1

.PHONY: run test lint bench clean env review-shots

env: $(STAMP)

$(STAMP): pyproject.toml
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e ".[dev]"
	touch $(STAMP)

run: $(STAMP)
	$(BIN)/sysid-run

lint: $(STAMP)
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .
	$(BIN)/mypy dynamics envs excitation identify harness

test: lint
	$(BIN)/python -m pytest -n 2 --dist worksteal -q

bench: $(VENV)/.installed-bench
	$(BIN)/python -m bench

# the benchmarks also need the peer tools (mujoco.sysid's extras): the [bench] group
$(VENV)/.installed-bench: $(STAMP)
	$(BIN)/python -m pip install --quiet -e ".[dev,bench]"
	touch $(VENV)/.installed-bench

clean:
	rm -rf outputs multirun review-shots .pytest_cache .mypy_cache .ruff_cache

# review-shots: one recording of each kind, shown in rerun's web viewer in headless Chromium, saved as PNGs
# into review-shots/ (needs Debian's chromium: apt-get install -y chromium)
review-shots: $(STAMP)
	$(BIN)/python -m tools.review_shots review-shots
