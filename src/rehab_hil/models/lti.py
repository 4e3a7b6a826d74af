"""Linear time-invariant SISO parts: a transfer function realised as a state-space ``Part``.

An identified model such as seed 001 eq 2a-2b (TF1: power -> temperature, TF2: temperature ->
force) is a deviation model about an operating point: y = y0 + C x + D (u - u0), x' = A x + B (u - u0).
``StateSpace1``..``StateSpace3`` hold A, B, C, D, u0 and y0 as parameters, so one compiled
diagram can be re-run with another transfer function of the same order through ``params=``.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from rehab_hil.models.system import Part, njit

if TYPE_CHECKING:  # python-control takes seconds to import: only where it is used
    import control

__all__ = ["MAX_ORDER", "PeakAfterCut", "StateSpace1", "StateSpace2", "StateSpace3", "lti_part", "modal_form",
           "peak_after_cut_part", "state_space_params"]

MAX_ORDER = 3


@njit
def _ss_output(x, u, p, y):
    """y = y0 + C x + D (u - u0); parameter layout A (n*n, row-major), B (n), C (n), D, u0, y0."""
    n = x.shape[0]
    base = n * n + n
    acc = p[base + n + 2] + p[base + n] * (u[0] - p[base + n + 1])
    for i in range(n):
        acc += p[base + i] * x[i]
    y[0] = acc


@njit
def _ss_derivatives(x, u, p, dx):
    """x' = A x + B (u - u0)."""
    n = x.shape[0]
    du = u[0] - p[n * n + 2 * n + 1]
    for i in range(n):
        acc = p[n * n + i] * du
        for j in range(n):
            acc += p[i * n + j] * x[j]
        dx[i] = acc


def _param_names(n: int) -> tuple[str, ...]:
    a = tuple(f"a{i}{j}" for i in range(1, n + 1) for j in range(1, n + 1))
    return (*a, *(f"b{i}" for i in range(1, n + 1)), *(f"c{i}" for i in range(1, n + 1)), "d", "u0", "y0")


class _StateSpace(Part):
    inputs = ("u",)
    outputs = ("y",)
    feedthrough = True  # D may be non-zero (seed 001 TF2 and TF_TP1 are biproper)

    @staticmethod
    @njit
    def output(t, x, xd, u, p, y):
        _ss_output(x, u, p, y)

    @staticmethod
    @njit
    def derivatives(t, x, xd, u, p, dx):
        _ss_derivatives(x, u, p, dx)


class StateSpace1(_StateSpace):
    """First-order SISO state-space part (parameters a11, b1, c1, d, u0, y0)."""

    states = ("x1",)
    params = _param_names(1)


class StateSpace2(_StateSpace):
    """Second-order SISO state-space part."""

    states = ("x1", "x2")
    params = _param_names(2)


class StateSpace3(_StateSpace):
    """Third-order SISO state-space part."""

    states = ("x1", "x2", "x3")
    params = _param_names(3)


_CLASSES = {1: StateSpace1, 2: StateSpace2, 3: StateSpace3}


def state_space_params(tf: control.TransferFunction, u0: float = 0.0, y0: float = 0.0) -> dict[str, float]:
    """Parameters of the ``StateSpace<n>`` part realising the proper SISO ``tf`` (n = its order),
    in controllable canonical form (python-control's ``tf2ss``)."""
    import control

    ss = control.tf2ss(tf)
    n = ss.nstates
    if ss.ninputs != 1 or ss.noutputs != 1:
        raise ValueError("only SISO transfer functions can be realised as a StateSpace part")
    if not 1 <= n <= MAX_ORDER:
        raise ValueError(f"transfer function order {n} not in 1..{MAX_ORDER}")
    A, B, C, D = (np.asarray(m, float) for m in (ss.A, ss.B, ss.C, ss.D))
    values = [*A.ravel(), *B.ravel(), *C.ravel(), float(D[0, 0]), float(u0), float(y0)]
    return dict(zip(_param_names(n), values, strict=True))


