# msarm: two commands on a fresh machine, `make demo` and `make test`.
# Both create .venv if needed and install the exact versions of requirements.lock
# (--no-compile: Python compiles only the modules it imports, when it first imports them;
# compiling every file of the locked packages took a third of the install). Then one import
# of every msarm module and the libraries they use writes their bytecode: where
# PYTHONDONTWRITEBYTECODE is set (as in many containers) Python never writes it itself, and
# every later process compiled its imports again (`msarm --help` 2.8 s, 1.2 s with the
# bytecode; `msarm track` of a Table I task 7.6 s, 5.0 s; the import that writes it takes
# about 12 s, once).
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed-stamp
# Imported once after the install to write their bytecode (with every msarm module).
WARM_IMPORTS := torch.optim cvxpy casadi pysindy matplotlib.pyplot scipy.signal \
	scipy.optimize scipy.integrate scipy.ndimage pyarrow.parquet daqp markdown_it yaml \
	typer.testing hypothesis pytest xdist
export MPLBACKEND := Agg

.PHONY: install demo tour test lint bench clean

$(STAMP): requirements.lock pyproject.toml
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --disable-pip-version-check --no-compile -r requirements.lock
	$(PY) -m pip install -q --disable-pip-version-check --no-deps --no-build-isolation -e .
	PYTHONDONTWRITEBYTECODE= $(PY) -c "import importlib, pkgutil, sys, msarm; \
	names = [m.name for m in pkgutil.walk_packages(msarm.__path__, 'msarm.')]; \
	[importlib.import_module(name) for name in names + sys.argv[1:]]" $(WARM_IMPORTS)
	touch $(STAMP)

install: $(STAMP)

# The main job: collect runs on the simulated robot, train the feedforward compensator,
# compare tracking without and with it (table and plots under runs/compare).
demo: install
	$(VENV)/bin/msarm train --config training/compensator.yaml
	$(VENV)/bin/msarm compare --ff runs/compensator/compensator.pt --out runs/compare

# A tour of the arm model: joints, muscles, moment arms, Hill curves (plots in runs/tour).
tour: install
	$(PY) examples/arm_tour.py --out runs/tour

lint: install
	$(VENV)/bin/ruff check msarm tests examples

test: install lint
	$(PY) -m pytest -n 2 --dist loadfile --no-loadscope-reorder -q

# Speed and accuracy benchmarks; the withheld-effect diagnosis benchmark simulates its 29
# scenarios once (cached under runs/bench-diagnose): 1 min 15 s the first time on the fastest
# 2-core development machine, up to 7 minutes on the slowest (1-3 minutes to re-score
# the cached logs).
bench: install
	$(VENV)/bin/msarm bench allocation
	$(VENV)/bin/msarm bench sim
	$(VENV)/bin/msarm bench diagnose

clean:
	rm -rf $(VENV) runs .pytest_cache .hypothesis
