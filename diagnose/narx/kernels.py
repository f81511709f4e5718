"""Compiled model-mode (free-run) loops for exported network weights.

The networks are trained in torch; for long free runs the trained weights are exported to plain
arrays and the same arithmetic runs here in a numba loop (a free run is sequential, one step at a
time, and a per-step torch call costs far more than the step's arithmetic). These functions are
the trained networks, not the plant.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit


@njit(cache=True, nogil=True)
def gated_free_run(x, y0, y1, p, out):  # pragma: no cover - compiled
    """Free run of the gated NARX-SP network with hard gates.

    p = [theta_s, theta_m, a_m, a_s, c_s, tau_pct, w_d, w_dx, w_dy, b_s]
    slip logit = (|d| - theta_s) + w_d*d + w_dx*dx + w_dy*dy + b_s, hard gate = logit > 0.
    """
    n = x.shape[0]
    th_s = p[0]
    th_m = p[1]
    a_m = p[2]
    a_s = p[3]
    c_s = p[4]
    tau = p[5]
    out[0] = y0
    if n > 1:
        out[1] = y1
    for t in range(2, n):
        ya = out[t - 1]
        yb = out[t - 2]
        d = x[t] - ya
        dx = x[t] - x[t - 1]
        dy = ya - yb
        pm = math.tanh(dx / tau) * math.tanh(dy / tau)
        if pm > th_m:
            out[t] = ya + a_m * dx
        else:
            ls = abs(d) - th_s + p[6] * d + p[7] * dx + p[8] * dy + p[9]
            if ls > 0.0:
                out[t] = ya + a_s * d - c_s * math.tanh(d / tau)
            else:
                out[t] = ya
    return out


@njit(cache=True, nogil=True)
def mlp_free_run(x, y0, y1, W1, b1, W2, b2, mu, sd, out):  # pragma: no cover - compiled
    """Free run of a one-hidden-layer tanh MLP NARX on normalised [y(t-1), y(t-2), x(t), x(t-1)]."""
    n = x.shape[0]
    h = W1.shape[0]
    out[0] = y0
    if n > 1:
        out[1] = y1
    z = np.empty(4)
    for t in range(2, n):
        z[0] = (out[t - 1] - mu) / sd
        z[1] = (out[t - 2] - mu) / sd
        z[2] = (x[t] - mu) / sd
        z[3] = (x[t - 1] - mu) / sd
        acc = b2
        for i in range(h):
            a = b1[i]
            for j in range(4):
                a += W1[i, j] * z[j]
            acc += W2[i] * math.tanh(a)
        out[t] = mu + sd * acc
    return out
