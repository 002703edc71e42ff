# Two entry points: `make demo` and `make test`. Both build .venv/ first and
# install the system libraries the Python wheels need.
PYTHON ?= python3.11
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed
SUDO   := $(shell [ "$$(id -u)" = 0 ] || echo sudo)
# The other Pythons ROS 2 runs: Humble (Ubuntu 22.04) 3.10, Jazzy (Ubuntu 24.04) 3.12. The suite's fast tier
# runs on each (.venv-3.10/, .venv-3.12/), and the wheel is installed and run on both.
OTHER_PYTHONS ?= 3.10 3.12
OTHER_STAMPS  := $(foreach v,$(OTHER_PYTHONS),.venv-$(v)/.installed)
# pythonX.Y on the PATH, else pyenv's (its shim refuses a version that is not selected), else the system's.
find_python = $(shell for p in python$(1) $$(ls -d $$HOME/.pyenv/versions/$(1).*/bin/python$(1) \
                      /usr/bin/python$(1) 2>/dev/null); do $$p -c '' 2>/dev/null && { echo $$p; break; }; done)

.PHONY: demo test test-main test-other wheel-check bench venv sysdeps clean

demo: $(STAMP)
	$(BIN)/handeye demo

test: test-main test-other wheel-check

# Two workers, a test file each: most of the suite's time is the simulated robot moving in real time.
test-main: $(STAMP)
	$(BIN)/python -m pytest -q -n 2 --dist loadfile

# On the other Pythons: every product module's fast tests, and the ROS 2 (real DDS), RTDE and MQTT paths
# (the benchmarks run from the checkout's .venv, so their tests stay on 3.11).
test-other: $(OTHER_STAMPS)
	@for v in $(OTHER_PYTHONS); do \
		echo "== Python $$v: fast tier"; \
		.venv-$$v/bin/python -m pytest -q -n 2 --dist loadfile -p no:cacheprovider \
			-m "not slow or every_python" --ignore=tests/bench || exit 1; \
	done

# The wheel as a user installs it (not editable) into clean venvs, run from another directory.
wheel-check: $(STAMP)
	bash .ci/wheel-check $(foreach v,$(OTHER_PYTHONS),$(call find_python,$(v)))

bench: $(STAMP)
	$(BIN)/python -m bench

venv: $(STAMP)

# libusb-1.0-0: open3d. libopenni2-0: the OpenNI2 camera driver (its dummy device is tested).
SYSLIBS := libusb-1.0.so.0:libusb-1.0-0 libOpenNI2.so.0:libopenni2-0
# mosquitto: the MQTT broker the alarm tests publish through (real broker on loopback).
# chromium: the headless browser the report tests render report.html in (and print to PDF);
# poppler-utils: pdftotext, which reads the printed report back.
SYSBINS := /usr/sbin/mosquitto:mosquitto /usr/bin/chromium:chromium /usr/bin/pdftotext:poppler-utils

sysdeps:
	@missing=""; for pair in $(SYSLIBS); do \
		ldconfig -p | grep -q "$${pair%%:*}" || missing="$$missing $${pair#*:}"; \
	done; \
	for pair in $(SYSBINS); do \
		[ -x "$${pair%%:*}" ] || missing="$$missing $${pair#*:}"; \
	done; \
	if [ -n "$$missing" ]; then \
		echo "installing system packages:$$missing"; \
		$(SUDO) apt-get update -qq && $(SUDO) apt-get install -y -qq $$missing; \
	fi

$(STAMP): pyproject.toml | sysdeps
	@command -v $(PYTHON) >/dev/null || { echo "need $(PYTHON) (set PYTHON=...)"; exit 1; }
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip
	@# setuptools' notice about editable installs is not actionable; keep the install quiet.
	PYTHONWARNINGS=ignore $(BIN)/python -m pip install -q -e '.[test,openni,ros,ros2,realsense]'
	touch $(STAMP)

.venv-%/.installed: pyproject.toml | sysdeps
	@py="$(call find_python,$*)"; [ -n "$$py" ] || { echo "need python$* (ROS 2's Python)"; exit 1; }; \
	$$py -m venv .venv-$*
	.venv-$*/bin/python -m pip install -q --upgrade pip
	PYTHONWARNINGS=ignore .venv-$*/bin/python -m pip install -q -e '.[test,openni,ros,ros2,realsense]'
	touch $@

clean:
	rm -rf $(VENV) $(foreach v,$(OTHER_PYTHONS),.venv-$(v)) build *.egg-info
