"""The two-parameter data-driven stiction model (Choudhury, Thornhill & Shah 2005, revised form).

x is the valve input (controller output OP, % of span) and y the stem position (MV, % of span).
S is deadband plus stickband and J the slip jump, both in % of span. The revised form stores the
direction of the last motion ``f`` explicitly and captures the stuck point only when a *moving*
valve stops or reverses, so noise on a stuck valve's input does not re-capture it. It equals Kano's
model sample for sample. See docs/model.md.

Two implementations that must agree exactly:

* `StictionValve` / `stiction_reference`: one valve, plain Python, the specification.
* `stiction_batch`: N candidate (S, J, f0) sets over one input series in one compiled call, what the
  fitting stage runs thousands of times.
"""

from __future__ import annotations

import math

import numpy as np

from .errors import DataError
from .native import njit  # numba.njit, deferred; runs the C twin when there is one (diagnose/native)

SPAN_LO = 0.0
SPAN_HI = 100.0


def _clip(v: float) -> float:
    return SPAN_LO if v < SPAN_LO else (SPAN_HI if v > SPAN_HI else v)


def _sign(v: float) -> float:
    return 1.0 if v > 0.0 else (-1.0 if v < 0.0 else 0.0)


class StictionValve:
    """One sticky valve, stepped one sample at a time (the reference implementation).

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
        if not (S_pct >= 0 and J_pct >= 0 and math.isfinite(S_pct) and math.isfinite(J_pct)):
            raise DataError(f"S and J must be finite and >= 0 % of span, got S={S_pct}, J={J_pct}")
        if f0 not in (1, -1):
            raise DataError(f"starting direction f0 must be +1 or -1, got {f0!r}")
        self.S_pct = float(S_pct)
        self.J_pct = float(J_pct)
        self.f0 = int(f0)
        self.reset(0.0)

    def reset(self, x0_pct: float) -> float:
        """Put the valve at rest at input ``x0_pct``; returns the stem position."""
        x0 = _clip(float(x0_pct))
        self.x_prev = x0
        self.v_prev = 0.0
        self.y = x0
        self.x_ss = x0
        self.stuck = True
        self.f = float(self.f0)
        return self.y

    def step(self, x_pct: float) -> float:
        """Advance one sample with input ``x_pct``; returns the stem position in % of span."""
        S, J = self.S_pct, self.J_pct
        x = _clip(float(x_pct))
        v = x - self.x_prev
        # Only a moving valve can stop: noise on a stuck valve's input does not move x_ss.
        if (not self.stuck) and (v == 0.0 or _sign(v) != _sign(self.v_prev)):
            self.stuck = True
            self.x_ss = self.x_prev
        if not self.stuck:
            y = x - self.f * (S - J) / 2.0
        elif -self.f * (x - self.x_ss) > S:          # reversal: the input must beat S
            self.f = -self.f
            self.stuck = False
            y = x - self.f * (S - J) / 2.0
        elif self.f * (x - self.x_ss) > J:           # same direction after a stop: beat J
            self.stuck = False
            y = x - self.f * (S - J) / 2.0
        else:
            y = self.y
        self.y = _clip(y)
        self.x_prev = x
        self.v_prev = v
        return self.y


def stiction_reference(x_pct, S_pct: float, J_pct: float, f0: int = 1, *,
                       return_state: bool = False):
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
    n = x.shape[0]
    y = np.empty(n)
    stuck = np.empty(n, dtype=bool)
    direction = np.empty(n)
    if n == 0:
        return (y, stuck, direction) if return_state else y
    valve = StictionValve(S_pct, J_pct, f0)
    y[0] = valve.reset(x[0])
    stuck[0], direction[0] = valve.stuck, valve.f
    for k in range(1, n):
        y[k] = valve.step(x[k])
        stuck[k], direction[k] = valve.stuck, valve.f
    if return_state:
        return y, stuck, direction
    return y


@njit(cache=True, nogil=True, boundscheck=False)
def _batch_kernel(x, S, J, f0, out):  # pragma: no cover - compiled
    m = S.shape[0]
    n = x.shape[0]
    for i in range(m):
        s = S[i]
        j = J[i]
        # f is +-1, so f * half equals f * (s - j) / 2 exactly, as in the reference.
        half = (s - j) / 2.0
        f = f0[i]
        xp = min(max(x[0], 0.0), 100.0)
        up = False          # direction of the previous increment (only read while moving)
        yp = xp
        xss = xp
        stuck = True
        out[i, 0] = yp
        for k in range(1, n):
            xk = min(max(x[k], 0.0), 100.0)
            v = xk - xp
            up_k = v > 0.0
            # While moving the previous increment is never 0, so "sign changed" is up != up_k.
            if not stuck and (v == 0.0 or up_k != up):
                stuck = True
                xss = xp
            if stuck:
                d = xk - xss
                if -f * d > s:
                    f = -f
                    stuck = False
                    yp = min(max(xk - f * half, 0.0), 100.0)
                elif f * d > j:
                    stuck = False
                    yp = min(max(xk - f * half, 0.0), 100.0)
            else:
                yp = min(max(xk - f * half, 0.0), 100.0)
            out[i, k] = yp
            xp = xk
            up = up_k
    return out


def stiction_batch(x_pct, S_pct, J_pct, f0=1, *, out: np.ndarray | None = None) -> np.ndarray:
    """Run many candidate valves over one input series in one compiled call.

    Parameters
    ----------
    x_pct : array_like, shape (n,)
        Valve input (controller output), % of span.
    S_pct, J_pct : array_like, shape (m,)
        Candidate stiction parameters, % of span.
    f0 : int or array_like of {+1, -1}, shape (m,)
        Starting direction per candidate.
    out : ndarray, shape (m, n), optional
        Preallocated output (saves an allocation inside fitting loops).

    Returns
    -------
    ndarray, shape (m, n)
        Stem position of each candidate, % of span; equal to `stiction_reference` bit for bit.
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
    elif out.shape != (m, n):
        raise DataError(f"out has shape {out.shape}, expected {(m, n)}")
    if n == 0:
        return out
    return _batch_kernel(x, np.ascontiguousarray(S), np.ascontiguousarray(J),
                         np.ascontiguousarray(f), out)


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
