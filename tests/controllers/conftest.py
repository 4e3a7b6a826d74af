"""Shared configs for the controller tests: the shipped plant configs and variants with effects."""

from __future__ import annotations

from pathlib import Path

import pytest

from rehab_hil.loading import load_config
from rehab_hil.testing import CONFIGS


def with_text(src: Path, dest: Path, extra: str = "", replace: tuple[str, str] | None = None) -> Path:
    """A copy of ``src`` with ``extra`` appended (an ``[[effects]]`` table) and one text replaced."""
    text = src.read_text()
    if replace is not None:
        assert replace[0] in text, replace[0]
        text = text.replace(*replace)
    dest.write_text(text + extra)
    return dest


def effect(name: str, params: str) -> str:
    return f'\n[[effects]]\nname = "{name}"\nparams = {{ {params} }}\n'


@pytest.fixture(scope="session")
def sma():
    return load_config(CONFIGS / "sma_exoskeleton.toml")


@pytest.fixture(scope="session")
def fe():
    return load_config(CONFIGS / "finger_extensor.toml")


@pytest.fixture(scope="session")
def tcp():
    return load_config(CONFIGS / "tcp_finger.toml")
