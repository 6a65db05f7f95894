# The two commands a user needs: `make demo` and `make test`. Both set everything up on first use.
SHELL := /bin/bash
.SHELLFLAGS := -euo pipefail -c
PYTHON ?= python3
VENV := .venv
VENV_STAMP := $(VENV)/.requirements-installed
BUILD_STAMP := install/.workspace-built
WORKSPACE_SOURCES := $(shell find -L src config launch -path '*/__pycache__' -prune -o -type f -print 2>/dev/null) colcon.meta
IN_ENV := source scripts/env.sh &&

.PHONY: setup demo test lint pytest model clean help
.DEFAULT_GOAL := help

help:
	@echo "make demo   set up (first time) and run the sensor graph on the simulated sensor"
	@echo "make test   set up (first time), lint, and run every test"
	@echo "make setup  create .venv with the pinned packages and build the colcon workspace (idempotent)"
	@echo "make model  retrain the shipped default model from the simulator"
	@echo "make lint   ruff over the whole repository"

setup: $(BUILD_STAMP)

# The venv is (re)installed only when requirements.txt or the CMake repair changed.
$(VENV_STAMP): requirements.txt scripts/fix_ros_wheel_cmake.py
	@test -x $(VENV)/bin/python || $(PYTHON) -m venv $(VENV)
	$(VENV)/bin/python -m pip install --quiet --disable-pip-version-check -r requirements.txt
	$(VENV)/bin/python scripts/fix_ros_wheel_cmake.py
	@touch $@

# colcon rebuilds only what changed; the stamp keeps a no-change `make setup` from even starting colcon.
$(BUILD_STAMP): $(VENV_STAMP) $(WORKSPACE_SOURCES)
	scripts/build.sh
	@touch $@

demo: setup
	$(IN_ENV) tactile-demo

lint: $(VENV_STAMP)
	$(VENV)/bin/ruff check .

pytest: setup
	$(IN_ENV) python -m pytest

test: setup lint pytest

model: setup
	$(IN_ENV) tactile-fusion train --out src/tactile_fusion/models/default

clean:
	rm -rf build install log
