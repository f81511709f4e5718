"""Error measures of the seed paper, as this package defines them (docs/narx.md).

All series are in % of valve span, so RMSE is in % of span. Scoring starts at ``start``
(the protocol's SCORE_FROM = 10).
"""

from __future__ import annotations

import numpy as np


def rmse_pct(y_true, y_hat, start: int = 10) -> float:
    """Root-mean-square error over samples ``start..n-1``, % of span."""
    y = np.asarray(y_true, float)[start:]
    yh = np.asarray(y_hat, float)[start:]
    return float(np.sqrt(np.mean((yh - y) ** 2)))


def cdc_pct(y_true, y_hat, start: int = 10) -> float:
    """Correct directional change, %: over samples t >= max(start, 1) where the true y changes,
    the share with sign(yhat[t] - y[t-1]) == sign(y[t] - y[t-1])."""
    y = np.asarray(y_true, float)
    yh = np.asarray(y_hat, float)
    t0 = max(start, 1)
    dy = y[t0:] - y[t0 - 1:-1]
    dh = yh[t0:] - y[t0 - 1:-1]
    moved = dy != 0.0
    if not np.any(moved):
        return float("nan")
    return float(100.0 * np.mean(np.sign(dh[moved]) == np.sign(dy[moved])))


def direction_agreement_pct(y_true, y_hat, start: int = 10, dead_pct: float = 0.05) -> float:
    """Three-way direction agreement, % of all scored samples: the step of y and of yhat (from the
    true previous y) are classed -1/0/+1 with |step| <= dead_pct counting as 0, and compared."""
    y = np.asarray(y_true, float)
    yh = np.asarray(y_hat, float)
    t0 = max(start, 1)
    dy = y[t0:] - y[t0 - 1:-1]
    dh = yh[t0:] - y[t0 - 1:-1]

    def cls(d):
        return np.where(np.abs(d) <= dead_pct, 0, np.sign(d))

    return float(100.0 * np.mean(cls(dy) == cls(dh)))
