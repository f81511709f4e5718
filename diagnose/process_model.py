"""Low-order linear process models: the linear block of the Hammerstein fit.

Discrete time, sample period ``ts_s``, input ``u`` the valve stem position in % of span::

    u_d[k] = u[k - d]                    (u[k] = u[0] for k < 0; d = round(delay_s / ts_s))
    z1[k]  = a1 z1[k-1] + (1 - a1) u_d[k]          a1 = exp(-ts_s / tau_s)
    z2[k]  = a2 z2[k-1] + (1 - a2) z1[k]           a2 = exp(-ts_s / tau2_s)   (soptd only)
    foptd / soptd:  pv[k] = bias + gain * z[k]     (z = z1 or z2, starting at u[0]: steady state)
    integrating:    pv[k] = bias + gain * ts_s * sum_{i<=k} (z1[i] - u_balance)

The closed-loop simulator (`diagnose.simulate`) steps the same model one sample at a time
(`ProcessModel.stepper`), so a model identified from a simulated loop can be compared with the
simulator's parameters directly. ``gain`` is PV units per % of valve travel (integrating: PV units
per second per %).

`ProcessModel` is the one description of a linear process: the fit's result, the simulator's plant,
the candidates of the fit's structure search (unit gain, zero bias) and the process part of
`stiction explain`'s augmented model.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from . import kernels
from .errors import DataError

KINDS = ("foptd", "soptd", "integrating")


def lag_coefficient(tau_s: float, ts_s: float) -> float:
    """Discrete pole ``exp(-ts/tau)`` of a lag (0 for tau = 0: no lag)."""
    return math.exp(-ts_s / tau_s) if tau_s > 0 else 0.0


@dataclass(frozen=True)
class ProcessModel:
    """A first/second-order-plus-dead-time or integrating process.

    Parameters
    ----------
    kind : {"foptd", "soptd", "integrating"}
    gain : float
        PV units per % of valve travel (integrating: PV units per second per %).
    tau_s : float
        (First) time constant, seconds (integrating: the input lag, may be 0).
    delay_s : float
        Dead time, seconds (a whole number of samples).
    bias : float
        PV offset (self-regulating: PV at 0 % valve travel; integrating: PV at the first sample).
    tau2_s : float
        Second time constant (soptd), seconds.
    u_balance_pct : float, optional
        Integrating only: valve position at which PV holds still (None: the first input).
    """

    kind: str
    gain: float
    tau_s: float
    delay_s: float
    bias: float
    tau2_s: float = 0.0
    u_balance_pct: float | None = None
    meta: dict = field(default_factory=dict, compare=False, repr=False)

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise DataError(f"unknown process kind {self.kind!r}; use foptd, soptd or integrating")
        if not (self.tau_s >= 0 and self.tau2_s >= 0 and self.delay_s >= 0):
            raise DataError("process time constants and dead time must be >= 0 seconds")

    def regressor(self, u_pct, ts_s: float) -> np.ndarray:
        """The unit-gain response ``z`` of the lags (and integrator) to ``u_pct``."""
        u = np.ascontiguousarray(u_pct, dtype=np.float64)
        if u.ndim != 1 or u.shape[0] == 0:
            raise DataError(f"u_pct must be a non-empty 1-D series, got shape {u.shape}")
        a1 = lag_coefficient(self.tau_s, ts_s)
        a2 = lag_coefficient(self.tau2_s, ts_s) if self.kind == "soptd" else -1.0
        d = int(round(self.delay_s / ts_s))
        return kernels.lag_filter(u, a1, a2, d, self.kind == "integrating", float(ts_s))

    def simulate(self, u_pct, ts_s: float) -> np.ndarray:
        """PV for valve position ``u_pct`` (% of span), starting at steady state at ``u_pct[0]``."""
        z = self.regressor(u_pct, ts_s)
        if self.kind == "integrating":
            u0 = float(np.asarray(u_pct, dtype=float)[0])
            ub = u0 if self.u_balance_pct is None else self.u_balance_pct
            t = ts_s * np.arange(1, z.shape[0] + 1)
            return self.bias + self.gain * (z - ub * t)
        return self.bias + self.gain * z

    def stepper(self) -> "ProcessStepper":
        """A stateful copy that runs this process one sample at a time (the simulator's plant)."""
        return ProcessStepper(self)

    def structure_key(self, ts_s: float) -> tuple:
        """(kind, tau_s, tau2_s, delay in samples): the process structure, gain and bias aside."""
        return (self.kind, float(self.tau_s), float(self.tau2_s) if self.kind == "soptd" else 0.0,
                int(round(self.delay_s / ts_s)))

    @property
    def time_constant_s(self) -> float:
        """Sum of lags plus dead time: a rough settling scale."""
        return self.tau_s + self.tau2_s + self.delay_s

    def describe(self, short: bool = False) -> str:
        """The process in words for a report: ``"soptd, gain 9.01, time constant 10.1 s, second
        time constant 10.1 s, dead time 10 s"``; ``short``: ``tau``/``tau2`` for a terminal line."""
        from .plain import duration, number

        lag, lag2 = ("tau", "tau2") if short else ("time constant", "second time constant")
        bits = [self.kind, f"gain {number(self.gain)}", f"{lag} {duration(self.tau_s)}"]
        if self.kind == "soptd":
            bits.append(f"{lag2} {duration(self.tau2_s)}")
        bits.append(f"dead time {duration(self.delay_s)}")
        return ", ".join(bits)

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {"kind": self.kind, "gain": float(self.gain), "tau_s": float(self.tau_s),
                               "delay_s": float(self.delay_s), "bias": float(self.bias)}
        if self.kind == "soptd":
            out["tau2_s"] = float(self.tau2_s)
        if self.kind == "integrating":
            out["u_balance_pct"] = None if self.u_balance_pct is None else float(self.u_balance_pct)
        return out


class ProcessStepper:
    """A `ProcessModel` run one sample at a time: ``reset(u0_pct, ts_s) -> pv``, ``step(u_pct) -> pv``.

    The closed-loop simulator's process protocol (`diagnose.simulate.Process`). It starts at steady
    state at ``u0_pct`` (integrating: PV at ``bias``, balanced at ``u_balance_pct`` or ``u0_pct``)
    and follows the discretisation of the module docstring sample for sample.
    """

    def __init__(self, model: ProcessModel) -> None:
        self.model = model

    def reset(self, u0_pct: float, ts_s: float) -> float:
        m = self.model
        if not ts_s > 0:
            raise DataError(f"ts_s must be > 0 seconds, got {ts_s}")
        self._ts = float(ts_s)
        self._a1 = lag_coefficient(m.tau_s, ts_s)
        self._a2 = lag_coefficient(m.tau2_s, ts_s)
        d = int(round(m.delay_s / ts_s))
        self._buf = deque([float(u0_pct)] * d)
        if m.kind == "integrating":
            self._ub = float(u0_pct) if m.u_balance_pct is None else float(m.u_balance_pct)
            self._uf = float(u0_pct)
            self._pv = float(m.bias)
            return self._pv
        self._x1 = self._x2 = m.gain * u0_pct
        return m.bias + (self._x2 if m.kind == "soptd" else self._x1)

    def step(self, u_pct: float) -> float:
        m = self.model
        if self._buf:
            self._buf.append(u_pct)
            u = self._buf.popleft()
        else:
            u = u_pct
        if m.kind == "integrating":
            self._uf = self._a1 * self._uf + (1.0 - self._a1) * u
            self._pv += self._ts * m.gain * (self._uf - self._ub)
            return self._pv
        self._x1 = self._a1 * self._x1 + (1.0 - self._a1) * m.gain * u
        if m.kind == "soptd":
            self._x2 = self._a2 * self._x2 + (1.0 - self._a2) * self._x1
            return m.bias + self._x2
        return m.bias + self._x1
