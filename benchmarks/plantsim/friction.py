"""Valve friction laws: controller output (OP, % of span) -> stem position (MV, % of span).

Three sticky laws and two healthy ones, each written for this generator alone (nothing here is
shared with `diagnose/`):

* `TwoParameter` -- the data-driven two-parameter model of Choudhury, Thornhill & Shah (2005) in the
  revised form (the stuck point is captured only when a *moving* valve stops or reverses, and the
  direction of the last motion is stored).
* `Kano` -- the stick-slip model of Kano, Maruta, Kugemoto & Shimizu (2004): a stopped valve that
  reverses must cross the deadband plus the stickband (S); a valve that stopped and goes on in the
  same direction only has to break the stickband (J).
* `ForceBalance` -- a physical stem, ``m x'' = F_a - k x - F_v x' - F_f`` with static and Coulomb
  friction and Karnopp stick detection (Karnopp 1985; the valve form of Choudhury, Thornhill & Shah
  2005), integrated exactly over a fine internal step.
* `Linear` (a perfect valve) and `Backlash` (a tiny deadband under the measurement resolution).

The data-driven laws step once per controller sample (`step(x) -> y`). `ForceBalance` integrates
continuous time: `advance(op, n_fine) -> None` moves it ``n_fine`` fine steps with the actuator
signal held, and `x` is the stem position afterwards.

Asymmetry (opening vs closing) and time-varying friction are parameters of the laws
(`set_bands` / `scale`), so the same law serves healthy, sticky and concealed-effect records.
"""

from __future__ import annotations

import math

import numpy as np

from .linalg import expm_small

__all__ = ["Linear", "Backlash", "TwoParameter", "Kano", "ForceBalance", "force_balance_bands",
           "run_static", "run_force_balance"]


def _clip(v: float) -> float:
    return 0.0 if v < 0.0 else (100.0 if v > 100.0 else v)


class Linear:
    """A healthy valve: the stem equals the clipped input."""

    law = "linear"

    def reset(self, x0: float) -> float:
        return _clip(x0)

    def step(self, x: float) -> float:
        return _clip(x)


class Backlash:
    """Mechanical play of total width ``width_pct``: the stem follows once the input pushes it.

    The classic play operator: ``y`` stays while ``|x - y| <= width/2`` and is dragged at
    ``x -/+ width/2`` otherwise. A width of 0.1-0.2 % of span sits under the resolution of a
    typical positioner and counts as healthy.
    """

    law = "backlash"

    def __init__(self, width_pct: float) -> None:
        if not width_pct >= 0:
            raise ValueError(f"backlash width must be >= 0 % of span, got {width_pct}")
        self.half = 0.5 * float(width_pct)

    def reset(self, x0: float) -> float:
        self.y = _clip(x0)
        return self.y

    def step(self, x: float) -> float:
        x = _clip(x)
        if x - self.y > self.half:
            self.y = x - self.half
        elif self.y - x > self.half:
            self.y = x + self.half
        return self.y


