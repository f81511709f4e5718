"""The matrix exponential of the small matrices this simulator discretises (2x2 to 5x5).

Scaling and squaring with a Taylor series: ``A`` is halved ``s`` times until its norm is below
1/2, the series is summed to machine precision, and the result squared ``s`` times. Written on
`numpy.dot` alone because LAPACK-backed routines (`scipy.linalg.expm`, `solve`) can spend
milliseconds per call on thread start-up for matrices this small on a busy multi-core machine.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["expm_small", "zoh"]


def expm_small(A: np.ndarray) -> np.ndarray:
    """``exp(A)`` for a small square matrix."""
    A = np.asarray(A, dtype=float)
    norm = float(np.abs(A).sum(axis=1).max()) if A.size else 0.0
    s = max(0, int(math.ceil(math.log2(norm / 0.5)))) if norm > 0.5 else 0
    X = A / (2.0 ** s)
    E = np.eye(A.shape[0])
    term = np.eye(A.shape[0])
    for k in range(1, 30):
        term = term @ X / k
        E = E + term
        if float(np.abs(term).max()) <= 1e-18 * float(np.abs(E).max()):
            break
    for _ in range(s):
        E = E @ E
    return E


def zoh(A: np.ndarray, B: np.ndarray, h_s: float) -> tuple[np.ndarray, np.ndarray]:
    """Zero-order-hold discretisation of ``x' = A x + B u`` over ``h_s``: returns (Phi, Gamma)."""
    A = np.atleast_2d(np.asarray(A, dtype=float))
    B = np.asarray(B, dtype=float).reshape(A.shape[0], -1)
    n, m = A.shape[0], B.shape[1]
    M = np.zeros((n + m, n + m))
    M[:n, :n] = A
    M[:n, n:] = B
    E = expm_small(M * h_s)
    return E[:n, :n], E[:n, n:]
