"""Closed-loop simulator: PI(D) controller -> valve -> process, with noise, loads and setpoint moves.

Everything is pluggable through two small protocols:

* a valve has ``reset(x0_pct) -> y`` and ``step(x_pct) -> y`` (stem position, % of span);
  `diagnose.stiction_model.StictionValve` and `LinearValve` are two;
* a process is a `diagnose.process_model.ProcessModel` (stepped by its `ProcessStepper`), or anything
  with ``reset(u0_pct, ts_s) -> pv`` and ``step(u_pct) -> pv`` (engineering units).

Loads (disturbances) are added to the process output in PV units before measurement noise; the
recorded MV is the valve's true output. The simulator is used by tests, by the NARX-SP training
and by the missing-physics proofs, which plug in valves and processes of their own.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol, Sequence

import numpy as np

from .errors import DataError
from .process_model import ProcessModel
from .record import LoopRecord
from .stiction_model import StictionValve


class Valve(Protocol):
    def reset(self, x0_pct: float) -> float: ...
    def step(self, x_pct: float) -> float: ...


class Process(Protocol):
    def reset(self, u0_pct: float, ts_s: float) -> float: ...
    def step(self, u_pct: float) -> float: ...


class LinearValve:
    """A healthy valve: the stem follows the input exactly (clipped to 0..100 %)."""

    def reset(self, x0_pct: float) -> float:
        return min(max(float(x0_pct), 0.0), 100.0)

    def step(self, x_pct: float) -> float:
        return min(max(float(x_pct), 0.0), 100.0)


@dataclass
class PIDController:
    """PI(D) controller in velocity form, output limited to ``op_lo..op_hi`` % (anti-windup).

    The velocity form integrates the output increment, so clamping the output stops the integral
    from winding up. Error is ``SP - PV``; give ``Kc`` the sign of the process gain.

    Parameters
    ----------
    Kc : float
        Proportional gain, % of OP per PV unit.
    Ti_s : float
        Integral time, seconds (``inf`` for P only).
    Td_s : float
        Derivative time, seconds, acting on PV (no derivative kick on setpoint moves).
    """

    Kc: float = 1.0
    Ti_s: float = 20.0
    Td_s: float = 0.0
    op_lo: float = 0.0
    op_hi: float = 100.0

    def reset(self, op0_pct: float, pv0: float, sp0: float, ts_s: float) -> None:
        self._ts = ts_s
        self._u = op0_pct
        self._e1 = sp0 - pv0
        self._pv1 = self._pv2 = pv0

    def step(self, sp: float, pv: float) -> float:
        e = sp - pv
        du = self.Kc * (e - self._e1)
        if math.isfinite(self.Ti_s) and self.Ti_s > 0:
            du += self.Kc * self._ts / self.Ti_s * e
        if self.Td_s > 0:
            du -= self.Kc * self.Td_s / self._ts * (pv - 2.0 * self._pv1 + self._pv2)
        self._u = min(max(self._u + du, self.op_lo), self.op_hi)
        self._e1 = e
        self._pv2, self._pv1 = self._pv1, pv
        return self._u


def simc_pi(gain: float, tau_s: float, delay_s: float, ts_s: float, *, tau_c_s: float | None = None) -> PIDController:
    """A PI controller tuned by Skogestad's SIMC rule for a first-order plus dead-time process."""
    theta = max(delay_s, ts_s) + ts_s / 2.0
    tau_c = theta if tau_c_s is None else tau_c_s
    Kc = tau_s / (gain * (tau_c + theta))
    Ti = min(tau_s, 4.0 * (tau_c + theta))
    return PIDController(Kc=Kc, Ti_s=Ti)


# --- disturbance and setpoint signals (arrays, one value per sample) -----------------------------

def random_walk(n: int, step_std: float, rng: np.random.Generator, *, leak: float = 0.0) -> np.ndarray:
    """Random walk with increments of ``step_std`` (PV units); ``leak`` > 0 makes it mean-reverting."""
    w = rng.normal(0.0, step_std, n)
    if leak <= 0:
        return np.cumsum(w)
    out = np.empty(n)
    acc = 0.0
    for k in range(n):
        acc = (1.0 - leak) * acc + w[k]
        out[k] = acc
    return out


