"""The closed loop: controller (sampled at ts) -> valve train -> installed flow -> process -> PV.

Order of events in sample ``k``: the transmitter reports PV (process output + output load +
measurement noise, through the optional transmitter filter and A/D quantisation); the controller
computes OP from it; OP is held for the sample; the valve train moves the stem on the ``m``
internal steps of the sample; the installed flow (plus any input load) enters the process after
its dead time; the process advances to the next sample. The record keeps what a DCS historian
sees: OP, the transmitted PV, SP and the stem position at the end of each sample.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .controller import PID
from .process import Process
from .valve import ValveTrain

__all__ = ["Signals", "run_loop"]


@dataclass
class Signals:
    """Exogenous signals over the whole run (warm-up included), one value per sample.

    sp : setpoint, PV units. out_load : load on PV, PV units. in_load : load on the process input,
    % of flow. meas_noise : transmitter noise, PV units.
    """

    sp: np.ndarray
    out_load: np.ndarray
    in_load: np.ndarray
    meas_noise: np.ndarray


def run_loop(*, n: int, warmup: int, ts_s: float, m: int, process: Process, valve: ValveTrain,
             controller: PID, signals: Signals, u0: float, pv0: float, flow=None,
             sensor_tau_s: float = 0.0, sensor_quant: float = 0.0) -> dict[str, np.ndarray]:
    """Simulate ``warmup + n`` samples and return the last ``n``.

    Parameters
    ----------
    n, warmup : int
        Samples returned, and samples run before them.
    ts_s : float
        Controller sample period, seconds.
    m : int
        Internal steps per sample (process and valve dynamics resolve ``ts_s / m``).
    process, valve, controller
        The loop's parts.
    signals : Signals
        Arrays of length ``warmup + n``.
    u0 : float
        Starting OP and stem position, % of span; the process starts at steady state there.
    pv0 : float
        PV at that steady state, PV units.
    flow : callable, optional
        Installed characteristic, stem % -> flow % (None: linear).
    sensor_tau_s : float
        Transmitter damping (first-order filter) seen by the controller, seconds.
    sensor_quant : float
        A/D resolution of the transmitted PV, PV units (0: none).

    Returns
    -------
    dict with ``op``, ``pv``, ``sp``, ``mv`` (stem at the end of each sample), ``friction`` (the
    friction element at the end of each sample: the stem unless a lag follows the friction) and
    ``pv_true`` (process output with loads, before the transmitter), each of length ``n``.
    """
    total = n + warmup
    disc = process.discretise(ts_s, m)
    D = disc.delay_steps
    Am, G, C = disc.Am, disc.G, disc.C
    inbuf = np.zeros(total * m + D)
    stem = np.empty(total * m)
    f0 = float(flow(u0)) if flow is not None else u0
    x = disc.reset()
    valve.reset(u0)
    sp = signals.sp
    out_load = signals.out_load
    in_load = signals.in_load
    noise = signals.meas_noise
    controller.reset(u0, pv0 + out_load[0] + noise[0], sp[0])
    a_f = math.exp(-ts_s / sensor_tau_s) if sensor_tau_s > 0 else 0.0
    pv_f = pv0 + out_load[0]
    q = float(sensor_quant)
    op = np.empty(total)
    pv = np.empty(total)
    pv_true = np.empty(total)
    fric = np.empty(total)
    dot = np.dot
    for k in range(total):
        pt = pv0 + float(dot(C, x)) + out_load[k]
        pm = pt + noise[k]
        if a_f > 0.0:
            pv_f = a_f * pv_f + (1.0 - a_f) * pm
            pm = pv_f
        if q > 0.0:
            pm = q * round(pm / q)
        u = controller.step(sp[k], pm)
        lo = k * m
        seg = stem[lo:lo + m]
        valve.fill(k, u, seg)
        fric[k] = valve.friction_y
        if flow is None:
            inbuf[lo + D:lo + D + m] = seg - f0 + in_load[k]
        else:
            inbuf[lo + D:lo + D + m] = flow(seg) - f0 + in_load[k]
        x = dot(Am, x) + dot(G, inbuf[lo:lo + m])
        op[k] = u
        pv[k] = pm
        pv_true[k] = pt
    sl = slice(warmup, None)
    return {"op": op[sl], "pv": pv[sl], "sp": np.asarray(sp[sl], dtype=float), "mv": stem[m - 1::m][sl],
            "friction": fric[sl], "pv_true": pv_true[sl]}
