# Every target CI and the README use. PYTHON may point at a virtualenv's python.
PYTHON ?= python3
PIP := $(PYTHON) -m pip
OUT ?= out

.PHONY: install demo test test-slow lint typecheck bench evaluate leaderboard train-all clean

# torch is pinned first so the CPU build is taken (an unpinned torch pulls GBs of CUDA packages)
install:
	$(PIP) install "torch==2.13.0"
	$(PIP) install -e ".[rl,dev]"

demo: install
	$(PYTHON) -m valve_env.cli demo --out $(OUT)/demo

test: install
	$(PYTHON) -m pytest -n 2 -q

test-slow: install
	$(PYTHON) -m pytest -n 2 -q -m slow

lint:
	$(PYTHON) -m ruff check valve_env agents tests benchmarks
	$(PYTHON) -m mypy

bench: install
	$(PYTHON) -m valve_env.cli bench --json $(OUT)/bench.json

evaluate: install
	$(PYTHON) -m valve_env.cli evaluate --env ThermoValve-v0 --controllers self_acting,pi,pi_compensated --episodes 10 --seed 0 --json $(OUT)/evaluate.json --out $(OUT)/evaluate

clean:
	rm -rf $(OUT) .pytest_cache .mypy_cache .ruff_cache
