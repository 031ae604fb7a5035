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

.PHONY: env figures figures-paper test test-fast bench clean

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

clean:
	rm -rf build figures/executed .pytest_cache
