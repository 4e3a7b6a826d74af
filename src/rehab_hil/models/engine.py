"""The compiled simulation engine: one numba module per set of part kinds, cached on disk.

The engine source is generated for each diagram structure (which parts, how wired) with every
slice and wire as a constant, so LLVM inlines the whole closed loop; RK4 stages use a
preallocated workspace (no allocation per step). It is written to a real file so numba's
on-disk cache works: a structure compiles once per machine (~10 s) and loads in about a second
after. The file name hashes the source of every module the kernels come from or call into
(``kernel_modules``), so editing a kernel or a helper it calls recompiles, and nothing else does.
"""

from __future__ import annotations

import hashlib
import importlib.util
import inspect
import os
import signal
import sys
import threading
from collections.abc import Callable, Sequence
from pathlib import Path
from types import CodeType, ModuleType
from typing import Any

from rehab_hil.models.layout import Layout, PartLayout, Span
from rehab_hil.progress import watch_compiles

__all__ = ["KERNELS", "cache_dir", "call_holding_ctrl_c", "engine_for", "kernel_modules"]

_LOADED: dict[str, ModuleType] = {}


KERNELS = ("output", "derivatives", "update")  # a part's numba functions (models.system.Part)


def kernel_modules(classes: Sequence[type], framework: type) -> tuple[str, ...]:
    """The modules whose source a compiled model depends on, sorted: those of the part classes and
    their bases (not ``framework``, the base class, which holds no kernel code) and, followed through
    every call, those of the jitted functions the kernels call: a helper imported from another module
    (the simulated patient's reference from ``control.trajectories``) recompiles the model when edited."""
    modules = {c.__module__ for cls in classes for c in cls.__mro__ if c not in (object, framework)}
    todo = [getattr(cls, name) for cls in classes for name in KERNELS]
    seen: set[Any] = set()
    while todo:
        fn = getattr(todo.pop(), "py_func", None)  # a numba dispatcher's Python function
        if fn is None or fn in seen:
            continue
        seen.add(fn)
        modules.add(fn.__module__)
        todo += _named_callables(fn)
    return tuple(sorted(modules))


def _named_callables(fn: Any) -> list[Any]:
    """The globals ``fn``'s code names, and the attributes it names of the modules among them (``mod.f``)."""
    names: set[str] = set()
    codes = [fn.__code__]
    while codes:
        code = codes.pop()
        names.update(code.co_names)
        codes += [c for c in code.co_consts if isinstance(c, CodeType)]
    found = []
    for name in names:
        value = fn.__globals__.get(name)
        if isinstance(value, ModuleType):
            found += [getattr(value, n) for n in names if hasattr(value, n)]
        elif value is not None:
            found.append(value)
    return found


def call_holding_ctrl_c(fn: Callable[..., Any], *args: Any) -> Any:
    """``fn(*args)``, with a Ctrl-C that comes meanwhile held and raised when it returns.

    numba boxes the arrays a compiled function returns with a call into Python (its unpickler); a
    Ctrl-C pending from the long loop before raises inside that call, and numba then fails with a
    ``SystemError`` or, sometimes, a segmentation fault (numba 0.68). Compiled code cannot be stopped
    midway anyway, so holding the interrupt costs nothing. Outside the main thread (which alone runs
    Python's signal handlers) it is a plain call: the twin's thread pays no more than the check."""
    if threading.current_thread() is not threading.main_thread():
        return fn(*args)
    previous = signal.getsignal(signal.SIGINT)
    if not callable(previous):  # SIGINT ignored or at the OS default: Python raises nothing
        return fn(*args)
    held: list[int] = []
    signal.signal(signal.SIGINT, lambda signum, frame: held.append(signum))
    try:
        return fn(*args)
    finally:
        signal.signal(signal.SIGINT, previous)
        if held:
            previous(signal.SIGINT, None)  # Python's own handler raises KeyboardInterrupt here


def cache_dir() -> Path:
    """Where generated engines and numba's cache live (``REHAB_HIL_CACHE_DIR`` overrides)."""
    env = os.environ.get("REHAB_HIL_CACHE_DIR")
    base = Path(env) if env else Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "rehab-hil"
    return base / "engines"


def _slice(a: Span) -> str:
    return f"{a[0]}:{a[1]}"


def _gather(layout: Layout, k: int, indent: str) -> list[str]:
    """Lines that sum each input port's wired signals into the part's slice of ``w``."""
    part = layout.parts[k]
    lines = []
    for i, wire in enumerate(part.wires):
        terms = []
        for sname, gain in wire:
            if sname in layout.producers:
                refs = [f"sig[{s}]" for s in layout.producers[sname]]
            else:
                refs = [f"uext[{layout.input_names.index(sname)}]"]
            terms += [r if gain == 1.0 else f"({gain!r}) * {r}" for r in refs]
        lines.append(f"{indent}w[{part.u[0] + i}] = {' + '.join(terms) or '0.0'}")  # unconnected: zero
    return lines


def _call(part: PartLayout, k: int, fn: str, last: str, indent: str) -> str:
    return (f"{indent}K{k}_{fn}(t, x[{_slice(part.x)}], xd[{_slice(part.xd)}], w[{_slice(part.u)}], "
            f"P[{_slice(part.p)}], {last})")


