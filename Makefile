# The two set-up commands of the README: `make render` and `make test`.
# Both create .venv and install caustica into it on first use (nothing else is needed).
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed

.PHONY: render test bench bench-compile clean

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e '.[test]'
	touch $(STAMP)

## Render the paper's diacaustic scene with streamed photon mapping to out/.
render: $(STAMP)
	$(VENV)/bin/caustica render cornell-diacaustic --method spm -o out/cornell-diacaustic.exr

## Run the tests (pytest's exit code 5, "no tests collected", is not a failure).  Test files are spread over up to
## 4 processes (pytest-xdist, a file's tests in one process, so its module fixtures run once); they share the kernel
## cache, which jit.py locks.  Compiling uses one core per process (docs/results.md: 28.2 -> 17.9 min on 2 cores).
test: $(STAMP)
	$(PY) -m pytest -q -p no:cacheprovider -n auto --maxprocesses 4 --dist loadfile tests; rc=$$?; if [ $$rc -eq 5 ]; then echo "no tests collected"; exit 0; fi; exit $$rc

## Print the performance numbers quoted in the README (the path tracer against Mitsuba 3 included).
bench: $(STAMP)
	$(PY) benchmarks/bench_render.py
	$(PY) benchmarks/bench_progressive.py
	$(PY) benchmarks/bench_cluster.py

## Where the first render's compile time goes: a table per kernel, and the cold-start total.
bench-compile: $(STAMP)
	$(PY) benchmarks/bench_compile.py

clean:
	rm -rf $(VENV) out
