"""The candidate terms of a search: the library effects that attach to the plant and its declared parameters."""

from __future__ import annotations

from typing import Any

from rehab_hil.discrepancy.fitting import Term, effect_term, parameter_term
from rehab_hil.discrepancy.parameters import parameter_terms
from rehab_hil.discrepancy.replay import Replay

__all__ = ["candidate_terms"]


def candidate_terms(replay: Replay, options: Any, refinements: bool = False) -> list[Term]:
    """The library effects that attach to the plant, then (``options.parameters``: ``workflow.Options``)
    its declared parameters.
    ``refinements``: also the effects that generalise another (``Effect.refines``: a level per direction),
    which the set search compares with what they refine; the rounds of ``Search`` leave them out (one
    record of one direction cannot tell them, and on EMPS a level per direction took the place of the
    published Coulomb friction plus offset in one round)."""
    terms: list[Term] = [effect_term(replay, e) for e in replay.candidates if refinements or not e.refines]
    if options.parameters:
        terms += [parameter_term(p) for p in parameter_terms(replay)]
    return terms
