"""The loop's controller seen from its own records: action (sign) and PI tuning.

A PI controller in velocity form obeys, sample by sample,

    OP[k] - OP[k-1] = Kc (e[k] - e[k-1]) + Kc ts / Ti e[k],   e = SP - PV,

acting on the PV of the same sample (DCS scan logged as one row) or of the sample before (a
historian that stamps the output after the scan). Least squares of the OP increments on the error
increments and the error, at both alignments, recovers Kc and Ti where the loop was in automatic
with a PI law; R^2 says whether it was. A PID law adds ``Kc Td / ts (e[k] - 2 e[k-1] + e[k-2])``:
where the PI regression finds no consistent sign, the same regression with that second
difference is tried, and its sign is taken when all three terms agree on it (the derivative
kick the PI regression cannot explain otherwise leaves too little R^2, or tilts the integral
term's sign).

Why the fitting stage needs it: in closed loop a linear block can explain PV *through the
controller* (PV = -OP / Kc + ...), and that path always has the sign opposite to the plant's gain
(negative feedback needs Kc Kp > 0). Knowing the controller's sign rules it out.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: Smallest R^2 of the PI regression for the controller's sign to be trusted.
MIN_R2 = 0.5


@dataclass(frozen=True)
class ControllerAction:
    """What the records say about the controller.

    Attributes
    ----------
    sign : int
        +1 reverse acting (OP rises when PV falls below SP: a process whose PV rises with the
        valve), -1 direct acting, 0 when the records do not show a PI law (R^2 below `MIN_R2`,
        manual mode, a cascade slave, or coefficients of opposite sign).
    Kc : float
        Proportional gain, % of OP per PV unit (signed), NaN when not found.
    Ti_s : float
        Integral time, seconds (NaN when not found or no integral action).
    r2 : float
        Fraction of the OP increments' variance the PI law explains.
    lag_samples : int
        0: OP acts on the PV of its own row; 1: on the row before.
    Td_s : float
        Derivative time, seconds, where the sign came from the PID regression (NaN otherwise).
    """

    sign: int
    Kc: float
    Ti_s: float
    r2: float
    lag_samples: int
    Td_s: float = float("nan")

    def to_dict(self) -> dict:
        f = (lambda v: None if not np.isfinite(v) else float(v))
        return {"action": {1: "reverse", -1: "direct"}.get(self.sign, "unknown"), "Kc": f(self.Kc),
                "Ti_s": f(self.Ti_s), "Td_s": f(self.Td_s), "r2": f(self.r2), "lag_samples": self.lag_samples}


def controller_action(op_pct, pv, ts_s: float, sp=None) -> ControllerAction:
    """Estimate the controller's action and PI tuning from OP, PV (and SP when recorded).

    Parameters
    ----------
    op_pct : array, shape (n,)
        Controller output, % of span.
    pv : array, shape (n,)
        Process variable, engineering units.
    ts_s : float
        Sample period, seconds.
    sp : array, shape (n,), optional
        Setpoint, PV units. Without it the setpoint is taken as constant (it drops out of the
        error increments, and the intercept absorbs it in the integral term).

    Returns
    -------
    ControllerAction
    """
    x = np.asarray(op_pct, float)
    y = np.asarray(pv, float)
    n = x.shape[0]
    none = ControllerAction(0, float("nan"), float("nan"), 0.0, 0)
    if n < 20 or np.ptp(x) <= 0 or np.ptp(y) <= 0:
        return none
    e = (np.asarray(sp, float) - y) if sp is not None else -y
    pi = _regression(x, e, ts_s, derivative=False)
    if pi.sign:
        return pi
    pid = _regression(x, e, ts_s, derivative=True)
    return pid if pid.sign else pi


def _regression(x: np.ndarray, e: np.ndarray, ts_s: float, *, derivative: bool) -> ControllerAction:
    """The PI (or PID) law fitted to the OP increments at both alignments; the better one."""
    dop = np.diff(x)
    de = np.diff(e)
    d2e = np.concatenate([[0.0], np.diff(de)])      # e[k] - 2 e[k-1] + e[k-2], aligned with de
    best = ControllerAction(0, float("nan"), float("nan"), 0.0, 0)
    for lag in (0, 1):
        # dop[k] (OP[k+1] - OP[k]) against de and e of row k+1 (lag 0) or row k (lag 1)
        a = dop[lag:]
        m = a.shape[0]
        b1 = de[: de.shape[0] - lag][:m]
        b2 = e[1: e.shape[0] - lag][:m]
        cols = [b1, b2, np.ones(m)]
        if derivative:
            b3 = d2e[: d2e.shape[0] - lag][:m]
            cols.append(b3)
        A = np.column_stack(cols)
        # a saturated or held OP is not the control law at work
        keep = np.abs(a) > 0
        keep &= (x[1 + lag: 1 + lag + m] > 0.0) & (x[1 + lag: 1 + lag + m] < 100.0)
        keep &= np.isfinite(a) & np.isfinite(A).all(axis=1)
        if derivative:
            keep[:1] = False        # no second difference at the first increment
        if np.count_nonzero(keep) < 10:
            continue
        coef, *_ = np.linalg.lstsq(A[keep], a[keep], rcond=None)
        res = a[keep] - A[keep] @ coef
        sst = float(np.sum((a[keep] - a[keep].mean()) ** 2))
        r2 = 1.0 - float(res @ res) / sst if sst > 0 else 0.0
        if r2 <= best.r2:
            continue
        Kc, KiTs = float(coef[0]), float(coef[1])
        agree = Kc * KiTs >= 0.0 or abs(KiTs) * np.std(b2) < 0.05 * abs(Kc) * np.std(b1)
        Td = float("nan")
        if derivative:
            KdTs = float(coef[3])
            agree = agree and (Kc * KdTs >= 0.0 or abs(KdTs) * np.std(b3) < 0.05 * abs(Kc) * np.std(b1))
            Td = KdTs * ts_s / Kc if Kc != 0.0 and Kc * KdTs > 0 else float("nan")
        sign = int(np.sign(Kc)) if (r2 >= MIN_R2 and agree and Kc != 0.0) else 0
        Ti = Kc * ts_s / KiTs if KiTs != 0.0 and Kc * KiTs > 0 else float("nan")
        best = ControllerAction(sign, Kc, Ti, r2, lag, Td)
    return best
