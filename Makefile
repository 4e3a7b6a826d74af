# The two commands: `make run` (main job on the simulated rig) and `make test` (every test).
# Both create .venv and install what they need; nothing is installed by hand.
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed-$(shell cat pyproject.toml | sha1sum | cut -c1-12)

.PHONY: run test lint bench firmware harness toolchain browser clients upload clean

$(BIN)/python:
	$(PY) -m venv $(VENV)

# The project and its test extras: uv installs them where it can be had from PyPI, else pip (the script says why).
$(STAMP): pyproject.toml | $(BIN)/python
	sh scripts/install_python.sh $(VENV)
	rm -f $(VENV)/.installed-* && touch $@

# Byte-compile the package: every process a session starts reads it from __pycache__ then, even where
# PYTHONDONTWRITEBYTECODE keeps Python from writing it (about 0.4 s of CPU per process otherwise).
PYC := $(BIN)/python -m compileall -q -j 0 src

run: $(STAMP)
	@$(PYC)
	$(BIN)/rehab-hil run --config configs/sma_exoskeleton.toml --device sim --duration 30 --twin --record out/

test: $(STAMP) toolchain browser clients firmware harness
	$(BIN)/ruff check .
	@$(PYC)
	$(BIN)/python -m pytest -n 3 --dist loadgroup

bench: $(STAMP)
	$(BIN)/python bench/finger_extensor_rtf.py
	$(BIN)/python bench/serial_roundtrip.py

lint: $(STAMP)
	$(BIN)/ruff check .

# AVR toolchain + simavr (Debian packages; installs them when missing and running as root).
toolchain:
	sh scripts/install_toolchain.sh

# Debian's Chromium, the headless browser the HTML report tests open reports in (root installs it when missing).
browser:
	sh scripts/install_browser.sh

# Third-party Node clients the tests connect with (tests/clients; npm ci, versions pinned in its lock file).
# Without npm or its registry the npm client test skips, saying why; the rest of make test goes on.
clients:
	sh scripts/install_node_clients.sh || echo "make clients: not installed; tests/telemetry/test_third_party_clients.py skips its npm client test"

# The Arduino Uno firmware (firmware/build/rehab_fw.elf/.hex); prints flash/RAM use.
firmware: toolchain
	$(MAKE) -s -C firmware

# Build and upload the firmware to the Uno with avrdude, then check its handshake (rehab-hil flash).
# PORT=/dev/serial/by-id/... picks the board; default: auto (the one Arduino-like USB port).
PORT ?= auto
upload: $(STAMP) firmware
	$(BIN)/rehab-hil flash --no-build --port $(PORT)

# The simavr harness that runs the firmware ELF (sim_devices/build/avr_harness).
harness: toolchain
	$(MAKE) -s -C sim_devices/avr

clean:
	rm -rf $(VENV) out build .pytest_cache firmware/build sim_devices/build
