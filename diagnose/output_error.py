"""The output-error cost of Hammerstein candidates: the compiled scoring kernel and its data.

A candidate is a stiction valve (S, J, starting direction f0) and a linear process structure
(kind, lags, dead time). `_Problem` holds a record prepared once (scaled PV, score weights,
orthonormal slow-load basis, noise prefilter) and scores any number of candidates in one compiled
pass (`_ham_sse`): PV is simulated from OP through the valve and the structure, and the gain, the
bias and the load coefficients, being linear, are solved by least squares inside the pass. The
search over candidates is in `diagnose.fit`.

The kernels run their C twins (`diagnose/native/kernels.c`) when there are any; their registry
keys in `diagnose.native` name this module.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from . import kernels
from .errors import DataError
from .process_model import lag_coefficient

MIN_SAMPLES = 50

def _legendre_basis(n: int, order: int) -> np.ndarray:
    t = np.linspace(-1.0, 1.0, n) if n > 1 else np.zeros(n)
    cols = [np.ones(n)]
    if order >= 1:
        cols.append(t)
    p_prev, p = np.ones(n), t
    for k in range(2, order + 1):
        p_prev, p = p, ((2 * k - 1) * t * p - (k - 1) * p_prev) / k
        cols.append(p)
    return np.stack(cols, axis=1)


# --------------------------------------------------------------------------------------------------
# the fitting problem
# --------------------------------------------------------------------------------------------------

@dataclass
class _Configs:
    a1: np.ndarray
    a2: np.ndarray
    d: np.ndarray
    integ: np.ndarray
    kind: list
    tau: np.ndarray
    tau2: np.ndarray

    def take(self, idx) -> "_Configs":
        idx = np.atleast_1d(np.asarray(idx, dtype=np.int64))
        return _Configs(self.a1[idx], self.a2[idx], self.d[idx], self.integ[idx],
                        [self.kind[i] for i in idx], self.tau[idx], self.tau2[idx])

    def __len__(self) -> int:
        return int(self.a1.shape[0])


def _make_configs(entries, ts_s: float, tau_max_s: float = math.inf) -> _Configs:
    """entries: iterable of (kind, tau_s, tau2_s, delay_samples); lags above ``tau_max_s`` are
    clipped to it (the local refinements scale lags freely)."""
    kinds, a1, a2, d, integ, tau, tau2 = [], [], [], [], [], [], []
    for kind, t1, t2, dd in entries:
        t1, t2 = min(t1, tau_max_s), min(t2, tau_max_s)
        kinds.append(kind)
        a1.append(lag_coefficient(t1, ts_s))
        a2.append(lag_coefficient(t2, ts_s) if kind == "soptd" else -1.0)
        d.append(int(dd))
        integ.append(kind == "integrating")
        tau.append(t1)
        tau2.append(t2 if kind == "soptd" else 0.0)
    return _Configs(np.asarray(a1, float), np.asarray(a2, float), np.asarray(d, np.int64),
                    np.asarray(integ, np.bool_), kinds, np.asarray(tau, float), np.asarray(tau2, float))


def _hp_filter(v: np.ndarray, a: float) -> np.ndarray:
    """``(1 - q^-1) / (1 - a q^-1)`` along axis 0, starting at rest at the first sample."""
    arr = np.asarray(v, dtype=np.float64)
    if arr.ndim == 2 and arr.shape[1] == 0:
        return np.zeros_like(arr)
    return kernels.hp_filter(arr, float(a))


def _score_design(z: np.ndarray, n: int, load_order: int, ahp: float) -> np.ndarray:
    """Columns [z, load basis] as the search scores them (prefiltered when ``ahp >= 0``)."""
    B = _legendre_basis(n, load_order)
    if ahp >= 0:
        return np.column_stack([_hp_filter(z, ahp), _hp_filter(B[:, 1:], ahp) if load_order >= 1
                                else np.zeros((n, 0))])
    return np.column_stack([z, B])


class _Problem:
    """Data prepared once: scaled PV, score weights, orthonormal load basis, noise prefilter."""

    def __init__(self, x: np.ndarray, y: np.ndarray, ts_s: float, w: np.ndarray, load_order: int,
                 hp_tau_s: float | None = None, gain_fixed: float | None = None,
                 gain_sign: float | None = None):
        self.x = np.ascontiguousarray(x, dtype=np.float64)
        self.ts_s = float(ts_s)
        self.n = x.shape[0]
        self.w = np.ascontiguousarray(w, dtype=np.float64)
        self.n_scored = int(np.count_nonzero(self.w))
        ws = self.w > 0
        self.y_mean = float(np.mean(y[ws]))
        self.y_std = float(np.std(y[ws])) or 1.0
        yn = (y - self.y_mean) / self.y_std
        self.yraw = np.asarray(y, dtype=float)
        self.load_order = load_order
        B = _legendre_basis(self.n, load_order)
        self.hp_tau_s = float(hp_tau_s) if hp_tau_s is not None and hp_tau_s > 0 else None
        if hp_tau_s is not None and hp_tau_s > 0:
            self.ahp = math.exp(-ts_s / hp_tau_s)
            yn = _hp_filter(yn, self.ahp)
            B = _hp_filter(B[:, 1:], self.ahp) if load_order >= 1 else np.zeros((self.n, 0))
        else:
            self.ahp = -1.0
        self.y = np.ascontiguousarray(yn)
        self.yw = self.w * self.y
        if B.shape[1] > 0:
            # Orthonormalise the basis on the scored samples: Q = B R^-1 with Q_s^T Q_s = I.
            _, R = np.linalg.qr(B[ws])
            self.Q = np.linalg.solve(R.T, B.T).T
        else:
            self.Q = np.zeros((self.n, 0))
        self.Qw = np.ascontiguousarray(self.Q * self.w[:, None])
        self.Qty = self.Qw.T @ self.y
        self.sst = float(np.sum(self.yw * self.y))
        self.yyp = float(self.sst - self.Qty @ self.Qty)
        self.evals = 0
        self.gain_fixed = gain_fixed
        self.gain_sign = float(np.sign(gain_sign)) if gain_sign else 0.0

    def sse(self, S, J, F, cfg: _Configs) -> tuple[np.ndarray, np.ndarray]:
        S = np.ascontiguousarray(S, dtype=np.float64)
        J = np.ascontiguousarray(J, dtype=np.float64)
        F = np.ascontiguousarray(F, dtype=np.float64)
        m, P = S.shape[0], len(cfg)
        out, gain = kernels.score(self.x, S, J, F, cfg.a1, cfg.a2, cfg.d, cfg.integ, self.ts_s, self.ahp,
                                  self.w, self.yw, self.Qw, self.Qty, self.yyp,
                                  self.gain_fixed / self.y_std if self.gain_fixed is not None else np.nan)
        self.evals += m * P * self.n
        if self.gain_sign:
            # a process gain against the controller's action is the controller path (PV explained
            # through OP = f(PV)), not the plant: score it no better than no process at all
            np.copyto(out, np.maximum(out, self.yyp), where=gain * self.gain_sign < 0)
        return np.maximum(out, 0.0), gain


def _burn_in(x: np.ndarray, burn_frac: float) -> int:
    """Samples left out of the score at the start: the valve's initial state is unknown.

    At least ``burn_frac`` of the record, and until OP has travelled over 60 % of its robust range
    and back by half of that (a candidate valve started at rest has then moved both ways and is in
    step with the plant's); never more than a quarter of the record.
    """
    n = x.shape[0]
    lo, hi = np.percentile(x, [0.5, 99.5])
    need = 0.6 * (hi - lo)
    run_max = np.maximum.accumulate(x)
    run_min = np.minimum.accumulate(x)
    k = np.flatnonzero(run_max - run_min >= need)
    burn = int(burn_frac * n)
    if k.size:
        k1 = int(k[0])
        # ... and back: the first reversal by half of that after k1
        up = x[k1] >= x[0] + 0.5 * (run_max[k1] - run_min[k1]) - 1e-12
        tail = x[k1:]
        ext = np.maximum.accumulate(tail) if up else np.minimum.accumulate(tail)
        back = np.flatnonzero(np.abs(ext - tail) >= 0.5 * need)
        k2 = k1 + int(back[0]) if back.size else n
        burn = max(burn, k2)
    else:
        burn = n
    return int(min(max(burn, 3), n // 4))


def _score_weights(n: int, train, burn: int) -> np.ndarray:
    w = np.zeros(n)
    if train is None:
        w[:] = 1.0
    else:
        t = np.asarray(train) if not isinstance(train, slice) else None
        if isinstance(train, slice):
            w[train] = 1.0
        elif t.dtype == bool:
            if t.shape[0] != n:
                raise DataError(f"train mask has {t.shape[0]} samples, the record {n}")
            w[t] = 1.0
        else:
            w[t.astype(np.int64)] = 1.0
    w[:burn] = 0.0
    if np.count_nonzero(w) < MIN_SAMPLES // 2:
        raise DataError(f"only {int(np.count_nonzero(w))} samples left to score the fit; "
                        f"give a longer record or a larger training set")
    return w
