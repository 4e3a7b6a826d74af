"""numba's settings for the part kernels, and the kernel of a part with nothing to compute.

A module of its own because the engine cache keys on the source of every module a compiled model's
kernels come from: the diagram framework (``system.py``) changes far more often than these lines,
and an edit there should not recompile every model on the machine."""

from __future__ import annotations

import numba

__all__ = ["njit", "noop"]

njit = numba.njit(cache=True, nogil=True, inline="always")


@njit
def noop(t, x, xd, u, p, out):  # pragma: no cover - compiled
    pass
