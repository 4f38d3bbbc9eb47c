# slam2d: everything a fresh clone needs goes through these targets.
PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
PIP    := $(PY) -m pip --disable-pip-version-check
PYTEST_ARGS ?=

.PHONY: demo test check bench docs clean browser ros1

# The report test renders report.html in Debian's Chromium. Where apt-get exists
# it is installed when missing and the test must run; elsewhere it skips.
SUDO := $(shell [ "$$(id -u)" = 0 ] || echo sudo)
HAVE_APT := $(shell command -v apt-get >/dev/null 2>&1 && echo 1)

# An install is redone whenever pyproject.toml changes. `slam2d compile` then compiles every
# method's numba kernels into their on-disk cache, so that no first run pays for it (about a minute).
$(VENV)/.installed: pyproject.toml
	@$(PYTHON) -c 'import sys; sys.exit(0 if sys.version_info >= (3, 11) else "slam2d needs Python >= 3.11")'
	$(PYTHON) -m venv $(VENV)
	$(PIP) install --quiet --upgrade pip
	$(PIP) install --quiet -e '.[test]'
	$(VENV)/bin/slam2d compile
	@touch $@

## demo: set up and rerun the source study in simulation, quick version (writes demo-out/report.html)
demo: $(VENV)/.installed
	$(VENV)/bin/slam2d paper --out demo-out --quick

## browser: install Debian's chromium for the report test when it is missing
browser:
ifeq ($(HAVE_APT),1)
	@command -v chromium >/dev/null 2>&1 || command -v chromium-browser >/dev/null 2>&1 || { \
	  echo "installing Debian's chromium (the report test renders report.html in it)"; \
	  $(SUDO) apt-get update -qq && DEBIAN_FRONTEND=noninteractive $(SUDO) apt-get install -y -qq chromium >/dev/null; }
endif

## ros1: install Debian's ROS 1 (roscore, rosbag, rospy, tf2) for the live node's tests when it is missing
ROS1_PACKAGES := ros-core python3-rospy python3-tf2-ros python3-sensor-msgs python3-nav-msgs \
                 python3-geometry-msgs python3-std-srvs python3-diagnostic-msgs python3-tf2-msgs
ros1:
ifeq ($(HAVE_APT),1)
	@command -v roscore >/dev/null 2>&1 || { \
	  echo "installing Debian's ROS 1 (the live node's tests run a real roscore and rosbag play)"; \
	  $(SUDO) apt-get update -qq && DEBIAN_FRONTEND=noninteractive $(SUDO) apt-get install -y -qq $(ROS1_PACKAGES) \
	    >/dev/null || echo "ROS 1 could not be installed: the live node's tests will skip"; }
endif

## test: set up and run the whole test suite (slow cases included)
test: $(VENV)/.installed browser ros1
	SLAM2D_REQUIRE_BROWSER=$(HAVE_APT) SLAM2D_REQUIRE_ROS=$$(command -v roscore >/dev/null 2>&1 && echo 1) \
	  $(PY) -m pytest -n 2 $(PYTEST_ARGS)

## check: the quick loop: everything but the cases marked slow
check: $(VENV)/.installed
	$(PY) -m pytest -n 2 -m "not slow" $(PYTEST_ARGS)

## bench: rerun the benchmarks and rewrite BENCHMARKS.md
bench: $(VENV)/.installed
	$(PY) benchmarks/run.py

## docs: regenerate the parameter tables and command pages in docs/
docs: $(VENV)/.installed
	$(PY) docs/generate.py

clean:
	rm -rf $(VENV) demo-out .pytest_cache .hypothesis
	find . -name __pycache__ -type d -prune -exec rm -rf {} +
