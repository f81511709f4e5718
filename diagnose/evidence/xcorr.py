"""Horch's cross-correlation test for self-regulating loops.

Horch (1999) observed that in a self-regulating loop (flow, pressure) oscillating because of a
sticky valve, OP is a triangle and PV a square-like wave a quarter period behind it, so the
cross-correlation function (CCF) of OP and PV is *odd* about lag zero; an oscillation from an
external disturbance or from aggressive tuning puts OP and PV nearly in antiphase and makes the CCF
*even* (an extremum at lag zero).

The oddness is read from the CCF lobe nearest to lag zero: with ``tau_l < 0 < ...`` its zero
crossings ``tau_l`` and ``tau_r``,

    delta = |tau_l + tau_r| / (tau_r - tau_l)

is 0 for an even CCF (the lobe centred on lag zero) and 1 for an odd one (the lobe starts at lag
zero); it is the lobe centre's offset from zero as a fraction of a quarter period.
"""

from __future__ import annotations

import numpy as np

from ._gates import oscillation_gate, process_gate, record_gate
from ._signals import Prepared
from .result import NO_STICTION, STICTION, UNDETERMINED, Evidence, cannot_judge, graded

TEST = "horch_xcorr"
ODD = 2.0 / 3.0     # delta at or above: odd CCF, stiction
EVEN = 1.0 / 3.0    # delta at or below: even CCF, no stiction


def ccf(u: np.ndarray, y: np.ndarray, max_lag: int) -> np.ndarray:
    """Normalised cross-correlation r(tau) = E[u(k) y(k + tau)] for tau = -max_lag..max_lag."""
    n = u.shape[0]
    nfft = 1 << int(np.ceil(np.log2(2 * n)))
    c = np.fft.irfft(np.conj(np.fft.rfft(u, nfft)) * np.fft.rfft(y, nfft), nfft)
    c = np.concatenate([c[nfft - max_lag:], c[: max_lag + 1]])
    den = float(np.sqrt((u @ u) * (y @ y)))
    return c / den if den > 0 else np.zeros_like(c)


def _lobe(r: np.ndarray, max_lag: int) -> tuple[float, float] | None:
    """Zero crossings (lags) around the CCF extremum nearest to lag zero."""
    a = np.abs(r)
    inner = np.flatnonzero((a[1:-1] >= a[:-2]) & (a[1:-1] >= a[2:])) + 1
    inner = inner[a[inner] >= 0.5 * a.max()]
    if inner.shape[0] == 0:
        return None
    lags = inner - max_lag
    k = int(inner[np.argmin(np.abs(lags))])
    s = np.sign(r[k])
    left = np.flatnonzero(np.sign(r[:k]) != s)
    right = np.flatnonzero(np.sign(r[k + 1:]) != s)
    if left.shape[0] == 0 or right.shape[0] == 0:
        return None
    i = int(left[-1])                  # r[i] is across zero, r[i+1] on the lobe
    j = k + 1 + int(right[0])          # r[j] is across zero, r[j-1] on the lobe
    tl = i + r[i] / (r[i] - r[i + 1])
    tr = (j - 1) + r[j - 1] / (r[j - 1] - r[j])
    return tl - max_lag, tr - max_lag


def horch_xcorr(op, pv, ts_s: float, *, sp=None, integrating: bool | None = None) -> Evidence:
    """Horch's (1999) OP-PV cross-correlation test (self-regulating loops only).

    Parameters
    ----------
    op : array (n,)
        Controller output, % of span.
    pv : array (n,)
        Process variable.
    ts_s : float
        Sample period, seconds.
    sp : array (n,), optional
        Setpoint; when it moves the control error SP - PV is correlated with OP instead of PV.
    integrating : bool or None
        Process type; the test judges only self-regulating loops (False).
    """
    return _horch_xcorr(Prepared(op, pv, ts_s, sp), integrating)


def _horch_xcorr(p: Prepared, integrating: bool | None) -> Evidence:
    gate = (record_gate(TEST, p, threshold=ODD)
            or process_gate(TEST, integrating, wants=False, threshold=ODD, other="horch_integrating")
            or oscillation_gate(TEST, p, "err", p.err_name, ODD))
    if gate is not None:
        return gate
    period = p.osc("err").period
    max_lag = int(min(p.n - 2, np.ceil(1.5 * period)))
    r = ccf(p.op_d, p.err_d, max_lag)
    lobe = _lobe(r, max_lag)
    if lobe is None:
        return cannot_judge(TEST, "irregular_ccf", "The OP-PV cross-correlation has no clear lobe near lag "
                            "zero (no zero crossing on one side within 1.5 periods).", ODD)
    tl, tr = lobe
    delta = abs(tl + tr) / (tr - tl)
    ex = {"threshold_low": EVEN, "tau_left_s": tl * p.ts_s, "tau_right_s": tr * p.ts_s,
          "ccf_lag0": float(r[max_lag]), "period_s": period * p.ts_s}
    return graded(TEST, delta, ODD, EVEN, {
        STICTION: f"The OP-PV cross-correlation is odd (delta {delta:.2f} >= {ODD:.2f}): PV follows OP a "
                  "quarter period late, as when a sticky valve jumps.",
        NO_STICTION: f"The OP-PV cross-correlation is even (delta {delta:.2f} <= {EVEN:.2f}): OP and PV move in "
                     "antiphase, as for an external disturbance or aggressive tuning.",
        UNDETERMINED: f"The OP-PV cross-correlation is neither clearly odd nor even (delta {delta:.2f} between "
                      f"{EVEN:.2f} and {ODD:.2f})."}, ex)
