# The two commands of the README: `make repro` (the study) and `make test` (the tests).
# Each creates .venv and installs rdnet into it on first use.
PYTHON ?= python3
VENV ?= .venv
BIN := $(VENV)/bin
# CPU wheel of torch (on the project machines it is on disk); override for CUDA, e.g.
#   make repro TORCH_SPEC="torch==2.13.0 --index-url https://download.pytorch.org/whl/cu126"
TORCH_SPEC ?= torch==2.13.0
STAMP := $(VENV)/.rdnet-installed
# Pinned versions of the packages that can change the study's bytes, those with which the data
# stages wrote the bytes dvc.lock records (checked in session 57; h5py 3.12-3.15 write other
# pairs-file bytes than 3.16 from the same arrays; numpy, numba, OpenCV and scikit-image compute
# the arrays, matplotlib draws the figures). pyproject.toml keeps ranges, so rdnet installs as a
# library beside other versions; `make ... STUDY_PINS=` drops these.
STUDY_PINS ?= numpy==2.4.6 scipy==1.17.1 numba==0.68.1 llvmlite==0.50.0 h5py==3.16.0 \
	scikit-image==0.26.0 opencv-python-headless==5.0.0.93 matplotlib==3.11.2 pillow==13.0.0 \
	aedat==2.3.0 dvc==3.67.1

.PHONY: install test repro bench clean-venv

# compileall: rdnet's bytecode, as pip writes it for a regular install (an editable one
# compiles on first import, and never where PYTHONDONTWRITEBYTECODE is set: then every
# command compiles rdnet's modules again, about 0.1 s of each CLI call)
$(STAMP): pyproject.toml Makefile
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip
	$(BIN)/python -m pip install -q $(TORCH_SPEC)
	$(BIN)/python -m pip install -q -e ".[test]" $(STUDY_PINS)
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
