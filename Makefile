# curbside: everything a fresh machine needs is installed from here.
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
TORCH_VERSION := 2.13.0

.PHONY: demo test lint bench clean install

$(BIN)/python:
	$(PY) -m venv $(VENV)

# torch first, pinned to the CPU wheel, so pip never resolves the multi-GB CUDA build.
$(STAMP): $(BIN)/python pyproject.toml
	$(BIN)/pip install -q torch==$(TORCH_VERSION)
	$(BIN)/pip install -q -e '.[test]'
	touch $(STAMP)

install: $(STAMP)

demo: $(STAMP)
	$(BIN)/python -m curbside.demo --out out

test: $(STAMP)
	$(BIN)/ruff check curbside tests benchmarks
	$(BIN)/python -m pytest -q

lint: $(STAMP)
	$(BIN)/ruff check curbside tests benchmarks

bench: $(STAMP)
	$(BIN)/python benchmarks/bench_osmseg.py
	$(BIN)/python benchmarks/bench_filter.py
	$(BIN)/python benchmarks/bench_ronin.py
	$(BIN)/python benchmarks/bench_serve.py

clean:
	rm -rf out .pytest_cache .ruff_cache
