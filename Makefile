# imulink: set-up, main job and tests. Everything runs from a local virtualenv.
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin

.PHONY: help setup system-packages firmware demo test test-long test-farm check bench clean

## help: this list
help:
	@awk '/^## [a-z-]+: / {sub(/^## /, ""); split($$0, a, ": "); printf "%-8s %s\n", a[1], substr($$0, length(a[1]) + 3); next} \
	     /^## / {sub(/^## /, ""); printf "%-8s %s\n", "", $$0}' $(MAKEFILE_LIST)

$(BIN)/imulink: pyproject.toml setup.py host/imulink/core/_build.py host/imulink/protocol/_schema.py \
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

## test: the test suite but its sanitizer campaigns, in parallel on every core (pytest-xdist);
## a test that hangs fails after 10 min with its name (pytest-timeout); the 15 slowest are
## listed at the end
# --max-worker-restart=0: a worker that crashes (a segfault) ends the run with the test it ran;
# xdist 3.8 replaces it otherwise, and under --dist loadgroup the session can then wait forever
# for work units already done (pytest-xdist issue 1378).
test: setup
	$(BIN)/python -m pytest -q -n auto --dist loadgroup --max-worker-restart=0 --timeout=600 --durations=15 -m "not long"

## test-long: the sanitizer campaigns and the virtual board's long runs (tests marked long); CI runs them after `make test`
test-long: setup
	$(BIN)/python -m pytest -q -n auto --max-worker-restart=0 --timeout=1200 --durations=15 -m long

# The lab's virtualenv: the package with its lab extra (labgrid, whose coordinator and exporter
# the farm tests start), apart from .venv so that the main suite keeps testing pyserial itself.
# pyserial-labgrid (labgrid's pyserial fork, the same `serial` module) is reinstalled last so
# that the module on disk is the one labgrid is tested with (docs/farm.md).
LAB_VENV := .venv-lab
LAB_BIN  := $(LAB_VENV)/bin

$(LAB_BIN)/imulink: pyproject.toml setup.py host/imulink/core/_build.py host/imulink/protocol/_schema.py \
		$(wildcard firmware/core/*.c firmware/core/*.h)
	$(PYTHON) -m venv $(LAB_VENV)
	$(LAB_BIN)/pip install --quiet --upgrade pip
	$(LAB_BIN)/pip install --quiet -e '.[lab]' 'pytest>=7' 'pytest-timeout>=2.2' 'pytest-xdist>=3.5'
	$(LAB_BIN)/pip install --quiet --force-reinstall --no-deps \
		"pyserial-labgrid==$$($(LAB_BIN)/python -c 'from importlib.metadata import version; print(version("pyserial-labgrid"))')"
	@touch $@

## test-farm: the labgrid farm tests (tests/test_farm.py, test_farm_swd.py) in .venv-lab, with a coordinator and an
## exporter of emulated boards started on this machine; CI runs them after `make test-long`
test-farm: setup $(LAB_BIN)/imulink
	IMULINK_REQUIRE_LABGRID=1 $(LAB_BIN)/python -m pytest -q --timeout=300 --durations=10 tests/test_farm.py tests/test_farm_swd.py tests/test_lab_address.py

## check: lint (ruff), types (mypy) and generated files up to date (tools/gen_protocol.py --check)
check: setup
	$(BIN)/ruff check host tests tools
	$(BIN)/mypy
	$(BIN)/python tools/gen_protocol.py --check

## bench: throughput and Cortex-M4 cost benchmarks (results in docs/performance.md)
bench: setup
	$(BIN)/python tools/bench_core.py
	$(BIN)/python tools/bench_protocol.py
	$(BIN)/python tools/bench_arm.py

## clean: remove the virtualenv, every build and the generated C of the cffi modules
clean:
	rm -rf $(VENV) $(LAB_VENV) build firmware/build host/*.egg-info host/imulink/core/_*.so host/imulink/core/_fixed.c host/imulink/core/_float.c \
		host/imulink/firmware
