"""Judging from OP alone, for when PV is unusable (flat, dead, bad).

A sticky valve in a self-regulating loop leaves its mark on OP itself: while the valve sticks the
error is constant and the integral action ramps OP in a straight line; when the valve jumps, the
error changes sign and OP turns sharply. OP becomes a regular triangle or saw-tooth. The test is
He et al.'s (2007) triangle-versus-sinusoid fit applied to OP's half-cycles (the same SI and the
same thresholds, 0.4 and 0.6), and it needs a regular oscillation of OP (Thornhill's r > 1).

What it can tell: that OP oscillates regularly with straight ramps and sharp turns, the shape a
sticky valve forces on a PI controller. What it cannot: OP takes the same shape whenever the
control error is square-like, whatever makes it so; an on/off disturbance upstream, a level loop
whose inflow switches, or any integrating loop whose PI controller ramps OP between sharp
reversals give triangles with a healthy valve. In an integrating loop a sticky valve gives OP
parabolic arcs rather than straight ramps, which the fit reads as undetermined more often. Without
PV the test cannot see the valve stand still, so its word is weaker evidence than the PV-based
tests, and its note says so. Setpoint steps make the control error square-like too, so where the
setpoint steps the test judges only the longest stretch between steps, less the loop's response
to the step at its start (a continuously moving setpoint, a cascade master's output, does not
step, and the whole record is judged).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ._gates import record_gate
from ._signals import Prepared
from .curve_fit import HIGH, LOW, fit_shape
from .result import NO_STICTION, STICTION, UNDETERMINED, Evidence, graded

TEST = "op_shape"


def op_shape(op, pv=None, ts_s: float = 1.0, *, sp=None, integrating: bool | None = None) -> Evidence:
    """OP-only shape judgement: He's triangle-versus-sinusoid index of OP.

    Parameters
    ----------
    op : array (n,)
        Controller output, % of span.
    pv : array (n,), optional
        Not used (the test is for when PV is unusable); accepted for a uniform signature.
    ts_s : float
        Sample period, seconds.
    sp : array (n,), optional
        Setpoint. When it moves in steps only the longest stretch between steps is judged: each
        step makes the control error square for a while, and OP's shape then follows the step,
        not the valve.
    integrating
        Not used; accepted for a uniform signature.
    """
    return _op_shape(Prepared(op, pv, ts_s, sp))


#: A setpoint that changes on at most this share of the samples moves in steps (an operator's or a
#: sequence's), not continuously (a cascade master's output).
SP_STEP_SHARE = 0.02
#: Share of each stretch between setpoint steps left out at its start: the loop's response to the
#: step, which ramps OP like a stick-slip cycle would.
SETTLE_SHARE = 0.1


def setpoint_steps(sp) -> np.ndarray:
    """Indices of the samples at which a stepping setpoint takes a new value (empty when there is
    no setpoint, it never moves, or it moves on more than `SP_STEP_SHARE` of the samples:
    continuously, not in steps)."""
    none = np.zeros(0, dtype=int)
    if sp is None:
        return none
    s = np.asarray(sp, dtype=float)
    if s.ndim != 1 or s.shape[0] < 2 or not np.all(np.isfinite(s)):
        return none
    d = np.abs(np.diff(s))
    moves = np.flatnonzero(d > 1e-6 * max(1.0, float(np.max(np.abs(s))))) + 1
    return moves if moves.shape[0] <= SP_STEP_SHARE * d.shape[0] else none


def steady_stretch(n: int, steps: np.ndarray) -> tuple[int, int]:
    """The longest stretch ``[start, end)`` of ``n`` samples between setpoint steps, its start
    moved on by `SETTLE_SHARE` of its length when a step begins it."""
    edges = np.concatenate([[0], steps, [n]])
    k = int(np.argmax(np.diff(edges)))
    start, end = int(edges[k]), int(edges[k + 1])
    return (start + int(SETTLE_SHARE * (end - start)) if start > 0 else start), end


def _op_shape(p: Prepared) -> Evidence:
    gate = record_gate(TEST, p, needs_pv=False, threshold=HIGH)
    if gate is not None:
        return gate
    steps = setpoint_steps(p.sp)
    where = ""
    if steps.shape[0]:
        # each step makes the control error square for a while, and a healthy loop's OP then ramps
        # between sharp turns too: only the longest stretch without a step is judged
        a, b = steady_stretch(p.n, steps)
        k = steps.shape[0]
        where = (f" (in samples {a}-{b}, the longest stretch without a setpoint step: the setpoint steps "
                 f"{'once' if k == 1 else f'{k} times'})")
        p = Prepared(p.op[a:b], None, p.ts_s)
        gate = record_gate(TEST, p, needs_pv=False, threshold=HIGH)
        if gate is not None:
            return _located(gate, where)
    res = fit_shape(p, "op", TEST, "OP")
    if isinstance(res, Evidence):
        return _located(res, where)
    si, ex = res
    return _located(graded(TEST, si, HIGH, LOW, {
        STICTION: (f"OP alone: a regular saw-tooth with straight ramps (SI {si:.2f} >= {HIGH}), as a sticky valve "
                   "forces on the controller; weaker evidence than PV-based tests, since any square-like error "
                   "gives the same shape."),
        NO_STICTION: (f"OP alone: the oscillation is smooth, close to a sinusoid (SI {si:.2f}); not the ramps a "
                      "sticky valve forces; weaker evidence than PV-based tests."),
        UNDETERMINED: (f"OP alone: the oscillation is between a triangle and a sinusoid (SI {si:.2f}); without PV "
                       "this cannot be told apart.")}, ex), where)


def _located(ev: Evidence, where: str) -> Evidence:
    """``ev`` with ``where`` (which part of the record was judged) at the end of its first sentence."""
    if not where:
        return ev
    head, dot, tail = ev.note.partition(". ")
    if not dot:
        head, tail = ev.note.rstrip("."), ""
    return replace(ev, note=head + where + "." + (" " + tail if tail else ""))
