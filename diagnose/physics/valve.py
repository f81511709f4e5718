"""The augmented valve: the two-parameter stiction model with the physics it leaves out.

The compiled valve (`diagnose.kernels.valve_run`, the one valve step of diagnose/csrc) runs many
candidate valves over one input series. Each candidate has

* separate stiction for the two directions of motion: ``S_up, J_up`` (opening, f = +1) and
  ``S_dn, J_dn`` (closing, f = -1), % of span;
* a drift of S and J, ``dS_pct_per_s``, ``dJ_pct_per_s`` (values clipped at 0), over the record or
  within a window (``drift_from_s``, ``drift_for_s``; one sample long: a step);
* a first-order actuator lag *after* the friction element, discrete pole ``a_lag`` (0: no lag);
* a starting direction ``f0``.

With S_up = S_dn, J_up = J_dn, no drift and no lag it equals `diagnose.stiction_model.stiction_batch`
sample for sample (tests/test_physics.py pins this). Reversal into direction f must beat S of
direction f; a restart in the same direction f must beat J of direction f; while moving in direction
f the stem sits at ``x - f (S_f - J_f) / 2``.

`characteristic` is the static installed characteristic between stem position and flow.
"""

from __future__ import annotations

import math

import numpy as np

from .. import kernels
from ..errors import DataError


def _param(v, m: int) -> np.ndarray:
    arr = np.ascontiguousarray(np.broadcast_to(np.asarray(v, dtype=np.float64), (m,)))
    return arr


def augmented_valve(x_pct, *, S_up, J_up, S_dn=None, J_dn=None, dS_pct_per_s=0.0,
                    dJ_pct_per_s=0.0, f0=1, tau_lag_s=0.0, ts_s: float = 1.0,
                    y0_pct=np.nan, xs0_pct=np.nan, drift_from_s=0.0, drift_for_s=math.inf) -> np.ndarray:
    """Stem position of one or many augmented valves driven by one input series.

    Parameters
    ----------
    x_pct : array_like, shape (n,)
        Valve input (controller output), % of span.
    S_up, J_up : float or array (m,)
        Stiction while opening, % of span.
    S_dn, J_dn : float or array (m,), optional
        Stiction while closing (default: the opening values).
    dS_pct_per_s, dJ_pct_per_s : float or array (m,)
        Rate of change of S and J while they drift, % of span per second.
    f0 : {+1, -1} or array (m,)
        Direction of the last motion before the record.
    tau_lag_s : float or array (m,)
        Time constant of the first-order actuator lag after the friction element, seconds.
    ts_s : float
        Sample period, seconds.
    y0_pct : float or array (m,)
        Stem position at the first sample, % of span: the valve is stuck there after a motion in
        direction ``f0`` (the input stood at ``y0 + f0 (S - J) / 2`` when it stuck). NaN (default):
        stuck at the first input sample.
    xs0_pct : float or array (m,)
        Input value at which the valve stuck (with ``y0_pct``; NaN: ``y0 + f0 (S - J) / 2``).
    drift_from_s, drift_for_s : float or array (m,)
        When the drift starts (seconds after the first sample) and how long it lasts (seconds;
        inf: to the end). One sample period makes it a step of the rate times ``ts_s``.

    Returns
    -------
    ndarray, shape (m, n), or (n,) when every parameter is a scalar.
    """
    x = np.ascontiguousarray(x_pct, dtype=np.float64)
    if x.ndim != 1:
        raise DataError(f"x_pct must be one-dimensional, got shape {x.shape}")
    if not ts_s > 0:
        raise DataError(f"ts_s must be > 0 seconds, got {ts_s}")
    S_dn = S_up if S_dn is None else S_dn
    J_dn = J_up if J_dn is None else J_dn
    params = [S_up, J_up, S_dn, J_dn, dS_pct_per_s, dJ_pct_per_s, f0, tau_lag_s, y0_pct, xs0_pct, drift_from_s,
              drift_for_s]
    scalar = all(np.ndim(p) == 0 for p in params)
    m = max(int(np.size(p)) for p in params)
    S_up_, J_up_, S_dn_, J_dn_, dS_, dJ_, f0_, tau_, y0_, xs0_, t0_, tw_ = (_param(p, m) for p in params)
    for nm, arr in (("S_up", S_up_), ("J_up", J_up_), ("S_dn", S_dn_), ("J_dn", J_dn_)):
        if np.any(~np.isfinite(arr)) or np.any(arr < 0):
            raise DataError(f"{nm} must be finite and >= 0 % of span")
    if np.any((f0_ != 1.0) & (f0_ != -1.0)):
        raise DataError("starting directions f0 must be +1 or -1")
    if np.any(tau_ < 0) or np.any(~np.isfinite(tau_)):
        raise DataError("tau_lag_s must be finite and >= 0 seconds")
    a = np.where(tau_ > 0, np.exp(-ts_s / np.where(tau_ > 0, tau_, 1.0)), 0.0)
    out = np.empty((m, x.shape[0]))
    if np.any(~(t0_ >= 0)) or np.any(~(tw_ >= 0)):
        raise DataError("drift_from_s and drift_for_s must be >= 0 seconds")
    kernels.valve_run(x, S_up_, J_up_, S_dn_, J_dn_, dS_, dJ_, f0_, np.ascontiguousarray(a), y0_, xs0_,
                      float(ts_s), out, t0=t0_, tw=tw_)
    return out[0] if scalar else out


def characteristic(y_pct, c: float) -> np.ndarray:
    """Installed characteristic: relative flow (% of maximum) at stem position ``y_pct``.

    ``c = ln R``: c > 0 is equal-percentage-like with rangeability R = e^c (normalised so that
    0 % -> 0 and 100 % -> 100 %: ``100 (e^(c y/100) - 1) / (e^c - 1)``), c < 0 quick opening, c = 0
    linear.
    """
    y = np.asarray(y_pct, dtype=float)
    if abs(c) < 1e-9:
        return y.copy()
    return 100.0 * np.expm1(c * y / 100.0) / math.expm1(c)


def characteristic_scalar(y: float, c: float) -> float:
    if abs(c) < 1e-9:
        return y
    return 100.0 * math.expm1(c * y / 100.0) / math.expm1(c)
