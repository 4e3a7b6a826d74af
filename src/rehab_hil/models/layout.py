"""The flat-array layout of a wired diagram: everything the engine's code generator reads.

A ``Diagram`` builds one ``Layout`` from its parts; ``engine.py`` generates code from the layout
alone, so the engine never imports the diagram (no import cycle) and sees plain data only.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

__all__ = ["Layout", "PartLayout", "Span", "Wire"]

# A half-open index range [start, stop) in one of the flat arrays.
Span = tuple[int, int]
# One input port's feed: the weighted signals summed into it, as (signal name, gain).
Wire = tuple[tuple[str, float], ...]


@dataclass(frozen=True)
class PartLayout:
    """One part's place in the flat arrays, its input wiring and where its kernels live.

    ``kernel_class`` is (module, qualified name) of the class whose ``output``, ``derivatives``
    and ``update`` the generated engine calls; ``kernel_modules`` are the modules their source
    depends on (the key of the class's compiled part module)."""

    name: str
    kernel_class: tuple[str, str]
    x: Span
    xd: Span
    u: Span
    p: Span
    y: Span
    wires: tuple[Wire, ...]  # one per input port, in port order
    kernel_modules: tuple[str, ...]  # the modules this class's kernels depend on

    @property
    def has_outputs(self) -> bool:
        return self.y[1] > self.y[0]

    @property
    def has_states(self) -> bool:
        return self.x[1] > self.x[0]

    @property
    def has_discrete_states(self) -> bool:
        return self.xd[1] > self.xd[0]


@dataclass(frozen=True)
class Layout:
    """A diagram's structure as flat-array indices: the whole input of code generation.

    ``producers`` maps each signal to its output slots (several slots are summed);
    ``input_names`` are the external inputs in ``uext`` order; ``order`` is the output
    evaluation order; ``kernel_modules`` are the modules whose source the kernels depend on
    (hashed into the engine's cache key so that editing a kernel recompiles)."""

    parts: tuple[PartLayout, ...]
    producers: Mapping[str, tuple[int, ...]]
    input_names: tuple[str, ...]
    order: tuple[int, ...]
    n_x: int
    n_xd: int
    n_w: int
    n_p: int
    n_sig: int
    kernel_modules: tuple[str, ...]
