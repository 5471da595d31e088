# msarm: two commands on a fresh machine, `make demo` and `make test`.
# Both create .venv if needed and install the exact versions of requirements.lock.
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed-stamp
export MPLBACKEND := Agg

.PHONY: install demo test lint bench clean

$(STAMP): requirements.lock pyproject.toml
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --disable-pip-version-check -r requirements.lock
	$(PY) -m pip install -q --disable-pip-version-check --no-deps --no-build-isolation -e .
	touch $(STAMP)

install: $(STAMP)

demo: install
	$(PY) examples/arm_tour.py --out runs/demo

lint: install
	$(VENV)/bin/ruff check msarm tests examples

test: install lint
	$(PY) -m pytest -n 2 -q

bench: install
	$(VENV)/bin/msarm bench allocation

clean:
	rm -rf $(VENV) runs .pytest_cache .hypothesis
