# The two commands: `make run` (main job on the simulated rig) and `make test` (every test).
# Both create .venv and install what they need; nothing is installed by hand.
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed-$(shell cat pyproject.toml | sha1sum | cut -c1-12)

.PHONY: run test lint bench firmware toolchain clean

$(BIN)/python:
	$(PY) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip

$(STAMP): pyproject.toml | $(BIN)/python
	$(BIN)/python -m pip install --quiet -e ".[test]"
	rm -f $(VENV)/.installed-* && touch $@

run: $(STAMP)
	$(BIN)/rehab-hil simulate --config configs/finger_extensor.toml --scenario cycle --out out/run.csv

test: $(STAMP)
	$(BIN)/ruff check src tests bench sim_devices
	$(BIN)/python -m pytest -n 2 --dist loadgroup

bench: $(STAMP)
	$(BIN)/python bench/finger_extensor_rtf.py

lint: $(STAMP)
	$(BIN)/ruff check src tests bench sim_devices

clean:
	rm -rf $(VENV) out build .pytest_cache
