"""Output written whole or not at all: a file or a report folder that Ctrl-C, a full disk or an
error part-way leaves as it was (no CSV cut short, no report folder holding one plot).

``replacing(path)`` gives a temporary sibling to write and renames it onto ``path`` at the end;
``staged_folder(out)`` gives a temporary sibling folder whose files move into ``out`` at the end.
Both remove what they wrote when the block fails.
"""

from __future__ import annotations

import os
import re
import shutil
import tempfile
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

__all__ = ["name_part", "replacing", "staged_folder"]


@contextmanager
def replacing(path: str | Path) -> Iterator[Path]:
    """A temporary file beside ``path`` (same folder, so the rename is atomic) that becomes ``path``
    when the block ends without an exception, and is removed when it does not."""
    path = Path(path)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.{threading.get_ident()}.partial")  # two writers, two files
    try:
        yield tmp
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


@contextmanager
def staged_folder(out: str | Path) -> Iterator[Path]:
    """A temporary folder beside ``out`` (same depth: a relative path in a written file resolves the
    same); its files move into ``out`` (made if missing) when the block succeeds. On an exception or
    Ctrl-C it is removed and ``out`` is as before; so is a folder ``out`` that was made for it empty."""
    out = Path(out)
    existed = out.exists()
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.partial-", dir=out.parent))
    try:
        yield tmp
        out.mkdir(parents=True, exist_ok=True)
        for f in sorted(tmp.iterdir()):
            os.replace(f, out / f.name)
    except BaseException:
        if not existed and out.is_dir() and not any(out.iterdir()):
            out.rmdir()
        raise
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def name_part(text: str, empty: str = "x") -> str:
    """``text`` as part of a file or folder name: runs of anything but letters, digits, ``_.-``
    become one ``-`` (a rig id, a patient id, a config name); ``empty`` if nothing is left."""
    return re.sub(r"[^A-Za-z0-9_.-]+", "-", text).strip("-") or empty
