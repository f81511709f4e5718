"""Locate a model/plant mismatch: where in time, after which events, in which direction, at which
operating point, at which frequency, and whether it drifts.

`locate` works on the baseline's residual (target minus whole-record simulation) and the baseline's
own simulated stem position, from which it takes the slip times, reversals and direction of motion.
It returns a `Mismatch` (typed parts; `Mismatch.to_dict` is its JSON form) with the arrays the
report draws.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any

import numpy as np


@dataclass(frozen=True)
class Window:
    """A stretch of the record where the residual is high (more than 1.5 times the median
    window's RMS), in seconds from the first sample."""

    start_s: float
    end_s: float
    rms: float
    ratio_to_median: float
    heldout: bool

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)


@dataclass(frozen=True)
class Events:
    """The residual just after the simulated valve's slips and reversals (``window_s`` after each),
    relative to its mean energy (None: no such event)."""

    n_slips: int
    n_reversals: int
    window_s: float
    after_slip_energy_ratio: float | None
    after_reversal_energy_ratio: float | None
    share_of_time_after_slips: float

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)


@dataclass(frozen=True)
class ResidualStats:
    """Count, mean and RMS of the residual over some samples (NaN when there are none)."""

    n: int
    mean: float
    rms: float


@dataclass(frozen=True)
class Direction:
    """The residual while the simulated valve last moved opening and closing (with its response
    time); the difference and the ratio when both have more than 10 samples, else None."""

    opening: ResidualStats
    closing: ResidualStats
    mean_difference: float | None = None
    rms_ratio_open_close: float | None = None

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)


@dataclass(frozen=True)
class OperatingBin:
    """The residual over one OP quintile."""

    n: int
    mean: float
    rms: float
    op_lo_pct: float
    op_hi_pct: float


@dataclass(frozen=True)
class OperatingPoint:
    """The residual by operating point: per OP quintile, and its correlation with OP."""

    bins: tuple[OperatingBin, ...]
    corr_residual_op: float
    op_range_pct: tuple[float, float]

    def to_dict(self) -> dict[str, Any]:
        return {"bins": [dataclasses.asdict(b) for b in self.bins], "corr_residual_op": self.corr_residual_op,
                "op_range_pct": list(self.op_range_pct)}


@dataclass(frozen=True)
class Frequency:
    """The loop's own oscillation period and the residual's spectral peak (None: not found)."""

    limit_cycle_period_s: float | None
    residual_peak_period_s: float | None = None
    peak_at_limit_cycle_harmonic: bool | None = None
    peak_to_median_power: float | None = None

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)


@dataclass(frozen=True)
class Drift:
    """The residual's RMS by thirds of the record, its trend (per hour) and last over first third."""

    rms_by_third: tuple[float, float, float]
    rms_trend_per_h: float
    last_over_first: float | None

    def to_dict(self) -> dict[str, Any]:
        return {"rms_by_third": list(self.rms_by_third), "rms_trend_per_h": self.rms_trend_per_h,
                "last_over_first": self.last_over_first}


@dataclass(frozen=True, eq=False)
class MismatchArrays:
    """Arrays for the figures: window centres (s) and RMS, the residual's RMS profile after slips
    (lag in s), RMS per OP bin (centres in %), the residual's spectrum (Hz), the simulated valve's
    direction per sample and its slip and reversal sample indices."""

    window_t_s: np.ndarray
    window_rms: np.ndarray
    profile_lag_s: np.ndarray
    after_slip_profile: np.ndarray
    op_bin_centres_pct: np.ndarray
    op_bin_rms: np.ndarray
    freq_hz: np.ndarray
    residual_psd: np.ndarray
    direction: np.ndarray
    slips: np.ndarray
    reversals: np.ndarray


@dataclass(frozen=True, eq=False)
class Mismatch:
    """Where a model misses: over time, after events, by direction, by operating point, in
    frequency and over the record, with hints in words. `to_dict` is its JSON form."""

    windows: tuple[Window, ...]
    events: Events
    direction: Direction
    operating_point: OperatingPoint
    frequency: Frequency
    drift: Drift
    hints: tuple[str, ...]
    arrays: MismatchArrays = field(repr=False)

    @property
    def limit_cycle_period_s(self) -> float | None:
        return self.frequency.limit_cycle_period_s

    def to_dict(self) -> dict[str, Any]:
        return {"windows": [w.to_dict() for w in self.windows], "events": self.events.to_dict(),
                "direction": self.direction.to_dict(), "operating_point": self.operating_point.to_dict(),
                "frequency": self.frequency.to_dict(), "drift": self.drift.to_dict(), "hints": list(self.hints)}


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


