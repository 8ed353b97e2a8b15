# One command for each job; each sets up its own virtual environment first.
#   make demo   replay the bundled recording through the service (Zenoh on DEMO_ZENOH,
#               default tcp/127.0.0.1:7447)
#   make test   lint, type-check and run the whole test suite on 2 workers (what CI runs)
#   make faults the fault-injection tests alone (tests/test_faults_*.py, a few minutes)
#   make soak   the 30-minute soak of the daemon under faults (benchmarks/soak.py)
PYTHON ?= python3
VENV ?= .venv
BIN := $(VENV)/bin

.PHONY: demo test lint setup clean faults soak

$(BIN)/.installed: pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip
	$(BIN)/pip install --quiet -e '.[test,report,foxglove,export]'
	touch $@

setup: $(BIN)/.installed

DEMO_SPEED ?= 2
DEMO_LOG ?= out/demo-log
DEMO_ZENOH ?= tcp/127.0.0.1:7447

# Watch it from another terminal: .venv/bin/tracker-service subscribe --connect tcp/127.0.0.1:7447
demo: setup
	$(BIN)/tracker-service replay recordings/three_sites.mcap --speed $(DEMO_SPEED) \
		--zenoh-listen $(DEMO_ZENOH) --mcap-dir $(DEMO_LOG)

lint: setup
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .
	$(BIN)/mypy

# Two workers, one test file each at a time (module fixtures are built once, in one worker),
# in the order of tests/conftest.py (files with slow tests first), not xdist's by test count.
# numba's cache filled first, as after an installation (docs/deployment.md): on a fresh
# clone the kernels are compiled once, in one process, rather than by both workers and by
# every daemon a test starts, each for up to two minutes in its warm-up.
TEST_WORKERS ?= 2
test: lint
	$(BIN)/tracker-service warm-up
	$(BIN)/python -m pytest -n $(TEST_WORKERS) --dist loadfile --no-loadscope-reorder

faults: setup
	$(BIN)/python -m pytest -q tests/test_faults_*.py

SOAK_MINUTES ?= 30
soak: setup
	$(BIN)/python benchmarks/soak.py --minutes $(SOAK_MINUTES)

clean:
	rm -rf $(VENV) .pytest_cache .mypy_cache .ruff_cache .hypothesis