def steps(n: int, at: Sequence[int], sizes: Sequence[float]) -> np.ndarray:
    """Steps of ``sizes`` (PV units) at sample indices ``at``."""
    out = np.zeros(n)
    for k, s in zip(at, sizes):
        out[int(k):] += s
    return out


def sinusoid(n: int, ts_s: float, period_s: float, amplitude: float, phase_rad: float = 0.0) -> np.ndarray:
    """A sinusoidal load of ``amplitude`` PV units and period ``period_s``."""
    return amplitude * np.sin(2.0 * np.pi * np.arange(n) * ts_s / period_s + phase_rad)


def simulate_loop(
    *,
    n: int,
    ts_s: float,
    process: ProcessModel | Process,
    controller: PIDController,
    valve: Valve | None = None,
    op0_pct: float = 50.0,
    sp: float | np.ndarray | None = None,
    load: np.ndarray | None = None,
    noise_std: float = 0.0,
    seed: int | None = 0,
    name: str = "SIM",
    warmup: int = 0,
) -> LoopRecord:
    """Simulate one closed loop and return its record (OP, PV, SP and the true MV).

    Parameters
    ----------
    n : int
        Number of samples to return.
    ts_s : float
        Sample period, seconds (controller, valve and process all run at this rate).
    process, controller, valve
        The pluggable parts; ``valve=None`` is a healthy valve.
    op0_pct : float
        Starting controller output and valve position, % of span. The loop starts at the steady
        state for it: the default setpoint is that steady-state PV.
    sp : float or array (n,), optional
        Setpoint (PV units): constant or one value per sample.
    load : array (n,), optional
        Additive load on the process output, PV units.
    noise_std : float
        Standard deviation of white measurement noise on PV, PV units.
    seed : int
        Seed of the noise generator.
    warmup : int
        Samples simulated before the returned record (lets a limit cycle establish itself).
    """
    if n < 2:
        raise DataError(f"n must be at least 2 samples, got {n}")
    if not ts_s > 0:
        raise DataError(f"ts_s must be > 0 seconds, got {ts_s}")
    valve = LinearValve() if valve is None else valve
    if isinstance(process, ProcessModel):
        process = process.stepper()
    total = n + warmup
    rng = np.random.default_rng(seed)
    pv_true0 = process.reset(op0_pct, ts_s)
    sp_arr = np.full(total, pv_true0) if sp is None else np.broadcast_to(np.asarray(sp, float), (n,))
    if sp is not None:
        sp_arr = np.concatenate([np.full(warmup, sp_arr[0]), sp_arr])
    load_arr = np.zeros(total) if load is None else np.concatenate([np.zeros(warmup), np.asarray(load, float)])
    if load_arr.shape[0] != total:
        raise DataError(f"load has {load_arr.shape[0] - warmup} samples, expected {n}")
    noise = rng.normal(0.0, noise_std, total) if noise_std > 0 else np.zeros(total)

    op = np.empty(total)
    pv = np.empty(total)
    mv = np.empty(total)
    y = valve.reset(op0_pct)
    pv_meas = pv_true0 + load_arr[0] + noise[0]
    controller.reset(op0_pct, pv_meas, sp_arr[0], ts_s)
    u = op0_pct
    for k in range(total):
        # The controller acts on the measurement; the valve and process then respond.
        if k > 0:
            u = controller.step(sp_arr[k], pv_meas)
            y = valve.step(u)
            pv_meas = process.step(y) + load_arr[k] + noise[k]
        op[k], mv[k], pv[k] = u, y, pv_meas
    sl = slice(warmup, None)
    return LoopRecord(name=name, ts_s=ts_s, op=op[sl], pv=pv[sl], sp=sp_arr[sl], mv=mv[sl],
                      units={"op": "%", "mv": "%", "pv": "", "sp": ""},
                      ranges={"op": (0.0, 100.0), "mv": (0.0, 100.0)},
                      source="simulator", meta={"simulated": True})


