# nmt_ros: make venv | demo | test | lint
SHELL := /bin/bash
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.nmt_stamp

# Every ROS 2 process we start stays on loopback (no DDS packet leaves the machine).
export ROS_AUTOMATIC_DISCOVERY_RANGE ?= LOCALHOST
export ROS_LOCALHOST_ONLY ?= 1
export AMENT_PREFIX_PATH := $(abspath $(VENV))
export PYTHONDONTWRITEBYTECODE := 1
# One BLAS/OpenMP thread per process: our factorisations are small, and a multithreaded
# OpenBLAS spinning on 2 shared cores made the estimator's banded solves ~100x slower.
export OPENBLAS_NUM_THREADS ?= 1
export OMP_NUM_THREADS ?= 1
export MKL_NUM_THREADS ?= 1

.PHONY: venv demo test lint reproduce bench clean-venv ts-reader

# The venv is (re)built only when the pinned requirements or the package metadata change.
$(STAMP): requirements.txt setup.py setup.cfg package.xml
	@test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --disable-pip-version-check wheel==0.48.0
	$(PY) -m pip install -q --disable-pip-version-check -r requirements.txt
	$(PY) -m pip install -q --disable-pip-version-check --no-deps --no-build-isolation -e .
	@touch $(STAMP)

venv: $(STAMP)

demo: venv
	$(VENV)/bin/nmt demo --out demo_out

# The independent TypeScript bag reader of test/test_ts_reader.py (@mcap/core, Foxglove's CDR),
# pinned by its package-lock.json. Without node or npm that test is skipped (it says so).
TS_READER := test/ts_reader
$(TS_READER)/dist/read_bag.js: $(TS_READER)/package-lock.json $(TS_READER)/tsconfig.json $(TS_READER)/src/read_bag.ts
	@if command -v npm >/dev/null; then \
		(cd $(TS_READER) && npm ci --no-audit --no-fund --loglevel=error && npx tsc -p .) \
		|| echo "the TypeScript reader did not build: its tests will fail, the rest runs"; \
	else echo "npm not found: test/test_ts_reader.py will be skipped"; fi

ts-reader: $(TS_READER)/dist/read_bag.js

test: venv ts-reader
	$(PY) -m pytest -q -p no:cacheprovider test

lint: venv
	$(VENV)/bin/ruff check nmt_ros msg_adapters test bench launch setup.py

reproduce: venv
	$(VENV)/bin/nmt reproduce --out out/reproduce

bench: venv
	$(PY) bench/run_all.py

clean-venv:
	rm -rf $(VENV)
