"""PI/PID controllers sampled at ts, their tuning rules, and the loop's stability margin.

`PID` runs in the positional form (``u = bias + P + I + D``, with the integral frozen while the
output is saturated in the direction the error pushes) or the velocity form (the increment is
integrated, so a clamped output cannot wind up). The derivative acts on PV through a first-order
filter ``Td/N``. The error is ``SP - PV`` and ``Kc`` carries the sign of the process gain.

Tuning: `simc` (Skogestad 2003), `lambda_tuning` (the IMC/lambda PI, Ti = tau) and `imc_pid`
(Rivera, Morari & Skogestad 1986, first-order-plus-dead-time form), all on a first-order model from
`fopdt_of` (Skogestad's half rule on the process's own lags). `gain_margin` measures how far a
tuned loop is from instability, from the poles of the sampled loop (`closed_loop_matrix`), so a
scenario can de-tune a loop to a safe margin or push it near the limit on purpose.
"""

from __future__ import annotations

import functools
import math

import numpy as np

from .process import Process

__all__ = ["PID", "fopdt_of", "simc", "lambda_tuning", "imc_pid", "integrating_pi", "closed_loop_matrix",
           "spectral_radius", "least_damped", "gain_margin", "closed_loop_sensitivity"]


class PID:
    """A sampled PI/PID controller.

    Parameters
    ----------
    Kc : float
        Proportional gain, % of OP per PV unit (sign of the process gain).
    Ti_s : float
        Integral time, seconds (``inf``: no integral action).
    Td_s : float
        Derivative time, seconds (0: PI).
    ts_s : float
        Controller sample period, seconds.
    form : {"positional", "velocity"}
    N : float
        Derivative filter: the derivative is filtered with time constant ``Td/N``.
    op_lo, op_hi : float
        Output limits, % of span.
    """

    def __init__(self, Kc: float, Ti_s: float, Td_s: float = 0.0, *, ts_s: float, form: str = "velocity",
                 N: float = 10.0, op_lo: float = 0.0, op_hi: float = 100.0) -> None:
        if form not in ("positional", "velocity"):
            raise ValueError(f"controller form must be 'positional' or 'velocity', got {form!r}")
        self.Kc, self.Ti, self.Td = float(Kc), float(Ti_s), float(Td_s)
        self.ts = float(ts_s)
        self.form = form
        self.lo, self.hi = float(op_lo), float(op_hi)
        self.ki = self.Kc * self.ts / self.Ti if (math.isfinite(self.Ti) and self.Ti > 0) else 0.0
        if self.Td > 0:
            tf = self.Td / N
            self.ad = tf / (tf + self.ts)
            self.bd = self.Kc * self.Td / (tf + self.ts)
        else:
            self.ad = self.bd = 0.0

    def reset(self, op0: float, pv0: float, sp0: float) -> None:
        """Bumpless start at output ``op0`` with measurement ``pv0`` and setpoint ``sp0``."""
        self.u = float(op0)
        self.pv_last = float(pv0)
        self.e_last = float(sp0 - pv0)
        self.dterm = 0.0
        self.integral = float(op0) - self.Kc * self.e_last     # positional form: bias folded in

    def step(self, sp: float, pv: float) -> float:
        e = sp - pv
        dterm = self.ad * self.dterm - self.bd * (pv - self.pv_last)
        if self.form == "velocity":
            u = self.u + self.Kc * (e - self.e_last) + self.ki * e + (dterm - self.dterm)
            u = self.lo if u < self.lo else (self.hi if u > self.hi else u)
        else:
            trial = self.integral + self.ki * e
            u = trial + self.Kc * e + dterm
            # conditional integration: a saturated output does not integrate further into the limit
            if u > self.hi:
                u = self.hi
                if self.ki * e < 0:
                    self.integral = trial
            elif u < self.lo:
                u = self.lo
                if self.ki * e > 0:
                    self.integral = trial
            else:
                self.integral = trial
        self.u = u
        self.e_last = e
        self.pv_last = pv
        self.dterm = dterm
        return u


