"""A fitted value that ended on its bound is said to be there, not reported as a finding.

A bounded fit that stops on a bound has not found a value: the data pushed past the range the
term allows (issue 38: a servo's inertia at +100 %, the top of a relative error's range, printed as
"off by +100 %"). ``at_bound`` names each such value of the chosen terms and of the joint
identification, with the bound; the verdict words it as what it is.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from rehab_hil.discrepancy.fitting import Fit, Term
from rehab_hil.effects import EffectParam

__all__ = ["BOUND_SHARE", "at_bound", "on_bound", "sentence"]

BOUND_SHARE = 0.01  # within this share of the parameter's range from a bound counts as on it


def on_bound(p: EffectParam, value: float) -> str | None:
    """"lower" or "upper" when ``value`` sits on that bound of ``p`` (a magnitude at its "off" value
    is not on a bound: it is off, and the term is dropped elsewhere), else None."""
    span = p.upper - p.lower
    if value <= p.lower + BOUND_SHARE * span and p.off != p.lower:
        return "lower"
    if value >= p.upper - BOUND_SHARE * span:
        return "upper"
    return None


def sentence(label: str, p: EffectParam, value: float, side: str) -> str:
    """'<label> ended on its upper bound (+100 %): ...' in the parameter's own terms."""
    shown = f"{100 * value:+.0f} %" if p.name == "error_fraction" else f"{value:.4g}"
    return (f"{label} ended on its {side} bound ({shown}): the records push it past the range allowed, so its "
            "value is not a finding (another term may be missing, or the records do not determine it)")


def at_bound(terms: Sequence[Term], fits: Sequence[Fit], joint: Any = None) -> list[str]:
    """Sentences for every chosen term's parameter (``terms``/``fits``) and every joint-identification
    value (``joint.at_bound``) that ended on a bound; each label once."""
    out: dict[str, str] = {}
    for t, f in zip(terms, fits, strict=True):
        for p in t.params:
            side = on_bound(p, f.params[p.name])
            label = t.name if t.kind == "parameter" else f"{t.name}.{p.name}"
            if side:
                out[label] = sentence(label, p, f.params[p.name], side)
    for label, (p, value, side) in (getattr(joint, "at_bound", None) or {}).items():
        out.setdefault(label, sentence(label, p, value, side))
    return list(out.values())
