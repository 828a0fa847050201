# Every target CI and the README use. Each works on a fresh machine: it builds its own virtualenv
# ($(VENV), default .venv) with $(PYTHON) and installs the versions CI tested (constraints.txt).
#   make demo                 core only (no torch): simulate, evaluate the baselines, write out/demo/
#   make test                 core + RL + test tools, then the default test suite
#   make test-slow            the long statistical studies, the full foreign-data corpus, the wheel test (marked slow)
#   make test-latest          the default suite against the newest versions pyproject.toml allows
#   make tutorials            re-run docs/tutorials/*.ipynb and save them with their outputs (figures inline)
PYTHON ?= python3
VENV ?= .venv
PY := $(VENV)/bin/python
PIP := $(PY) -m pip
CONSTRAINTS ?= constraints.txt
OUT ?= out

.PHONY: venv install-core install demo test test-slow test-latest tutorials lint typecheck bench evaluate constraints clean

$(PY):
	@$(PYTHON) -c 'import sys; sys.exit(0 if sys.version_info >= (3, 11) else "make: thermovalve needs Python >= 3.11 (constraints.txt pins versions that do); set PYTHON=/path/to/python3.11")'
	$(PYTHON) -m venv $(VENV)

venv: $(PY)

# the core: environments, baselines, identification, CLI (no torch)
install-core: venv
	$(PIP) install -q -c $(CONSTRAINTS) -e .

# torch is installed first and pinned so the local CPU build is taken (an unpinned torch pulls GBs of CUDA packages);
# rliable last, without its dependencies: it declares arch<8, the core pins arch 8 (numpy, scipy, absl-py and
# arch are already there; agents/rliable_summary.py has the compatibility shim)
install: venv
	$(PIP) install -q -c $(CONSTRAINTS) "torch==2.13.0"
	$(PIP) install -q -c $(CONSTRAINTS) -e ".[rl,dev]"
	$(PIP) install -q --no-deps -c $(CONSTRAINTS) rliable

demo: install-core
	$(PY) -m valve_env.cli demo --out $(OUT)/demo --force

# two pytest-xdist workers fill the two cores, each with one BLAS/OpenMP thread (with the libraries' own threads
# beside the other worker the default suite took 978 s against 773 s on 2 cores); worksteal evens out the long tests
SERIAL_BLAS := OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 MKL_NUM_THREADS=1

test: install
	$(SERIAL_BLAS) $(PY) -m pytest -n 2 --dist worksteal -q --durations=25

test-slow: install
	$(SERIAL_BLAS) $(PY) -m pytest -n 2 --dist worksteal -q -m slow

# the tests execute the tutorials (tests/docs/test_notebooks.py, with nbmake); this saves them with their outputs
tutorials: install
	THERMOVALVE_NO_PROGRESS=1 $(VENV)/bin/jupyter nbconvert --to notebook --execute --inplace docs/tutorials/*.ipynb

# the newest versions pyproject.toml allows (torch stays at the CPU build)
test-latest: venv
	$(PIP) install -q "torch==2.13.0"
	$(PIP) install -q --upgrade --upgrade-strategy eager -e ".[rl,dev]"
	$(PY) -m pytest -n 2 -q

# after changing dependencies: re-resolve in a scratch venv and write constraints.txt
constraints:
	rm -rf $(OUT)/constraints-venv && $(PYTHON) -m venv $(OUT)/constraints-venv
	$(OUT)/constraints-venv/bin/pip install -q "torch==2.13.0"
	$(OUT)/constraints-venv/bin/pip install -q -e ".[rl,dev]"
	{ sed -n '1,3p' $(CONSTRAINTS); $(OUT)/constraints-venv/bin/pip freeze --exclude-editable | \
	  sed 's/^torch==2.13.0+cpu/torch==2.13.0/'; } > $(CONSTRAINTS).new && mv $(CONSTRAINTS).new $(CONSTRAINTS)

lint: install
	$(PY) -m ruff check valve_env agents tests benchmarks studies
	$(PY) -m mypy

bench: install
	$(PY) -m valve_env.cli bench --json $(OUT)/bench.json --force

evaluate: install-core
	$(PY) -m valve_env.cli evaluate --env ThermoValve-v0 --controllers self_acting,pi,pi_compensated --episodes 10 \
	  --seed 0 --json $(OUT)/evaluate.json --out $(OUT)/evaluate --force

clean:
	rm -rf $(OUT) .pytest_cache .mypy_cache .ruff_cache
