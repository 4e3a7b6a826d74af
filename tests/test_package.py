"""rehab-hil as an installed package, not a checkout: the wheel the project's build backend (hatchling)
builds holds the shipped configs and profiles, and once ``pip install``-ed into a fresh venv it runs
``rehab-hil run --device sim`` and the docs' own-controller example from a folder with no configs/.

The venv is fresh (``python -m venv``) and the wheel goes in with a real ``pip install``; its
dependencies are not downloaded again (numba, scipy, zenoh ... would take minutes): a ``.pth`` file
puts the project venv's site-packages behind the venv's own. site adds that folder without reading
its ``.pth`` files, so the project's editable install (a ``.pth`` finder pointing at src/) is not
active: ``rehab_hil`` comes from the wheel, which the test checks. ``PYTHONPATH`` is dropped."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import sysconfig
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

pytestmark = [pytest.mark.slow, pytest.mark.xdist_group("installed_package")]  # one wheel and venv, not one per worker


@pytest.fixture(scope="module")
def wheel(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("wheel")
    proc = subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--quiet", "-w", str(out), str(ROOT)],
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-3000:]
    (whl,) = out.glob("rehab_hil-*.whl")
    return whl


@pytest.fixture(scope="module")
def venv(wheel, tmp_path_factory) -> Path:
    env_dir = tmp_path_factory.mktemp("venv") / "v"
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(env_dir)], check=True, timeout=120)
    python = env_dir / "bin" / "python"
    site = Path(subprocess.run([str(python), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                               check=True, capture_output=True, text=True).stdout.strip())
    (site / "zz_project_deps.pth").write_text(sysconfig.get_paths()["purelib"] + "\n")
    proc = subprocess.run([sys.executable, "-m", "pip", "--python", str(python), "install", "--no-deps", "--quiet",
                           str(wheel)], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return env_dir


def _env() -> dict[str, str]:
    return {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}


def test_the_wheel_ships_every_config_and_profile(wheel):
    names = set(zipfile.ZipFile(wheel).namelist())
    for folder in ("configs", "profiles"):
        for f in sorted((ROOT / folder).glob("*.toml")):
            assert f"rehab_hil/shipped_data/{folder}/{f.name}" in names
    assert "rehab_hil/shipped_data/foxglove_layout.json" in names  # the layout `run --foxglove` prints


def test_the_installed_package_finds_its_configs_outside_the_checkout(venv, tmp_path):
    code = ("import rehab_hil, rehab_hil.testing as t; print(rehab_hil.__file__); "
            "print(t.CONFIGS); print(sorted(p.name for p in t.CONFIGS.glob('*.toml')))")
    out = subprocess.run([str(venv / "bin" / "python"), "-c", code], cwd=tmp_path, env=_env(), check=True,
                         capture_output=True, text=True, timeout=120).stdout.splitlines()
    assert out[0].startswith(str(venv)) and out[1].startswith(str(venv))  # the wheel, not src/
    assert "finger_extensor.toml" in out[2] and "sma_exoskeleton.toml" in out[2]


def test_the_installed_command_runs_a_session_on_the_simulated_rig(venv, tmp_path):
    proc = subprocess.run([str(venv / "bin" / "rehab-hil"), "run", "--config", "configs/finger_extensor.toml",
                           "--device", "sim", "--lockstep", "--controller", "pid", "--reference", "step",
                           "--duration", "2", "--no-display", "--record", "out/"],
                          cwd=tmp_path, env=_env(), capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-3000:] + proc.stdout[-3000:]
    assert "using the one shipped with rehab-hil" in proc.stderr and str(venv) in proc.stderr
    assert "duration reached" in proc.stdout
    (run,) = (tmp_path / "out").iterdir()
    assert (run / "metadata.json").is_file() and (run / "run.csv").is_file()


def test_the_docs_own_controller_example_passes_against_the_installed_package(venv, tmp_path):
    shutil.copy(ROOT / "docs" / "examples" / "test_lab_controller.py", tmp_path)
    proc = subprocess.run([str(venv / "bin" / "python"), "-m", "pytest", "-q", "-p", "no:cacheprovider",
                           "-p", "no:randomly", "test_lab_controller.py"],
                          cwd=tmp_path, env=_env(), capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    assert "1 passed" in proc.stdout
