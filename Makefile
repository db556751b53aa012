# The two commands of the README: `make repro` (the study) and `make test` (the tests).
# Each creates .venv and installs rdnet into it on first use.
PYTHON ?= python3
VENV ?= .venv
BIN := $(VENV)/bin
# CPU wheel of torch (on the project machines it is on disk); override for CUDA, e.g.
#   make repro TORCH_SPEC="torch==2.13.0 --index-url https://download.pytorch.org/whl/cu126"
TORCH_SPEC ?= torch==2.13.0
STAMP := $(VENV)/.rdnet-installed

.PHONY: install test repro bench clean-venv

# compileall: rdnet's bytecode, as pip writes it for a regular install (an editable one
# compiles on first import, and never where PYTHONDONTWRITEBYTECODE is set: then every
# command compiles rdnet's modules again, about 0.1 s of each CLI call)
$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip
	$(BIN)/python -m pip install -q $(TORCH_SPEC)
	$(BIN)/python -m pip install -q -e ".[test]"
	$(BIN)/python -m compileall -q rdnet stages
	touch $@

install: $(STAMP)

# the suite in one pytest-xdist worker per CPU (`make test TEST_WORKERS=0`: in this process)
TEST_WORKERS ?= auto
test: $(STAMP)
	$(BIN)/python -m pytest -q -p no:cacheprovider -n $(TEST_WORKERS) --dist worksteal

repro: $(STAMP)
	PATH="$(abspath $(BIN)):$$PATH" $(BIN)/dvc repro

bench: $(STAMP)
	for f in benchmarks/bench_*.py; do $(BIN)/python $$f || exit 1; done

clean-venv:
	rm -rf $(VENV)
