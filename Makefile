# Two commands matter: `make demo` and `make test`. Every target creates .venv on first use, with the
# `dev` and `ray` extras (the Ray campaign tests run in CI); `make bench` adds the `bench` extra.
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed
export MUJOCO_GL ?= egl
export PYTHONDONTWRITEBYTECODE := 1
DEMO_OUT ?= out/demo

.PHONY: venv demo test bench lint clean

$(STAMP): pyproject.toml
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip==26.3
	$(BIN)/python -m pip install --quiet -e '.[dev,ray]'
	touch $(STAMP)

venv: $(STAMP)

demo: $(STAMP)
	$(BIN)/omnirotor info
	$(BIN)/omnirotor identify ../shared/data/omnirotor-hover-flight --out $(DEMO_OUT)/real-flight-maps.json
	$(BIN)/omnirotor reproduce --quick --out $(DEMO_OUT)

test: $(STAMP)
	$(BIN)/python -m pytest

# The benchmarks also need the `bench` extra (RotorPy, the peer of the quadrotor comparison) and crazyflow.
# `make bench BENCH_ARGS=--quick` for the one-minute version; the JSON lands in out/bench.json.
BENCH_STAMP := $(VENV)/.installed-bench
BENCH_ARGS ?=
$(BENCH_STAMP): $(STAMP)
	$(BIN)/python -m pip install --quiet -e '.[dev,ray,bench]'
	touch $(BENCH_STAMP)

# crazyflow (JAX) runs in its own venv, in a subprocess of run.py (benchmarks/peer-crazyflow.txt says why).
CRAZYFLOW_VENV  := out/peer-venvs/crazyflow
CRAZYFLOW_STAMP := $(CRAZYFLOW_VENV)/.installed
$(CRAZYFLOW_STAMP): benchmarks/peer-crazyflow.txt
	test -x $(CRAZYFLOW_VENV)/bin/python || $(PYTHON) -m venv $(CRAZYFLOW_VENV)
	$(CRAZYFLOW_VENV)/bin/python -m pip install --quiet -r benchmarks/peer-crazyflow.txt
	touch $(CRAZYFLOW_STAMP)

bench: $(BENCH_STAMP) $(CRAZYFLOW_STAMP)
	$(BIN)/python benchmarks/run.py --out out/bench.json $(BENCH_ARGS)

lint: $(STAMP)
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .

clean:
	rm -rf $(VENV) out .pytest_cache
