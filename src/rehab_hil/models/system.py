"""Composable plant parts and the diagram that wires them into one compiled system.

A ``Part`` is a leaf system in the spirit of Drake's ``LeafSystem`` and python-control's
``NonlinearIOSystem``: it declares named inputs, continuous states, discrete states, outputs and
parameters, and supplies small numba kernels for its output, derivatives and discrete update.
A ``Diagram`` wires parts by signal name (as ``control.interconnect`` does) and generates one
numba function for the whole plant, so a closed loop at a 1 kHz step runs hundreds of times
faster than real time. A new physical effect is a new part added to the list, never an edit
to another part.

Kernel signatures (all arrays are float64 views, SI units):
    output(t, x, xd, u, p, y)        -> writes y (outputs)
    derivatives(t, x, xd, u, p, dx)  -> writes dx (continuous states)
    update(t, x, xd, u, p, xd_next)  -> writes the discrete state for the next sample
"""

from __future__ import annotations

import difflib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from types import ModuleType
from typing import ClassVar

import numpy as np

from rehab_hil.models.engine import call_holding_ctrl_c, compile_for, engine_for, kernel_modules, prepare
from rehab_hil.models.jit import njit, noop
from rehab_hil.models.layout import Layout, PartLayout

__all__ = ["Connection", "Diagram", "DiagramError", "Part", "njit"]


class DiagramError(ValueError):
    """A diagram cannot be built: unknown signal, algebraic loop, duplicate name."""


# A connection feeds one input port: a weighted sum of named signals.
Connection = str | Sequence[str | tuple[str, float]]


class Part:
    """A leaf system with declared ports, states and parameters.

    Subclasses set the class attributes and override the kernels with numba functions.
    ``feedthrough`` says whether ``output`` reads ``u``: True (every input), False (none), or the
    names of the inputs it reads (as Drake declares direct feedthrough per port; an input only
    ``update`` reads, like a PID's anti-windup, closes no algebraic loop). It decides evaluation order.
    """

    inputs: ClassVar[tuple[str, ...]] = ()
    states: ClassVar[tuple[str, ...]] = ()
    discrete_states: ClassVar[tuple[str, ...]] = ()
    outputs: ClassVar[tuple[str, ...]] = ()
    params: ClassVar[tuple[str, ...]] = ()
    feedthrough: ClassVar[bool | tuple[str, ...]] = True

    output = staticmethod(noop)
    derivatives = staticmethod(noop)
    update = staticmethod(noop)

    def __init__(
        self,
        name: str,
        *,
        connect: Mapping[str, Connection] | None = None,
        rename: Mapping[str, str] | None = None,
        x0: Sequence[float] | None = None,
        xd0: Sequence[float] | None = None,
        **param_values: float,
    ) -> None:
        self.name = name
        missing = [p for p in self.params if p not in param_values]
        extra = [p for p in param_values if p not in self.params]
        if missing or extra:
            raise DiagramError(
                f"part {name!r} ({type(self).__name__}): missing parameters {missing}, "
                f"unknown parameters {extra}"
            )
        self.param_values = np.array([float(param_values[p]) for p in self.params], dtype=float)
        connect = dict(connect or {})
        bad = [k for k in connect if k not in self.inputs]
        if bad:
            raise DiagramError(f"part {name!r} has no inputs {bad}; inputs are {self.inputs}")
        self.connections: dict[str, list[tuple[str, float]]] = {}
        for port in self.inputs:
            spec = connect.get(port, port)
            terms = [spec] if isinstance(spec, str) else list(spec)
            self.connections[port] = [(s, 1.0) if isinstance(s, str) else (s[0], float(s[1])) for s in terms]
        rename = dict(rename or {})
        bad = [k for k in rename if k not in self.outputs]
        if bad:
            raise DiagramError(f"part {name!r} has no outputs {bad}; outputs are {self.outputs}")
        self.signal_names = tuple(rename.get(o, o) for o in self.outputs)
        self.x0 = np.zeros(len(self.states)) if x0 is None else np.asarray(x0, dtype=float)
        self.xd0 = np.zeros(len(self.discrete_states)) if xd0 is None else np.asarray(xd0, dtype=float)
        if self.x0.shape != (len(self.states),) or self.xd0.shape != (len(self.discrete_states),):
            raise DiagramError(f"part {name!r}: initial state has the wrong length")

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.name!r})"


