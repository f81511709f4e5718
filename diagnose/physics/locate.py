"""Locate a model/plant mismatch: where in time, after which events, in which direction, at which
operating point, at which frequency, and whether it drifts.

`locate` works on the baseline's residual (target minus whole-record simulation) and the baseline's
own simulated stem position, from which it takes the slip times, reversals and direction of motion.
It returns a JSON-ready dict (`Mismatch.summary`) and the arrays the report draws.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np


@dataclass(frozen=True, eq=False)
class Mismatch:
    """Where the baseline misses.

    Attributes
    ----------
    summary : dict
        JSON-ready: windows, events, direction, operating_point, frequency, drift, hints.
    arrays : dict of ndarray
        For figures: ``window_rms``, ``window_t_s``, ``after_slip_profile``, ``profile_lag_s``,
        ``op_bin_centres_pct``, ``op_bin_rms``, ``freq_hz``, ``residual_psd``.
    """

    summary: dict[str, Any]
    arrays: dict[str, np.ndarray] = field(default_factory=dict)
    limit_cycle_period_s: float | None = None


def _directions(stem: np.ndarray) -> np.ndarray:
    """Direction of the last motion of a simulated stem (+1 opening, -1 closing, 0 before any)."""
    d = np.sign(np.diff(stem, prepend=stem[0]))
    out = np.zeros_like(d)
    last = 0.0
    for k, v in enumerate(d):
        if v != 0:
            last = v
        out[k] = last
    return out


def slips_and_reversals(stem: np.ndarray, eps: float = 1e-9) -> tuple[np.ndarray, np.ndarray]:
    """Sample indices where a stuck simulated stem starts to move, and those that reverse direction."""
    d = np.diff(stem, prepend=stem[0])
    moving = np.abs(d) > eps
    start = np.flatnonzero(moving & ~np.roll(moving, 1))
    start = start[start > 0]
    dirs = np.sign(d[start])
    rev = np.zeros(start.shape[0], bool)
    if start.size > 1:
        rev[1:] = dirs[1:] != dirs[:-1]
    return start, start[rev]


def limit_cycle_period(stem: np.ndarray, op: np.ndarray, ts_s: float) -> float | None:
    """Period of the oscillation: median spacing of same-direction reversals, else OP's spectral peak."""
    _, rev = slips_and_reversals(stem)
    if rev.size >= 5:
        dirs = np.sign(np.diff(stem, prepend=stem[0]))[rev]
        ups = rev[dirs > 0]
        if ups.size >= 3:
            return float(np.median(np.diff(ups)) * ts_s)
    x = op - np.mean(op)
    n = x.shape[0]
    if n < 16 or np.ptp(x) == 0:
        return None
    P = np.abs(np.fft.rfft(x * np.hanning(n))) ** 2
    f = np.fft.rfftfreq(n, ts_s)
    ok = (f > 3.0 / (n * ts_s)) & (f < 0.25 / ts_s)
    if not ok.any():
        return None
    i = np.flatnonzero(ok)[np.argmax(P[ok])]
    return float(1.0 / f[i])


def _stats(r: np.ndarray) -> dict[str, float]:
    if r.size == 0:
        return {"n": 0, "mean": float("nan"), "rms": float("nan")}
    return {"n": int(r.size), "mean": float(np.mean(r)), "rms": float(np.sqrt(np.mean(r * r)))}


