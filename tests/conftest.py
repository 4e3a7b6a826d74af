"""Shared fixtures: paths to the repository's configs.

One BLAS thread per test process (before anything imports numpy; the simulated devices the tests
spawn inherit it). ``make test`` runs two xdist workers on a 2-core machine: each numpy/scipy
OpenBLAS would otherwise start a thread per core, and the two workers' threads spin against each
other in every large product (the discrepancy fits' least squares). Measured: the discrepancy
workflow and other-plant tests under -n 2 took 91 s of CPU (93 s wall) with the default threads and
50 s (55 s wall) with one; the results (what is named, fitted values within the tests' tolerances)
do not depend on it. Set the variable to override."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # neither import above loads numpy

ROOT = Path(__file__).resolve().parents[1]
CONFIGS = ROOT / "configs"


@pytest.fixture
def configs_dir() -> Path:
    return CONFIGS