class TwoParameter:
    """Two-parameter stiction (Choudhury, Thornhill & Shah 2005, revised form).

    Parameters
    ----------
    S_pct : float
        Deadband plus stickband, % of span: how far the input must travel back after the valve
        stopped before a reversal starts.
    J_pct : float
        Slip jump, % of span. While moving the stem lags the input by ``(S - J)/2`` (it leads it
        when ``J > S``).
    direction0 : {+1, -1}
        Direction of the last motion before the record starts.
    S_close_pct, J_close_pct : float, optional
        Bands for closing motions (direction -1) when friction differs by direction; the opening
        values apply to direction +1.

    Notes
    -----
    Asymmetric bands: the band that decides a start is the one of the motion that would start
    (a reversal to closing must beat ``S_close``; a same-direction restart while closing must beat
    ``J_close``), and the moving offset is that of the current direction.
    """

    law = "two_parameter"

    def __init__(self, S_pct: float, J_pct: float, direction0: int = 1, *,
                 S_close_pct: float | None = None, J_close_pct: float | None = None) -> None:
        self.direction0 = 1 if direction0 >= 0 else -1
        self.set_bands(S_pct, J_pct, S_close_pct, J_close_pct)
        self.reset(50.0)

    def set_bands(self, S_pct: float, J_pct: float, S_close_pct: float | None = None,
                  J_close_pct: float | None = None) -> None:
        """Change the friction bands (time-varying friction); the valve state is kept."""
        s_up, j_up = float(S_pct), float(J_pct)
        s_dn = s_up if S_close_pct is None else float(S_close_pct)
        j_dn = j_up if J_close_pct is None else float(J_close_pct)
        for v in (s_up, j_up, s_dn, j_dn):
            if not (math.isfinite(v) and v >= 0):
                raise ValueError(f"stiction bands must be finite and >= 0 % of span, got {v}")
        self.s_up, self.j_up, self.s_dn, self.j_dn = s_up, j_up, s_dn, j_dn

    def reset(self, x0: float) -> float:
        x0 = _clip(x0)
        self.x_last = x0
        self.dx_last = 0.0
        self.anchor = x0
        self.moving = False
        self.d = self.direction0
        self.y = x0
        return x0

    def _offset(self) -> float:
        return 0.5 * (self.s_up - self.j_up) if self.d > 0 else 0.5 * (self.s_dn - self.j_dn)

    def step(self, x: float) -> float:
        x = _clip(x)
        dx = x - self.x_last
        if self.moving and (dx == 0.0 or (dx > 0.0) != (self.dx_last > 0.0)):
            # a moving valve has stopped or reversed: it sticks where the input was
            self.moving = False
            self.anchor = self.x_last
        if not self.moving:
            progress = (x - self.anchor) * self.d       # travel in the last direction of motion
            if self.d > 0:
                s_rev, j_same = self.s_dn, self.j_up
            else:
                s_rev, j_same = self.s_up, self.j_dn
            if progress < -s_rev:
                self.d = -self.d
                self.moving = True
            elif progress > j_same:
                self.moving = True
        if self.moving:
            self.y = _clip(x - self.d * self._offset())
        self.x_last = x
        self.dx_last = dx
        return self.y


class Kano:
    """Stick-slip model of Kano et al. (2004) with its deadband/stickband distinction.

    Kano et al. split S into a deadband ``S - J`` (the play crossed only when the motion reverses)
    and a stickband ``J`` (static friction, to be broken at every start). The model keeps a stop
    flag, the input ``u_s`` at which the valve last stopped and the direction ``d`` of its last
    motion:

    * a moving valve stops when the input stops or turns against ``d``: ``u_s`` = previous input;
    * a stopped valve starts in the opposite direction when ``|u - u_s| > S`` (deadband +
      stickband) and in the same direction when ``|u - u_s| > J`` (stickband only);
    * while moving, ``y = u - d (S - J)/2``.

    Parameters are those of `TwoParameter` (``S_pct`` = deadband + stickband, ``J_pct`` =
    stickband = slip jump); ``deadband_pct`` and ``stickband_pct`` report the split.
    """

    law = "kano"

    def __init__(self, S_pct: float, J_pct: float, direction0: int = 1, *,
                 S_close_pct: float | None = None, J_close_pct: float | None = None) -> None:
        self.direction0 = 1 if direction0 >= 0 else -1
        self.set_bands(S_pct, J_pct, S_close_pct, J_close_pct)
        self.reset(50.0)

    set_bands = TwoParameter.set_bands

    @property
    def deadband_pct(self) -> float:
        return max(self.s_up - self.j_up, 0.0)

    @property
    def stickband_pct(self) -> float:
        return self.j_up

    def reset(self, x0: float) -> float:
        x0 = _clip(x0)
        self.u_prev = x0
        self.u_s = x0
        self.stopped = True
        self.d = self.direction0
        self.y = x0
        return x0

    def step(self, u: float) -> float:
        u = _clip(u)
        if not self.stopped and (u - self.u_prev) * self.d <= 0.0:
            # the input no longer drives the valve forward: it stops at the last input
            self.stopped = True
            self.u_s = self.u_prev
        if self.stopped:
            delta = u - self.u_s
            same = delta * self.d > 0.0
            if self.d > 0:
                band = self.j_up if same else self.s_dn
            else:
                band = self.j_dn if same else self.s_up
            if abs(delta) > band:
                if not same:
                    self.d = -self.d
                self.stopped = False
        if not self.stopped:
            off = 0.5 * (self.s_up - self.j_up) if self.d > 0 else 0.5 * (self.s_dn - self.j_dn)
            self.y = _clip(u - self.d * off)
        self.u_prev = u
        return self.y


