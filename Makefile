# curbside: everything a fresh machine needs is installed from here.
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
TORCH_VERSION := 2.13.0

.PHONY: demo test lint bench benchmark clean install browser

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

# Headless Chromium and its driver for the browser tests: Debian's packages, never a browser download.
# Quiet and idempotent; where they cannot be installed the browser tests skip with a one-line reason.
SUDO := $(if $(filter 0,$(shell id -u)),,sudo -n)
browser:
	@command -v chromium >/dev/null 2>&1 && command -v chromedriver >/dev/null 2>&1 || \
	  { $(SUDO) apt-get update -qq >/dev/null && DEBIAN_FRONTEND=noninteractive \
	    $(SUDO) apt-get install -y -qq chromium chromium-driver >/dev/null; } || \
	  echo "note: could not install chromium and chromium-driver; the browser tests will skip"

test: $(STAMP) browser
	$(BIN)/ruff check curbside tests benchmarks
	$(BIN)/python -m pytest -q -n auto --dist loadfile

lint: $(STAMP)
	$(BIN)/ruff check curbside tests benchmarks

# The accuracy benchmark of docs/evaluate.md (phone profile, test split; ~9 min on 2 cores), with the
# DataSF map and the IPIN trials (held-out ones with the bundled RoNIN, all of them with one that never
# saw IPIN) when ../shared/data has them. `make bench` is the speed one.
SHARED := ../shared/data
benchmark: $(STAMP)
	$(BIN)/localize benchmark \
		$(if $(wildcard $(SHARED)/datasf/*.topojson),--datasf-tiles $(wildcard $(SHARED)/datasf/*.topojson)) \
		$(if $(wildcard $(SHARED)/ipin2023/ipin2023-t3.h5),--ipin $(SHARED)/ipin2023/ipin2023-t3.h5 \
			--ipin-ronin benchmarks/weights/ronin_ms_only.pt) \
		-o out/benchmark-full

bench: $(STAMP)
	$(BIN)/python benchmarks/bench_osmseg.py
	$(BIN)/python benchmarks/bench_filter.py
	$(BIN)/python benchmarks/bench_ronin.py
	$(BIN)/python benchmarks/bench_serve.py
	$(BIN)/python benchmarks/bench_stream_rows.py
	$(BIN)/python benchmarks/bench_cli_start.py

clean:
	rm -rf out .pytest_cache .ruff_cache
