"""He, Wang, Pottmann and Qin's (2007) curve-fitting test: triangle or sinusoid?

A sticky valve in a self-regulating loop holds still while the integral action ramps OP, then
jumps: OP is a triangle. In an integrating loop the valve's steps make the level ramp: PV is a
triangle. An oscillation from a linear cause is close to a sinusoid in both. Each half-cycle of
the signal (between zero crossings) is fitted by least squares with a sinusoid (amplitude,
frequency, phase, offset) and with a triangle (two straight lines meeting at an apex; apex time,
apex height, two slopes), and

    SI = MSE_sin / (MSE_sin + MSE_tri)

over all half-cycles. He et al.: SI <= 0.4 no stiction, SI >= 0.6 stiction, undetermined between.

The frequency of the sinusoid is searched on a grid (11 frequencies from half to one and a half
times the half-cycle's own, then a parabola through the best three) and the triangle's apex at every sample but the two first and the two
last of the half-cycle; for each the rest is linear least squares, solved for all half-cycles at
once.
"""

from __future__ import annotations

import numpy as np

from ._gates import oscillation_gate, process_gate, record_gate
from ._signals import Prepared, lowpass, sample_range, segment_matrix
from .result import NO_STICTION, STICTION, UNDETERMINED, Evidence, cannot_judge, graded

TEST = "he_curve_fit"
HIGH = 0.6      # SI at or above: stiction (He et al. 2007)
LOW = 0.4       # SI at or below: no stiction
MIN_HALVES = 4
SMOOTH_HARMONICS = 10.0     # noise filter edge, multiples of the oscillation frequency
_OMEGA = np.pi * np.linspace(0.5, 1.5, 11)     # per unit of normalised half-cycle time


def _sse3(a00, a01, a02, a11, a12, a22, b0, b1, b2, yy):
    """Residual sum of squares of the least-squares fit with Gram matrix A (symmetric 3x3, given
    by its upper entries) and right-hand side b, elementwise over arrays: yy - b' A^-1 b."""
    c00 = a11 * a22 - a12 * a12
    c01 = a02 * a12 - a01 * a22
    c02 = a01 * a12 - a02 * a11
    c11 = a00 * a22 - a02 * a02
    c12 = a01 * a02 - a00 * a12
    c22 = a00 * a11 - a01 * a01
    det = a00 * c00 + a01 * c01 + a02 * c02
    quad = (b0 * (c00 * b0 + c01 * b1 + c02 * b2) + b1 * (c01 * b0 + c11 * b1 + c12 * b2)
            + b2 * (c02 * b0 + c12 * b1 + c22 * b2))
    with np.errstate(invalid="ignore", divide="ignore"):
        sse = yy - quad / det
    # a singular grid point (a degenerate apex or frequency) is no candidate
    return np.where(np.abs(det) > 1e-12 * np.abs(a00 * a11 * a22) + 1e-300, sse, np.inf)


def stiction_index(x: np.ndarray, start: np.ndarray, end: np.ndarray) -> tuple[float, float, float]:
    """``(SI, MSE_sin, MSE_tri)`` of the half-cycles ``x[start:end]``.

    Both fits are linear least squares for each value of their one nonlinear parameter, written
    with the sums that make up the normal equations so that all half-cycles and all grid values
    are solved at once. The triangle's apex is tried at every sample.
    """
    Y, M = segment_matrix(x, start, end)
    m = M.astype(float)
    length = (end - start).astype(float)
    tau = np.arange(Y.shape[1])[None, :] / np.maximum(length - 1.0, 1.0)[:, None] * m
    s0, s1, s2 = length, tau.sum(axis=1), (tau * tau).sum(axis=1)
    y0, y1, yy = Y.sum(axis=1), (Y * tau).sum(axis=1), (Y * Y).sum(axis=1)
    # sinusoid: offset + a sin(w tau) + b cos(w tau); w on a grid, then refined by a parabola
    # through the best grid point and its neighbours. On the grid the sine and cosine columns
    # depend only on a half-cycle's length: they are made once per length.
    rows = np.arange(Y.shape[0])
    grid = np.empty((Y.shape[0], _OMEGA.shape[0]))
    lengths = (end - start)
    for L in np.unique(lengths):
        sel = np.flatnonzero(lengths == L)
        t = np.arange(L) / max(L - 1.0, 1.0)
        sn, cs = np.sin(np.outer(_OMEGA, t)), np.cos(np.outer(_OMEGA, t))      # (G, L)
        y = Y[sel, :L]
        grid[sel] = _sse3(float(L), sn.sum(axis=1), cs.sum(axis=1), (sn * sn).sum(axis=1),
                          (sn * cs).sum(axis=1), (cs * cs).sum(axis=1), y0[sel, None], y @ sn.T, y @ cs.T,
                          yy[sel, None])
    g = np.clip(np.argmin(grid, axis=1), 1, _OMEGA.shape[0] - 2)
    e0, e1, e2 = grid[rows, g - 1], grid[rows, g], grid[rows, g + 1]
    curv = e0 - 2.0 * e1 + e2
    with np.errstate(invalid="ignore", divide="ignore"):
        shift = np.where(np.isfinite(curv) & (curv > 0), 0.5 * (e0 - e2) / curv, 0.0)
    w = (_OMEGA[g] + np.clip(shift, -1.0, 1.0) * (_OMEGA[1] - _OMEGA[0]))[:, None]
    sn, cs = np.sin(w * tau) * m, np.cos(w * tau) * m
    refined = _sse3(s0, sn.sum(axis=1), cs.sum(axis=1), (sn * sn).sum(axis=1), (sn * cs).sum(axis=1),
                    (cs * cs).sum(axis=1), y0, (sn * Y).sum(axis=1), (cs * Y).sum(axis=1), yy)
    sse_s = np.minimum(grid.min(axis=1), refined)
    # triangle: offset + slope tau + slope change after the apex at sample k, from tail sums
    def tail(v):                       # sum over j > k, for every k
        c = np.cumsum(v[:, ::-1], axis=1)[:, ::-1]
        return np.concatenate([c[:, 1:], np.zeros((v.shape[0], 1))], axis=1)
    n_k, t1, t2 = tail(m), tail(tau), tail(tau * tau)
    q0, q1 = tail(Y), tail(Y * tau)
    a02 = t1 - tau * n_k
    a12 = t2 - tau * t1
    a22 = t2 - 2.0 * tau * t1 + tau * tau * n_k
    b2 = q1 - tau * q0
    apex = M & (np.arange(Y.shape[1])[None, :] >= 1) & (np.arange(Y.shape[1])[None, :] <= length[:, None] - 3)
    sse_t = _sse3(s0[:, None], s1[:, None], a02, s2[:, None], a12, a22, y0[:, None], y1[:, None], b2, yy[:, None])
    sse_t = np.where(apex, sse_t, np.inf).min(axis=1)
    sse_s, sse_t = np.maximum(sse_s, 0.0), np.maximum(sse_t, 0.0)
    total = float(length.sum())
    mse_s, mse_t = float(sse_s.sum()) / total, float(sse_t.sum()) / total
    si = mse_s / (mse_s + mse_t) if mse_s + mse_t > 0 else 0.5
    return si, mse_s, mse_t


