"""The direct valve fit: the stiction model fitted on recorded OP -> stem position MV.

When the stem position is recorded, the valve can be fitted on its own: ``MV = offset +
lag(valve(OP))`` delayed by a few samples (a positioner's response; gain 1, OP and MV both in % of
span), scored by the plain output error of MV simulated from OP (`diagnose.objective.Objective`
with no noise prefilter and a constant load: the offset).

The stem position shows the valve itself, so the search can be exact:

1. the global (S, J/S, f0) grid at every dead time without lag, on the window where OP covers the
   widest range (`diagnose.search.global_grid`), and its distinct best starts;
2. for each start the lag and the dead time from a small grid, a shrinking local (S, J, f0) grid
   (`diagnose.search.zoom`) and Nelder-Mead on (S, J, lag) (`diagnose.search.nelder_mead`);
3. on the whole record, that valve and the valves read off the stem record's stays and slips
   (`slip_brackets`: exact on a clean record, however few its slips), each from the valve's state at
   the first sample, which the record shows: stuck at the recorded stem position after a motion in
   either direction, or at rest at OP's first sample. When the best of these fits the first samples
   as well as the rest, every sample is scored (no burn-in: an early slip counts like any other);
4. a final zoom and polish on the whole record, the error surface and the intervals (as the
   Hammerstein fit, `diagnose.fit.finish`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from .fit import ErrorSurface, HammersteinFit, finish
from .objective import Candidate, Objective, burn_in, op_offset, score_weights, validate_record
from .search import (GridConfig, Limits, ModelSpace, PolishConfig, ZoomConfig, best_structure, nelder_mead,
                     profile_intervals, resolve, widest_window, zoom)
from .stiction_model import stiction_batch

#: J/S ratios of the valve fit's global grid (deadband to overshoot with J = 2 S).
VALVE_J_RATIOS = tuple(np.linspace(0.0, 2.0, 13))
#: Samples of the window the global grid runs on (where OP covers the widest range).
VALVE_SEARCH_SAMPLES = 3000
#: Actuator lags tried for each start besides none: this many, geometric from 0.3 samples to the
#: largest lag searched.
VALVE_N_LAGS = 5
#: The whole-record objective scores every sample when its best start state fits them within this
#: factor of the burn-in objective's mean squared error.
START_FIT_TOLERANCE = 1.1


@dataclass(frozen=True)
class ValveFit:
    """Result of `fit_valve`: the stiction model fitted on recorded OP -> stem position MV.

    ``MV ~ offset_pct + gain * lag(valve(OP))`` with an actuator lag ``lag_s`` and dead time
    ``delay_s`` (a positioner's response), both small. ``start_pct``: the stem position the valve
    was stuck at on the first sample (None: at rest at OP's first sample).
    """

    S_pct: float
    J_pct: float
    f0: int
    lag_s: float
    delay_s: float
    gain: float
    offset_pct: float
    ts_s: float
    rmse: float
    r2: float
    S_interval_pct: tuple[float, float]
    J_interval_pct: tuple[float, float]
    surface: ErrorSurface
    hammerstein: HammersteinFit
    start_pct: float | None = None

    def simulate(self, op_pct) -> np.ndarray:
        """Modelled stem position (% of span) for any OP series."""
        return self.hammerstein.simulate(op_pct)[1]

    @property
    def stiction_class(self) -> str:
        from .stiction_model import stiction_class
        return stiction_class(self.S_pct, self.J_pct)

    def to_dict(self) -> dict[str, Any]:
        return {"S_pct": self.S_pct, "J_pct": self.J_pct, "f0": self.f0, "lag_s": self.lag_s,
                "delay_s": self.delay_s, "gain": self.gain, "offset_pct": self.offset_pct,
                "rmse": self.rmse, "r2": self.r2, "S_interval_pct": list(self.S_interval_pct),
                "J_interval_pct": list(self.J_interval_pct), "start_pct": self.start_pct}


def lag_and_delay(obj: Objective, cand: Candidate, lim: Limits) -> Candidate:
    """The candidate's valve at every dead time x no lag, its own lag and `VALVE_N_LAGS` lags (a lag
    and a dead time trade off: both are tried together)."""
    lo, hi = lim.tau_range_s
    lags = {lo, float(cand.structure[1])}
    if hi > 0.3 * obj.ts_s:
        lags |= {float(t) for t in np.geomspace(0.3 * obj.ts_s, hi, VALVE_N_LAGS)}
    best = best_structure(obj, cand.S_pct, cand.J_pct, cand.f0,
                          lim.grid([("foptd", t, 0.0, d) for d in range(lim.dmin, lim.dmax + 1)
                                    for t in sorted(lags)]))
    return best if not best.sse >= cand.sse else cand


def fit_valve(op_pct, mv_pct, ts_s: float = 1.0, *, train=None, stiction: bool = True,
              max_lag_s: float | None = None, max_delay_s: float | None = None,
              free_gain: bool = False, surface: bool = True) -> ValveFit:
    """Fit the two-parameter valve model directly on OP -> recorded stem position MV.

    Parameters
    ----------
    op_pct, mv_pct : array (n,)
        Controller output and stem position, % of span.
    ts_s : float
        Sample period, seconds.
    train : slice or mask, optional
        Samples the fit may score.
    stiction : bool
        False fits a valve without stiction (MV = offset + lag(OP)), the reference for detection.
    max_lag_s, max_delay_s : float, optional
        Largest actuator lag and dead time searched (default 5 and 3 samples).
    free_gain : bool
        Fit the stem's gain too (default: 1, OP and MV both in % of span; only an offset is
        fitted). A free gain lets a wrong (S, J) hide behind a smaller travel.
    surface : bool
        Compute the error surface and the intervals (False: point estimates only).
    """
    x, y = validate_record(op_pct, mv_pct, ts_s, "MV (the stem position)")
    n = x.shape[0]
    off = op_offset(x)
    x = x + off
    lag_hi = max_lag_s if max_lag_s is not None else 5.0 * ts_s
    space = ModelSpace(kinds=("foptd",), max_delay_s=max_delay_s if max_delay_s is not None else 3.0 * ts_s,
                       tau_range_s=(0.05 * ts_s, lag_hi), min_delay_s=0.0)
    gcfg = GridConfig(n_S=40, J_ratios=VALVE_J_RATIOS, n_starts=3, both_f0=not free_gain)
    lim = resolve(x, ts_s, space, gcfg.n_S, gcfg.n_J)
    obj = Objective(x, y, float(ts_s), score_weights(n, train, burn_in(x, 0.05)), 0, None,
                    None if free_gain else 1.0)
    # 1-2. global grid and local search on the window of the widest OP range, the valve started in
    # each of the states the window's first stem sample allows
    m = min(n, VALVE_SEARCH_SAMPLES)
    i0 = widest_window(x, m, None if train is None else obj.weights > 0) if m < n else 0
    # a window inside the record's burn-in scores no sample at all, and an objective without a
    # scored sample cannot be built: such a window falls back to the whole record as a thin one does
    wobj = obj.window(i0, m) if m < n and np.count_nonzero(obj.weights[i0:i0 + m]) >= 50 else obj
    if wobj is obj or np.count_nonzero(wobj.weights) < 50:
        i0, wobj = 0, obj
    no_lag = lim.grid([("foptd", lim.tau_range_s[0], 0.0, d) for d in range(lim.dmin, lim.dmax + 1)])
    best = lag_and_delay(wobj, best_structure(wobj, 0.0, 0.0, 1.0, no_lag), lim)
    if stiction:
        zcfg = ZoomConfig(rounds=3, size=9, span=0.08)
        pcfg = PolishConfig(max_iter=40, tol=1e-4)
        found = []
        for c, (stem0, stuck0) in _global_with_starts(wobj, lim, gcfg, no_lag, float(y[i0]) - _offset(x, y)):
            o = wobj.with_start_stem(stem0, stuck0)
            c = nelder_mead(o, zoom(o, lag_and_delay(o, c, lim), lim, zcfg), lim, pcfg)
            found.append(c)
        best = min(found, key=lambda c: c.sse)
    # 3-4. the whole record, from the valve's state at the first sample (chosen again after the
    # polish: a start read with a slightly wrong (S, J) can be the wrong one)
    burn_obj = obj
    every = obj.with_weights(score_weights(n, train, 0))     # the same samples, no burn-in
    pool = [best] + (slip_candidates(obj, lim) if stiction else [])
    scored = []
    for c in pool:
        c = c.with_valve(c.S_pct, c.J_pct, c.f0, obj.cost(c, lim.tau_max_s))
        o, c = start_from_stem(obj, c, lim, every)
        scored.append((float(o.mse(c.sse)), c))
    best = min(scored, key=lambda t: t[0])[1]
    for _ in range(2):
        cand = best.with_valve(best.S_pct, best.J_pct, best.f0, burn_obj.cost(best, lim.tau_max_s))
        obj, best = start_from_stem(burn_obj, cand, lim, every)
        if stiction and best.S_pct > 0:
            best = zoom(obj, best, lim, ZoomConfig(rounds=3, size=9, span=0.02))
            best = nelder_mead(obj, best, lim, PolishConfig(max_iter=100, tol=1e-8))
        best = lag_and_delay(obj, best, lim)
    h = finish(obj, best, lim, off, surface=False)
    bound = best.sse * 0.05 ** (-2.0 / max(h.n_eff - 2.0, 1.0)) + ZERO_COST * obj.n_scored
    if stiction and best.S_pct > 0:
        best = special_shapes(obj, best, lim, bound)
    # the error surface on the Hammerstein fit's coarser (S, J) grid
    h = finish(obj, best, resolve(x, ts_s, space, 12, 12), off, surface=stiction and surface)
    if stiction and surface:
        # on near-exact data the F-test region is a flat cell narrower than the surface's grid
        S_p, J_p = profile_intervals(obj, best, lim, bound)
        h = replace(h, S_interval_pct=(min(h.S_interval_pct[0], S_p[0]), max(h.S_interval_pct[1], S_p[1])),
                    J_interval_pct=(min(h.J_interval_pct[0], J_p[0]), max(h.J_interval_pct[1], J_p[1])))
    p = h.process
    return ValveFit(S_pct=h.S_pct, J_pct=h.J_pct, f0=h.f0, lag_s=p.tau_s, delay_s=p.delay_s,
                    gain=p.gain, offset_pct=p.bias, ts_s=h.ts_s, rmse=h.rmse, r2=h.r2,
                    S_interval_pct=h.S_interval_pct, J_interval_pct=h.J_interval_pct,
                    surface=h.surface, hammerstein=h, start_pct=obj.start_stem_pct)


#: Costs below this fraction of the stem's variance per sample are zero (rounding in the normal
#: equations): on exact data the F-test bound is then the flat cell of zero cost.
ZERO_COST = 1e-9
#: `special_shapes`: S scanned over +- this fraction of the free fit's S, in this many steps.
SHAPE_SPAN = 0.03
SHAPE_STEPS = 241
#: ... tried only when the free fit's J is within this fraction of S of the shape's (the class
#: tolerance, `diagnose.stiction_model.stiction_class`, is 15 %).
SHAPE_NEAR = 0.2


def special_shapes(obj: Objective, cand: Candidate, lim: Limits, bound_sse: float) -> Candidate:
    """J = 0 (deadband) and J = S (no offset) when the data do not reject them: for each, the best S
    of a fine scan (+-`SHAPE_SPAN` of the free fit's S, both starting directions); the restriction
    with the lower cost replaces the free fit when its cost is within ``bound_sse`` (the F-test
    bound of the free fit). Exact data leave a truth of either shape its zero cost, and a free fit a
    hair away from it (J = 0.003 % for a deadband) would report the wrong cell."""
    grid = cand.grid(obj.ts_s, lim.tau_max_s)
    best = None
    for shape in (0.0, 1.0):
        if abs(cand.J_pct - shape * cand.S_pct) > SHAPE_NEAR * cand.S_pct:
            continue            # clearly another shape: the data reject this one
        centre, half = cand.S_pct, SHAPE_SPAN * cand.S_pct
        for _ in range(2):      # the scan, then a finer one around its best (zero-cost cells are narrow)
            Ss = np.clip(centre + half * np.linspace(-1.0, 1.0, SHAPE_STEPS), 1e-6, lim.S_cap)
            m = Ss.shape[0]
            S = np.concatenate([Ss, Ss])
            sse, _ = obj.score(S, S * shape, np.repeat([1.0, -1.0], m), grid)
            i = int(np.argmin(sse[:, 0]))
            centre, half = float(S[i]), 2.0 * half / (SHAPE_STEPS - 1)
        if sse[i, 0] <= bound_sse and (best is None or sse[i, 0] < best.sse):
            best = cand.with_valve(S[i], S[i] * shape, 1.0 if i < m else -1.0, sse[i, 0])
    return best if best is not None else cand


#: Stuck points tried for the valve's start, in units of max(S, J) around the recorded stem (the
#: valve's history before the record is unknown).
START_STUCK_DELTAS = tuple(np.linspace(-1.3, 1.3, 27))


def slip_brackets(u: np.ndarray, y: np.ndarray, tol: float = 1e-9) -> tuple | None:
    """Bounds on S and J read off a clean stem record, and the stem's offset (S - J) / 2.

    ``u`` is the valve input aligned with the stem ``y`` (OP shifted by the dead time). A sample
    whose stem moves (|dy| > ``tol``) moves in the direction f of dy and sits at ``u - f (S - J) / 2``;
    a valve that stops sticks at the input of its last moving sample, x_ss. While it stays stuck the
    input stayed within S against the last direction and within J along it (lower bounds); the slip
    that ends the stay went beyond S (a reversal) or beyond J (a restart): upper bounds. A stay
    after the first moving sample is skipped (where the valve stuck before the record, and in which
    direction it last moved, are unknown).

    Returns ``(S_lo, S_hi, J_lo, J_hi, half)`` (``half`` the median of f (u - y) over moving samples),
    or None when the record has no complete stay or the bounds contradict each other (noise, a lag:
    then the search alone decides)."""
    u = np.clip(u, 0.0, 100.0)            # as the valve sees its input
    dy = np.diff(y)
    moving = np.abs(dy) > tol
    if moving.sum() < 2:
        return None
    f = np.sign(dy)
    k_mov = np.flatnonzero(moving) + 1            # samples at which the stem moved
    half = float(np.median(f[k_mov - 1] * (u[k_mov] - y[k_mov])))
    # a stay runs from a moving sample k (the valve stops after it) to the next moving sample j;
    # all stays at once (this runs at every dead time tried). The first moving sample jumps out of
    # a state the record does not show: a valve can leave its first stuck point against the
    # direction it last moved in, so that sample's dy need not be the valve's direction, and a
    # stay after it would start from the wrong stuck point. The stays start at the second moving
    # sample (a motion over several samples has the valve's direction from its second on).
    if k_mov.shape[0] < 3:
        return None
    ks, js = k_mov[1:-1], k_mov[2:]
    fk, fj = f[ks - 1], f[js - 1]
    xss = u[ks]
    dj = u[js] - xss
    rev = fj != fk
    held = js > ks + 1              # j == k + 1: the stem kept moving, no stay
    stays = int(np.count_nonzero(held))
    # stopped and reversed within one sample, or reversed after a stay: beyond S
    S_hi = float(np.min(-fk[rev] * dj[rev], initial=math.inf))
    # a restart after a stay: beyond J, and within S against the last direction
    fwd = held & ~rev
    J_hi = float(np.min(fk[fwd] * dj[fwd], initial=math.inf))
    S_lo = float(np.max(-fk[fwd] * dj[fwd], initial=0.0))
    J_lo = 0.0
    if stays:
        # during a stay the input stayed within S against the last direction and within J along
        # it: the extremes of u over u[k+1:j] (u - x_ss rounds monotonically in u, so the extremes
        # of the differences are the differences of the extremes)
        bounds = np.column_stack([ks[held] + 1, js[held]]).ravel()
        lo_u = np.minimum.reduceat(u, bounds)[::2] - xss[held]
        hi_u = np.maximum.reduceat(u, bounds)[::2] - xss[held]
        up = fk[held] > 0
        S_lo = max(S_lo, float(np.max(np.where(up, -lo_u, hi_u))))
        J_lo = max(J_lo, float(np.max(np.where(up, hi_u, -lo_u))))
    if stays == 0 or S_lo > S_hi or J_lo > J_hi:
        return None
    return S_lo, S_hi, J_lo, J_hi, half


def delayed(x: np.ndarray, d: int) -> np.ndarray:
    """The input ``x`` as a valve behind ``d`` samples of dead time sees it (held at its first value
    before that), aligned with the stem."""
    return np.r_[np.full(d, x[0]), x[: x.shape[0] - d]] if d > 0 else np.asarray(x)


def stem_slips(y, tol_sigmas: float = 5.0) -> np.ndarray:
    """Samples a recorded stem slipped to: steps larger than ``tol_sigmas`` times the noise of its
    sample-to-sample changes (a robust scale: most samples of a sticky stem hold still), one per
    motion (a step right after another the same way continues it).

    Parameters
    ----------
    y : array (n,)
        Recorded stem position, % of span.
    tol_sigmas : float
        Slip threshold in noise standard deviations of the stem's steps.
    """
    y = np.asarray(y, float)
    if y.shape[0] < 3:
        return np.empty(0, np.intp)
    dy = np.diff(y)
    scale = 1.4826 * float(np.median(np.abs(dy - np.median(dy))))
    tol = max(tol_sigmas * scale, 1e-9 * (float(np.ptp(y)) or 1.0))
    slips = np.flatnonzero(np.abs(dy) > tol) + 1
    if slips.shape[0] == 0:
        return slips
    f = np.sign(dy[slips - 1])
    keep = np.r_[True, (np.diff(slips) > 1) | (f[1:] != f[:-1])]
    return slips[keep]


@dataclass(frozen=True)
class SlipReading:
    """Friction bands per direction read off a noisy stem record by `slip_reading` (% of span;
    NaN where the record shows too few events of that kind).

    ``S_up_pct`` / ``S_dn_pct``: the band a reversal into opening / closing crossed (median over
    reversals); ``J_up_pct`` / ``J_dn_pct``: the band a restart in that direction crossed (median over
    restarts); ``half_up_pct`` / ``half_dn_pct``: the moving stem's lag behind OP, (S - J) / 2 of that
    direction (median over moving samples); ``n_*``: how many events each median rests on.
    """

    S_up_pct: float
    S_dn_pct: float
    J_up_pct: float
    J_dn_pct: float
    half_up_pct: float
    half_dn_pct: float
    n_reversals: tuple[int, int]
    n_restarts: tuple[int, int]

    def valves(self) -> list[tuple[float, float, float, float]]:
        """(S_up, J_up, S_dn, J_dn) readings: J from the restarts and from the moving offsets, each
        where the record shows it; none without both reversal bands."""
        if not (math.isfinite(self.S_up_pct) and math.isfinite(self.S_dn_pct)):
            return []
        out = []
        for J_up, J_dn in ((self.J_up_pct, self.J_dn_pct),
                           (self.S_up_pct - 2.0 * self.half_up_pct, self.S_dn_pct - 2.0 * self.half_dn_pct)):
            J_up = J_up if math.isfinite(J_up) else self.S_up_pct - 2.0 * self.half_up_pct
            J_dn = J_dn if math.isfinite(J_dn) else self.S_dn_pct - 2.0 * self.half_dn_pct
            if math.isfinite(J_up) and math.isfinite(J_dn):
                v = (self.S_up_pct, max(J_up, 0.0), self.S_dn_pct, max(J_dn, 0.0))
                if v not in out:
                    out.append(v)
        return out


def slip_reading(u, y, *, min_events: int = 2, tol_sigmas: float = 5.0) -> SlipReading | None:
    """Friction bands per direction read off a stem record with measurement noise.

    `slip_brackets` needs a clean stem; this reading takes medians instead of intersections, so a
    few misread events do not void it. A slip is a stem step larger than ``tol_sigmas`` times the
    noise of the stem's sample-to-sample changes (robust scale). After a slip the model itself says
    how long the stem moves: while the input goes on in the slip's direction (``u`` is OP, known
    without noise), so the stuck point is the input where it stopped or turned. The next slip
    crossed the band of a reversal (into the other direction: S of that direction) or of a restart
    (J of the same direction); each crossing is read as the middle between the furthest the input
    went while the stem held and where it stood at the slip. The first slip is skipped (the state
    before it is not in the record).

    Parameters
    ----------
    u : array (n,)
        Valve input, % of span, aligned with the stem (OP shifted by any dead time).
    y : array (n,)
        Recorded stem position, % of span.
    min_events : int
        Events of one kind needed for its band (else NaN).
    tol_sigmas : float
        Slip threshold in noise standard deviations of the stem's steps.

    Returns
    -------
    SlipReading or None
        None when the stem shows fewer than three slips.

    Notes
    -----
    Exact on the model's own stem up to the input's step size; a stem that moves in steps no larger
    than its noise (a pure deadband valve under a slow input) shows few slips and reads poorly: the
    reading is a start for a search, not a fit.
    """
    u = np.clip(np.asarray(u, float), 0.0, 100.0)
    y = np.asarray(y, float)
    if u.ndim != 1 or u.shape != y.shape:
        raise ValueError(f"slip_reading: input and stem must be 1-D of one length, got {u.shape} and {y.shape}")
    n = y.shape[0]
    du = np.diff(u)
    slips = stem_slips(y, tol_sigmas)
    if slips.shape[0] < 3:
        return None
    f = np.sign(y[slips] - y[slips - 1])
    bands: dict[tuple[str, int], list[float]] = {(k, d): [] for k in "SJ" for d in (1, -1)}
    halves: dict[int, list[np.ndarray]] = {1: [], -1: []}
    for i in range(slips.shape[0] - 1):
        a, fa = int(slips[i]), int(f[i])
        # the stem moves on while the input goes on in its direction (the model's own rule)
        b = a
        while b + 1 < n and du[b] * fa > 0.0 and b + 1 < slips[i + 1]:
            b += 1
        halves[fa].append(fa * (u[a:b + 1] - y[a:b + 1]))
        if i == 0:
            continue
        j, fj = int(slips[i + 1]), int(f[i + 1])
        xss = u[b]
        held = u[b + 1:j]
        sense = -fa if fj != fa else fa          # the direction the input had to go
        lo = float(np.max(sense * (held - xss), initial=0.0))
        hi = float(sense * (u[j] - xss))
        if hi <= lo:
            continue                             # noise or a lag: not readable
        bands[("S" if fj != fa else "J", fj)].append(0.5 * (lo + hi))

    def med(v) -> float:
        return float(np.median(v)) if len(v) >= min_events else math.nan

    def med_half(parts) -> float:
        v = np.concatenate(parts) if parts else np.empty(0)
        return float(np.median(v)) if v.shape[0] >= 3 else math.nan

    return SlipReading(S_up_pct=med(bands[("S", 1)]), S_dn_pct=med(bands[("S", -1)]),
                       J_up_pct=med(bands[("J", 1)]), J_dn_pct=med(bands[("J", -1)]),
                       half_up_pct=med_half(halves[1]), half_dn_pct=med_half(halves[-1]),
                       n_reversals=(len(bands[("S", 1)]), len(bands[("S", -1)])),
                       n_restarts=(len(bands[("J", 1)]), len(bands[("J", -1)])))


def slip_candidates(obj: Objective, lim: Limits) -> list[Candidate]:
    """Valves read off the stem record by `slip_brackets` at each dead time (no lag): S and J
    inside their bounds, consistent with the moving offset where it can be. Unscored."""
    out = []
    x, y = obj.x, obj.y
    span = float(np.ptp(y)) or 1.0
    for d in range(lim.dmin, lim.dmax + 1):
        u = delayed(x, d)
        res = slip_brackets(u, y, 1e-9 * span)
        if res is None:
            continue
        S_lo, S_hi, J_lo, J_hi, half = res
        S = 0.5 * (S_lo + S_hi) if math.isfinite(S_hi) else S_lo * 1.01
        J = 0.5 * (J_lo + J_hi) if math.isfinite(J_hi) else max(S - 2.0 * half, J_lo)
        key = ("foptd", lim.tau_range_s[0], 0.0, d)
        out.append(Candidate(S, J, 1.0, key, math.nan))
        J2 = S - 2.0 * half
        if J_lo <= J2 <= J_hi and J2 >= 0:
            out.append(Candidate(S, J2, 1.0, key, math.nan))
    return out


def _offset(x: np.ndarray, y: np.ndarray) -> float:
    """A first guess of the stem's offset against OP: the median difference."""
    return float(np.median(y - x))


