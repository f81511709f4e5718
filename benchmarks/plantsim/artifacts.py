"""Measurement and historian artifacts: quantisation, swinging-door compression, sensor filtering.

`swinging_door` is the archiving rule of Bristol (1990), the one process historians apply to
every tag: from the last archived point two "doors" pivot at +/- the compression deviation E; each
new sample narrows the range of slopes that keep all samples since the last archive within E of a
straight line; when the doors open past parallel the previous sample is archived and a new segment
starts. `reconstruct` interpolates the archive linearly back onto the sample grid, as a historian
export does. The reconstruction stays within 2 E of the raw signal (within E for most samples) and
is piecewise straight -- exactly the signal shape that can pass for a stiction triangle.
"""

from __future__ import annotations

import math

import numpy as np

from .disturbances import first_order_filter

__all__ = ["quantise", "swinging_door", "reconstruct", "compress", "sensor_filter"]


def quantise(x: np.ndarray, step: float) -> np.ndarray:
    """Round to multiples of ``step`` (an A/D converter's or a historian's resolution)."""
    if step <= 0:
        return np.asarray(x, dtype=float)
    return np.round(np.asarray(x, dtype=float) / step) * step


def swinging_door(x: np.ndarray, dev: float, *, max_gap: int | None = None) -> np.ndarray:
    """Indices of the samples a swinging-door historian archives.

    Parameters
    ----------
    x : array (n,)
        Signal, one value per sample.
    dev : float
        Compression deviation E, in the signal's units.
    max_gap : int, optional
        Archive at least every ``max_gap`` samples (a historian's maximum time between archives).

    Returns
    -------
    ndarray of int
        Archived sample indices, always including the first and the last.
    """
    x = np.asarray(x, dtype=float)
    n = x.shape[0]
    if n <= 2 or dev <= 0:
        return np.arange(n)
    keep = [0]
    a = 0
    xa = float(x[0])
    lo, hi = -math.inf, math.inf
    i = 1
    while i < n:
        dt = i - a
        xi = float(x[i])
        lo_i = max(lo, (xi - xa - dev) / dt)
        hi_i = min(hi, (xi - xa + dev) / dt)
        if lo_i > hi_i or (max_gap is not None and dt > max_gap):
            # the doors opened past parallel: archive the previous sample and restart from it
            a = i - 1
            keep.append(a)
            xa = float(x[a])
            lo, hi = -math.inf, math.inf
            continue                     # re-examine sample i against the new archive
        lo, hi = lo_i, hi_i
        i += 1
    if keep[-1] != n - 1:
        keep.append(n - 1)
    return np.asarray(keep, dtype=int)


def reconstruct(x: np.ndarray, idx: np.ndarray) -> np.ndarray:
    """Linear interpolation of the archived samples ``x[idx]`` back onto every sample."""
    x = np.asarray(x, dtype=float)
    return np.interp(np.arange(x.shape[0]), idx, x[idx])


def compress(x: np.ndarray, dev: float, *, max_gap: int | None = None) -> tuple[np.ndarray, int]:
    """Swinging-door compression and linear reconstruction; returns (signal, archived count)."""
    idx = swinging_door(x, dev, max_gap=max_gap)
    return reconstruct(x, idx), int(idx.shape[0])


def sensor_filter(x: np.ndarray, tau_s: float, ts_s: float) -> np.ndarray:
    """A transmitter's first-order damping filter of time constant ``tau_s``."""
    return first_order_filter(x, tau_s, ts_s)
