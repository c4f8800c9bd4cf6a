# Set-up is part of every target: the virtual environment .venv is (re)built when it is missing,
# older than pyproject.toml or the C++ core, or when Python modules were added, moved or removed
# (the editable install maps each module to its file, so a module turned into a package needs a
# reinstall; editing a module does not).
PYTHON ?= $(shell command -v python3.11 || command -v python3)
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed
MODULES := $(VENV)/.modules-$(shell find nca_qd experiments -name '*.py' | sort | cksum | cut -d' ' -f1)

.PHONY: test lint run bench notebook clean-venv

$(STAMP): pyproject.toml CMakeLists.txt $(wildcard nca_qd/sim/rhcr/src/*) $(MODULES)
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --upgrade --quiet pip
	$(PY) -m pip install --quiet -e '.[dev]'
	touch $(STAMP)

$(MODULES):
	mkdir -p $(VENV)
	rm -f $(VENV)/.modules-*
	touch $@

# Style (ruff: lint + format) and types of the shared API (mypy), configured in pyproject.toml.
lint: $(STAMP)
	$(PY) -m ruff check nca_qd experiments tests benchmarks
	$(PY) -m ruff format --check nca_qd experiments tests benchmarks
	$(PY) -m mypy

# Test files run in parallel worker processes (pytest-xdist), one file per worker at a time so
# that a file's shared compiled programs and fixtures stay in one process; the workers share the
# session's persistent JAX compilation cache (tests/conftest.py). TEST_WORKERS=1 runs serially.
TEST_WORKERS ?= $(shell n=$$(nproc 2>/dev/null || echo 2); [ $$n -gt 4 ] && n=4; echo $$n)

test: lint
	$(PY) -m pytest tests $(if $(filter 1,$(TEST_WORKERS)),,-n $(TEST_WORKERS) --dist loadfile)

run: $(STAMP)
	$(PY) -m experiments.run domain=maze

bench: $(STAMP)
	$(PY) -m benchmarks.run_all

# JupyterLab (the `notebook` extra) on the archive-exploration notebook.
notebook: $(STAMP)
	$(PY) -m pip install --quiet -e '.[notebook]'
	$(PY) -m jupyter lab notebooks/explore_archive.ipynb

clean-venv:
	rm -rf $(VENV)