def fopdt_of(proc: Process, ts_s: float) -> tuple[float, float, float]:
    """A first-order-plus-dead-time model ``(K, tau_s, theta_s)`` of a self-regulating process.

    Skogestad's half rule on the process's own lags: half of the second-largest lag goes to the
    time constant, the other half and all smaller lags to the dead time; half a sample is added for
    the hold. An underdamped pair counts as two lags of ``1/wn``; a lead cancels part of a lag.
    """
    p = proc.params
    if proc.kind == "underdamped":
        lags = [1.0 / p["wn_rad_s"], 1.0 / p["wn_rad_s"]]
    else:
        lags = sorted((p[k] for k in ("tau1_s", "tau2_s", "tau3_s") if p.get(k, 0.0) > 0), reverse=True)
    lead = p.get("lead_s", 0.0)
    if lead > 0 and len(lags) > 1:
        lags[1] = max(lags[1] - lead, 0.0)
        lags.sort(reverse=True)
    tau = lags[0] + (lags[1] / 2.0 if len(lags) > 1 else 0.0)
    theta = proc.delay_s + (lags[1] / 2.0 if len(lags) > 1 else 0.0) + sum(lags[2:]) + ts_s / 2.0
    return proc.gain, tau, theta


def simc(K: float, tau_s: float, theta_s: float, tau_c_s: float) -> tuple[float, float]:
    """SIMC PI (Skogestad 2003): ``Kc = tau / (K (tau_c + theta))``, ``Ti = min(tau, 4 (tau_c + theta))``."""
    return tau_s / (K * (tau_c_s + theta_s)), min(tau_s, 4.0 * (tau_c_s + theta_s))


def lambda_tuning(K: float, tau_s: float, theta_s: float, lam_s: float) -> tuple[float, float]:
    """Lambda (IMC) PI: ``Kc = tau / (K (lambda + theta))``, ``Ti = tau``."""
    return tau_s / (K * (lam_s + theta_s)), tau_s


def imc_pid(K: float, tau_s: float, theta_s: float, lam_s: float) -> tuple[float, float, float]:
    """IMC PID for a first-order-plus-dead-time model (Rivera, Morari & Skogestad 1986).

    ``Kc K = (tau + theta/2) / (lambda + theta/2)``, ``Ti = tau + theta/2``,
    ``Td = tau theta / (2 tau + theta)``.
    """
    Kc = (tau_s + theta_s / 2.0) / (K * (lam_s + theta_s / 2.0))
    return Kc, tau_s + theta_s / 2.0, tau_s * theta_s / (2.0 * tau_s + theta_s)


def integrating_pi(k_rate: float, theta_s: float, tau_c_s: float) -> tuple[float, float]:
    """SIMC PI for an integrating process ``k e^{-theta s}/s``.

    ``Kc = 1/(k (tau_c + theta))``, ``Ti = 4 (tau_c + theta)``.
    """
    return 1.0 / (k_rate * (tau_c_s + theta_s)), 4.0 * (tau_c_s + theta_s)


def closed_loop_matrix(proc: Process, Kc: float, Ti_s: float, Td_s: float, ts_s: float, *, N: float = 10.0,
                       flow_slope: float = 1.0, m: int = 20) -> np.ndarray:
    """State matrix of the sampled loop (linear valve, no saturation), one row per state.

    The process is folded exactly as in the simulation (`process.Discrete`): with a dead time of
    ``q`` samples and ``r`` internal steps, ``x[k+1] = Phi x[k] + Ga u[k-q-1] + Gb u[k-q]``. The
    controller is the velocity form of `PID` (same dynamics as the positional form away from the
    limits). State: ``[x, u[k-1] .. u[k-q-1], y[k-1], D[k-1]]``.
    """
    d = _folded(proc.num, proc.den, proc.delay_s, float(ts_s), int(m))
    q, r = divmod(d.delay_steps, m)
    Ga = flow_slope * d.G[:, :r].sum(axis=1)
    Gb = flow_slope * d.G[:, r:].sum(axis=1)
    nx = d.nx
    nu = q + 1
    n = nx + nu + 2
    iu, iy, iD = nx, nx + nu, nx + nu + 1
    ki = Kc * ts_s / Ti_s if (math.isfinite(Ti_s) and Ti_s > 0) else 0.0
    if Td_s > 0:
        tf = Td_s / N
        ad, bd = tf / (tf + ts_s), Kc * Td_s / (tf + ts_s)
    else:
        ad = bd = 0.0
    # rows giving y[k], D[k] and u[k] as functions of the state
    y = np.zeros(n)
    y[:nx] = d.C
    D = np.zeros(n)
    D[iD] = ad
    D -= bd * y
    D[iy] += bd
    u = np.zeros(n)
    u[iu] = 1.0                     # u[k-1]
    u -= (Kc + ki) * y
    u[iy] += Kc
    u += D
    u[iD] -= 1.0
    M = np.zeros((n, n))
    M[:nx, :nx] = d.Am
    u_q = u if q == 0 else np.eye(n)[iu + q - 1]          # u[k-q]
    M[:nx] += np.outer(Gb, u_q)
    M[:nx, iu + q] += Ga                                   # u[k-q-1]
    M[iu] = u
    for j in range(1, nu):
        M[iu + j, iu + j - 1] = 1.0
    M[iy] = y
    M[iD] = D
    return M


