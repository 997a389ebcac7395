# baarda — the two commands of the README: `make demo` and `make test`.
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin

.PHONY: install demo serve test test-fast bench clean

$(BIN)/python:
	$(PY) -m venv $(VENV)
	$(BIN)/pip install -q --upgrade pip

install: $(BIN)/python
	$(BIN)/pip install -q -e ".[dashboard,test,browser,fast,batch]"

# Analyse the bundled demo block and write a report to out/
demo: install
	mkdir -p out
	$(BIN)/baarda analyze data/demo-block.json --json out/demo-block.json --csv out/demo-block
	@echo "serve the dashboard with:  $(BIN)/baarda serve data/demo-block.json"

serve: install
	$(BIN)/baarda serve

# the tests without a browser on two workers (pytest-xdist; a module's tests stay on one worker),
# then the browser tests on their own
test: install
	$(BIN)/python -m pytest -q -n 2 --dist loadfile -m "not browser"
	$(BIN)/python -m pytest -q -m browser

test-fast: install
	$(BIN)/python -m pytest -q -m "not slow and not browser"

# every benchmark, as a module from the repository root (bench/__init__.py)
bench: install
	OPENBLAS_NUM_THREADS=1 $(BIN)/python -m bench.bench_solve
	OPENBLAS_NUM_THREADS=1 $(BIN)/python -m bench.bench_read
	OPENBLAS_NUM_THREADS=1 $(BIN)/python -m bench.bench_document
	OPENBLAS_NUM_THREADS=1 $(BIN)/python -m bench.bench_memory
	OPENBLAS_NUM_THREADS=1 $(BIN)/python -m bench.bench_network
	OPENBLAS_NUM_THREADS=1 $(BIN)/python -m bench.bench_blocks
	OPENBLAS_NUM_THREADS=1 $(BIN)/python -m bench.bench_dashboard
	OPENBLAS_NUM_THREADS=1 $(BIN)/python -m bench.bench_load
	OPENBLAS_NUM_THREADS=1 $(BIN)/python -m bench.bench_batch

clean:
	rm -rf $(VENV) out build *.egg-info
