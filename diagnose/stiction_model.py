"""The two-parameter data-driven stiction model (Choudhury, Thornhill & Shah 2005, revised form).

x is the valve input (controller output OP, % of span) and y the stem position (MV, % of span).
S is deadband plus stickband and J the slip jump, both in % of span. The revised form stores the
direction of the last motion ``f`` explicitly and captures the stuck point only when a *moving*
valve stops or reverses, so noise on a stuck valve's input does not re-capture it. It equals Kano's
model sample for sample. See docs/model.md.

The valve step itself is written once, in C (``diagnose/csrc/valve_step.h``, run through
`diagnose.kernels`); this module is its public face:

* `StictionValve`: one valve stepped one sample at a time (the simulator's valve);
* `simulate_valve`: one valve over an input series;
* `stiction_batch`: many candidate (S, J, f0) over one input series in one call, what the fitting
  stage runs thousands of times.
"""

from __future__ import annotations

import math

import numpy as np

from . import kernels
from .errors import DataError

SPAN_LO = 0.0
SPAN_HI = 100.0


def _check_sj(S_pct: float, J_pct: float, f0: int) -> None:
    if not (S_pct >= 0 and J_pct >= 0 and math.isfinite(S_pct) and math.isfinite(J_pct)):
        raise DataError(f"S and J must be finite and >= 0 % of span, got S={S_pct}, J={J_pct}")
    if f0 not in (1, -1):
        raise DataError(f"starting direction f0 must be +1 or -1, got {f0!r}")


class StictionValve:
    """One sticky valve, stepped one sample at a time.

    Parameters
    ----------
    S_pct : float
        Deadband plus stickband, % of valve span (S >= 0).
    J_pct : float
        Slip jump, % of valve span (J >= 0).
    f0 : {+1, -1}
        Direction of the valve's last motion before the record starts. It is not observable from
        data; the fitting stage treats it as a nuisance parameter.

    Notes
    -----
    The valve starts stuck at its first input: ``y = x0``, ``x_ss = x0``. Input and output are
    clipped to 0..100 % (a valve cannot travel past its stops).
    """

    def __init__(self, S_pct: float, J_pct: float, f0: int = 1) -> None:
        _check_sj(S_pct, J_pct, f0)
        self.S_pct = float(S_pct)
        self.J_pct = float(J_pct)
        self.f0 = int(f0)
        self._valve = kernels.ValveState(self.S_pct, self.J_pct, self.S_pct, self.J_pct)
        self.reset(0.0)

    def reset(self, x0_pct: float) -> float:
        """Put the valve at rest at input ``x0_pct``; returns the stem position."""
        self.y = self._valve.start(x0_pct, self.f0)
        return self.y

    def step(self, x_pct: float) -> float:
        """Advance one sample with input ``x_pct``; returns the stem position in % of span."""
        self.y = self._valve.step(x_pct)
        return self.y

    @property
    def stuck(self) -> bool:
        return self._valve.stuck

    @property
    def f(self) -> float:
        """Direction of the last motion (+1 / -1)."""
        return self._valve.direction


def simulate_valve(x_pct, S_pct: float, J_pct: float, f0: int = 1, *, return_state: bool = False):
    """Run one valve over an input series.

    Parameters
    ----------
    x_pct : array_like, shape (n,)
        Valve input (controller output), % of span.
    S_pct, J_pct : float
        Stiction parameters, % of span.
    f0 : {+1, -1}
        Direction of the last motion before the series.
    return_state : bool
        Also return the stuck flag and the direction after each sample.

    Returns
    -------
    y : ndarray, shape (n,)
        Stem position, % of span.
    stuck, direction : ndarray of bool and of float, shape (n,)
        Only with ``return_state``.
    """
    x = np.asarray(x_pct, dtype=float)
    if not return_state:
        _check_sj(S_pct, J_pct, f0)
        return stiction_batch(x, [S_pct], [J_pct], [f0])[0]
    n = x.shape[0]
    y = np.empty(n)
    stuck = np.empty(n, dtype=bool)
    direction = np.empty(n)
    if n == 0:
        return y, stuck, direction
    valve = StictionValve(S_pct, J_pct, f0)
    y[0] = valve.reset(x[0])
    stuck[0], direction[0] = valve.stuck, valve.f
    for k in range(1, n):
        y[k] = valve.step(x[k])
        stuck[k], direction[k] = valve.stuck, valve.f
    return y, stuck, direction


