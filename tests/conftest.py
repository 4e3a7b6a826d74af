"""Shared fixtures: paths to the repository's configs.

One BLAS thread per test process (before anything imports numpy; the simulated devices the tests
spawn inherit it). ``make test`` runs three xdist workers on a 2-core machine (a third fills the time
the others' real-time sessions wait on the clock: 660 -> 572 s, measured): each numpy/scipy OpenBLAS
would otherwise start a thread per core, and the workers' threads spin against each other in every
large product (the discrepancy fits' least squares). Measured: the discrepancy
workflow and other-plant tests under -n 2 took 91 s of CPU (93 s wall) with the default threads and
50 s (55 s wall) with one; the results (what is named, fitted values within the tests' tolerances)
do not depend on it. Set the variable to override."""

from __future__ import annotations

import os
from collections import Counter
from pathlib import Path

import pytest

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # neither import above loads numpy

ROOT = Path(__file__).resolve().parents[1]
CONFIGS = ROOT / "configs"


def pytest_configure(config: pytest.Config) -> None:
    """Refuse a pytest / pytest-xdist pair under which ``--dist loadgroup`` ignores ``xdist_group``:
    xdist 3.8 tags a grouped test's node id ``@group`` in ``item._nodeid``, which pytest 9.2 no
    longer reads, so the tests that share a device spread over both workers, without a word."""
    if config.getoption("dist", "no") != "loadgroup":
        return
    from importlib.metadata import version

    def release(name: str) -> tuple[int, ...]:
        return tuple(int(x) for x in version(name).split(".")[:2] if x.isdigit())

    if release("pytest") >= (9, 2) and release("pytest-xdist") <= (3, 8):
        raise pytest.UsageError(f"pytest {version('pytest')} with pytest-xdist {version('pytest-xdist')}: "
                                "--dist loadgroup would ignore every xdist_group (pyproject.toml pins pytest<9.2; "
                                "make test reinstalls it)")


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """Modules with the most tests marked ``slow`` run first; each module's tests stay together and in
    their order (its module fixtures are made once). The workers then end on short tests within seconds
    of each other, instead of one running the twin's 30 s sessions alone at the end (measured: 20-30 s)."""
    def module(item: pytest.Item) -> str:
        return item.nodeid.split("::")[0]

    weight: Counter[str] = Counter(module(i) for i in items if i.get_closest_marker("slow"))
    first = {}
    for n, item in enumerate(items):
        first.setdefault(module(item), n)
    items.sort(key=lambda i: (-weight[module(i)], first[module(i)]))


@pytest.fixture
def configs_dir() -> Path:
    return CONFIGS


@pytest.fixture(autouse=True)
def _own_learning_store(tmp_path_factory: pytest.TempPathFactory, monkeypatch: pytest.MonkeyPatch) -> None:
    """Each test's sessions keep their tables learned on the rig and their assistance in folders of
    their own (``REHAB_HIL_LEARNING_DIR``, ``REHAB_HIL_ASSISTANCE_DIR``): no test starts from what
    another, or a user's sessions, learned."""
    monkeypatch.setenv("REHAB_HIL_LEARNING_DIR", str(tmp_path_factory.mktemp("rig_learning")))
    monkeypatch.setenv("REHAB_HIL_ASSISTANCE_DIR", str(tmp_path_factory.mktemp("assistance")))
