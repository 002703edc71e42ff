# Two entry points: `make demo` and `make test`. Both build .venv/ first and
# install the system libraries the Python wheels need.
PYTHON ?= python3.11
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed
SUDO   := $(shell [ "$$(id -u)" = 0 ] || echo sudo)

.PHONY: demo test bench venv sysdeps clean

demo: $(STAMP)
	$(BIN)/handeye demo

# Two workers, a test file each: most of the suite's time is the simulated robot moving in real time.
test: $(STAMP)
	$(BIN)/python -m pytest -q -n 2 --dist loadfile

bench: $(STAMP)
	$(BIN)/handeye bench

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

clean:
	rm -rf $(VENV) build *.egg-info