def start_table(S, J, f, x0: float, y0: float) -> np.ndarray:
    """Valve candidates (S, J, f arrays) each in four start states: at rest at the input x0; at rest
    at the stem position y0 (stuck there with the input there too: a valve that has not moved since
    it was set); stuck at y0 where a valve moving in direction f stops; and moving in direction f
    through y0 (stuck at the input less J: any further input in direction f moves it). Returns the
    (5, 4m) valve table of `diagnose.objective.Objective.score_table`."""
    S, J, f = (np.asarray(v, dtype=float) for v in (S, J, f))
    m = S.shape[0]
    nan = np.full(m, np.nan)
    y = np.full(m, y0)
    return np.ascontiguousarray(np.hstack([np.vstack([S, J, f, nan, nan]), np.vstack([S, J, f, y, y])]))


def _global_with_starts(obj: Objective, lim: Limits, cfg: GridConfig, grid, y0: float):
    """The distinct best (S, J/S, f0) of the global grid at the structures of ``grid``, each valve in
    the four start states of `start_table`: [(candidate, (start stem, start stuck point)), ...]."""
    ratios = np.asarray(cfg.J_ratios, float)
    Sg, Rg, Fg = np.meshgrid(lim.S_grid, ratios, [1.0, -1.0], indexing="ij")
    table = start_table(Sg.ravel(), (Sg * Rg).ravel(), Fg.ravel(), float(obj.x[0]), y0)
    sse, _ = obj.score_table(table, grid.table)
    order = np.argsort(sse.min(axis=1))
    out: list = []
    for i in order:
        p = int(np.argmin(sse[i]))
        c = Candidate(float(table[0, i]), float(table[1, i]), float(table[2, i]), grid.keys[p], float(sse[i, p]))
        if all(abs(c.S_pct - s.S_pct) > 0.2 * c.S_pct or abs(c.J_pct - s.J_pct) > 0.2 * max(c.S_pct, 1e-9)
               for s, _ in out):
            out.append((c, (float(table[3, i]), float(table[4, i]))))
        if len(out) >= cfg.n_starts:
            break
    return out


