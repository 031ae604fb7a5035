# ctxmatch: two commands do all the set-up on a fresh machine.
#   make figures   virtual environment + package + every figure on the embedded offline default dataset
#                  (rewrites the tracked figures/)
#   make test      same environment, the whole test suite including the notebooks under nbval
#   make lab       same environment, JupyterLab on notebooks/
# Any Python >= 3.11 builds the environment: make PYTHON=python3.12 (default: python3).
PYTHON ?= python3
VENV   ?= .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.ctxmatch-installed
# The tests also cover the optional extras (learned filters, kornia interop, hloc and COLMAP export) and drive
# JupyterLab in a browser (selenium): the test environment adds them; the default install and `make figures` do not
# need them. torch 2.13.0 is the CPU build.
TEST_EXTRAS := torch==2.13.0 kornia==0.9.0 kornia_rs==0.2.0 h5py==3.16.0 pycolmap==4.2.1 selenium==4.50.0
TEST_STAMP  := $(VENV)/.ctxmatch-test-extras
# pip installs without byte-compiling, and compileall then byte-compiles the environment on every core (pip does
# it on one); with PYTHONDONTWRITEBYTECODE set, a module without its .pyc would be compiled anew on every import.
# The packages' own tests/ folders (a third of the files, never imported here) are left out. A file that does not
# compile (pip skips those too) leaves compileall's exit status non-zero: ignored.
PIP := $(BIN)/python -m pip install -q --no-compile
COMPILE := $(BIN)/python -m compileall -q -j 0 -x '/tests/' $(VENV)/lib > /dev/null || true
# The suite runs on every core (pytest-xdist): a file's tests, and a notebook's cells, stay on one worker in order, and
# the files start in the order tests/conftest.py gives them (the longest first).
TEST_WORKERS ?= auto
# Real data: CTXMATCH_DATA from the environment, else ../shared/data when that folder exists.
export CTXMATCH_DATA ?= $(abspath $(wildcard ../shared/data))
export MPLBACKEND := Agg
export PYTHONHASHSEED := 0

.PHONY: env figures figures-paper lab test test-fast bench docs clean

env: $(STAMP)

$(STAMP): environment.txt pyproject.toml
	@$(PYTHON) -c 'import sys; sys.exit(0 if sys.version_info >= (3, 11) else "ctxmatch needs Python >= 3.11 but $(PYTHON) is " + sys.version.split()[0] + "; choose one with make PYTHON=python3.11 (or newer)")'
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip
	$(PIP) -r environment.txt
	$(PIP) --no-deps --no-build-isolation -e .
	$(COMPILE)
	touch $@

$(TEST_STAMP): $(STAMP) Makefile
	$(PIP) $(TEST_EXTRAS)
	$(COMPILE)
	touch $@

# `ctxmatch warmup` compiles the kernels of `ctxmatch match` first (once per machine and version of the kernel
# code; seconds when they are in the cache), so that a first `ctxmatch match` afterwards does not wait for them.
figures: $(STAMP)
	$(BIN)/ctxmatch warmup
	$(BIN)/ctxmatch figures

figures-paper: $(STAMP)
	$(BIN)/ctxmatch warmup
	$(BIN)/ctxmatch figures --params paper

# The kernels draw inline: MPLBACKEND (Agg, for the batch runs above) is left out. JupyterLab refuses to run as root
# unless told to.
lab: $(STAMP)
	env -u MPLBACKEND $(BIN)/jupyter lab notebooks/ $(if $(filter 0,$(shell id -u)),--allow-root)

test: $(TEST_STAMP)
	mkdir -p build
	CTXMATCH_FIGURES=$(abspath build/figures) $(BIN)/python -m pytest -n $(TEST_WORKERS) --dist loadfile --no-loadscope-reorder --durations=15 tests notebooks --nbval-lax --doctest-modules ctxmatch_lib --junitxml=build/junit.xml

test-fast: $(TEST_STAMP)
	$(BIN)/python -m pytest tests -m "not slow" -x -q

bench: $(STAMP)
	for b in benchmarks/bench_*.py; do echo "== $$b"; $(BIN)/python $$b || exit 1; done

# The user guide (docs/*.md and the README, rendered with mistune by docs/render_guide.py) and the numpydoc API
# of ctxmatch_lib (pdoc, the optional 'docs' extra) as HTML in build/docs, index.html linking both: the package
# and every public module and subpackage (pdoc alone follows only the submodules named in __all__, like dtm).
DOC_MODULES := ctxmatch_lib \
	$(subst /,.,$(patsubst %.py,%,$(filter-out ctxmatch_lib/_%,$(wildcard ctxmatch_lib/*.py)))) \
	$(filter-out ctxmatch_lib.dtm ctxmatch_lib._numerics,$(subst /,.,$(patsubst %/__init__.py,%,$(wildcard ctxmatch_lib/*/__init__.py))))

docs: $(STAMP)
	$(PIP) "pdoc>=14"
	rm -rf build/docs
	$(BIN)/pdoc --docformat numpy --no-show-source -o build/docs $(DOC_MODULES)
	$(BIN)/python docs/render_guide.py build/docs
	@echo "User guide and API docs -> build/docs/index.html"

clean:
	rm -rf build figures/executed .pytest_cache