@functools.lru_cache(maxsize=64)
def _folded(num: tuple, den: tuple, delay_s: float, ts_s: float, m: int):
    return Process("tf", num, den, delay_s, 1.0).discretise(ts_s, m)


def spectral_radius(proc: Process, Kc: float, Ti_s: float, Td_s: float, ts_s: float, *,
                    flow_slope: float = 1.0) -> float:
    """Largest closed-loop pole magnitude of the sampled loop (< 1: stable)."""
    M = closed_loop_matrix(proc, Kc, Ti_s, Td_s, ts_s, flow_slope=flow_slope)
    return float(np.max(np.abs(np.linalg.eigvals(M))))


def least_damped(proc: Process, Kc: float, Ti_s: float, Td_s: float, ts_s: float, *,
                 flow_slope: float = 1.0) -> tuple[float, float]:
    """Damping ratio and period (seconds) of the least-damped oscillatory closed-loop pole pair.

    A sampled pole ``z`` maps to ``s = ln(z)/ts``; ``zeta = -Re(s)/|s|``. Returns ``(inf, nan)``
    when the loop has no oscillatory pole.
    """
    M = closed_loop_matrix(proc, Kc, Ti_s, Td_s, ts_s, flow_slope=flow_slope)
    z = np.linalg.eigvals(M)
    z = z[(np.abs(z.imag) > 1e-9) & (np.abs(z) > 1e-9)]
    if z.size == 0:
        return math.inf, math.nan
    s = np.log(z.astype(complex)) / ts_s
    zeta = -s.real / np.abs(s)
    i = int(np.argmin(zeta))
    return float(zeta[i]), float(2.0 * math.pi / abs(s[i].imag))


def gain_margin(proc: Process, Kc: float, Ti_s: float, Td_s: float, ts_s: float, *,
                flow_slope: float = 1.0) -> float:
    """Factor on ``Kc`` (Ti, Td fixed) that brings the sampled loop to the edge of stability.

    Computed from the closed-loop poles (`spectral_radius`) by bisection. Returns ``inf`` when no
    gain up to 1000 x destabilises the loop, and 0 when the loop is unstable at every gain down
    to 1/1000 (the integral time is too short for the process).
    """
    def unstable(g: float) -> bool:
        return spectral_radius(proc, g * Kc, Ti_s, Td_s, ts_s, flow_slope=flow_slope) >= 1.0

    if unstable(1.0):
        hi, lo = 1.0, 0.5
        while unstable(lo):
            hi, lo = lo, lo / 2.0
            if lo < 1e-3:
                return 0.0
    else:
        lo, hi = 1.0, 2.0
        while not unstable(hi):
            lo, hi = hi, hi * 2.0
            if hi > 1e3:
                return math.inf
    for _ in range(30):
        mid = math.sqrt(lo * hi)
        if unstable(mid):
            hi = mid
        else:
            lo = mid
        if hi / lo < 1.0 + 1e-4:
            break
    return math.sqrt(lo * hi)


def closed_loop_sensitivity(proc: Process, Kc: float, Ti_s: float, Td_s: float, ts_s: float,
                            w_rad_s: float) -> float:
    """``|1 / (1 + C P)|`` at ``w_rad_s``: the share of an output load the loop leaves in PV.

    Continuous PI(D) with the sampled loop's hold taken as a delay of half a sample; good to a few
    per cent well below the Nyquist frequency, which is where loads that shape a record lie.
    """
    s = 1j * float(w_rad_s)
    integral = 1.0 / (Ti_s * s) if math.isfinite(Ti_s) and Ti_s > 0 else 0.0
    C = Kc * (1.0 + integral + Td_s * s / (1.0 + Td_s * s / 10.0))
    P = proc.frequency_response(np.array([w_rad_s]))[0] * np.exp(-s * ts_s / 2.0)
    return float(abs(1.0 / (1.0 + C * P)))
