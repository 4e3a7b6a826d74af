"""The compiled simulation engine: generated modules, compiled by numba once and cached on disk.

Two kinds of module (``models/codegen.py`` writes their source): a part module per part class (its
kernels, compiled once per machine whatever diagram uses them) and an engine module per diagram
structure (which parts, how wired: every slice and wire a constant, the part functions inlined by
LLVM, so the whole closed loop is one piece of machine code; RK4 stages use a preallocated workspace,
no allocation per step). They are written to real files so numba's on-disk cache works: a structure
compiles once per machine and loads in well under a second after. A module's name hashes its source
and the source of every module its kernels come from or call into (``kernel_modules``), so editing a
kernel or a helper it calls recompiles what uses it, and nothing else does.
"""

from __future__ import annotations

import fcntl
import hashlib
import importlib.util
import inspect
import os
import signal
import sys
import threading
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from types import CodeType, ModuleType
from typing import Any

from rehab_hil.models.codegen import KERNELS, engine_source, part_source
from rehab_hil.models.layout import Layout
from rehab_hil.progress import watch_compiles

__all__ = ["KERNELS", "cache_dir", "call_holding_ctrl_c", "compile_for", "compiling", "engine_for", "kernel_modules",
           "prepare"]

_LOADED: dict[str, ModuleType] = {}


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


def engine_for(layout: Layout) -> ModuleType:
    """The compiled module for this layout's structure, generating and importing it if needed.

    Parameter values are not part of the structure: diagrams that differ only in values share
    one engine. Each part class's kernels come from its own part module, shared by every engine."""
    names = [_load("rehab_hil_part", part_source(*p.kernel_class), p.kernel_modules).__name__
             for p in layout.parts]
    return _load("rehab_hil_engine", engine_source(layout, names), ())


def prepare(engine: ModuleType, *entry_points: str) -> None:
    """Compile ``engine``'s ``entry_points`` now (or load them from the disk cache) for the types the
    flat arrays have (``CompiledSystem.workspace``): a caller that steps an engine by hand (the rig's
    controller, a simulated device) would otherwise compile it at its first step, inside its loop, for
    seconds on a clean cache. ``simulate`` compiles these as its own callees: preparing them first adds
    no compilation."""
    from numba import float64, int64, types

    v, m = types.Array(float64, 1, "C"), types.Array(float64, 2, "C")
    slots = types.Array(int64, 2, "C")
    signatures = {
        "sample": (float64, v, v, v, v, v, v, v),
        "read_outputs": (slots, v, v),
        "integrate": (float64, v, v, v, v, float64, int64, v, v, m),
        "step": (float64, v, v, v, v, float64, int64, slots, v, v, v, m, v),
    }
    _compile_locked(engine, [(name, signatures[name]) for name in entry_points])


def compile_for(engine: ModuleType, entry_point: str, args: Sequence[Any]) -> None:
    """Compile ``engine``'s ``entry_point`` (or load it) for the types of ``args``, under its lock. A
    Ctrl-C meanwhile is raised when the compilation ends (``call_holding_ctrl_c``): raised inside numba's
    compiler, it left a half-built library ("no compiled object yet") instead of a KeyboardInterrupt."""
    from numba import typeof

    _compile_locked(engine, [(entry_point, tuple(typeof(a) for a in args))])


def _compile_locked(engine: ModuleType, signatures: Sequence[tuple[str, tuple[Any, ...]]]) -> None:
    """Each (entry point, argument types) compiled or loaded under ``engine``'s lock, a Ctrl-C held."""
    with compiling(engine):
        for name, sig in signatures:
            call_holding_ctrl_c(getattr(engine, name).compile, sig)


@contextmanager
def compiling(engine: ModuleType) -> Iterator[None]:
    """Hold ``engine``'s machine-wide lock while numba compiles or loads its code: another process that
    needs the same engine meanwhile (a parallel test worker, the simulated device beside a session) waits,
    then loads the first one's compilation from the disk cache instead of compiling it a second time."""
    from numba.core.compiler_lock import global_compiler_lock

    # numba's own lock first: a thread that held this file while it waited for another thread of its
    # process to finish compiling (the twin's beside the session's) kept every other process waiting too
    with global_compiler_lock, open(cache_dir() / f"{engine.__name__}.lock", "a") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # released when the file closes, or when the process dies
        yield


def _load(prefix: str, src: str, modules: Sequence[str]) -> ModuleType:
    """The module of generated source ``src``, written once under ``cache_dir`` and imported by path.

    Its name hashes ``src`` and the source of ``modules`` (what its kernels come from), so an edit to
    any of them gives a new module, and numba compiles it anew instead of loading stale machine code."""
    h = hashlib.sha1(src.encode())
    for mod in sorted(set(modules)):
        h.update(inspect.getsource(sys.modules[mod]).encode())
    name = f"{prefix}_{h.hexdigest()[:20]}"
    if name in _LOADED:
        return _LOADED[name]
    watch_compiles()  # a compilation on a clean cache (a minute) says so instead of silence
    d = cache_dir()
    d.mkdir(parents=True, exist_ok=True)
    path = d / f"{name}.py"
    if not path.exists() or path.read_text() != src:
        tmp = path.with_suffix(f".{os.getpid()}.tmp")
        tmp.write_text(src)
        os.replace(tmp, path)  # atomic: parallel test workers never see half a file
    spec = importlib.util.spec_from_file_location(name, path)
    assert spec and spec.loader
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module  # numba's cache re-imports the module by name; an engine imports its parts so
    spec.loader.exec_module(module)
    _LOADED[name] = module
    return module
