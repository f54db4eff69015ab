# teamslam: two commands do everything on a fresh machine.
#   make run   create .venv, install teamslam, run the default job
#   make test  create .venv, install teamslam with every extra and the test tools, lint,
#              build the docs strictly, run the test suite (never installs system packages;
#              .ci/run does that in CI)
#   make docs  the documentation site into site/ (mkdocs build --strict: a broken link, a
#              missing page or an unresolved reference fails; builds offline)

PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed

.PHONY: run test lint docs bench clean

$(BIN)/python:
	$(PYTHON) -m venv $(VENV)

$(STAMP): $(BIN)/python pyproject.toml
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[all,test]'
	touch $(STAMP)

run: $(STAMP)
	OPENBLAS_NUM_THREADS=1 $(BIN)/teamslam simulate --robots 5 --steps 150 --seed 0 --out results/team5
	OPENBLAS_NUM_THREADS=1 $(BIN)/teamslam calibrate results/team5 --frames 60
	OPENBLAS_NUM_THREADS=1 $(BIN)/teamslam config show results/team5 --set filter.window=10
	OPENBLAS_NUM_THREADS=1 $(BIN)/teamslam run results/team5 --compare --set filter.window=10 --out results/team5-run --overwrite --mcap

# the Python of the docs: the build hooks and the examples the pages include
DOCS_PY := $(wildcard docs/*/*.py)

lint: $(STAMP)
	$(BIN)/ruff check src tests benchmarks examples $(DOCS_PY)
	$(BIN)/ruff format --check src tests benchmarks examples $(DOCS_PY)

docs: $(STAMP)
	$(BIN)/python -m mkdocs build --strict --site-dir site

# -ra: the reason of every skipped test (and every failure) is listed at the end
# -n auto: one pytest-xdist worker per CPU (PYTEST_XDIST_AUTO_NUM_WORKERS=N to choose);
# --dist loadscope: a module's tests on one worker (tests/conftest.py: pytest_xdist_make_scheduler)
# then the network tests (robot processes paced by timeouts) alone, one after another
TEST_ENV := OPENBLAS_NUM_THREADS=1 OMP_NUM_THREADS=1 NUMBA_NUM_THREADS=1
test: lint docs
	$(TEST_ENV) $(BIN)/python -m pytest -q -ra -n auto --dist loadscope -m "not network"
	$(TEST_ENV) $(BIN)/python -m pytest -q -ra -m network

clean:
	rm -rf $(VENV) results build site src/*.egg-info .pytest_cache .ruff_cache