class Diagram:
    """Parts wired by signal name; a signal declared summable is the sum of all its producers.

    ``inputs`` names the signals allowed to come from outside: a part input that no part
    produces must be declared there, so a misspelled signal is an error, not an input of zero.
    The declared inputs that some part reads and no part produces are the diagram's external
    inputs (``input_names``, in order of first use), as Drake refuses an unconnected port.

    ``sums`` names the signals several parts may add onto (the torques on one joint, heat flows,
    a feedforward plus a feedback effort): a signal produced by two or more parts that is not
    declared there is refused, naming the parts, so two un-renamed parts never add up silently.
    A declared sum that no part produces is allowed (an effect may be the one that feeds it).
    """

    def __init__(self, parts: Sequence[Part], inputs: Sequence[str], *, sums: Sequence[str] = ()) -> None:
        names = [p.name for p in parts]
        dup = {n for n in names if names.count(n) > 1}
        if dup:
            raise DiagramError(f"duplicate part names {sorted(dup)}")
        if isinstance(inputs, str):
            raise DiagramError(f"inputs must be a sequence of signal names, not the string {inputs!r}")
        if isinstance(sums, str):
            raise DiagramError(f"sums must be a sequence of signal names, not the string {sums!r}")
        self.parts = list(parts)
        self.declared_inputs: tuple[str, ...] = tuple(inputs)
        self.sums: tuple[str, ...] = tuple(dict.fromkeys(sums))
        self.producers: dict[str, list[int]] = {}  # signal -> flat output slots
        owners: dict[str, list[str]] = {}  # signal -> producing part names, one per slot
        spans = []
        xo = xdo = uo = po = slot = 0
        for part in self.parts:
            for i, sname in enumerate(part.signal_names):
                self.producers.setdefault(sname, []).append(slot + i)
                owners.setdefault(sname, []).append(part.name)
            ends = (xo + len(part.states), xdo + len(part.discrete_states), uo + len(part.inputs),
                    po + len(part.params), slot + len(part.outputs))
            spans.append(((xo, ends[0]), (xdo, ends[1]), (uo, ends[2]), (po, ends[3]), (slot, ends[4])))
            xo, xdo, uo, po, slot = ends
        self._check_sums(owners)
        self.n_x, self.n_xd, self.n_w, self.n_p, self.n_sig = xo, xdo, uo, po, slot
        self.input_names: tuple[str, ...] = self._external_inputs()
        self.signal_names: tuple[str, ...] = tuple(self.producers)
        self.state_names = tuple(f"{p.name}.{s}" for p in self.parts for s in p.states)
        self.discrete_state_names = tuple(f"{p.name}.{s}" for p in self.parts for s in p.discrete_states)
        self.param_names = tuple(f"{p.name}.{s}" for p in self.parts for s in p.params)
        self.order = self._evaluation_order([y for *_, y in spans])
        self.layout = self._flat_layout(spans)

    def _flat_layout(self, spans: Sequence[tuple[tuple[int, int], ...]]) -> Layout:
        """The structure handed to the engine: slices, wiring, order and the kernels' modules."""
        modules = {cls: kernel_modules([cls], framework=Part) for cls in {type(part) for part in self.parts}}
        parts = tuple(
            PartLayout(name=part.name, kernel_class=(type(part).__module__, type(part).__qualname__),
                       x=x, xd=xd, u=u, p=p, y=y,
                       wires=tuple(tuple(part.connections[port]) for port in part.inputs),
                       kernel_modules=modules[type(part)])
            for part, (x, xd, u, p, y) in zip(self.parts, spans, strict=True)
        )
        return Layout(
            parts=parts,
            producers={s: tuple(slots) for s, slots in self.producers.items()},
            input_names=self.input_names,
            order=tuple(self.order),
            n_x=self.n_x, n_xd=self.n_xd, n_w=self.n_w, n_p=self.n_p, n_sig=self.n_sig,
            kernel_modules=tuple(sorted({m for ms in modules.values() for m in ms})),
        )

    def _check_sums(self, owners: Mapping[str, Sequence[str]]) -> None:
        """Refuse a signal with several producers unless it is declared summable."""
        for sname, parts in owners.items():
            if len(parts) < 2 or sname in self.sums:
                continue
            distinct = list(dict.fromkeys(parts))
            if len(distinct) == 1:
                who = f"{len(parts)} outputs of part {distinct[0]!r}"
            else:
                quoted = [repr(p) for p in distinct]
                who = f"parts {', '.join(quoted[:-1])} and {quoted[-1]}"
            raise DiagramError(f"signal {sname!r} is produced by {who}; only signals declared summable "
                               f"(sums=...) may have several producers")

    def _external_inputs(self) -> tuple[str, ...]:
        """Unproduced signals the parts read, in order of first use; undeclared ones are refused."""
        declared = self.declared_inputs
        external: list[str] = []
        for part in self.parts:
            for port, terms in part.connections.items():
                for sname, _ in terms:
                    if sname in self.producers or sname in external:
                        continue
                    if sname not in declared:
                        raise DiagramError(self._undeclared_message(part, port, sname))
                    external.append(sname)
        return tuple(external)

    def _undeclared_message(self, part: Part, port: str, sname: str) -> str:
        known = list(dict.fromkeys([*self.producers, *self.declared_inputs]))
        close = difflib.get_close_matches(sname, known, n=1)
        hint = f"; did you mean {close[0]!r}?" if close else "; if it comes from outside, declare it in inputs"
        return (f"part {part.name!r} input {port!r} reads {sname!r}, which no part produces and is not "
                f"a declared input{hint}")

    def _evaluation_order(self, outputs: Sequence[tuple[int, int]]) -> list[int]:
        """Topological order of output evaluation; feedthrough parts after their sources."""
        slot_owner = {}
        for k, y in enumerate(outputs):
            for s in range(*y):
                slot_owner[s] = k
        deps: dict[int, set[int]] = {}
        for k, part in enumerate(self.parts):
            deps[k] = set()
            direct = part.inputs if part.feedthrough is True else part.feedthrough or ()
            for port in direct:
                for sname, _ in part.connections[port]:
                    for s in self.producers.get(sname, []):
                        deps[k].add(slot_owner[s])
        order: list[int] = []
        state: dict[int, int] = {}

        def visit(k: int, path: list[int]) -> None:
            if state.get(k) == 2:
                return
            if state.get(k) == 1:
                loop = " -> ".join(self.parts[i].name for i in [*path, k])
                raise DiagramError(f"algebraic loop through feedthrough parts: {loop}")
            state[k] = 1
            for d in sorted(deps[k]):
                if d != k:
                    visit(d, [*path, k])
                else:
                    raise DiagramError(f"part {self.parts[k].name!r} feeds its own input")
            state[k] = 2
            order.append(k)

        for k in range(len(self.parts)):
            visit(k, [])
        return order

    def param_index(self, qualified: str) -> int:
        """Index of ``"part.param"`` in the flat parameter vector."""
        try:
            return self.param_names.index(qualified)
        except ValueError:
            raise DiagramError(f"no parameter {qualified!r}; have {self.param_names}") from None

    def signal_slots(self, name: str) -> list[int]:
        if name not in self.producers:
            raise DiagramError(f"no signal {name!r}; have {self.signal_names}")
        return self.producers[name]

    def initial_params(self) -> np.ndarray:
        return np.concatenate([p.param_values for p in self.parts]) if self.parts else np.zeros(0)

    def initial_state(self) -> tuple[np.ndarray, np.ndarray]:
        x = np.concatenate([p.x0 for p in self.parts]) if self.n_x else np.zeros(0)
        xd = np.concatenate([p.xd0 for p in self.parts]) if self.n_xd else np.zeros(0)
        return x, xd

    def compile(self, dt: float, substeps: int = 1) -> CompiledSystem:
        return CompiledSystem(self, dt, substeps)


