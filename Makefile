# Two commands do all the set-up on a fresh machine:
#   make demo   create .venv, install everything pinned, run the main job
#   make test   create .venv, install everything pinned, run the whole test suite
# Other targets: make bench (work-precision, stability, fidelity charts), make bags
# (regenerate reference recordings), make clean.

PYTHON ?= python3
VENV   ?= .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed
WARMED := $(VENV)/.warmed

# DDS traffic of the demo and the tests stays on this machine, unless you chose a
# range yourself (ROS_LOCALHOST_ONLY is deprecated in Jazzy and never set here).
ifeq ($(origin ROS_LOCALHOST_ONLY),undefined)
export ROS_AUTOMATIC_DISCOVERY_RANGE ?= LOCALHOST
endif
export MPLBACKEND := Agg

.PHONY: demo test bench bags install clean help

help:
	@sed -n '1,8p' Makefile

$(STAMP): pyproject.toml setup.py setup.cfg constraints.txt tests/foxglove/package-lock.json
	@command -v node >/dev/null && command -v npm >/dev/null || { \
	  echo "error: node and npm are needed (the tests decode recordings with Foxglove's parsers): install nodejs and npm" >&2; exit 1; }
	npm ci --prefix tests/foxglove --no-audit --no-fund --loglevel=error
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --disable-pip-version-check -c constraints.txt pip
	$(PY) -m pip install --quiet --disable-pip-version-check -c constraints.txt -e '.[ros,plot,test,campaign]'
	touch $(STAMP)

# The kernels compiled again whenever their disk cache was dropped, so a first run compiles nothing: the cache
# of a kernel file is dropped when it or any package module it imports changes (core/jit_cache.py: the kind
# codes of profile_data.py, model.py, the steppers ...), which is nearly all of core, so all of it. A stamp of
# its own: a changed source compiles again without installing everything again.
KERNELS := $(wildcard belt_drive_ros/core/*.py belt_drive_ros/core/network/*.py)

$(WARMED): $(STAMP) $(KERNELS)
	@echo "compiling the numba kernels once (cached on disk; a first run then compiles nothing)"
	$(PY) -c "from belt_drive_ros.core.warm import warm; warm(jobs=2)"
	$(VENV)/bin/belt-drive sim paper --duration 0.01 --quiet
	touch $(WARMED)

install: $(WARMED)

demo: $(WARMED)
	$(VENV)/bin/belt-drive demo

# The suite runs on TEST_WORKERS processes (pytest-xdist; 2 = this project's machines' cores); each
# worker holds a ROS domain of its own; an idle worker takes tests from the busy one (worksteal), so a
# long test near the end does not leave the other core idle. TEST_WORKERS=0 runs it in one process.
TEST_WORKERS ?= 2
test: $(WARMED)
	$(PY) -m pytest -q -n $(TEST_WORKERS) --dist worksteal

bench: $(WARMED)
	$(VENV)/bin/belt-drive bench all --out docs/bench

bags: $(WARMED)
	$(VENV)/bin/belt-drive make-bags --out bags --force

clean:
	rm -rf $(VENV) build *.egg-info .pytest_cache tests/foxglove/node_modules
