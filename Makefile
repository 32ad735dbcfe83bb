# The two commands a user needs: `make demo` and `make test`.
# Both create .venv on first use and install everything, system packages included,
# at the versions in requirements.lock (`make lock` regenerates it).

PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed
SUDO   := $(shell [ "$$(id -u)" = 0 ] || echo sudo)

.PHONY: demo test system-deps firmware-deps lock emulator clean

demo: $(STAMP) emulator
	$(VENV)/bin/plush-opt demo --out out/demo

# One BLAS thread: the solvers' dense pieces are small, and on 2 cores
# OpenBLAS threads fighting each other (and pytest) slow them tenfold.
# One pytest worker per core (pytest-xdist); a test file stays on one worker,
# so its module fixtures are built once.
test: $(STAMP) emulator
	OPENBLAS_NUM_THREADS=1 $(PY) -m pytest -q -n auto --dist loadfile tests

# CHOLMOD headers for the [cholmod] extra (scikit-sparse builds from source),
# OpenBLAS as the system BLAS (CHOLMOD's supernodal factorisation of large
# meshes is BLAS-3 bound: twice as fast as with the reference BLAS), and a
# C++ compiler for the board emulator.
SYSTEM_PKGS := libsuitesparse-dev libopenblas0-pthread g++
system-deps:
	@if [ ! -f /usr/include/suitesparse/cholmod.h ] || ! command -v g++ >/dev/null || \
	    ! ldconfig -p 2>/dev/null | grep -q libopenblas; then \
	  echo "installing system packages: $(SYSTEM_PKGS)"; \
	  $(SUDO) apt-get update -qq && \
	  $(SUDO) env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq $(SYSTEM_PKGS) >/dev/null || \
	  { echo "error: could not install $(SYSTEM_PKGS) (need apt-get and root or sudo)" >&2; exit 1; }; \
	fi

# The lock constrains every dependency to the versions the suite passed with.
$(STAMP): pyproject.toml requirements.lock | system-deps
	@[ -x $(PY) ] || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -c requirements.lock -e '.[cholmod,dev]'
	@touch $(STAMP)

# Resolve pyproject's dependencies afresh in a clean venv and freeze them.
# Run it to move to newer versions, then `make test` before committing.
LOCK_VENV := .lock-venv
lock: | system-deps
	rm -rf $(LOCK_VENV)
	$(PYTHON) -m venv $(LOCK_VENV)
	$(LOCK_VENV)/bin/python -m pip install -q --upgrade pip
	$(LOCK_VENV)/bin/python -m pip install -q '.[cholmod,dev,bench]'
	{ echo "# Versions the test suite passes with; made by \`make lock\`, used as pip constraints."; \
	  $(LOCK_VENV)/bin/python -m pip freeze --exclude plush_opt --exclude plush-opt; } > requirements.lock
	rm -rf $(LOCK_VENV) build

# The AVR toolchain and Arduino core for the firmware, simavr for the simulated board.
FIRMWARE_PKGS := gcc-avr avr-libc binutils-avr arduino-core-avr avrdude simavr libsimavr-dev libelf-dev pkg-config
firmware-deps:
	@if ! command -v avr-g++ >/dev/null || [ ! -f /usr/share/arduino/hardware/arduino/avr/cores/arduino/Arduino.h ] || \
	    [ ! -f /usr/include/simavr/sim_avr.h ] || ! pkg-config --exists libelf 2>/dev/null; then \
	  echo "installing firmware packages: $(FIRMWARE_PKGS)"; \
	  $(SUDO) apt-get update -qq && \
	  $(SUDO) env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq $(FIRMWARE_PKGS) >/dev/null || \
	  { echo "error: could not install $(FIRMWARE_PKGS) (need apt-get and root or sudo)" >&2; exit 1; }; \
	fi

emulator: | firmware-deps
	@if [ -f hw/Makefile ]; then $(MAKE) -s -C hw everything; fi

clean:
	rm -rf $(VENV) $(LOCK_VENV) out build *.egg-info
	@if [ -f hw/Makefile ]; then $(MAKE) -s -C hw clean; fi
