"""Linear process models, discretised exactly on a fine internal step.

A process is a continuous transfer function ``G(s) = num(s)/den(s)`` (PV units per % of valve
flow) with a dead time. It is turned into a state-space model (`scipy.signal.tf2ss`), discretised
with a zero-order hold on an internal step ``h = ts/m`` (the exact exponential of the augmented
matrix ``[[A, B], [0, 0]] h``, `linalg.zoh`), and the
``m`` internal steps of one controller sample are folded into one update::

    x[k+1] = Phi^m x[k] + sum_j Phi^(m-1-j) Gamma u_j        (u_j: input on internal step j)

so the process responds exactly to an input that changes inside a sample (a lagged or sliding
stem). The dead time is a whole number of *internal* steps, so it need not be a multiple of the
sample period. Variables are deviations from the starting steady state: ``PV = pv0 + C x`` and the
input is the flow minus its starting value.

Builders: `foptd`, `soptd` (two distinct lags), `underdamped` (a second-order resonance),
`third_order` (three lags, optionally a lead), `integrating` (an integrator with a lag).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy import signal

from .linalg import zoh

__all__ = ["Process", "foptd", "soptd", "underdamped", "third_order", "integrating", "step_response",
           "flow_characteristic"]


@dataclass(frozen=True)
class Process:
    """A linear process with dead time.

    Parameters
    ----------
    kind : str
        Structure name (``foptd``, ``soptd``, ``underdamped``, ``third_order``, ``integrating``).
    num, den : tuple of float
        Transfer-function coefficients in descending powers of s (time in seconds).
    delay_s : float
        Dead time, seconds.
    gain : float
        Steady-state gain (PV units per % flow), or the integrating rate (PV units per second per
        % flow) for an integrating process.
    params : dict
        The structure's own parameters (time constants, damping), for the labels.
    """

    kind: str
    num: tuple
    den: tuple
    delay_s: float
    gain: float
    params: dict = field(default_factory=dict)

    @property
    def integrating(self) -> bool:
        return abs(self.den[-1]) < 1e-15

    def discretise(self, ts_s: float, m: int) -> "Discrete":
        """The sample-period update for controller period ``ts_s`` with ``m`` internal steps."""
        return Discrete(self, ts_s, m)

    def frequency_response(self, w_rad_s: np.ndarray) -> np.ndarray:
        """``G(jw) exp(-jw delay)`` at angular frequencies ``w_rad_s``."""
        s = 1j * np.asarray(w_rad_s, dtype=float)
        return np.polyval(self.num, s) / np.polyval(self.den, s) * np.exp(-s * self.delay_s)

    def describe(self) -> dict:
        out = {"process": self.kind, "integrating": self.integrating, "gain": self.gain,
               "delay_s": self.delay_s}
        out.update(self.params)
        return out


class Discrete:
    """A `Process` folded to one update per controller sample (see the module docstring)."""

    def __init__(self, proc: Process, ts_s: float, m: int) -> None:
        if not (ts_s > 0 and m >= 1):
            raise ValueError(f"need ts_s > 0 and m >= 1, got {ts_s}, {m}")
        self.proc = proc
        self.ts_s = float(ts_s)
        self.m = int(m)
        self.h_s = ts_s / m
        A, B, C, D = signal.tf2ss(proc.num, proc.den)
        if np.any(np.abs(D) > 0):
            raise ValueError(f"{proc.kind}: a process must be strictly proper (no direct feed-through)")
        Ad, Bd = zoh(A, B, self.h_s)
        Cd = C
        nx = Ad.shape[0]
        G = np.empty((nx, m))
        col = Bd[:, 0].copy()
        for j in range(m - 1, -1, -1):
            G[:, j] = col
            col = Ad @ col
        self.Am = np.linalg.matrix_power(Ad, m)
        self.G = G
        self.C = Cd[0].copy()
        self.nx = nx
        self.delay_steps = int(round(proc.delay_s / self.h_s))

    def reset(self) -> np.ndarray:
        """The steady state (zero deviation)."""
        return np.zeros(self.nx)


def foptd(gain: float, tau_s: float, delay_s: float) -> Process:
    """``K / (tau s + 1)`` with dead time."""
    return Process("foptd", (gain,), (tau_s, 1.0), delay_s, gain, {"tau1_s": tau_s})


def soptd(gain: float, tau1_s: float, tau2_s: float, delay_s: float) -> Process:
    """``K / ((tau1 s + 1)(tau2 s + 1))`` with dead time (two distinct real lags)."""
    den = tuple(np.polymul([tau1_s, 1.0], [tau2_s, 1.0]))
    return Process("soptd", (gain,), den, delay_s, gain, {"tau1_s": tau1_s, "tau2_s": tau2_s})


def underdamped(gain: float, wn_rad_s: float, zeta: float, delay_s: float) -> Process:
    """``K wn^2 / (s^2 + 2 zeta wn s + wn^2)`` with dead time (``zeta < 1``: an overshooting process)."""
    return Process("underdamped", (gain * wn_rad_s ** 2,), (1.0, 2.0 * zeta * wn_rad_s, wn_rad_s ** 2),
                   delay_s, gain, {"wn_rad_s": wn_rad_s, "zeta": zeta})


def third_order(gain: float, taus_s: tuple[float, float, float], delay_s: float,
                lead_s: float = 0.0) -> Process:
    """``K (lead s + 1) / prod(tau_i s + 1)`` with dead time."""
    den = np.array([1.0])
    for t in taus_s:
        den = np.polymul(den, [t, 1.0])
    num = (gain * lead_s, gain) if lead_s > 0 else (gain,)
    return Process("third_order", num, tuple(den), delay_s, gain,
                   {"tau1_s": taus_s[0], "tau2_s": taus_s[1], "tau3_s": taus_s[2], "lead_s": lead_s})


def integrating(rate: float, tau_s: float, delay_s: float) -> Process:
    """``k / (s (tau s + 1))`` with dead time: a level fed through a lag (``rate`` PV units/s per %)."""
    den = (tau_s, 1.0, 0.0) if tau_s > 0 else (1.0, 0.0)
    return Process("integrating", (rate,), den, delay_s, rate, {"tau1_s": tau_s})


def step_response(proc: Process, ts_s: float, n: int, *, m: int = 10, size: float = 1.0) -> np.ndarray:
    """PV deviation at the sample instants after a step of ``size`` % in the input at t = 0.

    Runs the same folded update as the closed loop, so it checks the discretisation itself.
    """
    d = proc.discretise(ts_s, m)
    buf = np.zeros(n * m + d.delay_steps)
    buf[d.delay_steps:] = size
    x = d.reset()
    y = np.empty(n)
    for k in range(n):
        y[k] = d.C @ x
        x = d.Am @ x + d.G @ buf[k * m:(k + 1) * m]
    return y


def flow_characteristic(kind: str, R: float = 30.0):
    """The installed flow (% of maximum) as a function of stem position (% of span).

    ``linear``: ``f = y``; ``equal_percentage``: ``f = 100 R^(y/100 - 1)`` (rangeability ``R``);
    ``quick_opening``: the hyperbolic curve ``f = 100 (1 + R) u / (1 + R u)`` with ``u = y/100``
    (``R`` sets how early it opens). Both keep ``f(100) = 100``. Returns a function of a float or
    a numpy array.
    """
    if kind == "linear":
        return lambda y: y
    if kind == "equal_percentage":
        lnR = math.log(R)
        return lambda y: 100.0 * np.exp(lnR * (np.asarray(y) / 100.0 - 1.0))
    if kind == "quick_opening":
        return lambda y: 100.0 * (1.0 + R) * (np.asarray(y) / 100.0) / (1.0 + R * np.asarray(y) / 100.0)
    raise ValueError(f"unknown flow characteristic {kind!r}; use linear, equal_percentage or quick_opening")
