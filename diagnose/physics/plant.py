"""Simulator parts that hide one piece of missing physics in a closed loop.

They follow the `diagnose.simulate` protocols (a valve has ``reset(x0_pct)`` and ``step(x_pct)``; a
process has ``reset(u0_pct, ts_s)`` and ``step(u_pct)``), so ``simulate_loop(valve=LaggedValve(...))``
produces a record whose plant has the effect while the baseline model does not. A sinusoidal
external load needs no part: pass ``load=diagnose.simulate.sinusoid(...)`` to `simulate_loop`.

`AugmentedValve` runs the compiled valve of `diagnose.physics.valve.augmented_valve` (the kernel the
hypotheses fit: the valve step, the friction's drift or step and the actuator lag) one sample at a
time (`diagnose.kernels.ValveState`); the tests check that both agree sample for sample.
"""

from __future__ import annotations

import math

from .. import kernels
from ..errors import DataError
from ..process_model import ProcessModel, lag_coefficient


class AugmentedValve:
    """A sticky valve with direction-dependent and drifting friction and an actuator lag.

    Parameters
    ----------
    S_up_pct, J_up_pct : float
        Stiction while opening (direction +1), % of span.
    S_dn_pct, J_dn_pct : float, optional
        Stiction while closing (direction -1); default the opening values.
    dS_pct_per_s, dJ_pct_per_s : float
        Drift of S and J per second (clipped at 0), from ``drift_from_s`` after `reset` for
        ``drift_for_s`` seconds (default: from the start, for ever; one sample period: a step).
    tau_lag_s : float
        First-order actuator lag after the friction element, seconds (0: none).
    ts_s : float
        Sample period, seconds (needed by the lag and the drift).
    f0 : {+1, -1}
        Direction of the last motion before the start.
    """

    def __init__(self, S_up_pct: float, J_up_pct: float, S_dn_pct: float | None = None,
                 J_dn_pct: float | None = None, *, dS_pct_per_s: float = 0.0,
                 dJ_pct_per_s: float = 0.0, tau_lag_s: float = 0.0, ts_s: float = 1.0,
                 f0: int = 1, drift_from_s: float = 0.0, drift_for_s: float = math.inf) -> None:
        S_dn_pct = S_up_pct if S_dn_pct is None else S_dn_pct
        J_dn_pct = J_up_pct if J_dn_pct is None else J_dn_pct
        for nm, v in (("S_up_pct", S_up_pct), ("J_up_pct", J_up_pct), ("S_dn_pct", S_dn_pct),
                      ("J_dn_pct", J_dn_pct)):
            if not (math.isfinite(v) and v >= 0):
                raise DataError(f"{nm} must be finite and >= 0 % of span, got {v}")
        if not (ts_s > 0 and tau_lag_s >= 0):
            raise DataError("ts_s must be > 0 and tau_lag_s >= 0 seconds")
        if f0 not in (1, -1):
            raise DataError(f"starting direction f0 must be +1 or -1, got {f0!r}")
        if not (drift_from_s >= 0 and drift_for_s >= 0):
            raise DataError("drift_from_s and drift_for_s must be >= 0 seconds")
        self.t0, self.tw = float(drift_from_s), float(drift_for_s)
        self.S_up, self.J_up, self.S_dn, self.J_dn = map(float, (S_up_pct, J_up_pct, S_dn_pct, J_dn_pct))
        self.dS, self.dJ = float(dS_pct_per_s), float(dJ_pct_per_s)
        self.ts_s = float(ts_s)
        self.tau_lag_s = float(tau_lag_s)
        self.a = lag_coefficient(tau_lag_s, ts_s)
        self.f0 = int(f0)
        self.reset(0.0)

    def reset(self, x0_pct: float) -> float:
        # the drift, the step and the lag are the kernel's own (valve_step1), not a copy of them
        self._valve = kernels.ValveState(self.S_up, self.J_up, self.S_dn, self.J_dn, dS=self.dS, dJ=self.dJ,
                                         drift_from_s=self.t0, drift_for_s=self.tw, a_lag=self.a, ts_s=self.ts_s)
        self.z = self._valve.start(x0_pct, self.f0)
        return self.z

    def step(self, x_pct: float) -> float:
        self.z = self._valve.step(x_pct)
        return self.z


class LaggedValve(AugmentedValve):
    """Stiction followed by a first-order actuator lag of ``tau_lag_s`` seconds."""

    def __init__(self, S_pct: float, J_pct: float, tau_lag_s: float, *, ts_s: float = 1.0,
                 f0: int = 1) -> None:
        super().__init__(S_pct, J_pct, tau_lag_s=tau_lag_s, ts_s=ts_s, f0=f0)


class AsymmetricStictionValve(AugmentedValve):
    """Different (S, J) when opening and when closing."""

    def __init__(self, S_up_pct: float, J_up_pct: float, S_dn_pct: float, J_dn_pct: float, *,
                 f0: int = 1) -> None:
        super().__init__(S_up_pct, J_up_pct, S_dn_pct, J_dn_pct, f0=f0)


class DriftingStictionValve(AugmentedValve):
    """S and J drifting linearly in time (packing wear, temperature): ``S(t) = S0 + dS t``."""

    def __init__(self, S0_pct: float, J0_pct: float, *, dS_pct_per_s: float, dJ_pct_per_s: float,
                 ts_s: float = 1.0, f0: int = 1) -> None:
        super().__init__(S0_pct, J0_pct, dS_pct_per_s=dS_pct_per_s, dJ_pct_per_s=dJ_pct_per_s,
                         ts_s=ts_s, f0=f0)


def equal_percentage(y_pct: float, R: float) -> float:
    """Relative flow (% of maximum) of an equal-percentage valve: ``100 R^(y/100 - 1)``."""
    return 100.0 * R ** (y_pct / 100.0 - 1.0)


class CharacteristicProcess:
    """A process whose input is the flow of an installed equal-percentage valve.

    Parameters
    ----------
    process : ProcessModel or Process
        The process behind the valve (a `diagnose.process_model.ProcessModel`, or any object with
        the simulator's ``reset``/``step``).
    R : float
        Rangeability (R > 1); the loop gain at the stem grows as ``ln R * flow``.
    """

    def __init__(self, process, R: float) -> None:
        if not R > 1:
            raise DataError(f"rangeability R must be > 1, got {R}")
        self.process = process.stepper() if isinstance(process, ProcessModel) else process
        self.R = float(R)

    def reset(self, u0_pct: float, ts_s: float) -> float:
        return self.process.reset(equal_percentage(u0_pct, self.R), ts_s)

    def step(self, u_pct: float) -> float:
        return self.process.step(equal_percentage(u_pct, self.R))