def start_from_stem(obj: Objective, cand: Candidate, lim: Limits, full: Objective) -> tuple[Objective, Candidate]:
    """The valve's state at the first sample, read from the recorded stem position, and the
    objective that scores from there.

    Tried, in both directions f: at rest at OP's first sample; stuck at the recorded stem position
    (less the candidate's offset) after a motion in direction f, where a moving valve stops, or
    anywhere within reach of a slip (`START_STUCK_DELTAS`); moving in direction f at the first
    sample (stuck at the input less J: any further input in direction f moves it). The objective
    then scores every sample when the best start fits them within `START_FIT_TOLERANCE` of the
    burn-in objective's mean squared error; otherwise the burn-in objective is kept. ``full`` is
    ``obj`` scoring every training sample (no burn-in)."""
    grid = lim.grid([cand.structure])
    stem = grid.model(0).regressor(stiction_batch(obj.x, [cand.S_pct], [cand.J_pct], [cand.f0])[0], obj.ts_s)
    ws = obj.weights > 0
    offset = float(np.mean(obj.y[ws] - stem[ws])) if obj.gain_fixed is not None else 0.0
    x0 = float(np.clip(obj.x[0], 0.0, 100.0))
    reach = max(cand.S_pct, cand.J_pct, 0.05)
    starts = [(math.nan, math.nan, f) for f in (1.0, -1.0)]
    # the recorded stem as it is (OP and MV in % of span) and less the offset the candidate fits
    # (a stem that has stayed put since the record began biases that offset)
    for y0 in sorted({float(np.clip(obj.y[0], 0.0, 100.0)), float(np.clip(obj.y[0] - offset, 0.0, 100.0))}):
        for f in (1.0, -1.0):
            starts += [(y0, math.nan, f), (y0, x0 - f * cand.J_pct, f)]
            starts += [(y0, y0 + f * dl * reach, f) for dl in START_STUCK_DELTAS]
    st = np.array(starts)
    valves = np.ascontiguousarray(np.vstack([np.full(len(starts), cand.S_pct), np.full(len(starts), cand.J_pct),
                                             st[:, 2], st[:, 0], st[:, 1]]))
    sse, _ = full.score_table(valves, grid.table)
    k = int(np.argmin(sse[:, 0]))
    if float(full.mse(sse[k, 0])) > START_FIT_TOLERANCE * float(obj.mse(cand.sse)) + 1e-12:
        return obj, cand
    stem0, stuck0, f = starts[k]
    return full.with_start_stem(stem0, stuck0), cand.with_valve(cand.S_pct, cand.J_pct, f, sse[k, 0])
