"""A valve as the loop sees it: a friction law, an optional actuator/positioner lag, drifting friction.

`ValveTrain.fill(k, op, out)` writes the stem position on each of the ``m`` internal steps of
sample ``k`` (OP is held over the sample, as a DCS output is). The lag is linear and solved exactly
over the sample:

* ``lag_at="after"`` -- the friction element moves a member that the stem follows through the lag
  (a slow positioner behind a sticking packing: jumps arrive smoothed);
* ``lag_at="before"`` -- the lag acts on the signal before the friction (I/P converter and
  actuator pressure: the friction sees a smooth, delayed OP and the jumps stay sharp).

A `ForceBalance` stem has its own pressure lag and is stepped on its fine step; an extra lag is
put before it. Time-varying friction is a per-sample factor on the bands (or forces).
"""

from __future__ import annotations

import math

import numpy as np

from .friction import ForceBalance
from .linalg import expm_small

__all__ = ["Lag", "ValveTrain"]


class Lag:
    """A unity-gain first- or second-order lag, with its exact response over one held sample.

    Parameters
    ----------
    order : {1, 2}
    tau_s : float
        Time constant (order 1), or ``1/wn`` (order 2), seconds.
    zeta : float
        Damping of the second-order lag.
    h_s : float
        Internal step, seconds; ``m`` internal steps per sample.
    """

    def __init__(self, order: int, tau_s: float, zeta: float, h_s: float, m: int) -> None:
        if order not in (1, 2) or not tau_s > 0:
            raise ValueError(f"a lag needs order 1 or 2 and tau_s > 0, got {order}, {tau_s}")
        if order == 1:
            A = np.array([[-1.0 / tau_s]])
            B = np.array([1.0 / tau_s])
        else:
            wn = 1.0 / tau_s
            A = np.array([[0.0, 1.0], [-wn * wn, -2.0 * zeta * wn]])
            B = np.array([0.0, wn * wn])
        nx = A.shape[0]
        M = np.zeros((nx + 1, nx + 1))
        M[:nx, :nx] = A
        M[:nx, nx] = B
        E = expm_small(M * h_s)
        Phi, Gam = E[:nx, :nx], E[:nx, nx]
        # output on internal step j (1..m) from the state at the start and the held input
        O = np.empty((m, nx))
        Gc = np.empty(m)
        P = np.eye(nx)
        acc = np.zeros(nx)
        for j in range(m):
            acc = Phi @ acc + Gam
            P = Phi @ P
            O[j] = P[0]
            Gc[j] = acc[0]
        self.O, self.Gc = O, Gc
        self.Pm, self.Gm = P, acc
        self.nx = nx
        self.state = np.zeros(nx)

    def reset(self, y0: float) -> None:
        self.state = np.zeros(self.nx)
        self.state[0] = y0

    def respond(self, u: float) -> np.ndarray:
        """The lag's output on the ``m`` internal steps with input ``u`` held; advances the state."""
        out = self.O @ self.state + self.Gc * u
        self.state = self.Pm @ self.state + self.Gm * u
        return out


class ValveTrain:
    """Friction law + optional lag + optional friction schedule, stepped once per controller sample.

    Parameters
    ----------
    law : friction law
        `Linear`, `Backlash`, `TwoParameter`, `Kano` or `ForceBalance`.
    m : int
        Internal steps per sample; ``h_s`` their length in seconds.
    lag : Lag, optional
    lag_at : {"after", "before"}
    schedule : array (n_total,), optional
        Friction factor per sample (1 = nominal); applied with ``bands`` (S, J, S_close, J_close)
        for the data-driven laws, or as a force scale for `ForceBalance`.
    """

    def __init__(self, law, *, m: int, h_s: float, lag: Lag | None = None, lag_at: str = "after",
                 schedule: np.ndarray | None = None, bands: tuple | None = None) -> None:
        if lag_at not in ("after", "before"):
            raise ValueError(f"lag_at must be 'after' or 'before', got {lag_at!r}")
        self.law = law
        self.m = int(m)
        self.lag = lag
        self.lag_at = "before" if isinstance(law, ForceBalance) else lag_at
        self.schedule = schedule
        self.bands = bands
        self.physical = isinstance(law, ForceBalance)
        # position of the friction element at the end of the last sample (the stem itself unless a
        # lag follows the friction): where stick and slip are measured
        self.friction_y = 0.0
        if self.physical:
            # a whole number of fine steps per internal step, so the stem keeps real time
            self.n_fine = max(1, int(math.ceil(h_s / law.h - 1e-9)))
            law.set_step(h_s / self.n_fine)

    def reset(self, x0: float) -> float:
        y = self.law.reset(x0)
        if self.physical:
            y = self.law.x
        self.friction_y = y
        if self.lag is not None:
            self.lag.reset(x0 if self.lag_at == "before" else y)
        return y

    def _apply_schedule(self, k: int) -> None:
        f = float(self.schedule[k])
        if self.physical:
            self.law.scale(f)
        else:
            S, J, Sc, Jc = self.bands
            self.law.set_bands(S * f, J * f, None if Sc is None else Sc * f, None if Jc is None else Jc * f)

    def fill(self, k: int, op: float, out: np.ndarray) -> None:
        """Write the stem position on each internal step of sample ``k`` into ``out`` (length m)."""
        if self.schedule is not None:
            self._apply_schedule(k)
        law = self.law
        if self.physical:
            n_fine = self.n_fine
            if self.lag is None:
                if law.holds(op, n_fine * self.m):
                    out[:] = law.x
                    self.friction_y = law.x
                    return
                for j in range(self.m):
                    law.advance(op, n_fine)
                    out[j] = law.x
            else:
                z = self.lag.respond(op)
                for j in range(self.m):
                    law.advance(float(z[j]), n_fine)
                    out[j] = law.x
            self.friction_y = law.x
            return
        if self.lag is None:
            out[:] = self.friction_y = law.step(op)
        elif self.lag_at == "after":
            self.friction_y = law.step(op)
            out[:] = self.lag.respond(self.friction_y)
        else:
            z = self.lag.respond(op)
            for j in range(self.m):
                out[j] = law.step(float(z[j]))
            self.friction_y = out[-1]