def make_process(kind: str, *, gain: float, tau_s: float, delay_s: float, tau2_s: float | None = None,
                 bias: float = 0.0, u_balance_pct: float | None = None) -> ProcessModel:
    """A process by name: ``foptd``, ``soptd`` (second lag ``tau2_s``, default ``tau_s / 4``) or
    ``integrating`` (``tau_s``: a lag on its input; ``bias``: PV at the start; ``u_balance_pct``:
    the valve position at which PV stands still, default the loop's starting OP)."""
    if kind not in ("foptd", "soptd", "integrating"):
        raise DataError(f"unknown process kind {kind!r}; use foptd, soptd or integrating")
    if kind != "integrating" and not tau_s > 0:
        raise DataError(f"{kind} tau_s must be > 0 seconds, got {tau_s}")
    tau2 = (tau2_s if tau2_s is not None else tau_s / 4) if kind == "soptd" else 0.0
    return ProcessModel(kind=kind, gain=gain, tau_s=tau_s, delay_s=delay_s, bias=bias, tau2_s=tau2,
                        u_balance_pct=u_balance_pct if kind == "integrating" else None)


def sticky_loop(S_pct: float, J_pct: float, *, n: int = 3000, ts_s: float = 1.0, gain: float = 1.0,
                tau_s: float = 20.0, delay_s: float = 3.0, kind: str = "foptd", noise_std: float = 0.0,
                load_walk_std: float = 0.0, f0: int = 1, seed: int = 0, name: str = "SIM",
                warmup: int = 500, Kc: float | None = None, Ti_s: float | None = None,
                u_balance_pct: float | None = None) -> LoopRecord:
    """A convenience closed loop: a sticky (or healthy, S = 0) valve on a tuned PI loop.

    Self-regulating processes get SIMC tuning; integrating ones a PI tuned for the integrator.
    The loop starts with OP and the valve at 50 %; an integrating process stands still at
    ``u_balance_pct`` (default 50 %, so a stuck valve may never be asked to move: give a balance
    off 50 % for a level whose inflow the starting valve does not match, as
    ``stiction simulate --process integrating`` does).

    Parameters
    ----------
    S_pct, J_pct : float
        The valve's deadband plus stickband and its slip jump, % of valve span (0 and 0: a healthy
        valve). A band wider than OP's swing leaves the stem stuck for the whole record.
    n : int
        Samples kept after the warm-up.
    ts_s : float
        Sample period, seconds.
    gain : float
        Process gain, PV units per % of valve travel (integrating: PV units per second per %).
    tau_s, delay_s : float
        Process time constant (integrating: its input lag) and dead time, seconds.
    kind : {"foptd", "soptd", "integrating"}
        Process structure (soptd: a second lag of ``tau_s / 4``).
    noise_std : float
        Standard deviation of white measurement noise on PV, PV units (0: none).
    load_walk_std : float
        Step size of a slowly leaking random-walk load on PV, PV units per sample (0: none).
    f0 : {1, -1}
        Direction of the valve's last motion before the record starts.
    seed : int
        Seed of the noise and the load.
    name : str
        Loop name of the record.
    warmup : int
        Samples simulated and dropped before the record starts.
    Kc, Ti_s : float, optional
        Controller gain (% per PV unit) and integral time (seconds) instead of the automatic tuning.
    u_balance_pct : float, optional
        Integrating only: the valve position at which PV holds still (default 50 %).

    Returns
    -------
    LoopRecord
        OP, PV, SP (constant) and MV (the true stem position), uniformly sampled.
    """
    process = make_process(kind, gain=gain, tau_s=tau_s, delay_s=delay_s,
                           bias=50.0 if kind == "integrating" else 0.0, u_balance_pct=u_balance_pct)
    if kind == "integrating":
        theta = delay_s + tau_s + ts_s
        ctrl = PIDController(Kc=1.0 / (gain * 2 * theta), Ti_s=8 * theta)
    else:
        # SIMC half rule: half of the second lag goes to the time constant, half to the delay.
        tau2 = 0.0 if kind == "foptd" else tau_s / 4
        ctrl = simc_pi(gain, tau_s + tau2 / 2, delay_s + tau2 / 2, ts_s)
    if Kc is not None:
        ctrl.Kc = Kc
    if Ti_s is not None:
        ctrl.Ti_s = Ti_s
    valve = StictionValve(S_pct, J_pct, f0) if (S_pct > 0 or J_pct > 0) else LinearValve()
    rng = np.random.default_rng(seed + 7919)
    load = random_walk(n, load_walk_std, rng, leak=0.002) if load_walk_std > 0 else None
    return simulate_loop(n=n, ts_s=ts_s, process=process, controller=ctrl, valve=valve, load=load,
                         noise_std=noise_std, seed=seed, name=name, warmup=warmup)