def stiction_batch(x_pct, S_pct, J_pct, f0=1, *, start_pct=None, stuck_at_pct=None,
                   out: np.ndarray | None = None) -> np.ndarray:
    """Run many candidate valves over one input series in one compiled call.

    Parameters
    ----------
    x_pct : array_like, shape (n,)
        Valve input (controller output), % of span.
    S_pct, J_pct : array_like, shape (m,)
        Candidate stiction parameters, % of span.
    f0 : int or array_like of {+1, -1}, shape (m,)
        Starting direction per candidate.
    start_pct : float or array_like, shape (m,), optional
        The stem position at the first sample, % of span: the valve is stuck there after a motion
        in direction ``f0`` (the input then stood at ``start + f0 (S - J) / 2``). None or NaN: at
        rest at the first input.
    stuck_at_pct : float or array_like, shape (m,), optional
        With ``start_pct``: the input at which the valve stuck (None or NaN: where a valve moving in
        direction ``f0`` stops, ``start + f0 (S - J) / 2``).
    out : ndarray, shape (m, n), optional
        Preallocated output (saves an allocation inside fitting loops).

    Returns
    -------
    ndarray, shape (m, n)
        Stem position of each candidate, % of span; equal to stepping `StictionValve` sample by
        sample.
    """
    x = np.ascontiguousarray(x_pct, dtype=np.float64)
    S = np.atleast_1d(np.asarray(S_pct, dtype=np.float64))
    J = np.atleast_1d(np.asarray(J_pct, dtype=np.float64))
    S, J = np.broadcast_arrays(S, J)
    f = np.broadcast_to(np.asarray(f0, dtype=np.float64), S.shape)
    if x.ndim != 1:
        raise DataError(f"x_pct must be one-dimensional, got shape {x.shape}")
    if np.any(~np.isfinite(S)) or np.any(~np.isfinite(J)) or np.any(S < 0) or np.any(J < 0):
        raise DataError("S and J must be finite and >= 0 % of span")
    if np.any((f != 1.0) & (f != -1.0)):
        raise DataError("starting directions f0 must be +1 or -1")
    m, n = S.shape[0], x.shape[0]
    if out is None:
        out = np.empty((m, n))
    elif out.shape != (m, n) or out.dtype != np.float64 or not out.flags.c_contiguous:
        raise DataError(f"out must be a C-contiguous float64 array of shape {(m, n)}, got {out.shape}")
    zero = np.zeros(m)
    nan = np.full(m, np.nan)
    y0 = nan if start_pct is None else np.broadcast_to(np.asarray(start_pct, dtype=np.float64), (m,))
    xs0 = nan if stuck_at_pct is None else np.broadcast_to(np.asarray(stuck_at_pct, dtype=np.float64), (m,))
    return kernels.valve_run(x, S, J, S, J, zero, zero, f, zero, y0, xs0, 1.0, out)


def stiction_class(S_pct: float, J_pct: float, *, tol_pct: float | None = None) -> str:
    """Name the class of a (S, J) pair.

    ``none`` when S is below ``tol_pct``; ``deadband`` when J is; ``no_offset`` when
    |J - S| <= tol; else ``undershoot`` (J < S) or ``overshoot`` (J > S).
    The default tolerance is max(0.1 % of span, 15 % of S): an identification can rarely tell
    J from S closer than that. See docs/model.md.
    """
    return str(stiction_classes([S_pct], [J_pct], tol_pct=tol_pct)[0])


def stiction_classes(S_pct, J_pct, *, tol_pct: float | None = None) -> np.ndarray:
    """`stiction_class` for arrays of (S, J) pairs (% of span); returns an array of class names."""
    S = np.asarray(S_pct, dtype=float)
    J = np.asarray(J_pct, dtype=float)
    tol = np.maximum(0.1, 0.15 * S) if tol_pct is None else np.full(S.shape, float(tol_pct))
    lim = np.maximum(tol, 0.1)
    return np.where((S <= lim) & (J <= lim), "none",
                    np.where(J <= tol, "deadband",
                             np.where(np.abs(J - S) <= tol, "no_offset",
                                      np.where(J < S, "undershoot", "overshoot"))))


CLASSES = ("none", "deadband", "undershoot", "no_offset", "overshoot")
