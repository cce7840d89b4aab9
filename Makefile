# Two commands on a fresh machine:
#   make demo   creates .venv, installs the apt packages and pinned Python packages, runs the pipeline on the sample
#   make test   the same setup, then the test suite
PYTHON ?= python3.11
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
DEMO_OUT ?= demo-output

# libportaudio2: sounddevice; jackd2: real-time audio with no sound card (tests, benchmarks);
# libusb-1.0-0: pyrealsense2; the GL/EGL/X11 runtime: pyorbslam3's Pangolin-linked extension.
APT_PACKAGES := libportaudio2 jackd2 libusb-1.0-0 libgl1 libegl1 libopengl0 libglx0 libsm6 libice6 libx11-6 libxext6
SUDO := $(shell [ "$$(id -u)" = 0 ] || echo sudo)

.PHONY: all setup apt venv demo test clean

all: test

apt:
	@missing=$$(for p in $(APT_PACKAGES); do dpkg -s $$p >/dev/null 2>&1 || echo $$p; done); \
	if [ -n "$$missing" ]; then \
		echo "installing apt packages: $$missing"; \
		$(SUDO) apt-get update -qq && \
		DEBIAN_FRONTEND=noninteractive $(SUDO) apt-get install -y -qq --no-install-recommends $$missing; \
	fi

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip
	$(BIN)/python -m pip install -q -e ".[test]"
	touch $(STAMP)

venv: $(STAMP)

setup: apt venv

# The pipeline on the embedded sample: ORB-SLAM3 + RTS monitor (session folder with frames, trajectory, RTS rows and
# PSD matrices), the true per-frame pose error from the ground truth, and what the SEESys advisory would play
# for it (the estimator service is not built yet, so the true error stands in for its estimates).
demo: setup
	$(BIN)/seesys monitor run --source tum:data/sample --mode rgbd --out $(DEMO_OUT)/session
	$(BIN)/seesys dataset label $(DEMO_OUT)/session --labelled-only --out $(DEMO_OUT)/true-error.csv
	$(BIN)/seesys advisory render --estimates $(DEMO_OUT)/true-error.csv --out $(DEMO_OUT)/advisory-preview.wav

test: setup
	$(BIN)/python -m pytest

clean:
	rm -rf $(VENV) $(DEMO_OUT)
