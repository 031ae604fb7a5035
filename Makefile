# ctxmatch: two commands do all the set-up on a fresh machine.
#   make figures   virtual environment + package + every figure on the embedded offline default dataset
#   make test      same environment, the whole test suite including the notebooks under nbval
PYTHON ?= python3.11
VENV   ?= .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.ctxmatch-installed
# The shared real data sits beside the checkout on the project machines; elsewhere set CTXMATCH_DATA yourself.
export CTXMATCH_DATA ?= $(abspath $(wildcard ../shared/data))
export MPLBACKEND := Agg
export PYTHONHASHSEED := 0

.PHONY: env figures figures-paper test test-fast bench docs clean

env: $(STAMP)

$(STAMP): environment.txt pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip
	$(BIN)/python -m pip install -q -r environment.txt
	$(BIN)/python -m pip install -q --no-deps --no-build-isolation -e .
	touch $@

figures: $(STAMP)
	$(BIN)/ctxmatch figures

figures-paper: $(STAMP)
	$(BIN)/ctxmatch figures --params paper

test: $(STAMP)
	mkdir -p build
	CTXMATCH_FIGURES=$(abspath build/figures) $(BIN)/python -m pytest tests notebooks --nbval-lax --doctest-modules ctxmatch_lib --junitxml=build/junit.xml

test-fast: $(STAMP)
	$(BIN)/python -m pytest tests -m "not slow" -x -q

bench: $(STAMP)
	for b in benchmarks/bench_*.py; do echo "== $$b"; $(BIN)/python $$b || exit 1; done

# The numpydoc API of ctxmatch_lib as HTML (pdoc, the optional 'docs' extra) in build/docs: the package and
# every public module and subpackage (pdoc alone follows only the submodules named in __all__, like dtm).
DOC_MODULES := ctxmatch_lib \
	$(subst /,.,$(patsubst %.py,%,$(filter-out ctxmatch_lib/_%,$(wildcard ctxmatch_lib/*.py)))) \
	$(filter-out ctxmatch_lib.dtm,$(subst /,.,$(patsubst %/__init__.py,%,$(wildcard ctxmatch_lib/*/__init__.py))))

docs: $(STAMP)
	$(BIN)/python -m pip install -q "pdoc>=14"
	rm -rf build/docs
	$(BIN)/pdoc --docformat numpy --no-show-source -o build/docs $(DOC_MODULES)
	@echo "API docs -> build/docs/index.html"

clean:
	rm -rf build figures/executed .pytest_cache
