# Set-up is part of every target: the virtual environment .venv is (re)built when it is missing
# or older than pyproject.toml.
PYTHON ?= $(shell command -v python3.11 || command -v python3)
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed

.PHONY: test lint run bench clean-venv

$(STAMP): pyproject.toml CMakeLists.txt $(wildcard nca_qd/sim/rhcr/src/*)
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --upgrade --quiet pip
	$(PY) -m pip install --quiet -e '.[dev]'
	touch $(STAMP)

# Style (ruff: lint + format) and types of the shared API (mypy), configured in pyproject.toml.
lint: $(STAMP)
	$(PY) -m ruff check nca_qd experiments tests benchmarks
	$(PY) -m ruff format --check nca_qd experiments tests benchmarks
	$(PY) -m mypy

test: lint
	$(PY) -m pytest tests

run: $(STAMP)
	$(PY) -m experiments.run domain=maze

bench: $(STAMP)
	$(PY) -m benchmarks.run_all

clean-venv:
	rm -rf $(VENV)
