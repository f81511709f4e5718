"""Kano's stiction model, written for the tests from the paper, apart from the package's C kernel.

Kano, M., Maruta, H., Kugemoto, H. and Shimizu, K. (2004). Practical model and detection algorithm
for valve stiction. Proc. 7th IFAC Symposium on Dynamics and Control of Process Systems (DYCOPS),
Boston.

Notation of the paper: u(t) valve input (controller output), y(t) valve position, S (deadband plus
stickband) and J (slip jump), u_s the input at the moment the valve last changed from moving to
resting, stp = 1 while the valve rests, d the direction of its last movement (+1 / -1). Per sample:

1. u(t) is limited to [u_min, u_max];
2. a moving valve (stp = 0) stops when its input stops or reverses,
   (u(t) - u(t-1)) (u(t-1) - u(t-2)) <= 0: u_s = u(t-1), stp = 1;
3. a resting valve moves again when the input has left u_s by more than S against the last
   direction (then d = -d), or by more than J along it;
4. moving: y(t) = u(t) - d (S - J) / 2, limited to [u_min, u_max]; resting: y(t) = y(t-1).

The state before the first sample is an argument: the model must be told where the valve was.
"""

from __future__ import annotations

import numpy as np


class KanoValve:
    """One valve of Kano's model, stepped sample by sample (also a simulator valve).

    Parameters
    ----------
    S, J : float
        % of span.
    d0 : {+1, -1}
        Direction of the last movement before the first sample.
    moving : bool
        The valve is moving (in direction d0) at the first sample instead of resting.
    y0, us0 : float, optional
        Resting start: the valve position and the input at which it stopped (default: both the
        first input).
    """

    def __init__(self, S: float, J: float, d0: int = 1, *, moving: bool = False, y0: float | None = None,
                 us0: float | None = None, u_min: float = 0.0, u_max: float = 100.0) -> None:
        self.S, self.J, self.d0 = float(S), float(J), int(d0)
        self.moving, self.y0, self.us0 = moving, y0, us0
        self.u_min, self.u_max = u_min, u_max

    def _lim(self, v: float) -> float:
        return min(max(v, self.u_min), self.u_max)

    def reset(self, u0: float) -> float:
        u0 = self._lim(float(u0))
        self.d = self.d0
        self.u_prev = u0
        if self.moving:
            self.stp = 0
            self.v_prev = float(self.d0)          # it was travelling in direction d0
            self.us = u0
            self.y = self._lim(u0 - self.d * (self.S - self.J) / 2.0)
        else:
            self.stp = 1
            self.v_prev = 0.0
            self.us = u0 if self.us0 is None else float(self.us0)
            self.y = u0 if self.y0 is None else float(self.y0)
        return self.y

    def step(self, u: float) -> float:
        u = self._lim(float(u))
        v = u - self.u_prev
        if self.stp == 0 and v * self.v_prev <= 0.0:
            self.us = self.u_prev
            self.stp = 1
        if self.stp == 1:
            if self.d * (u - self.us) < -self.S:
                self.d = -self.d
                self.stp = 0
            elif self.d * (u - self.us) > self.J:
                self.stp = 0
        if self.stp == 0:
            self.y = self._lim(u - self.d * (self.S - self.J) / 2.0)
        self.u_prev = u
        self.v_prev = v
        return self.y


def kano_valve(u, S: float, J: float, d0: int = 1, **start) -> np.ndarray:
    """Valve position y for the input series u (see `KanoValve` for the start state)."""
    u = np.asarray(u, dtype=float)
    valve = KanoValve(S, J, d0, **start)
    y = np.empty(u.shape[0])
    if u.shape[0]:
        y[0] = valve.reset(u[0])
        for t in range(1, u.shape[0]):
            y[t] = valve.step(u[t])
    return y