def force_balance_bands(Fs_N: float, Fc_N: float, F_span_N: float, zeta: float) -> tuple[float, float]:
    """Approximate (S, J) in % of span of a force-balance stem.

    A stem that stopped while moving rests with the net force ``Fc`` still on it; to move back the
    actuator must swing by ``Fc + Fs`` (S), and a restart releases ``Fs - Fc`` onto a damped
    spring-mass that travels ``(Fs - Fc)/k (1 + overshoot)`` (J), the overshoot being
    ``exp(-pi zeta / sqrt(1 - zeta^2))`` for an underdamped stem and 0 otherwise. ``F_span_N`` is
    the spring force over the full stroke (``k x_max``).
    """
    over = math.exp(-math.pi * zeta / math.sqrt(1.0 - zeta * zeta)) if zeta < 1.0 else 0.0
    S = 100.0 * (Fs_N + Fc_N) / F_span_N
    J = 100.0 * (Fs_N - Fc_N) * (1.0 + over) / F_span_N
    return S, max(J, 0.0)


class ForceBalance:
    """A pneumatic valve stem with static and Coulomb friction (force balance, Karnopp sticking).

    The stem obeys ``m x'' = F_a - k x - F_v x' - F_f``. The actuator force follows OP through a
    first-order pressure lag ``tau_p_s`` (I/P converter and diaphragm volume); the spring force over
    the full stroke is ``F_span = k x_max``. Friction is Karnopp's: a stem at rest (|v| below a
    small band) holds any net force up to ``Fs``; once the net force exceeds it the stem slides
    against the Coulomb force ``Fc sign(v)``. Positions are carried in % of stroke and forces in %
    of ``F_span``, so ``x'' = wn^2 (p - x - f) - 2 zeta wn x'``.

    Within a fine step ``h_s`` the sliding stem is integrated exactly (zero-order hold on the
    pressure and the friction force); a velocity that changes sign inside a step stops the stem
    at the interpolated zero crossing, and the stick test is made there.

    Parameters
    ----------
    m_kg, k_N_per_m, Fv_Ns_per_m : float
        Effective moving mass, spring rate and viscous friction coefficient.
    Fs_N, Fc_N : float
        Static (breakaway) and Coulomb (sliding) friction, N.
    F_span_N : float
        Spring force over the full stroke, N.
    tau_p_s : float
        Actuator pressure lag, seconds (0: pressure follows OP at once).
    h_s : float
        Fine integration step, seconds.
    Fs_close_N, Fc_close_N : float, optional
        Friction when sliding/breaking away in the closing direction (default: as opening).
    """

    law = "force_balance"

    def __init__(self, *, m_kg: float, k_N_per_m: float, Fv_Ns_per_m: float, Fs_N: float, Fc_N: float,
                 F_span_N: float, tau_p_s: float, h_s: float, Fs_close_N: float | None = None,
                 Fc_close_N: float | None = None) -> None:
        if not (m_kg > 0 and k_N_per_m > 0 and Fv_Ns_per_m >= 0 and F_span_N > 0 and h_s > 0
                and tau_p_s >= 0):
            raise ValueError("force-balance stem needs m, k, F_span, h > 0 and Fv, tau_p >= 0")
        self.wn = math.sqrt(k_N_per_m / m_kg)
        self.zeta = Fv_Ns_per_m / (2.0 * math.sqrt(k_N_per_m * m_kg))
        self.F_span = float(F_span_N)
        self.tau_p = float(tau_p_s)
        self._base = (float(Fs_N), float(Fc_N),
                      float(Fs_N if Fs_close_N is None else Fs_close_N),
                      float(Fc_N if Fc_close_N is None else Fc_close_N))
        self.scale(1.0)
        # Karnopp's velocity band: far below any real motion of the stem (% of stroke per second)
        self.dv = 1e-6 * self.wn * 100.0
        self.set_step(h_s)
        self.reset(50.0)

    def set_step(self, h_s: float) -> None:
        """Use a fine step of ``h_s`` seconds (the exact transition over it is precomputed)."""
        if not h_s > 0:
            raise ValueError(f"fine step must be > 0 s, got {h_s}")
        self.h = float(h_s)
        self.a_p = math.exp(-h_s / self.tau_p) if self.tau_p > 0 else 0.0
        # exact transition of (x, v) over one fine step with a constant forcing w = p - f
        M = np.zeros((3, 3))
        M[0, 1] = 1.0
        M[1, 0] = -self.wn ** 2
        M[1, 1] = -2.0 * self.zeta * self.wn
        M[1, 2] = self.wn ** 2
        E = expm_small(M * h_s)
        self._phi = tuple(float(v) for v in E[:2, :2].ravel())
        self._gam = (float(E[0, 2]), float(E[1, 2]))

    def scale(self, factor: float) -> None:
        """Multiply all friction forces by ``factor`` (time-varying friction)."""
        fs_u, fc_u, fs_d, fc_d = (factor * 100.0 * f / self.F_span for f in self._base)
        self.fs_up, self.fc_up, self.fs_dn, self.fc_dn = fs_u, fc_u, fs_d, fc_d

    def reset(self, x0: float) -> float:
        x0 = _clip(x0)
        self.p = x0
        self.x = x0
        self.v = 0.0
        self.stuck = True
        return x0

    def holds(self, op: float, n_fine: int) -> bool:
        """True (and the pressure advanced) when a stuck stem stays stuck for ``n_fine`` fine steps.

        The pressure relaxes monotonically toward ``op``: if the net force at both ends of the
        interval is inside the static band, the stem cannot break away anywhere in between.
        """
        if not self.stuck:
            return False
        op = _clip(op)
        p_end = op + (self.p - op) * self.a_p ** n_fine
        net0 = self.p - self.x
        net1 = p_end - self.x
        if -self.fs_dn <= net0 <= self.fs_up and -self.fs_dn <= net1 <= self.fs_up:
            self.p = p_end
            return True
        return False

    def advance(self, op: float, n_fine: int) -> None:
        """Run ``n_fine`` fine steps with the actuator input held at ``op`` (% of span)."""
        if self.holds(op, n_fine):
            return
        op = _clip(op)
        a = self.a_p
        f11, f12, f21, f22 = self._phi
        g1, g2 = self._gam
        x, v, p, stuck = self.x, self.v, self.p, self.stuck
        dv = self.dv
        for _ in range(n_fine):
            p_new = op + (p - op) * a
            pm = 0.5 * (p + p_new)
            p = p_new
            if stuck:
                net = pm - x
                if net > self.fs_up:
                    s = 1.0
                elif net < -self.fs_dn:
                    s = -1.0
                else:
                    continue
                stuck = False
            else:
                s = 1.0 if v > 0.0 else -1.0
            fc = self.fc_up if s > 0 else self.fc_dn
            w = pm - s * fc
            x1 = f11 * x + f12 * v + g1 * w
            v1 = f21 * x + f22 * v + g2 * w
            if v1 * s <= 0.0 or abs(v1) < dv:
                # the stem came to rest inside this step: stop it at the zero crossing
                if v1 * s < 0.0 and v != v1:
                    frac = v / (v - v1)
                    x = x + (x1 - x) * min(max(frac, 0.0), 1.0)
                else:
                    x = x1
                v = 0.0
                net = pm - x
                if -self.fs_dn <= net <= self.fs_up:
                    stuck = True
                else:
                    # still overpowered: slide on in the direction of the net force
                    v = 1e-12 if net > 0 else -1e-12
            else:
                x, v = x1, v1
            if x < 0.0 or x > 100.0:
                x = _clip(x)
                v = 0.0
                stuck = True
        self.x, self.v, self.p, self.stuck = x, v, p, stuck


