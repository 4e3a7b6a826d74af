"""The docs' example of a lab's own controller in the lab's CI runs as written, and docs/sessions.md
shows that file as it is."""

from __future__ import annotations

import subprocess
import sys

from rehab_hil.testing import CONFIGS

ROOT = CONFIGS.parent
EXAMPLE = ROOT / "docs" / "examples" / "test_lab_controller.py"


def test_the_docs_show_the_example_file_as_it_is():
    text = (ROOT / "docs" / "sessions.md").read_text()
    assert f"```python\n{EXAMPLE.read_text()}```" in text


def test_the_example_passes_when_run_as_a_lab_would_from_the_repository_root():
    proc = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider",
                           str(EXAMPLE.relative_to(ROOT))], cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    assert "1 passed" in proc.stdout
