"""Horch's test for integrating loops: the distribution of the second derivative of PV.

In a level loop a sticky valve sits still, so the level ramps at a constant rate; then it jumps,
and the level ramps the other way: PV is a triangle, its first derivative a square wave, and its
second derivative a train of short pulses on a background of zero. After low-pass filtering the
second derivative is zero most of the time: its distribution is single-humped, close to Gaussian
(Horch 2000; Horch and Isaksson 2001). An oscillation from any linear cause (a sinusoidal inflow,
tight tuning) keeps PV close to a sinusoid, and the second derivative of a sinusoid is a sinusoid,
whose distribution is the two-humped "camel" (the arcsine density, most mass near the extremes).

Horch decides by which of the two densities fits the standardised filtered second derivative
better. The fit is measured here on the cumulative distribution (a Cramer-von Mises distance,
free of histogram bins and of the arcsine density's infinite edges):

    E_g = mean (F_emp - Phi)^2,    E_s = mean (F_emp - F_sin)^2,    index = E_s / (E_s + E_g)

with ``Phi`` the standard normal CDF and ``F_sin(z) = 1/2 + asin(z / sqrt 2) / pi`` that of a
unit-variance sinusoid. ``index > 0.5``: the Gaussian fits better, stiction.
"""

from __future__ import annotations

import math

import numpy as np

from ._gates import oscillation_gate, process_gate, record_gate
from ._signals import Prepared, lowpass
from .result import NO_STICTION, STICTION, Evidence, cannot_judge

TEST = "horch_integrating"
THRESHOLD = 0.5
CUTOFF_HARMONICS = 4.0    # low-pass edge: keeps harmonics 1 to 3 of the oscillation, drops the 5th and above


def _normal_cdf(z: np.ndarray) -> np.ndarray:
    # math.erfc rather than scipy.special.ndtr: importing scipy.special costs a noticeable share of
    # the command's start-up, for one call on a few thousand values
    s2 = math.sqrt(2.0)
    return np.array([0.5 * math.erfc(-v / s2) for v in z.tolist()])


def _sin_cdf(z: np.ndarray) -> np.ndarray:
    return 0.5 + np.arcsin(np.clip(z / np.sqrt(2.0), -1.0, 1.0)) / np.pi


def d2_index(y: np.ndarray, period: float) -> tuple[float, float, int]:
    """``(index, excess kurtosis, samples used)`` of the filtered second difference of ``y``."""
    f0 = 1.0 / period
    yf = lowpass(y, CUTOFF_HARMONICS * f0, order=4)
    d2 = np.diff(yf, 2)
    # the filter's start-up and end transients are no part of the signal
    trim = int(min(d2.shape[0] // 10, np.ceil(period / 2)))
    d2 = d2[trim: d2.shape[0] - trim]
    sd = float(np.std(d2))
    if d2.shape[0] < 16 or not sd > 0:
        return float("nan"), float("nan"), int(d2.shape[0])
    z = np.sort((d2 - d2.mean()) / sd)
    m = z.shape[0]
    f_emp = (np.arange(1, m + 1) - 0.5) / m
    e_g = float(np.mean((f_emp - _normal_cdf(z)) ** 2))
    e_s = float(np.mean((f_emp - _sin_cdf(z)) ** 2))
    kurt = float(np.mean(z ** 4) - 3.0)
    return e_s / (e_s + e_g) if e_s + e_g > 0 else 0.5, kurt, m


def horch_integrating(op, pv, ts_s: float, *, sp=None, integrating: bool | None = None) -> Evidence:
    """Horch's (2000) second-derivative distribution test (integrating loops only).

    Parameters
    ----------
    op : array (n,)
        Controller output, % of span (only checked for usability).
    pv : array (n,)
        Process variable (a level, or another integrating variable).
    ts_s : float
        Sample period, seconds.
    sp : array (n,), optional
        Setpoint; when it moves the control error SP - PV is analysed instead of PV.
    integrating : bool or None
        Process type; the test judges only integrating loops (True).
    """
    return _horch_integrating(Prepared(op, pv, ts_s, sp), integrating)


def _horch_integrating(p: Prepared, integrating: bool | None) -> Evidence:
    gate = (record_gate(TEST, p, threshold=THRESHOLD)
            or process_gate(TEST, integrating, wants=True, threshold=THRESHOLD, other="horch_xcorr")
            or oscillation_gate(TEST, p, "err", p.err_name, THRESHOLD))
    if gate is not None:
        return gate
    period = p.osc("err").period
    index, kurt, m = d2_index(p.err_d, period)
    if not np.isfinite(index):
        return cannot_judge(TEST, "too_short", "Too few samples remain after filtering to read the distribution "
                            "of PV's second derivative.", THRESHOLD)
    ex = {"excess_kurtosis": kurt, "samples": float(m), "period_s": period * p.ts_s}
    if index > THRESHOLD:
        return Evidence(TEST, index, THRESHOLD, STICTION,
                        f"PV's filtered second derivative is single-humped like a Gaussian (index {index:.2f} > "
                        f"{THRESHOLD}): PV ramps straight and turns sharply, as a level does behind a sticky valve.",
                        extras=ex)
    return Evidence(TEST, index, THRESHOLD, NO_STICTION,
                    f"PV's filtered second derivative has the two-humped distribution of a sinusoid (index "
                    f"{index:.2f} <= {THRESHOLD}): PV oscillates smoothly, as from a linear cause.", extras=ex)
