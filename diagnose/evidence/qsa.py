"""Yamashita's (2006) qualitative shape analysis of OP and the valve position.

Each sample of the (smoothed) controller output and valve position is described by the sign of
its rate of change: I (increasing), D (decreasing) or S (steady), the rates being normalised by
their own standard deviation. A sticky valve spends long stretches steady while OP moves (the
patterns IS and DS), then jumps. Yamashita's index is the share of such stretches in the time
when anything moves at all:

    rho = (t_IS + t_DS) / (t_total - t_SS)

and the valve is judged sticky when rho > 0.25. The valve position is rarely recorded; as in
Yamashita's flow-loop examples, PV stands in for it, so the test judges self-regulating loops
only. A rate counts as steady when its magnitude is under 0.3 of its standard deviation (this
tool's choice) or under three standard deviations of the smoothed noise's rate, so that noise
alone does not make symbols.
"""

from __future__ import annotations

import numpy as np

from ._gates import process_gate, record_gate
from ._signals import Prepared, smoothed_noise_sd
from .result import NO_STICTION, STICTION, Evidence, cannot_judge

TEST = "yamashita_qsa"
THRESHOLD = 0.25
STEADY = 0.3        # |rate| / sd(rate) under this is S


def symbols(raw: np.ndarray, smooth: np.ndarray, fc: float) -> np.ndarray:
    """+1 (I), -1 (D) or 0 (S) per sample of a smoothed signal."""
    d = np.gradient(smooth)
    sd = float(np.std(d))
    _, noise_rate = smoothed_noise_sd(raw, smooth, fc)
    limit = max(STEADY * sd, 3.0 * noise_rate)
    return np.where(d > limit, 1, np.where(d < -limit, -1, 0))


def yamashita_qsa(op, pv, ts_s: float, *, sp=None, integrating: bool | None = None) -> Evidence:
    """Yamashita's (2006) IS/DS share of OP and PV (self-regulating loops only).

    Parameters
    ----------
    op : array (n,)
        Controller output, % of span.
    pv : array (n,)
        Process variable, the valve position's stand-in.
    ts_s : float
        Sample period, seconds.
    sp : array (n,), optional
        Setpoint (used only for the smoothing scale).
    integrating : bool or None
        Process type; the test judges only self-regulating loops (False).
    """
    return _yamashita_qsa(Prepared(op, pv, ts_s, sp), integrating)


def _yamashita_qsa(p: Prepared, integrating: bool | None) -> Evidence:
    gate = (record_gate(TEST, p, threshold=THRESHOLD)
            or process_gate(TEST, integrating, wants=False, threshold=THRESHOLD, other="horch_integrating"))
    if gate is not None:
        return gate
    so = symbols(p.op, p.op_s, p.smooth_fc)
    sv = symbols(p.pv, p.pv_s, p.smooth_fc)
    moving = np.count_nonzero((so != 0) | (sv != 0))
    if moving < 0.05 * p.n:
        return cannot_judge(TEST, "op_still", "OP and PV hardly move beyond their noise, so no shape can be "
                            "read.", THRESHOLD)
    is_ds = np.count_nonzero((so != 0) & (sv == 0))
    rho = is_ds / moving
    ex = {"share_IS_DS": is_ds / p.n, "share_SS": 1.0 - moving / p.n,
          "share_II_DD": np.count_nonzero((so != 0) & (so == sv)) / p.n,
          "share_ID_DI": np.count_nonzero((so != 0) & (so == -sv)) / p.n}
    if rho > THRESHOLD:
        return Evidence(TEST, rho, THRESHOLD, STICTION,
                        f"PV stays steady while OP moves for {100 * rho:.0f} % of the moving time (> "
                        f"{100 * THRESHOLD:.0f} %), the signature of a valve that sticks.", extras=ex)
    return Evidence(TEST, rho, THRESHOLD, NO_STICTION,
                    f"PV stays steady while OP moves for only {100 * rho:.0f} % of the moving time (<= "
                    f"{100 * THRESHOLD:.0f} %).", extras=ex)
