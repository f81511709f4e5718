"""The checks that come before every test: is the record usable, is the process type right."""

from __future__ import annotations

from .result import Evidence, cannot_judge
from ._signals import Prepared


def record_gate(test: str, p: Prepared, *, needs_pv: bool = True, threshold: float | None = None) -> Evidence | None:
    """A cannot-judge `Evidence` when the record (or its PV, if needed) is unusable, else None."""
    if p.problem is not None:
        reason, note = p.problem
        return cannot_judge(test, reason, note, threshold)
    if needs_pv and not p.pv_ok:
        return cannot_judge(test, "pv_unusable", f"PV is unusable ({p.pv_reason}); the tests on OP alone (and a valve fit on a recorded stem position) judge.",
                            threshold)
    return None


def process_gate(test: str, integrating: bool | None, *, wants: bool | None,
                 threshold: float | None = None, other: str = "") -> Evidence | None:
    """A cannot-judge `Evidence` when the process type is unknown or not the one the test is for.

    ``wants`` is True (test for integrating loops), False (self-regulating) or None (either, but
    the type must be known because the test reads a different signal for each).
    """
    if integrating is None:
        return cannot_judge(test, "process_type_unknown",
                            "The process type is unknown: pass integrating=True for a level or other "
                            "integrating loop, False for a self-regulating one.", threshold)
    if wants is not None and bool(integrating) != wants:
        kind = "integrating" if integrating else "self-regulating"
        return cannot_judge(test, "wrong_process_type",
                            f"This test is for {'integrating' if wants else 'self-regulating'} loops and this "
                            f"one is {kind}" + (f"; {other} judges it instead." if other else "."), threshold)
    return None


def oscillation_gate(test: str, p: Prepared, name: str, what: str,
                     threshold: float | None = None) -> Evidence | None:
    """A cannot-judge `Evidence` when signal ``name`` does not oscillate regularly for 2+ cycles."""
    prob = p.osc(name).problem(what)
    if prob is not None:
        o = p.osc(name)
        extras = {"regularity": o.regularity, "cycles": o.cycles}
        if o.period is not None:
            extras["period_s"] = o.period * p.ts_s
        return cannot_judge(test, prob[0], prob[1], threshold, **extras)
    return None