def _stats(r: np.ndarray) -> ResidualStats:
    if r.size == 0:
        return ResidualStats(0, float("nan"), float("nan"))
    return ResidualStats(int(r.size), float(np.mean(r)), float(np.sqrt(np.mean(r * r))))


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
            rms_ab = float(np.sqrt(np.mean(r[a:b] ** 2)))
            windows.append(Window(float(a * ts_s), float(b * ts_s), rms_ab, rms_ab / med, bool(not train[a:b].any())))
            k = j + 1
        else:
            k += 1
    windows.sort(key=lambda w: -w.rms)
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
    ev = Events(int(slips.size), int(revs.size), float(W * ts_s),
                float(np.mean(r[m_slip] ** 2) / ms) if m_slip.any() else None,
                float(np.mean(r[m_rev] ** 2) / ms) if m_rev.any() else None,
                float(m_slip.mean()))
    if ev.after_slip_energy_ratio and ev.after_slip_energy_ratio > 2.0:
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
    direction = Direction(up, dn)
    if up.n > 10 and dn.n > 10:
        direction = Direction(up, dn, up.mean - dn.mean, up.rms / dn.rms if dn.rms > 0 else None)
        if abs(direction.mean_difference) > 0.5 * np.sqrt(ms):
            hints.append("residual mean differs between opening and closing (asymmetric friction?)")

    # --- by operating point ----------------------------------------------------------------------
    q = np.quantile(op, np.linspace(0, 1, 6))
    bins = []
    centres, brms = [], []
    for a, b in zip(q[:-1], q[1:]):
        m = (op >= a) & (op <= b)
        st = _stats(r[m])
        bins.append(OperatingBin(st.n, st.mean, st.rms, float(a), float(b)))
        centres.append((a + b) / 2)
        brms.append(st.rms)
    corr = float(np.corrcoef(op, r)[0, 1]) if np.std(op) > 0 and np.std(r) > 0 else 0.0
    opp = OperatingPoint(tuple(bins), corr, (float(op.min()), float(op.max())))
    if abs(corr) > 0.3:
        hints.append("residual correlates with the operating point (valve characteristic?)")

    # --- frequency -------------------------------------------------------------------------------
    plc = limit_cycle_period(stem, op, ts_s)
    rr = r - np.mean(r)
    P = np.abs(np.fft.rfft(rr * np.hanning(n))) ** 2
    f = np.fft.rfftfreq(n, ts_s)
    ok = (f > 3.0 / (n * ts_s)) & (f < 0.4 / ts_s)
    freq = Frequency(plc)
    if ok.any():
        i = np.flatnonzero(ok)[np.argmax(P[ok])]
        peak_p = float(1.0 / f[i])
        at_h = False
        if plc:
            h = f[i] * plc
            at_h = bool(round(h) >= 1 and abs(h - round(h)) < 0.1)
        freq = Frequency(plc, peak_p, at_h, float(P[i] / (np.median(P[ok]) or 1e-300)))
        if not at_h and freq.peak_to_median_power > 50:
            from ..plain import duration

            hints.append(f"residual has a spectral peak at a period of {duration(peak_p)}, not a limit-cycle harmonic "
                         "(external disturbance?)")

    # --- drift over the record ---------------------------------------------------------------------
    thirds = np.array_split(r, 3)
    rms3 = [float(np.sqrt(np.mean(t ** 2))) for t in thirds]
    tw = (edges[:-1] + edges[1:]) / 2 * ts_s
    slope = float(np.polyfit(tw / 3600.0, wrms, 1)[0]) if nw >= 3 else 0.0
    drift = Drift((rms3[0], rms3[1], rms3[2]), slope, rms3[2] / rms3[0] if rms3[0] > 0 else None)
    if rms3[0] > 0 and rms3[2] / rms3[0] > 2.0:
        hints.append("residual grows over the record (drifting friction or plant change?)")

    arrays = MismatchArrays(window_t_s=tw, window_rms=wrms, profile_lag_s=lags * ts_s, after_slip_profile=prof,
                            op_bin_centres_pct=np.array(centres), op_bin_rms=np.array(brms), freq_hz=f[ok],
                            residual_psd=P[ok], direction=dirs, slips=slips, reversals=revs)
    return Mismatch(windows=tuple(windows), events=ev, direction=direction, operating_point=opp, frequency=freq,
                    drift=drift, hints=tuple(hints), arrays=arrays)