def run_static(law, x_pct) -> np.ndarray:
    """Open-loop response of a sampled law (`Linear`, `Backlash`, `TwoParameter`, `Kano`).

    Parameters
    ----------
    law : object with ``reset`` and ``step``
    x_pct : array (n,)
        Input (OP), % of span, one value per sample.

    Returns
    -------
    ndarray (n,)
        Stem position, % of span.
    """
    x = np.asarray(x_pct, dtype=float)
    y = np.empty(x.shape[0])
    if x.shape[0] == 0:
        return y
    y[0] = law.reset(float(x[0]))
    for k in range(1, x.shape[0]):
        y[k] = law.step(float(x[k]))
    return y


def run_force_balance(stem: ForceBalance, x_pct, ts_s: float) -> np.ndarray:
    """Open-loop response of a `ForceBalance` stem to OP held over each sample of ``ts_s``.

    Returns the stem position at the end of each sample period, % of span.
    """
    x = np.asarray(x_pct, dtype=float)
    n_fine = max(1, int(math.ceil(ts_s / stem.h - 1e-9)))
    stem.set_step(ts_s / n_fine)
    y = np.empty(x.shape[0])
    if x.shape[0] == 0:
        return y
    stem.reset(float(x[0]))
    y[0] = stem.x
    for k in range(1, x.shape[0]):
        stem.advance(float(x[k]), n_fine)
        y[k] = stem.x
    return y