def fit_shape(p: Prepared, name: str, test: str, what: str) -> Evidence | tuple[float, dict]:
    """SI of signal ``name`` with its extras, or a cannot-judge `Evidence`."""
    gate = oscillation_gate(test, p, name, what, HIGH)
    if gate is not None:
        return gate
    o = p.osc(name)
    start, end = sample_range(*p.halves(name))
    if start.shape[0] < MIN_HALVES:
        return cannot_judge(test, "too_few_cycles", f"{what} has only {start.shape[0]} clean half-cycles; "
                            f"the fit needs {MIN_HALVES}.", HIGH, period_s=o.period * p.ts_s)
    key = ("he_si", name)
    if key not in p.cache:
        x = lowpass(getattr(p, name + "_d"), SMOOTH_HARMONICS / o.period)
        p.cache[key] = stiction_index(x, start, end)
    si, mse_s, mse_t = p.cache[key]
    ex = {"threshold_low": LOW, "mse_sin": mse_s, "mse_tri": mse_t, "half_cycles": float(start.shape[0]),
          "period_s": o.period * p.ts_s, "regularity": o.regularity}
    return si, ex


def he_curve_fit(op, pv, ts_s: float, *, sp=None, integrating: bool | None = None) -> Evidence:
    """He et al.'s (2007) triangle-versus-sinusoid fit: OP of a self-regulating loop, PV of an
    integrating one.

    Parameters
    ----------
    op : array (n,)
        Controller output, % of span.
    pv : array (n,)
        Process variable.
    ts_s : float
        Sample period, seconds.
    sp : array (n,), optional
        Setpoint; for an integrating loop with a moving setpoint the control error is fitted.
    integrating : bool or None
        Process type; it decides which signal is fitted, so it must be known.
    """
    return _he_curve_fit(Prepared(op, pv, ts_s, sp), integrating)


def _he_curve_fit(p: Prepared, integrating: bool | None) -> Evidence:
    gate = (record_gate(TEST, p, threshold=HIGH)
            or process_gate(TEST, integrating, wants=None, threshold=HIGH))
    if gate is not None:
        return gate
    name, what = ("err", p.err_name) if integrating else ("op", "OP")
    res = fit_shape(p, name, TEST, what)
    if isinstance(res, Evidence):
        return res
    si, ex = res
    return graded(TEST, si, HIGH, LOW, {
        STICTION: (f"{what}'s half-cycles fit a triangle better than a sinusoid (SI {si:.2f} >= {HIGH}): "
                   "straight ramps with sharp turns, as a sticky valve makes."),
        NO_STICTION: (f"{what}'s half-cycles fit a sinusoid better than a triangle (SI {si:.2f} <= {LOW}): "
                      "a smooth oscillation, as from a linear cause."),
        UNDETERMINED: (f"{what}'s half-cycles fit a triangle and a sinusoid about equally (SI {si:.2f}, between "
                       f"{LOW} and {HIGH}).")}, ex)
