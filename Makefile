# Two entry points, each creating or reusing the local virtual environment .venv:
#   make demo   the whole chain in simulation
#   make test   the test suite
PYTHON ?= python3
VENV   ?= .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed

.PHONY: demo test lint bench clean

# Reinstall only when the dependency list changes; the package itself is installed editable.
$(STAMP): pyproject.toml
	@test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e '.[dev]'
	@touch $(STAMP)

demo: $(STAMP)
	$(VENV)/bin/cobotlab demo

test: $(STAMP)
	$(PY) -m pytest -n 2 --dist loadfile -q

lint: $(STAMP)
	$(VENV)/bin/ruff check robots sim_backends autograder solutions cobotlab tests benchmarks

bench: $(STAMP)
	$(PY) benchmarks/handeye_accuracy.py --quick

clean:
	rm -rf $(VENV) out .pytest_cache
