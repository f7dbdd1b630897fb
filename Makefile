# Set-up and entry points. `make demo` and `make test` do all set-up on a fresh Debian 12 /
# Python 3.11 machine: a .venv with pinned dependencies and a non-editable install of ibr_ros
# (so its ament index entry and lib/ibr_ros launchers exist, as `ros2 run` needs them).

PYTHON ?= python3
VENV   ?= .venv
BIN    := $(VENV)/bin
PIP    := $(BIN)/python -m pip
SOURCES := $(shell git ls-files setup.py setup.cfg package.xml resource ibr_ros msg_utils config launch 2>/dev/null)

export AMENT_PREFIX_PATH := $(abspath $(VENV))$(if $(AMENT_PREFIX_PATH),:$(AMENT_PREFIX_PATH))
export ROS_AUTOMATIC_DISCOVERY_RANGE ?= LOCALHOST
export PYTHONDONTWRITEBYTECODE := 1

.PHONY: all venv install demo test test-fast lint bench lock clean chromium

all: install

$(VENV)/.deps: requirements/constraints.txt requirements/runtime.txt requirements/test.txt
	@$(PYTHON) -c 'import sys; assert sys.version_info[:2] >= (3, 10), sys.version' \
	  || { echo "error: $(PYTHON) must be Python >= 3.10"; exit 2; }
	@$(PYTHON) -m venv --help >/dev/null 2>&1 && $(PYTHON) -c 'import ensurepip' 2>/dev/null \
	  || { echo "python3-venv missing: installing it with apt-get"; \
	       apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq python3-venv; }
	$(PYTHON) -m venv $(VENV)
	$(PIP) install -q --upgrade -c requirements/constraints.txt pip setuptools wheel
	$(PIP) install -q -c requirements/constraints.txt -r requirements/runtime.txt -r requirements/test.txt
	@touch $@

# tf2_msgs has no PyPI wheel: build it (TFMessage only, vendor/tf2_msgs) into the venv where it is
# missing, so that scene_viz publishes /tf and /tf_static; a ROS 2 install's is used as it is.
$(VENV)/.tf2_msgs: $(VENV)/.deps vendor/tf2_msgs/CMakeLists.txt vendor/tf2_msgs/msg/TFMessage.msg requirements/tf2_msgs_build.txt
	sh tools/build_tf2_msgs.sh $(VENV) || echo "warning: tf2_msgs not built (see above): scene_viz will not publish /tf live"
	@touch $@

$(VENV)/.installed: $(VENV)/.deps $(VENV)/.tf2_msgs $(SOURCES)
	$(PIP) install -q --no-deps --no-build-isolation --force-reinstall .
	@rm -rf build *.egg-info
	@# Compile the nodes' numba kernels into the installed package's cache: first starts take seconds.
	cd / && $(abspath $(BIN))/python -P -m ibr_ros.jobs.warmup
	@touch $@

venv: $(VENV)/.deps
install: $(VENV)/.installed

demo: install
	$(BIN)/ibr demo

# CI (.ci/run) runs this: the lint first, then every test.
test: install lint chromium
	$(BIN)/python -m pytest -q test

# The web viewer's browser test drives Debian's chromium headless (Playwright, no browser download):
# installed with apt-get when missing and run as root; without it that test skips, saying why.
chromium:
	@[ -x /usr/bin/chromium ] || { [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null \
	  && apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium; } \
	  || echo "note: /usr/bin/chromium missing and not installable here (needs root and apt-get)"

# The unit tests alone (no DDS, no end-to-end job): a couple of minutes.
test-fast: install
	$(BIN)/python -m pytest -q -m 'not dds and not e2e' test

# ruff over all Python; mypy over ibr_ros and msg_utils (configuration: setup.cfg [mypy]).
lint: install
	$(BIN)/ruff check ibr_ros msg_utils test bench tools launch setup.py
	$(BIN)/ruff format --check ibr_ros msg_utils test bench tools launch setup.py
	$(BIN)/mypy

bench: install
	@for b in bench/bench_*.py; do echo "== $$b"; $(BIN)/python $$b || exit 1; done

# Re-resolve the pins from the loose requirement lists (needs the package index).
lock:
	rm -rf /tmp/ibr_lock && $(PYTHON) -m venv /tmp/ibr_lock
	/tmp/ibr_lock/bin/pip install -q -r requirements/runtime.txt -r requirements/test.txt setuptools wheel
	{ echo '# Exact versions for make demo / make test. Regenerate: make lock'; \
	  /tmp/ibr_lock/bin/pip freeze --all | grep -v '^pip=='; } > requirements/constraints.txt

clean:
	rm -rf $(VENV) build *.egg-info .pytest_cache .mypy_cache out