def _source(layout: Layout) -> str:
    """Specialised Python source of one diagram: outputs, derivatives, RK4 step, simulate."""
    L = [
        "# Generated by rehab_hil.models.engine from a Diagram: do not edit.",
        "import numpy as np",
        "from numba import njit as _njit",
        "njit = _njit(cache=True, nogil=True, error_model='numpy')",
    ]
    for k, part in enumerate(layout.parts):
        module, qualname = part.kernel_class
        L.append(f"from {module} import {qualname} as _C{k}")
        for f in ("output", "derivatives", "update"):
            L.append(f"K{k}_{f} = _C{k}.{f}")
    L += ["", "", "@njit", "def eval_outputs(t, x, xd, uext, P, sig, w, sample):"]
    for k in layout.order:
        part = layout.parts[k]
        if not part.has_outputs:
            continue
        ind = "    "
        if part.has_discrete_states:
            L.append("    if sample:")
            ind = "        "
        L += _gather(layout, k, ind)
        L.append(_call(part, k, "output", f"sig[{_slice(part.y)}]", ind))
    L += ["    return", "", "", "@njit", "def rhs(t, x, xd, uext, P, sig, w, dx):",
          "    eval_outputs(t, x, xd, uext, P, sig, w, False)"]
    for k, part in enumerate(layout.parts):
        if part.has_states:
            L += _gather(layout, k, "    ")
            L.append(_call(part, k, "derivatives", f"dx[{_slice(part.x)}]", "    "))
    L += ["", "", "@njit", "def sample(t, x, xd, uext, P, sig, w, xdn):",
          "    eval_outputs(t, x, xd, uext, P, sig, w, True)"]
    discrete = [k for k, p in enumerate(layout.parts) if p.has_discrete_states]
    for k in discrete:
        L += _gather(layout, k, "    ")
        L.append(_call(layout.parts[k], k, "update", f"xdn[{_slice(layout.parts[k].xd)}]", "    "))
    if discrete:
        L.append(f"    xd[:] = xdn[:{layout.n_xd}]")
    L.append(_TEMPLATE)
    return "\n".join(L)


_TEMPLATE = """

@njit
def integrate(t, x, xd, uext, P, dt, nsub, sig, w, stage):
    n = x.shape[0]
    if n == 0:
        return
    h = dt / nsub
    k1 = stage[0]; k2 = stage[1]; k3 = stage[2]; k4 = stage[3]; xs = stage[4]
    for s in range(nsub):
        ts = t + s * h
        rhs(ts, x, xd, uext, P, sig, w, k1)
        for i in range(n):
            xs[i] = x[i] + 0.5 * h * k1[i]
        rhs(ts + 0.5 * h, xs, xd, uext, P, sig, w, k2)
        for i in range(n):
            xs[i] = x[i] + 0.5 * h * k2[i]
        rhs(ts + 0.5 * h, xs, xd, uext, P, sig, w, k3)
        for i in range(n):
            xs[i] = x[i] + h * k3[i]
        rhs(ts + h, xs, xd, uext, P, sig, w, k4)
        for i in range(n):
            x[i] += (h / 6.0) * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i])


@njit
def read_outputs(out_slots, sig, y):
    for j in range(out_slots.shape[0]):
        acc = 0.0
        for m in range(out_slots.shape[1]):
            if out_slots[j, m] >= 0:
                acc += sig[out_slots[j, m]]
        y[j] = acc


@njit
def step(t, x, xd, uext, P, dt, nsub, out_slots, y, sig, w, stage, xdn):
    sample(t, x, xd, uext, P, sig, w, xdn)
    read_outputs(out_slots, sig, y)
    integrate(t, x, xd, uext, P, dt, nsub, sig, w, stage)


@njit
def simulate(x, xd, U, P, dt, nsub, out_slots, sig, w, stage, xdn):
    nsteps = U.shape[0]
    Y = np.empty((nsteps, out_slots.shape[0]))
    X = np.empty((nsteps, x.shape[0]))
    for k in range(nsteps):
        t = k * dt
        uext = U[k]
        sample(t, x, xd, uext, P, sig, w, xdn)
        for i in range(x.shape[0]):
            X[k, i] = x[i]
        read_outputs(out_slots, sig, Y[k])
        integrate(t, x, xd, uext, P, dt, nsub, sig, w, stage)
    return X, Y
"""


def engine_for(layout: Layout) -> ModuleType:
    """The compiled module for this layout's structure, generating and importing it if needed.

    Parameter values are not part of the structure: diagrams that differ only in values share
    one engine."""
    src = _source(layout)
    h = hashlib.sha1(src.encode())
    for mod in sorted(set(layout.kernel_modules)):
        h.update(inspect.getsource(sys.modules[mod]).encode())
    key = h.hexdigest()[:20]
    if key in _LOADED:
        return _LOADED[key]
    watch_compiles()  # a compilation on a clean cache (a minute) says so instead of silence
    d = cache_dir()
    d.mkdir(parents=True, exist_ok=True)
    name = f"rehab_hil_engine_{key}"
    path = d / f"{name}.py"
    if not path.exists() or path.read_text() != src:
        tmp = path.with_suffix(f".{os.getpid()}.tmp")
        tmp.write_text(src)
        os.replace(tmp, path)  # atomic: parallel test workers never see half a file
    spec = importlib.util.spec_from_file_location(name, path)
    assert spec and spec.loader
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module  # numba's cache re-imports the module by name
    spec.loader.exec_module(module)
    _LOADED[key] = module
    return module
