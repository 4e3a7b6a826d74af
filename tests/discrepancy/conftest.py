"""Shared fixtures: the Finger Extensor config and plant, and a workflow run per hidden effect."""

from __future__ import annotations

from pathlib import Path

import pytest

from rehab_hil.plants import get_plant, load_config

ROOT = Path(__file__).resolve().parents[2]
FE_CONFIG = ROOT / "configs" / "finger_extensor.toml"


@pytest.fixture(scope="session")
def fe():
    """(spec, cfg) of the Finger Extensor."""
    return get_plant("finger_extensor"), load_config(FE_CONFIG)
