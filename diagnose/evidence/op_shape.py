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
tests, and its note says so. Setpoint steps make the control error square-like too, so the test
does not judge a record whose setpoint steps (a continuously moving setpoint, a cascade master's
output, is judged).
"""

from __future__ import annotations

import numpy as np

from ._gates import record_gate
from ._signals import Prepared
from .curve_fit import HIGH, LOW, fit_shape
from .result import NO_STICTION, STICTION, UNDETERMINED, Evidence, cannot_judge, graded

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
        Setpoint. When it moves in steps the test cannot judge: each step makes the control error
        square for a while, and OP's shape then follows the steps, not the valve.
    integrating
        Not used; accepted for a uniform signature.
    """
    return _op_shape(Prepared(op, pv, ts_s, sp))


#: A setpoint that changes on at most this share of the samples moves in steps (an operator's or a
#: sequence's), not continuously (a cascade master's output).
SP_STEP_SHARE = 0.02


def setpoint_steps(sp) -> int:
    """How many times a stepping setpoint moves (0 when there is no setpoint, it never moves, or
    it moves on more than `SP_STEP_SHARE` of the samples: continuously, not in steps)."""
    if sp is None:
        return 0
    s = np.asarray(sp, dtype=float)
    if s.ndim != 1 or s.shape[0] < 2 or not np.all(np.isfinite(s)):
        return 0
    d = np.abs(np.diff(s))
    tol = 1e-6 * max(1.0, float(np.max(np.abs(s))))
    k = int(np.count_nonzero(d > tol))
    return k if 0 < k <= SP_STEP_SHARE * d.shape[0] else 0


def _op_shape(p: Prepared) -> Evidence:
    gate = record_gate(TEST, p, needs_pv=False, threshold=HIGH)
    if gate is not None:
        return gate
    steps = setpoint_steps(p.sp)
    if steps:
        # each step makes the control error square for a while: a healthy loop's OP then ramps
        # between sharp turns too, and the shape no longer says anything of the valve
        return cannot_judge(TEST, "setpoint_steps",
                            f"The setpoint steps {steps} times in the record: OP's ramps and turns follow those "
                            "steps, so its shape says nothing of the valve; judge a window without setpoint "
                            "changes.", HIGH)
    res = fit_shape(p, "op", TEST, "OP")
    if isinstance(res, Evidence):
        return res
    si, ex = res
    return graded(TEST, si, HIGH, LOW, {
        STICTION: (f"OP alone: a regular saw-tooth with straight ramps (SI {si:.2f} >= {HIGH}), as a sticky valve "
                   "forces on the controller; weaker evidence than PV-based tests, since any square-like error "
                   "gives the same shape."),
        NO_STICTION: (f"OP alone: the oscillation is smooth, close to a sinusoid (SI {si:.2f}); not the ramps a "
                      "sticky valve forces; weaker evidence than PV-based tests."),
        UNDETERMINED: (f"OP alone: the oscillation is between a triangle and a sinusoid (SI {si:.2f}); without PV "
                       "this cannot be told apart.")}, ex)