def locate(residual, stem_hat, op_pct, ts_s: float, *, train=None, response_s: float = 0.0,
           n_windows: int = 24) -> Mismatch:
    """Locate the mismatch of a baseline.

    Parameters
    ----------
    residual : array (n,)
        Target minus the baseline's whole-record simulation.
    stem_hat : array (n,)
        The baseline's simulated stem position, % of span (slips, reversals, direction).
    op_pct : array (n,)
        Controller output, % of span (operating point).
    ts_s : float
        Sample period, seconds.
    train : array of bool (n,), optional
        Training samples (windows are marked held-out or not).
    response_s : float
        Delay plus about half the time constant of the linear part: how long after a slip its
        effect on the target lasts (0 on the valve stage).
    n_windows : int
        Number of equal windows for the residual-over-time view.
    """
    r = np.asarray(residual, float)
    stem = np.asarray(stem_hat, float)
    op = np.asarray(op_pct, float)
    n = r.shape[0]
    train = np.ones(n, bool) if train is None else np.asarray(train, bool)
    ms = float(np.mean(r * r)) or 1e-300
    hints: list[str] = []

    # --- over time -----------------------------------------------------------------------------
    nw = max(4, min(n_windows, n // 10))
    edges = np.linspace(0, n, nw + 1).astype(int)
    wrms = np.array([np.sqrt(np.mean(r[a:b] ** 2)) for a, b in zip(edges[:-1], edges[1:])])
    med = float(np.median(wrms)) or 1e-300
    hot = wrms > 1.5 * med
    windows = []
    k = 0
    while k < nw:
        if hot[k]:
            j = k
            while j + 1 < nw and hot[j + 1]:
                j += 1
            a, b = edges[k], edges[j + 1]
            windows.append({"start_s": float(a * ts_s), "end_s": float(b * ts_s),
                            "rms": float(np.sqrt(np.mean(r[a:b] ** 2))),
                            "ratio_to_median": float(np.sqrt(np.mean(r[a:b] ** 2)) / med),
                            "heldout": bool(not train[a:b].any())})
            k = j + 1
        else:
            k += 1
    windows.sort(key=lambda w: -w["rms"])
    windows = windows[:6]

    # --- events: after slips and reversals ------------------------------------------------------
    slips, revs = slips_and_reversals(stem)
    W = max(2, int(round(response_s / ts_s)) + 2)

    def after(idx: np.ndarray) -> np.ndarray:
        m = np.zeros(n, bool)
        for i in idx:
            m[i:i + W] = True
        return m

    m_slip, m_rev = after(slips), after(revs)
    ev = {"n_slips": int(slips.size), "n_reversals": int(revs.size), "window_s": float(W * ts_s),
          "after_slip_energy_ratio": float(np.mean(r[m_slip] ** 2) / ms) if m_slip.any() else None,
          "after_reversal_energy_ratio": float(np.mean(r[m_rev] ** 2) / ms) if m_rev.any() else None,
          "share_of_time_after_slips": float(m_slip.mean())}
    if ev["after_slip_energy_ratio"] and ev["after_slip_energy_ratio"] > 2.0:
        hints.append("residual energy piles up just after slips (actuator lag?)")
    lags = np.arange(0, 3 * W)
    prof = np.full(lags.shape, np.nan)
    if slips.size:
        for j, L in enumerate(lags):
            ii = slips + L
            ii = ii[ii < n]
            if ii.size:
                prof[j] = np.sqrt(np.mean(r[ii] ** 2))

    # --- by direction of motion ------------------------------------------------------------------
    dirs = _directions(stem)
    shift = int(round(response_s / ts_s))
    if shift:
        dirs = np.concatenate([np.zeros(shift), dirs[:-shift]]) if shift < n else np.zeros(n)
    up, dn = _stats(r[dirs > 0]), _stats(r[dirs < 0])
    direction = {"opening": up, "closing": dn}
    if up["n"] > 10 and dn["n"] > 10:
        direction["mean_difference"] = up["mean"] - dn["mean"]
        direction["rms_ratio_open_close"] = up["rms"] / dn["rms"] if dn["rms"] > 0 else None
        if abs(direction["mean_difference"]) > 0.5 * np.sqrt(ms):
            hints.append("residual mean differs between opening and closing (asymmetric friction?)")

    # --- by operating point ----------------------------------------------------------------------
    q = np.quantile(op, np.linspace(0, 1, 6))
    bins = []
    centres, brms = [], []
    for a, b in zip(q[:-1], q[1:]):
        m = (op >= a) & (op <= b)
        s = _stats(r[m])
        s.update({"op_lo_pct": float(a), "op_hi_pct": float(b)})
        bins.append(s)
        centres.append((a + b) / 2)
        brms.append(s["rms"])
    corr = float(np.corrcoef(op, r)[0, 1]) if np.std(op) > 0 and np.std(r) > 0 else 0.0
    opp = {"bins": bins, "corr_residual_op": corr, "op_range_pct": [float(op.min()), float(op.max())]}
    if abs(corr) > 0.3:
        hints.append("residual correlates with the operating point (valve characteristic?)")

    # --- frequency -------------------------------------------------------------------------------
    plc = limit_cycle_period(stem, op, ts_s)
    rr = r - np.mean(r)
    P = np.abs(np.fft.rfft(rr * np.hanning(n))) ** 2
    f = np.fft.rfftfreq(n, ts_s)
    ok = (f > 3.0 / (n * ts_s)) & (f < 0.4 / ts_s)
    freq: dict[str, Any] = {"limit_cycle_period_s": plc}
    if ok.any():
        i = np.flatnonzero(ok)[np.argmax(P[ok])]
        peak_p = float(1.0 / f[i])
        at_h = False
        if plc:
            h = f[i] * plc
            at_h = bool(round(h) >= 1 and abs(h - round(h)) < 0.1)
        freq.update({"residual_peak_period_s": peak_p, "peak_at_limit_cycle_harmonic": at_h,
                     "peak_to_median_power": float(P[i] / (np.median(P[ok]) or 1e-300))})
        if not at_h and freq["peak_to_median_power"] > 50:
            from ..plain import duration

            hints.append(f"residual has a spectral peak at a period of {duration(peak_p)}, not a limit-cycle harmonic "
                         "(external disturbance?)")

    # --- drift over the record ---------------------------------------------------------------------
    thirds = np.array_split(r, 3)
    rms3 = [float(np.sqrt(np.mean(t ** 2))) for t in thirds]
    tw = (edges[:-1] + edges[1:]) / 2 * ts_s
    slope = float(np.polyfit(tw / 3600.0, wrms, 1)[0]) if nw >= 3 else 0.0
    drift = {"rms_by_third": rms3, "rms_trend_per_h": slope,
             "last_over_first": rms3[2] / rms3[0] if rms3[0] > 0 else None}
    if rms3[0] > 0 and rms3[2] / rms3[0] > 2.0:
        hints.append("residual grows over the record (drifting friction or plant change?)")

    summary = {"windows": windows, "events": ev, "direction": direction, "operating_point": opp,
               "frequency": freq, "drift": drift, "hints": hints}
    arrays = {"window_t_s": tw, "window_rms": wrms, "profile_lag_s": lags * ts_s,
              "after_slip_profile": prof, "op_bin_centres_pct": np.array(centres),
              "op_bin_rms": np.array(brms), "freq_hz": f[ok], "residual_psd": P[ok],
              "direction": dirs, "slips": slips, "reversals": revs}
    return Mismatch(summary=summary, arrays=arrays, limit_cycle_period_s=plc)
