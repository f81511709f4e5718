"""Beyond the paper: one conditional NARX-SP network for the whole (S, J) plane.

The gated NARX-SP network of `networks.NarxSP` with its slip threshold and jump offset made linear
functions of (S, J), which are inputs of the network::

    theta_s(S, J) = p0 + p1 S + p2 J          (slip gate threshold, % of span)
    c_s(S, J)     = q0 + q1 S + q2 J          (jump offset, % of span)
    y(t) = y(t-1) + m a_m dx + (1 - m) s (a_s d - c_s(S, J) sign(d))

Training on many (S, J) cases at once: Adam with annealed gates, then the two heads by least
squares and the slip gate's weights (p0, p1, p2) by a maximum-margin linear program over the
non-moving training samples (the gate is a linear threshold unit in (|d|, 1, S, J)). It never calls
the stiction model; the training data come from it.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from ..errors import DataError, NotFittedError
from .kernels import gated_free_run
from .networks import TAU_PCT


@dataclass(frozen=True)
class ConditionalFit:
    p: tuple            # slip threshold weights (p0, p1, p2)
    q: tuple            # jump offset weights (q0, q1, q2)
    a_m: float
    a_s: float
    theta_m: float
    margin_pct: float   # the max-margin LP's margin on the training data
    fit_time_s: float


class ConditionalNarxSP:
    """One NARX-SP network with (S, J) as inputs. ``fit(cases)`` with cases = [(S, J, x, y), ...]."""

    def __init__(self, *, epochs: int = 200, lr: float = 0.05, seed: int = 0):
        self.epochs = epochs
        self.lr = lr
        self.seed = seed

    @staticmethod
    def _stack(cases):
        cols = {k: [] for k in ("d", "dx", "dy", "t", "S", "J")}
        for S, J, x, y in cases:
            x = np.asarray(x, float)
            y = np.asarray(y, float)
            moved = np.flatnonzero(np.diff(y) != 0.0)
            if moved.size < 3:
                raise DataError(f"case S={S}, J={J}: the valve barely moves in its training data")
            st = int(moved[0]) + 1
            x, y = x[st:], y[st:]
            cols["d"].append(x[2:] - y[1:-1])
            cols["dx"].append(x[2:] - x[1:-1])
            cols["dy"].append(y[1:-1] - y[:-2])
            cols["t"].append(y[2:] - y[1:-1])
            cols["S"].append(np.full(x.shape[0] - 2, float(S)))
            cols["J"].append(np.full(x.shape[0] - 2, float(J)))
        return {k: np.concatenate(v) for k, v in cols.items()}

    def fit(self, cases):
        import torch
        from scipy.optimize import linprog
        t0 = time.perf_counter()
        torch.manual_seed(self.seed)
        z = self._stack(cases)
        T = {k: torch.tensor(v) for k, v in z.items()}
        prm = {k: torch.nn.Parameter(torch.tensor(v, dtype=torch.float64)) for k, v in
               dict(p=[0.0, 0.5, 0.5], q=[0.0, 0.0, 0.0], a_m=1.0, a_s=1.0, th_m=0.5,
                    log_k=0.0).items()}
        opt = torch.optim.Adam(prm.values(), lr=self.lr)
        pm = torch.tanh(T["dx"] / TAU_PCT) * torch.tanh(T["dy"] / TAU_PCT)
        sg = torch.tanh(T["d"] / TAU_PCT)
        for ep in range(self.epochs):
            beta = 300.0 ** (ep / max(self.epochs - 1, 1))
            opt.zero_grad()
            k = 4.0 * torch.exp(prm["log_k"]) * beta
            th = prm["p"][0] + prm["p"][1] * T["S"] + prm["p"][2] * T["J"]
            c = prm["q"][0] + prm["q"][1] * T["S"] + prm["q"][2] * T["J"]
            m = torch.sigmoid(k * (pm - prm["th_m"]))
            s = torch.sigmoid(k * (T["d"].abs() - th))
            pred = m * prm["a_m"] * T["dx"] + (1 - m) * s * (prm["a_s"] * T["d"] - c * sg)
            loss = torch.mean((pred - T["t"]) ** 2)
            loss.backward()
            opt.step()
        th_m = float(prm["th_m"].detach())
        pm_n, sg_n, d, t = pm.numpy(), sg.numpy(), z["d"], z["t"]
        moving = pm_n > th_m
        a_m = float(np.linalg.lstsq(z["dx"][moving, None], t[moving], rcond=None)[0][0])
        free = ~moving
        slip = free & (t != 0.0)
        stuck = free & (t == 0.0)
        # slip gate: maximum-margin threshold  |d| - (p0 + p1 S + p2 J) >= +margin on slips,
        # <= -margin on stuck samples; maximise margin (bounded so the LP is bounded)
        ad = np.abs(d)
        A_s = np.column_stack([np.ones(slip.sum()), z["S"][slip], z["J"][slip], np.ones(slip.sum())])
        A_t = np.column_stack([-np.ones(stuck.sum()), -z["S"][stuck], -z["J"][stuck],
                               np.ones(stuck.sum())])
        A = np.vstack([A_s, A_t])
        b = np.concatenate([ad[slip], -ad[stuck]])
        res = linprog(c=[0, 0, 0, -1], A_ub=A, b_ub=b,
                      bounds=[(None, None)] * 3 + [(None, 1.0)], method="highs")
        if res.status != 0:
            raise DataError(f"conditional network: the slip-gate linear program failed ({res.message})")
        p = tuple(float(v) for v in res.x[:3])
        margin = float(res.x[3])
        # jump head: t = a_s d - (q0 + q1 S + q2 J) sign(d) on slips (least squares)
        Ah = np.column_stack([d[slip], -sg_n[slip], -sg_n[slip] * z["S"][slip],
                              -sg_n[slip] * z["J"][slip]])
        sol = np.linalg.lstsq(Ah, t[slip], rcond=None)[0]
        self.fit_ = ConditionalFit(p, tuple(float(v) for v in sol[1:]), a_m, float(sol[0]), th_m,
                                   margin, time.perf_counter() - t0)
        return self

    def params_for(self, S_pct: float, J_pct: float) -> np.ndarray:
        """The kernel parameter vector of the network at (S, J)."""
        if not hasattr(self, "fit_"):
            raise NotFittedError("the conditional network is not fitted yet; call fit() first")
        f = self.fit_
        th = f.p[0] + f.p[1] * S_pct + f.p[2] * J_pct
        c = f.q[0] + f.q[1] * S_pct + f.q[2] * J_pct
        return np.array([th, f.theta_m, f.a_m, f.a_s, c, TAU_PCT, 0.0, 0.0, 0.0, 0.0])

    def free_run(self, S_pct: float, J_pct: float, x, y_init=None) -> np.ndarray:
        x = np.ascontiguousarray(x, dtype=np.float64)
        y0, y1 = (x[0], x[0]) if y_init is None else (float(y_init[0]), float(y_init[1]))
        return gated_free_run(x, y0, y1, self.params_for(S_pct, J_pct), np.empty_like(x))
