"""The fixed experimental protocol for the seed paper's NARX experiments (shared/notes/narx-protocol.md).

Plant: the two-parameter stiction model, f0 = +1, starting at rest at its first input. Signals: one
sample per time step; a training, a validation (model selection only) and an unseen test signal.
Scoring: samples ``SCORE_FROM..N-1``. Everything here generates data; no network calls it at run time.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..stiction_model import simulate_valve

#: The paper's four classes as the protocol fixes them: (S, J) in % of span.
CASES: dict[str, tuple[float, float]] = {
    "deadband": (3.0, 0.0),
    "undershoot": (3.0, 1.0),
    "no_offset": (3.0, 3.0),
    "overshoot": (1.0, 3.0),
}

#: First scored sample of every signal.
SCORE_FROM = 10


def _two_sines(n: int, a1: float, p1: float, a2: float, p2: float, scale: float = 1.0) -> np.ndarray:
    t = np.arange(n, dtype=float)
    return 50.0 + scale * (a1 * np.sin(2 * np.pi * t / p1) + a2 * np.sin(2 * np.pi * t / p2))


def train_signal(n: int = 2000, scale: float = 1.0) -> np.ndarray:
    """Training input, % of span: 50 + 10 sin(2 pi t/100) + 0.5 sin(2 pi t/730) (amplitudes x scale)."""
    return _two_sines(n, 10.0, 100.0, 0.5, 730.0, scale)


def validation_signal(n: int = 1000, scale: float = 1.0) -> np.ndarray:
    """Validation input (model selection only): 50 + 9 sin(2 pi t/113) + 1.0 sin(2 pi t/277)."""
    return _two_sines(n, 9.0, 113.0, 1.0, 277.0, scale)


def test_signal(n: int = 2000, scale: float = 1.0) -> np.ndarray:
    """Unseen test input: 50 + 8 sin(2 pi t/87) + 1.5 sin(2 pi t/331)."""
    return _two_sines(n, 8.0, 87.0, 1.5, 331.0, scale)


def long_signal(n: int = 10_000, scale: float = 1.0) -> np.ndarray:
    """Unseen input for the 10 000-step model-mode run (Section IV-C):
    50 + 7 sin(2 pi t/123) + 2 sin(2 pi t/457) + 0.7 sin(2 pi t/1999)."""
    t = np.arange(n, dtype=float)
    return 50.0 + scale * (7.0 * np.sin(2 * np.pi * t / 123.0) + 2.0 * np.sin(2 * np.pi * t / 457.0)
                           + 0.7 * np.sin(2 * np.pi * t / 1999.0))


def signal_scale(S_pct: float, J_pct: float) -> float:
    """Amplitude factor of the bank protocol: 1 up to S + J = 8 % of span, then (S + J)/8.

    The protocol's signals swing about 20 % of span; a valve with S + J above that would never slip
    again after the first move, so bank cases with large stiction use proportionally larger sines.
    """
    return max(1.0, (S_pct + J_pct) / 8.0)


@dataclass(frozen=True)
class Dataset:
    """Input/output series of one case: x = valve input (OP), y = stem position (MV), % of span."""

    S_pct: float
    J_pct: float
    x_train: np.ndarray
    y_train: np.ndarray
    x_val: np.ndarray
    y_val: np.ndarray
    x_test: np.ndarray
    y_test: np.ndarray
    scale: float = 1.0


def bank_train_signal(n: int = 6000, scale: float = 1.0) -> np.ndarray:
    """Bank training input: 50 + s (10 sin(2 pi t/97.3) + 1.0 sin(2 pi t/731) + 0.3 sin(2 pi t/17.9)).

    Richer than the protocol's training sine (whose integer period puts every slip at nearly the
    same phase): slips fall at many phases, which pins the slip threshold more tightly.
    """
    t = np.arange(n, dtype=float)
    return 50.0 + scale * (10.0 * np.sin(2 * np.pi * t / 97.3) + 1.0 * np.sin(2 * np.pi * t / 731.0)
                           + 0.3 * np.sin(2 * np.pi * t / 17.9))


def bank_validation_signal(n: int = 40_000, scale: float = 1.0) -> np.ndarray:
    """Bank validation input: 50 + s (9 sin(2 pi t/113) + 1.0 sin(2 pi t/277) + 0.4 sin(2 pi t/23.1))."""
    t = np.arange(n, dtype=float)
    return 50.0 + scale * (9.0 * np.sin(2 * np.pi * t / 113.0) + 1.0 * np.sin(2 * np.pi * t / 277.0)
                           + 0.4 * np.sin(2 * np.pi * t / 23.1))


def make_dataset(S_pct: float, J_pct: float, *, scale: float = 1.0, bank: bool = False) -> Dataset:
    """Train/validation/test series for one (S, J) case (f0 = +1).

    ``bank=False``: the fixed protocol's signals (Table I). ``bank=True``: the bank protocol, with
    richer training and validation inputs (`bank_train_signal`, `bank_validation_signal`); the test
    signal is the protocol's in both, amplitudes times ``scale``.
    """
    if bank:
        xs = [bank_train_signal(scale=scale), bank_validation_signal(scale=scale),
              test_signal(scale=scale)]
    else:
        xs = [train_signal(scale=scale), validation_signal(scale=scale), test_signal(scale=scale)]
    ys = [simulate_valve(x, S_pct, J_pct, 1) for x in xs]
    return Dataset(float(S_pct), float(J_pct), xs[0], ys[0], xs[1], ys[1], xs[2], ys[2], float(scale))
