"""Singhal and Salsbury's (2005) area-peak ratio of the control error.

In a self-regulating loop a sticky valve jumps, the process output then moves like a step
response and keeps going until the next jump: in each half-cycle of the control error, the error
climbs quickly and stays near its extreme for most of the half-cycle, then the next jump brings it
back fast. The peak of the half-cycle therefore comes late and the area before the peak is larger
than the area after it. For a sinusoid the two areas are equal. With A1 the area of a half-cycle
before its peak and A2 after it,

    R = sum A1 / sum A2     (over all half-cycles)

R > 1 points to stiction, R near 1 to a linear cause (Singhal and Salsbury 2005). Noise and a
finite number of cycles move R by several per cent either way, so this tool reads R >= 1.25 as
stiction, R <= 1.1 as no stiction and the band between as undetermined: the paper's rule is the
inequality R > 1, the band is this tool's.
"""

from __future__ import annotations

import numpy as np

from ._gates import oscillation_gate, process_gate, record_gate
from ._signals import Prepared, lowpass, sample_range, segment_matrix
from .result import NO_STICTION, STICTION, UNDETERMINED, Evidence, cannot_judge, graded

TEST = "singhal_area"
HIGH = 1.25     # R at or above: stiction
LOW = 1.1       # R at or below: no stiction
MIN_HALVES = 4
SMOOTH_HARMONICS = 10.0


def area_ratio(e: np.ndarray, c_start: np.ndarray, c_end: np.ndarray) -> tuple[float, float, float]:
    """``(R, sum A1, sum A2)`` of the half-cycles of ``e`` between zero crossings ``c_start`` and
    ``c_end`` (fractional sample positions).

    The areas are those under the straight-line interpolation of ``|e|`` from crossing to
    crossing, split at the peak located between samples (parabola through the largest sample and
    its neighbours): at a few samples per half-cycle, splitting at a sample would tilt R by where
    the samples happen to fall.
    """
    start, end = sample_range(c_start, c_end)
    Y, M = segment_matrix(np.abs(e), start, end)
    length = end - start
    rows = np.arange(Y.shape[0])
    k = np.argmax(np.where(M, Y, -np.inf), axis=1)
    j = np.arange(Y.shape[1])[None, :]
    # trapezoids between consecutive samples inside the half-cycle, and the end triangles
    trap = 0.5 * (Y[:, :-1] + Y[:, 1:]) * M[:, 1:]
    total = trap.sum(axis=1) + 0.5 * (start - c_start) * Y[:, 0] + 0.5 * (c_end - (end - 1)) * Y[rows, length - 1]
    a1 = np.sum(np.where(j[:, :-1] < k[:, None], trap, 0.0), axis=1) + 0.5 * (start - c_start) * Y[:, 0]
    # the peak between samples, from the parabola through the largest sample and its neighbours
    inner = (k > 0) & (k < length - 1)
    km, kp = np.maximum(k - 1, 0), np.minimum(k + 1, Y.shape[1] - 1)
    y0, ym, yp = Y[rows, k], Y[rows, km], Y[rows, kp]
    curv = ym - 2.0 * y0 + yp
    with np.errstate(invalid="ignore", divide="ignore"):
        d = np.where(inner & (curv < 0), 0.5 * (ym - yp) / curv, 0.0)
    d = np.clip(d, -0.5, 0.5)
    after = np.where(d > 0, d * (y0 + 0.5 * d * (yp - y0)), 0.0)        # part of trapezoid k..k+1
    before = np.where(d < 0, -d * (y0 + 0.5 * -d * (ym - y0)), 0.0)     # part of trapezoid k-1..k
    a1 = a1 + after - before
    a2 = total - a1
    s1, s2 = float(a1.sum()), float(a2.sum())
    return (s1 / s2 if s2 > 0 else float("inf")), s1, s2


def singhal_area(op, pv, ts_s: float, *, sp=None, integrating: bool | None = None) -> Evidence:
    """Singhal and Salsbury's (2005) area-peak ratio (self-regulating loops only).

    Parameters
    ----------
    op : array (n,)
        Controller output, % of span (only checked for usability).
    pv : array (n,)
        Process variable.
    ts_s : float
        Sample period, seconds.
    sp : array (n,), optional
        Setpoint; the control error SP - PV is analysed (just -PV when there is none).
    integrating : bool or None
        Process type; the ratio is defined for self-regulating loops (False).
    """
    return _singhal_area(Prepared(op, pv, ts_s, sp), integrating)


def _singhal_area(p: Prepared, integrating: bool | None) -> Evidence:
    gate = (record_gate(TEST, p, threshold=HIGH)
            or process_gate(TEST, integrating, wants=False, threshold=HIGH)
            or oscillation_gate(TEST, p, "err", p.err_name, HIGH))
    if gate is not None:
        return gate
    o = p.osc("err")
    start, end = p.halves("err")
    if start.shape[0] < MIN_HALVES:
        return cannot_judge(TEST, "too_few_cycles", f"{p.err_name} has only {start.shape[0]} clean half-cycles; "
                            f"the ratio needs {MIN_HALVES}.", HIGH, period_s=o.period * p.ts_s)
    e = lowpass(p.err_d, SMOOTH_HARMONICS / o.period)
    R, a1, a2 = area_ratio(e, start, end)
    ex = {"threshold_low": LOW, "half_cycles": float(start.shape[0]), "period_s": o.period * p.ts_s}
    what = "the control error" if p.sp_moves else "PV"
    return graded(TEST, R, HIGH, LOW, {
        STICTION: f"Each half-cycle of {what} peaks late, area before the peak {R:.2f} times the area after "
                  "it: a step-like rise and a fast return, as after a sticky valve's jumps.",
        NO_STICTION: f"The half-cycles of {what} are symmetric or peak early (area ratio {R:.2f} <= {LOW}), as "
                     "for a sinusoid: not the late peak a sticky valve gives.",
        UNDETERMINED: f"The half-cycles of {what} peak a little late (area ratio {R:.2f}, between {LOW} and "
                      f"{HIGH}): too little to tell stiction from noise."}, ex)
