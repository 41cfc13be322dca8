# imulink: set-up, main job and tests. Everything runs from a local virtualenv.
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin

.PHONY: setup demo test bench clean

$(BIN)/imulink: pyproject.toml setup.py host/imulink/_build_core.py host/imulink/_protocol_schema.py \
		$(wildcard firmware/core/*.c firmware/core/*.h)
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip
	$(BIN)/pip install --quiet -e '.[test]'
	@touch $@

## setup: create .venv and build the package with both C core builds
setup: $(BIN)/imulink

## demo: the main job (no hardware): a virtual board streams a simulated run over the
## frame protocol; the host records it and proves every estimate bit-exact
demo: setup
	$(BIN)/imulink demo

## test: the whole test suite
test: setup
	$(BIN)/python -m pytest -q

## bench: core and protocol throughput benchmarks (results in docs/performance.md)
bench: setup
	$(BIN)/python tools/bench_core.py
	$(BIN)/python tools/bench_protocol.py

clean:
	rm -rf $(VENV) build host/*.egg-info host/imulink/_core_*.so host/imulink/_core_*.c