def lti_part(name: str, tf: control.TransferFunction, *, u0: float = 0.0, y0: float = 0.0,
             **kwargs: Any) -> Part:
    """A ``StateSpace<n>`` part for ``tf`` with operating point (u0, y0); ``kwargs`` go to ``Part``
    (``connect``, ``rename``)."""

    params = state_space_params(tf, u0, y0)
    n = sum(1 for k in params if k.startswith("b"))
    part = _CLASSES[n](name, **kwargs, **params)
    if params["d"] == 0.0:  # strictly proper: the output does not read the input (no algebraic loop)
        part.feedthrough = False
    return part


class PeakAfterCut(Part):
    """The most a strictly proper LTI part's output can still rise to if its input returned to its
    operating point now: y0 + the sum of its modes' positive parts (each real mode decays
    monotonically, so no sum of them exceeds that). A mode that falls as the input rises (seed 001's
    TF_TP002: -2.7 C/W at 2 1/s beside +55 C/W at 0.06 1/s) hides heat while the input is on and gives
    it back once it is cut; the temperature a ceiling must keep below is this, not the output.
    The modes run in parallel with the part they copy (modal form, up to ``MAX_ORDER``; unused modes
    have zero gain)."""

    inputs = ("u",)
    states = ("z1", "z2", "z3")
    outputs = ("peak",)
    params = ("lam1", "lam2", "lam3", "b1", "b2", "b3", "c1", "c2", "c3", "u0", "y0")
    feedthrough = False

    @staticmethod
    @njit
    def output(t, x, xd, u, p, y):
        acc = p[10]
        for i in range(3):
            acc += max(p[6 + i] * x[i], 0.0)
        y[0] = acc

    @staticmethod
    @njit
    def derivatives(t, x, xd, u, p, dx):
        du = u[0] - p[9]
        for i in range(3):
            dx[i] = p[i] * x[i] + p[3 + i] * du


def modal_form(part: Part) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None:
    """(poles, modal input gains b, modal output gains c, the map from the part's state to the modal one)
    of a ``StateSpace<n>`` part with real, stable poles; None otherwise (modes that oscillate)."""
    if not isinstance(part, _StateSpace):
        return None
    values = dict(zip(part.params, part.param_values, strict=True))
    n = len(part.states)
    A = np.array([values[f"a{i}{j}"] for i in range(1, n + 1) for j in range(1, n + 1)]).reshape(n, n)
    B = np.array([values[f"b{i}"] for i in range(1, n + 1)])
    C = np.array([values[f"c{i}"] for i in range(1, n + 1)])
    lam, V = np.linalg.eig(A)
    if np.any(np.abs(lam.imag) > 1e-12) or np.any(lam.real >= 0.0):
        return None
    lam, V = lam.real, V.real
    to_modal = np.linalg.inv(V)
    return lam, to_modal @ B, C @ V, to_modal


def peak_after_cut_part(name: str, part: Part, **kwargs: Any) -> Part | None:
    """A ``PeakAfterCut`` copying ``part`` (a ``StateSpace<n>``, started at rest), or None where the
    bound does not hold: an output that reads its input (D != 0) or modes that oscillate. Its states
    are the modal ones of ``part``'s (``modal_form``'s map), so one follows the other."""
    form = modal_form(part)
    if form is None:
        return None
    values = dict(zip(part.params, part.param_values, strict=True))
    if values["d"] != 0.0 or np.any(part.x0 != 0.0):
        return None
    lam, b, c, _ = form
    n = lam.size
    pad = [0.0] * (MAX_ORDER - n)
    modal = dict(zip(PeakAfterCut.params, [*lam, *[-1.0] * (MAX_ORDER - n), *b, *pad, *c, *pad,
                                           values["u0"], values["y0"]], strict=True))
    return PeakAfterCut(name, **kwargs, **modal)
