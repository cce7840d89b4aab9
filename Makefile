# Two commands on a fresh machine:
#   make demo   creates .venv, installs the apt packages and pinned Python packages, runs the app on the sample
#   make test   the same setup, then the import contracts and the test suite
PYTHON ?= python3.11
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
DEMO_OUT ?= demo-output

# libportaudio2: sounddevice; jackd2: real-time audio with no sound card (tests, benchmarks);
# libusb-1.0-0: pyrealsense2; the GL/EGL/X11 runtime: pyorbslam3's Pangolin-linked extension; tmux: the test that
# reads `seesys run`'s live view from a terminal as a person sees it (a pseudo-terminal stands in without it).
APT_PACKAGES := libportaudio2 jackd2 libusb-1.0-0 libgl1 libegl1 libopengl0 libglx0 libsm6 libice6 libx11-6 libxext6 \
	tmux
SUDO := $(shell [ "$$(id -u)" = 0 ] || echo sudo)

.PHONY: all setup apt venv demo lint test test-fast clean

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

# The whole app on the embedded sample (150 frames at camera rate): ORB-SLAM3 + RTS monitor, the estimator
# service with the served model (configs/service.toml: the random forest), the advisory in the seesys condition.
# The audio goes to the default output device (or, with no sound card, only to the WAV); the session folder gets
# every part's logs, the WAV of what was played, summary.json and plot.png (estimated vs true error, the pulses,
# Equation 2's thresholds).
demo: setup
	rm -rf $(DEMO_OUT)
	$(BIN)/seesys run --source tum:data/sample --local --condition seesys --out $(DEMO_OUT)

# ruff: lint and format check; mypy: the library packages' types; lint-imports: the one-way layers of
# docs/architecture.md (a broken contract names the import and fails the run).
lint: setup
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .
	$(BIN)/mypy
	$(BIN)/lint-imports

# Everything: the checks, then every test (unit and system), TEST_WORKERS pytest processes at once, a module to a
# process (its module-scoped fixtures are made once). Most system tests wait on paced frames, audio clocks and child
# processes, so two processes on two cores take about 70 % of the time one takes.
TEST_WORKERS ?= 2
test: lint
	$(BIN)/python -m pytest -n $(TEST_WORKERS) --dist loadfile

# The unit tests alone (no process started, each a few seconds at most): under a minute.
test-fast: setup
	$(BIN)/python -m pytest -m "not system" -q

clean:
	rm -rf $(VENV) $(DEMO_OUT)