class CompiledSystem:
    """A diagram bound to a compiled engine for a fixed sample step ``dt`` and RK4 ``substeps``."""

    def __init__(self, diagram: Diagram, dt: float, substeps: int = 1) -> None:
        if not (dt > 0 and np.isfinite(dt)):
            raise DiagramError(f"step dt must be positive and finite, got {dt}")
        if int(substeps) < 1:
            raise DiagramError(f"substeps must be >= 1, got {substeps}")
        self.diagram = diagram
        self.dt = float(dt)
        self.substeps = int(substeps)
        self._engine = engine_for(diagram.layout)
        self._prepared = False
        self.params = diagram.initial_params()
        self.x0, self.xd0 = diagram.initial_state()

    @property
    def engine(self) -> ModuleType:
        """The compiled module, for a caller that steps it by hand: its ``sample``, ``read_outputs`` and
        ``integrate`` compiled (or loaded) here, before that caller's loop, not at its first step there."""
        if not self._prepared:
            prepare(self._engine, "sample", "read_outputs", "integrate")
            self._prepared = True
        return self._engine

    @property
    def input_names(self) -> tuple[str, ...]:
        return self.diagram.input_names

    def out_slots(self, names: Sequence[str]) -> np.ndarray:
        rows = [self.diagram.signal_slots(n) for n in names]
        width = max((len(r) for r in rows), default=1)
        out = -np.ones((len(rows), width), dtype=np.int64)
        for i, r in enumerate(rows):
            out[i, : len(r)] = r
        return out

    def input_matrix(self, n_steps: int, inputs: Mapping[str, float | np.ndarray] | None) -> np.ndarray:
        """Stack named external inputs (scalars or per-step arrays) into an (n, m) matrix."""
        inputs = dict(inputs or {})
        unknown = [k for k in inputs if k not in self.input_names]
        if unknown:
            raise DiagramError(f"unknown inputs {unknown}; the system's inputs are {self.input_names}")
        U = np.zeros((n_steps, len(self.input_names)))
        for j, name in enumerate(self.input_names):
            v = np.asarray(inputs.get(name, 0.0), dtype=float)
            if v.ndim == 0 or v.shape == (n_steps,):
                U[:, j] = v
            else:
                raise DiagramError(f"input {name!r} has shape {v.shape}, expected () or ({n_steps},)")
        return U

    def workspace(self) -> tuple[np.ndarray, ...]:
        d = self.diagram
        return (np.zeros(max(d.n_sig, 1)), np.zeros(max(d.n_w, 1)), np.zeros((5, d.n_x)),
                np.zeros(max(d.n_xd, 1)))

    def simulate(
        self,
        n_steps: int,
        inputs: Mapping[str, float | np.ndarray] | None = None,
        outputs: Sequence[str] | None = None,
        params: np.ndarray | None = None,
        x0: np.ndarray | None = None,
        xd0: np.ndarray | None = None,
    ) -> SimulationResult:
        """Run ``n_steps`` samples; inputs are held over each step (zero-order hold).

        Outputs at ``t[k]`` are sampled before the step from ``t[k]`` to ``t[k] + dt``."""
        outputs = list(outputs or self.diagram.signal_names)
        U = self.input_matrix(n_steps, inputs)
        P = self.params if params is None else np.asarray(params, dtype=float)
        if P.shape != self.params.shape:
            raise DiagramError(f"parameter vector has shape {P.shape}, expected {self.params.shape}")
        X, Y = self.run_arrays((self.x0 if x0 is None else np.asarray(x0, float)).copy(),
                               (self.xd0 if xd0 is None else np.asarray(xd0, float)).copy(),
                               U, P, self.out_slots(outputs), self.workspace())
        t = np.arange(n_steps) * self.dt
        return SimulationResult(t, {n: Y[:, i] for i, n in enumerate(outputs)}, X, self.diagram.state_names)

    def run_arrays(self, x: np.ndarray, xd: np.ndarray, U: np.ndarray, P: np.ndarray, out_slots: np.ndarray,
                   workspace: tuple[np.ndarray, ...]) -> tuple[np.ndarray, np.ndarray]:
        """The compiled loop on raw arrays (``x`` and ``xd`` advanced in place): the states and outputs per
        step. For callers that keep their own workspace; a Ctrl-C during it is raised when it returns."""
        # a Ctrl-C raised inside numba's return could crash the interpreter (see call_holding_ctrl_c)
        args = (x, xd, U, P, self.dt, self.substeps, out_slots, *workspace)
        if not self._engine.simulate.overloads:  # the first run in this process: compile or load the loop
            compile_for(self._engine, "simulate", args)
        return call_holding_ctrl_c(self._engine.simulate, *args)

    def stepper(self, outputs: Sequence[str] | None = None, params: np.ndarray | None = None) -> Stepper:
        return Stepper(self, outputs, params)


