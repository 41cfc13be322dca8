# imulink: set-up, main job and tests. Everything runs from a local virtualenv.
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin

.PHONY: setup system-packages firmware demo test bench clean

$(BIN)/imulink: pyproject.toml setup.py host/imulink/_build_core.py host/imulink/_protocol_schema.py \
		$(wildcard firmware/core/*.c firmware/core/*.h)
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip
	$(BIN)/pip install --quiet -e '.[test]'
	@touch $@

## setup: system packages (ARM compiler, QEMU; needs root or sudo), .venv with the package
## and both C core builds, and every firmware image (native, QEMU, STM32F407)
setup: system-packages $(BIN)/imulink firmware

system-packages:
	@sh tools/install-system-packages.sh

firmware: system-packages
	@$(MAKE) --no-print-directory -C firmware

## demo: the main job (no hardware): the firmware runs as a native process fed by the
## simulator, streams a simulated minute; the host records it and proves it bit-exact
demo: setup
	$(BIN)/imulink demo

## test: the whole test suite, in parallel on every core (pytest-xdist); a test that hangs
## fails after 10 min with its name (pytest-timeout); the 15 slowest are listed at the end
test: setup
	$(BIN)/python -m pytest -q -n auto --timeout=600 --durations=15

## bench: throughput and Cortex-M4 cost benchmarks (results in docs/performance.md)
bench: setup
	$(BIN)/python tools/bench_core.py
	$(BIN)/python tools/bench_protocol.py
	$(BIN)/python tools/bench_arm.py

clean:
	rm -rf $(VENV) build firmware/build host/*.egg-info host/imulink/_core_*.so host/imulink/_core_*.c \
		host/imulink/firmware
