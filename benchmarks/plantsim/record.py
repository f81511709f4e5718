"""The record type of the simulator and the names of the stiction classes."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["SimLoop", "CLASSES", "stiction_class"]

CLASSES = ("deadband", "undershoot", "no_offset", "overshoot")


@dataclass(frozen=True)
class SimLoop:
    """One simulated record with its truth.

    Attributes
    ----------
    op, pv, sp, mv : ndarray (n,)
        Controller output (% of span), transmitted PV and setpoint (PV units), stem position
        (% of span; the true stem, before any historian artifact). Read-only.
    ts_s : float
        Sample period, seconds.
    name : str
        Loop tag (also the file stem when written).
    sticky : bool
        The label: the valve has stiction.
    kind : str
        Scenario (see `SCENARIOS`) or, for concealed-effect records, ``concealed``.
    meta : dict
        Every drawn parameter and derived truth (``S_pct``, ``J_pct``, ``law``, ``process``...).
    """

    op: np.ndarray
    pv: np.ndarray
    sp: np.ndarray
    mv: np.ndarray
    ts_s: float
    name: str
    sticky: bool
    kind: str
    meta: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        for k in ("op", "pv", "sp", "mv"):
            a = np.array(getattr(self, k), dtype=float)
            a.setflags(write=False)
            object.__setattr__(self, k, a)

    @property
    def n(self) -> int:
        return int(self.op.shape[0])


def stiction_class(S_pct: float, J_pct: float) -> str:
    """Class of a (S, J) pair, with J judged equal to S or to 0 within 15 % of S (0.1 % at least)."""
    if S_pct <= 0.1 and J_pct <= 0.1:
        return "none"
    tol = max(0.1, 0.15 * S_pct)
    if J_pct <= tol:
        return "deadband"
    if abs(J_pct - S_pct) <= tol:
        return "no_offset"
    return "undershoot" if J_pct < S_pct else "overshoot"