@dataclass
class SimulationResult:
    """Time base and named output signals (each sampled at ``t``) plus the state history."""

    t: np.ndarray
    signals: dict[str, np.ndarray]
    states: np.ndarray
    state_names: tuple[str, ...]

    def __getitem__(self, name: str) -> np.ndarray:
        return self.signals[name]

    def state(self, qualified: str) -> np.ndarray:
        return self.states[:, self.state_names.index(qualified)]


class Stepper:
    """Advances a compiled system one sample at a time (for simulated devices and the loop)."""

    def __init__(self, system: CompiledSystem, outputs: Sequence[str] | None, params: np.ndarray | None) -> None:
        self.system = system
        self.outputs = list(outputs or system.diagram.signal_names)
        self._slots = system.out_slots(self.outputs)
        self.params = (system.params if params is None else np.asarray(params, float)).copy()
        self._engine = system._engine
        prepare(self._engine, "step")  # compiled here, not at the first step of a device's loop
        self.reset()

    def reset(self) -> None:
        self.t = 0.0
        self.x = self.system.x0.copy()
        self.xd = self.system.xd0.copy()
        self._ws = self.system.workspace()
        self._y = np.zeros(len(self.outputs))

    def step(self, uext: np.ndarray) -> np.ndarray:
        """Sample outputs at the current time with inputs ``uext``, then advance one ``dt``."""
        s = self.system
        self._engine.step(self.t, self.x, self.xd, np.asarray(uext, float), self.params, s.dt, s.substeps,
                      self._slots, self._y, *self._ws)
        self.t += s.dt
        return self._y.copy()

    def advance(self, uext: np.ndarray) -> np.ndarray:
        """``step`` for a caller in a hot loop (a simulated device's tick): ``uext`` already a float
        array, and the outputs returned in the stepper's own buffer, overwritten by the next call."""
        s = self.system
        s.engine.step(self.t, self.x, self.xd, uext, self.params, s.dt, s.substeps, self._slots, self._y, *self._ws)
        self.t += s.dt
        return self._y
