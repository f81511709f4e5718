"""Oscillation context of a loop: is it oscillating, with what period, how regularly.

The method is the autocorrelation zero-crossing test of Thornhill, Huang & Zhang (2003): the
autocorrelation function (ACF) of a (detrended) signal that oscillates is itself an oscillation with
the same period and less noise. The intervals between successive zero crossings of the ACF are
half-periods; their mean gives the period and the ratio

    r = mean(T_p) / (3 * std(T_p))

their regularity. ``r > 1`` is the published threshold for a regular oscillation. At least two full
cycles (four half-period intervals) are required.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

REGULARITY_THRESHOLD = 1.0


@dataclass(frozen=True)
class Oscillation:
    """Oscillation context.

    Attributes
    ----------
    oscillating : bool
        A regular oscillation was found (regularity > 1, >= 2 cycles in the ACF).
    period_s : float or None
        Mean period, seconds (None when no period could be measured).
    regularity : float
        Thornhill's regularity r (0 when undefined).
    cycles : float
        Number of periods the record holds.
    amplitude_pv : float
        Half the robust peak-to-peak (5-95 percentile) of the detrended PV (or error), PV units.
    amplitude_op_pct : float
        The same for OP, % of span.
    signal : str
        Which signal was analysed ("error" = SP - PV when a setpoint is given, else "pv").
    """

    oscillating: bool
    period_s: float | None
    regularity: float
    cycles: float
    amplitude_pv: float
    amplitude_op_pct: float
    signal: str = "pv"

    def to_dict(self) -> dict[str, Any]:
        return {"oscillating": bool(self.oscillating),
                "period_s": None if self.period_s is None else float(self.period_s),
                "regularity": float(self.regularity), "cycles": float(self.cycles),
                "amplitude_pv": float(self.amplitude_pv),
                "amplitude_op_pct": float(self.amplitude_op_pct), "signal": self.signal}


def _detrend(v: np.ndarray) -> np.ndarray:
    t = np.arange(v.shape[0], dtype=float)
    if v.shape[0] < 3:
        return v - v.mean()
    A = np.column_stack([np.ones_like(t), t])
    coef, *_ = np.linalg.lstsq(A, v, rcond=None)
    return v - A @ coef


def acf(v, max_lag: int | None = None) -> np.ndarray:
    """Normalised autocorrelation of a mean-removed series (FFT), lags 0..max_lag."""
    x = np.asarray(v, dtype=float)
    x = x - x.mean()
    n = x.shape[0]
    max_lag = n - 1 if max_lag is None else min(max_lag, n - 1)
    nfft = 1 << int(np.ceil(np.log2(2 * n)))
    f = np.fft.rfft(x, nfft)
    r = np.fft.irfft(f * np.conj(f), nfft)[: max_lag + 1]
    return r / r[0] if r[0] > 0 else np.zeros(max_lag + 1)


def _half_amplitude(v: np.ndarray) -> float:
    lo, hi = np.percentile(v, [5, 95])
    return float(hi - lo) / 2.0


def oscillation_context(pv, ts_s: float, *, sp=None, op=None) -> Oscillation:
    """Detect a regular oscillation and measure its period.

    Parameters
    ----------
    pv : array (n,)
        Process variable.
    ts_s : float
        Sample period, seconds.
    sp : array (n,), optional
        Setpoint; the control error SP - PV is analysed when given.
    op : array (n,), optional
        Controller output, for its amplitude.
    """
    y = np.asarray(pv, dtype=float)
    signal = "pv"
    if sp is not None:
        s = np.asarray(sp, dtype=float)
        if np.ptp(s) > 0:          # a moving setpoint: analyse the control error
            y = s - y
            signal = "error"
    y = _detrend(y)
    amp_op = _half_amplitude(_detrend(np.asarray(op, dtype=float))) if op is not None else 0.0
    n = y.shape[0]
    if n < 8 or np.ptp(y) <= 0:
        return Oscillation(False, None, 0.0, 0.0, _half_amplitude(y) if n else 0.0, amp_op, signal)
    r = acf(y, max_lag=n // 2)
    sgn = np.signbit(r)
    zc = np.flatnonzero(sgn[1:] != sgn[:-1]) + 1
    if zc.shape[0] < 2:
        return Oscillation(False, None, 0.0, 0.0, _half_amplitude(y), amp_op, signal)
    # interpolate the crossing positions
    pos = []
    for k in zc:
        a, b = r[k - 1], r[k]
        pos.append(k - 1 + (a / (a - b) if a != b else 0.0))
    pos = np.asarray(pos)
    half = np.diff(pos)
    if half.shape[0] == 0:
        return Oscillation(False, None, 0.0, 0.0, _half_amplitude(y), amp_op, signal)
    # Use up to 10 intervals (the ACF decays and its late crossings are noisy).
    half = half[:10]
    periods = 2.0 * half
    Tp = float(np.mean(periods))
    sd = float(np.std(periods))
    regularity = float(Tp / (3.0 * sd)) if sd > 0 else (10.0 if half.shape[0] >= 2 else 0.0)
    regularity = min(regularity, 100.0)
    cycles = n / Tp if Tp > 0 else 0.0
    oscillating = bool(regularity > REGULARITY_THRESHOLD and half.shape[0] >= 4 and cycles >= 2.0)
    return Oscillation(oscillating, Tp * ts_s, regularity, cycles, _half_amplitude(y), amp_op, signal)
