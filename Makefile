# hsmap: two commands on a fresh machine with python3 (3.11+) and make.
#   make reproduce   the whole study into reports/
#   make test        the test suite
# Both run `setup` first; `setup` is idempotent and cheap when nothing changed.

PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.hsmap-installed
UV_VERSION := 0.13.9
export RERUN_ANALYTICS := 0
export MPLBACKEND := Agg
export PYTHONHASHSEED := 0
# third-party benchmark data (read in place, never copied): $HSMAP_DATASETS when set, else ../shared/datasets
# when it exists, else what `make data` (hsmap data fetch) downloaded into the user cache; tests and notebook 08
# skip, saying why, without it
ifeq ($(origin HSMAP_DATASETS),undefined)
ifneq ($(wildcard ../shared/datasets),)
HSMAP_DATASETS := $(abspath ../shared/datasets)
export HSMAP_DATASETS
endif
else
export HSMAP_DATASETS
endif

.PHONY: setup system-libs reproduce test bench lint clean lock data

# Bytecode is compiled once here (site-packages by uv, hsmap by compileall): with PYTHONDONTWRITEBYTECODE set,
# every Python process (each notebook kernel, each command) would otherwise compile its imports from source.
setup: system-libs $(STAMP)
	@$(BIN)/python -m compileall -q -j 0 hsmap

# open3d links against libusb-1.0, which a fresh Debian/Ubuntu machine lacks.
system-libs:
	@.ci/ensure-system-libs

$(STAMP): requirements.lock pyproject.toml Makefile
	@test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	@$(BIN)/python -m pip install --quiet --disable-pip-version-check uv==$(UV_VERSION)
	$(BIN)/uv pip sync --quiet --compile-bytecode --python $(BIN)/python requirements.lock
	$(BIN)/uv pip install --quiet --python $(BIN)/python --no-deps -e .
	@$(BIN)/python tools/warm_kernels.py
	@$(BIN)/python -c "import open3d, rerun, hsmap; print('hsmap', hsmap.__version__, 'ready in $(VENV)')"
	@touch $@

# the whole study into reports/ (two notebooks at a time on the 2-core target machine);
# e.g. make reproduce REPRODUCE_ARGS="--quick --jobs 2" for the smoke run, "--only 03" for one notebook
REPRODUCE_ARGS ?= --jobs 2
reproduce: setup
	$(BIN)/hsmap reproduce $(REPRODUCE_ARGS)

# the public benchmark data (Freiburg logs, Bormann maps), hash-checked, into the user cache
data: setup
	$(BIN)/hsmap data fetch

test: setup
	$(BIN)/python -m pytest -n 2 --durations=25 $(PYTEST_ARGS)

bench: setup
	$(BIN)/python benchmarks/registration.py
	$(BIN)/python benchmarks/segmentation.py
	$(BIN)/python benchmarks/slam.py
	$(BIN)/python benchmarks/slam_buildings.py
	$(BIN)/python benchmarks/slam_buildings.py --laser sparse
	$(BIN)/python benchmarks/speed.py
	$(BIN)/python benchmarks/simulate.py
	$(BIN)/python benchmarks/readers.py

lint: setup
	$(BIN)/ruff check hsmap tests benchmarks notebooks

# Re-resolve the pinned versions (needs the registry); commit requirements.lock afterwards.
lock:
	@test -x $(BIN)/uv || (test -x $(BIN)/python || $(PYTHON) -m venv $(VENV); $(BIN)/python -m pip install --quiet uv==$(UV_VERSION))
	$(BIN)/uv pip compile pyproject.toml --extra study --extra dev --extra peers --python-version 3.11 --universal -o requirements.lock

clean:
	rm -rf $(VENV) reports/* .pytest_cache
