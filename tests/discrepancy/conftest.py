"""Shared fixtures: the Finger Extensor config and plant, and a workflow run per hidden effect."""

from __future__ import annotations

from pathlib import Path

import pytest

from rehab_hil.loading import load_config
from rehab_hil.plants import get_plant

ROOT = Path(__file__).resolve().parents[2]
FE_CONFIG = ROOT / "configs" / "finger_extensor.toml"


@pytest.fixture(scope="session")
def fe():
    """(spec, cfg) of the Finger Extensor."""
    return get_plant("finger_extensor"), load_config(FE_CONFIG)


@pytest.fixture(scope="session")
def independent():
    """The benchmark's independent Finger Extensor simulator (bench/discrepancy.py), which shares no
    code with the plant models: records the code under test did not make."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("bench_discrepancy", ROOT / "bench" / "discrepancy.py")
    assert spec and spec.loader
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


@pytest.fixture(scope="session")
def independent_sma(independent):
    """The benchmark's independent SMA-exoskeleton simulator (bench/sma_independent.py), loaded the
    way the benchmark loads it."""
    return independent._independent_sma()
