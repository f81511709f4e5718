"""Search strategies over an `diagnose.objective.Objective`: small named functions, each with a frozen
config, each returning scored `Candidate` objects and never changing the objective.

* `linear_fit`: the best process structure for a valve without stiction (S = J = 0);
* `best_structure`, `polish_structure`: a valve's process structure from a grid, then finer lags;
* `coarse_structures`, `global_grid`: (S, J/S) x a coarse set of lags and dead times: the distinct
  best starts;
* `dense_grid`: a dense (S, J/S, f0) grid at a few structures (the valley in S and J is narrow);
* `shape_profile`: every class shape (J/S) picks its own structure, then gets the dense grid;
* `nelder_mead`: local polish of (S, J, lags) by the Nelder-Mead simplex (`simplex_minimize`);
* `refine`: rounds of structure polish and Nelder-Mead;
* `shape_bands`: the best candidate of each class band (deadband, undershoot, no offset, overshoot)
  over J/S, S and every dead time near the best lags, each refined with its own structure;
* `zoom`: a shrinking local (S, J, f0) grid (the cost is piecewise constant in S and J: a grid cannot
  stall where a simplex can);
* `noise_costs`, `noise_model`: a candidate's cost under each noise prefilter, and the cheapest;
* `start_state`: the valve's unknown state at the record's start, as a nuisance parameter;
* `widest_window`, `search_windows`: where in a record to search;
* `class_test`: the special shapes J = 0 and J = S against the free fit, the start state free.

`diagnose.fit` composes them into the Hammerstein fit.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from . import kernels
from .objective import MIN_SAMPLES, Candidate, Objective, ProcessGrid, burn_in, score_weights
from .parallel import thread_count, thread_map
from .process_model import lag_coefficient
from .stiction_model import stiction_classes

#: J/S ratios of the global grid (deadband, undershoot, no offset, overshoot).
DEFAULT_J_RATIOS = (0.0, 0.25, 0.5, 0.75, 1.0, 1.3, 1.6, 2.0)
#: Dead times (samples) of the global (S, J) grid's structures, besides the linear model's.
GLOBAL_DELAYS = (0, 2, 5, 12)
#: J/S ratios whose best valve picks its own process structure (one per class shape)
PROFILE_RATIOS = (0.0, 0.5, 1.0, 1.5, 2.0)
#: S relative to the best fit's, profiled with J/S and the dead time (`shape_bands`)
PROFILE_S_FACTORS = (0.8, 0.9, 1.0, 1.1, 1.2)
#: Refinements keep S and J at or below this multiple of the S grid's end (OP's 0.5-99.5 % range):
#: a valve that sticks and slips both ways needs OP to travel more than S; a larger S can only fit by
#: never reversing (a ratchet that follows a drift).
S_CAP_FACTOR = 1.2
#: Noise-model time constants (samples) tried by `noise_model`; None is pure output error.
NOISE_CANDIDATES = (2.0, 5.0, 10.0, 20.0, 50.0, None)
NAN = float("nan")
#: First stuck points tried by `start_state`, as multiples of max(S, J) around OP's first sample
START_DELTAS = (-1.0, -0.5, 0.5, 1.0)


# --------------------------------------------------------------------------------------------------
# the model space
# --------------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class ModelSpace:
    """The model family searched.

    kinds : process structures (``foptd``, ``soptd``, ``integrating``);
    max_delay_s / min_delay_s : dead times (defaults: a tenth of the record, at most 60 samples / one
    sample: logged PV cannot respond to the OP logged at the same instant, and allowing it lets the
    fit explain PV through the controller);
    tau_range_s : lags (default half a sample to a quarter of the record);
    S_max_pct : largest S of the grid (default OP's robust range);
    structure : (kind, tau_s, tau2_s, delay_s) to fix the process instead of searching it.
    """

    kinds: tuple = ("foptd", "soptd", "integrating")
    max_delay_s: float | None = None
    min_delay_s: float | None = None
    tau_range_s: tuple | None = None
    S_max_pct: float | None = None
    structure: tuple | None = None


@dataclass(frozen=True, eq=False)
class Limits:
    """A `ModelSpace` resolved on one record: dead-time range (samples), lag bound, the (S, J) grid
    of the global search and the error surface, the cap of S and J, and the full process grid."""

    ts_s: float
    n: int
    kinds: tuple
    dmin: int
    dmax: int
    tau_range_s: tuple | None
    tau_max_s: float
    S_grid: np.ndarray
    J_grid: np.ndarray
    S_cap: float
    structure: tuple | None
    process: ProcessGrid

    @property
    def fixed(self) -> bool:
        return self.structure is not None

    def grid(self, keys) -> ProcessGrid:
        return ProcessGrid.of(keys, self.ts_s, self.tau_max_s)


def s_grid(x: np.ndarray, n_S: int, S_max_pct: float | None) -> np.ndarray:
    """S values of a grid: denser at small S, up to OP's robust range (or ``S_max_pct``)."""
    if S_max_pct is None:
        lo, hi = np.percentile(x, [0.5, 99.5])
        S_max_pct = float(min(max(hi - lo, 0.2), 100.0))
    k = np.arange(1, n_S + 1) / n_S
    return S_max_pct * k ** 1.4


def process_keys(ts_s: float, n: int, kinds, dmin: int, dmax: int,
                 tau_range_s: tuple[float, float] | None = None) -> list:
    """The full process grid: 11 lags (geometric) x dead times (0-4 samples, then geometric to the
    maximum) x kinds (SOPTD with tau2 = tau / 3 and tau2 = tau; the integrator's input lag tau / 4)."""
    span_s = n * ts_s
    lo, hi = tau_range_s if tau_range_s is not None else (0.5 * ts_s, max(span_s / 4.0, 2 * ts_s))
    taus = np.geomspace(max(lo, 1e-9), max(hi, lo * 1.01), 11)
    delays = sorted(set([0, 1, 2, 3, 4] + [int(round(v)) for v in np.geomspace(5, max(dmax, 5), 8)]))
    delays = [dd for dd in delays if dmin <= dd <= dmax] or [max(dmin, 0)]
    keys = []
    for dd in delays:
        for t in taus:
            if "foptd" in kinds:
                keys.append(("foptd", float(t), 0.0, dd))
            if "soptd" in kinds:
                keys.append(("soptd", float(t), float(t) / 3.0, dd))
                keys.append(("soptd", float(t), float(t), dd))
            if "integrating" in kinds:
                keys.append(("integrating", float(t) / 4.0, 0.0, dd))
    return keys


def resolve(x: np.ndarray, ts_s: float, space: ModelSpace, n_S: int, n_J: int) -> Limits:
    """The `Limits` of ``space`` on a record with valve input ``x``."""
    n = x.shape[0]
    dmax = int(round((space.max_delay_s if space.max_delay_s is not None
                      else min(n * ts_s / 10.0, 60 * ts_s)) / ts_s))
    dmax = max(0, min(dmax, n // 5))
    dmin = int(round((space.min_delay_s if space.min_delay_s is not None else ts_s) / ts_s))
    dmin = min(max(dmin, 0), dmax)
    tau_max = max(space.tau_range_s[1], 0.0) if space.tau_range_s is not None else math.inf
    S_grid = s_grid(x, n_S, space.S_max_pct)
    J_grid = np.concatenate([[0.0], 1.5 * S_grid[-1] * (np.arange(1, n_J) / (n_J - 1)) ** 1.4])
    if space.structure is not None:
        k_, t1_, t2_, d_ = space.structure
        keys = [(k_, t1_, t2_, int(round(d_ / ts_s)))]
        fixed = keys[0]
    else:
        keys = process_keys(ts_s, n, space.kinds, dmin, dmax, space.tau_range_s)
        fixed = None
    return Limits(float(ts_s), n, tuple(space.kinds), dmin, dmax, space.tau_range_s, tau_max, S_grid, J_grid,
                  S_CAP_FACTOR * float(S_grid[-1]), fixed, ProcessGrid.of(keys, ts_s, tau_max))


# --------------------------------------------------------------------------------------------------
# process structure
# --------------------------------------------------------------------------------------------------

def best_structure(obj: Objective, S: float, J: float, f0: float, grid: ProcessGrid) -> Candidate:
    """The structure of ``grid`` that fits the valve (S, J, f0) best."""
    sse, _ = obj.score([S], [J], [f0], grid)
    p = int(np.argmin(sse[0]))
    return Candidate(float(S), float(J), float(f0), grid.keys[p], float(sse[0, p]))


#: Lag factors of `polish_structure` (the dead time also moves by one sample each way).
POLISH_LAG_FACTORS = tuple(2.0 ** np.arange(-1.0, 1.01, 0.25))


def polish_structure(obj: Objective, cand: Candidate, lim: Limits) -> Candidate:
    """Finer lags (x 2^(-1..1) in quarter octaves) and +-1 sample of dead time around the candidate's
    structure; the candidate itself when the structure is fixed or nothing is better."""
    if lim.fixed:
        return cand
    kind, tau, tau2, dd = cand.structure
    keys = []
    for f in POLISH_LAG_FACTORS:
        for ddd in sorted({max(lim.dmin, dd - 1), dd, max(lim.dmin, min(lim.dmax, dd + 1))}):
            keys.append((kind, tau * f, tau2 * f if kind == "soptd" else 0.0, ddd))
    best = best_structure(obj, cand.S_pct, cand.J_pct, cand.f0, lim.grid(keys))
    return best if best.sse < cand.sse else cand


def other_kinds(obj: Objective, cand: Candidate, lim: Limits, cfg: "PolishConfig",
                stiction: bool = True) -> list[Candidate]:
    """The candidate's valve under the process kinds of the other family (an integrating process
    for a self-regulating candidate, FOPTD and SOPTD for an integrating one): each kind's full
    structure grid and a structure polish, then `refine`; those that come within
    `KIND_CHECK_MARGIN` of the candidate's cost, for the caller to finish alongside it and keep the
    cheapest.

    Over a record shorter than its lag a self-regulating process integrates, and the searches,
    which pick the kind with the structures they try, can end in the wrong family: a level loop as
    a first-order lag of hours with its input lag read as dead time, a training span of a
    first-order loop as an integrator that misses the held-out part by many times PV's spread.
    Near-equals are finished, not compared here: which family wins can turn on the last polish.
    A self-regulating model whose lag outgrows a quarter of the record (an integrator in all but
    name) is not offered against an integrator. FOPTD against SOPTD is left to the searches,
    which try both on one grid: where the valve model is itself wrong (an asymmetric valve fitted
    as a symmetric one), the cheaper of the two is often the one further from the plant."""
    if lim.fixed or len(lim.kinds) < 2:
        return []
    integrating = cand.structure[0] == "integrating"
    out = []
    for kind in lim.kinds:
        keys = [k for k in lim.process.keys if k[0] == kind]
        if (kind == "integrating") == integrating or not keys:
            continue
        alt = polish_structure(obj, best_structure(obj, cand.S_pct, cand.J_pct, cand.f0, lim.grid(keys)), lim)
        if alt.sse >= KIND_CHECK_MARGIN * cand.sse:
            continue
        if stiction:
            alt = refine(obj, alt, lim, cfg)
        if integrating and max(alt.structure[1], alt.structure[2]) > 0.25 * lim.n * lim.ts_s:
            continue
        if alt.sse < KIND_CHECK_MARGIN * cand.sse:
            out.append(alt)
    return out


#: `other_kinds` offers another kind's structure when it costs less than this many times the
#: candidate.
KIND_CHECK_MARGIN = 1.1


def linear_fit(obj: Objective, lim: Limits) -> Candidate:
    """The valve without stiction (S = J = 0): the best structure of the full grid, polished."""
    return polish_structure(obj, best_structure(obj, 0.0, 0.0, 1.0, lim.process), lim)


def noise_costs(obj: Objective, cand: Candidate, lim: Limits,
                candidates_samples=NOISE_CANDIDATES) -> tuple[float, ...]:
    """The prediction-error cost of ``cand`` (mean squared prefiltered error per scored sample, PV
    units^2) under each noise prefilter of ``candidates_samples`` (samples; None: plain output
    error). The filters are monic, so the costs of different noise models compare directly."""
    grid = cand.grid(obj.ts_s, lim.tau_max_s)
    costs = []
    for hp in candidates_samples:
        o = obj.with_noise(None if hp is None else hp * obj.ts_s)
        sse, _ = o.score([cand.S_pct], [cand.J_pct], [cand.f0], grid)
        costs.append(float(o.mse(sse[0, 0])))
    return tuple(costs)


def noise_model(obj: Objective, cand: Candidate, lim: Limits,
                candidates_samples=NOISE_CANDIDATES) -> float | None:
    """The noise prefilter (``hp_tau_s`` in seconds, None: plain output error) under which
    ``cand`` has the lowest prediction-error cost (`noise_costs`)."""
    costs = noise_costs(obj, cand, lim, candidates_samples)
    best = candidates_samples[int(np.argmin(costs))]
    return None if best is None else best * obj.ts_s


# --------------------------------------------------------------------------------------------------
# global and dense grids
# --------------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class GridConfig:
    """The global grid: ``n_S`` values of S (`s_grid`) x ``J_ratios`` (J/S) x a coarse set of 6
    lags and the dead times `GLOBAL_DELAYS`; ``n_starts`` distinct best starts are kept (S or J
    apart by more than 20 % of S). ``both_f0``: score both starting directions (the valve fit: on
    clean data f0 matters for long)."""

    n_S: int = 12
    n_J: int = 12
    J_ratios: tuple = DEFAULT_J_RATIOS
    n_starts: int = 3
    both_f0: bool = False


def coarse_structures(lim: Limits, linear: Candidate) -> ProcessGrid:
    """The global grid's structures: FOPTD at 6 lags (geometric, one sample to an eighth of the
    record) x the dead times `GLOBAL_DELAYS` and the linear model's, plus the integrator at those
    dead times (when searched); the linear model's structure alone when the structure is fixed."""
    if lim.fixed:
        return lim.grid([linear.structure])
    ts = lim.ts_s
    t_lo, t_hi = lim.tau_range_s if lim.tau_range_s is not None else (ts, max(lim.n * ts / 8.0, 2 * ts))
    taus = np.geomspace(t_lo, max(t_hi, 1.01 * t_lo), 6)
    d_lin = int(linear.structure[3])
    dset = sorted({max(lim.dmin, dd) for dd in GLOBAL_DELAYS + (d_lin,) if dd <= lim.dmax})
    # the lags as FOPTD (or, where FOPTD is not searched, the SOPTD of equal lags): each start's own
    # structure is then picked from the full grid
    lag = ("foptd", 0.0) if "foptd" in lim.kinds else ("soptd", 1.0) if "soptd" in lim.kinds else None
    keys = [] if lag is None else [(lag[0], float(t), lag[1] * float(t), dd) for t in taus for dd in dset]
    if "integrating" in lim.kinds:
        keys += [("integrating", float(ts), 0.0, dd) for dd in dset]
    return lim.grid(keys)


def global_grid(obj: Objective, lim: Limits, cfg: GridConfig, grid: ProcessGrid
                ) -> tuple[list[Candidate], np.ndarray]:
    """Distinct best starts of the global (S, J/S, f0) grid at the structures of ``grid``.

    Returns the starts (best first) and each structure's best cost over the valves.
    """
    ratios = np.asarray(cfg.J_ratios, float)
    f_set = [1.0, -1.0] if cfg.both_f0 else [1.0]
    Sg, Rg, Fg = np.meshgrid(lim.S_grid, ratios, f_set, indexing="ij")
    Sg, Jg, Fg = Sg.ravel(), (Sg * Rg).ravel(), Fg.ravel()
    sse, _ = obj.score(Sg, Jg, Fg, grid)
    order = np.argsort(sse.min(axis=1))
    starts: list[Candidate] = []
    for i in order:
        p = int(np.argmin(sse[i]))
        c = Candidate(float(Sg[i]), float(Jg[i]), float(Fg[i]), grid.keys[p], float(sse[i, p]))
        if all(abs(c.S_pct - s.S_pct) > 0.2 * c.S_pct or abs(c.J_pct - s.J_pct) > 0.2 * max(c.S_pct, 1e-9)
               for s in starts):
            starts.append(c)
        if len(starts) >= cfg.n_starts:
            break
    return starts, sse.min(axis=0)


@dataclass(frozen=True)
class DenseConfig:
    """The dense grid: ``n_S`` values of S x ``n_ratios`` J/S in 0..2 x both starting directions,
    at the structures of the starts, the linear model and the ``extra_structures`` best coarse
    structures. ``profile_ratios``: J/S values whose best valve picks its own structure
    (`shape_profile`; empty: off)."""

    n_S: int = 36
    n_ratios: int = 17
    extra_structures: int = 0
    profile_ratios: tuple = PROFILE_RATIOS


def dense_valves(lim: Limits, cfg: DenseConfig) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The dense grid's (S, J, f0) as three flat arrays."""
    S_dense = s_grid(np.zeros(1), cfg.n_S, float(lim.S_grid[-1]))
    Sd, Rd, Fd = np.meshgrid(S_dense, np.linspace(0.0, 2.0, cfg.n_ratios), [1.0, -1.0], indexing="ij")
    return Sd.ravel(), (Sd * Rd).ravel(), Fd.ravel()


def dense_grid(obj: Objective, lim: Limits, cfg: DenseConfig, keys: list
               ) -> tuple[list[Candidate], np.ndarray]:
    """The dense (S, J, f0) grid at each structure of ``keys``: the best valve of each, and the
    whole cost table (valves x structures) for `shape_profile`."""
    Sd, Jd, Fd = dense_valves(lim, cfg)
    grid = lim.grid(keys)
    sse, _ = obj.score(Sd, Jd, Fd, grid)
    out = []
    for p in range(len(grid)):
        i = int(np.argmin(sse[:, p]))
        out.append(Candidate(float(Sd[i]), float(Jd[i]), float(Fd[i]), grid.keys[p], float(sse[i, p])))
    return out, sse


def shape_profile(obj: Objective, lim: Limits, cfg: DenseConfig, sse_dense: np.ndarray, dense_keys: list
                  ) -> list[Candidate]:
    """Every valve shape gets its own process: the lags and the dead time trade off against J, so a
    structure picked for one shape can hide the right one. For each profiled J/S, the best valve of
    the dense grid picks its structure from the full process grid (polished); structures not yet in
    ``dense_keys`` get the dense grid too, and the best valve near each profiled J/S is returned."""
    if lim.fixed or not cfg.profile_ratios:
        return []
    Sd, Jd, Fd = dense_valves(lim, cfg)
    Rdv = Jd / np.maximum(Sd, 1e-12)
    keys = list(dense_keys)
    new = []
    for r in cfg.profile_ratios:
        sel = np.abs(Rdv - r) < 1e-6
        if not sel.any():
            continue
        sub = np.where(sel[:, None], sse_dense, np.inf)
        i, _p = np.unravel_index(int(np.argmin(sub)), sub.shape)
        c = polish_structure(obj, best_structure(obj, float(Sd[i]), float(Jd[i]), float(Fd[i]), lim.process), lim)
        if c.structure not in keys:
            keys.append(c.structure)
            new.append(c.structure)
    out = []
    if new:
        grid = lim.grid(new)
        sse, _ = obj.score(Sd, Jd, Fd, grid)
        for p in range(len(grid)):
            for r in cfg.profile_ratios:
                col = np.where(np.abs(Rdv - r) < 0.07, sse[:, p], np.inf)
                i = int(np.argmin(col))
                if np.isfinite(col[i]):
                    out.append(Candidate(float(Sd[i]), float(Jd[i]), float(Fd[i]), grid.keys[p], float(col[i])))
    return out


# --------------------------------------------------------------------------------------------------
# local polish
# --------------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class PolishConfig:
    """Nelder-Mead on (S, J, log lag) (dead time and lag ratio fixed; both starting directions
    scored at every point, the better counts): at most ``max_iter`` iterations, stopping when the
    simplex's costs agree within ``tol`` (relative). ``rounds`` alternations of structure polish and
    Nelder-Mead per `refine`; ``n_refine`` best candidates refined."""

    max_iter: int = 60
    tol: float = 1e-3
    rounds: int = 2
    n_refine: int = 3


def simplex_minimize(cost, simplex: np.ndarray, max_iter: int, fatol: float, *,
                     costs=None) -> tuple[np.ndarray, float]:
    """Minimise ``cost`` by the Nelder-Mead simplex (reflection 1, expansion 2, contraction and
    shrink 1/2; Lagarias et al. 1998) from ``simplex`` (N + 1 points of N parameters): at most
    ``max_iter`` iterations, stopping once every vertex's cost is within ``fatol`` of the best's.
    Returns the best point and its cost.

    The same iterations as ``scipy.optimize.minimize(method="Nelder-Mead")`` with
    ``initial_simplex``, ``maxiter``, ``fatol`` and ``xatol=inf``, written here because importing
    scipy.optimize costs a noticeable share of the ``stiction identify`` command's start-up.

    ``costs``, optional, scores several points (k, N) in one call, each exactly as ``cost`` would:
    the start simplex and each shrink are then scored at once, and every reflection together
    with the inside contraction, the step most often needed next (spent when it is not). Where
    one call scores a few points for about the price of one (a vector kernel's lanes), this cuts
    the calls by about a third; the iterations and the result stay exactly the same.
    """
    if costs is None:
        score = lambda pts: [cost(np.array(v)) for _, v in pts]         # noqa: E731
    else:
        score = lambda pts: costs(np.array([v for _, v in pts]))       # noqa: E731
    return simplex_minimize_many(score, [simplex], max_iter, [fatol], pair=costs is not None)[0]


def simplex_minimize_many(score, simplexes, max_iter: int, fatols, *, pair: bool = True) -> list:
    """Several independent Nelder-Mead minimisations (`simplex_minimize`) in lockstep: each
    simplex takes exactly the steps it would take alone, and every stage of an iteration (the
    reflections, then the expansions and contractions, then the shrinks) is scored for all the
    simplexes that need it in one call, ``score([(j, point), ...])`` returning one cost per
    (simplex index, point) pair. With ``pair``, each reflection is scored together with the inside
    contraction. Returns ``[(best point, best cost), ...]`` in the order of ``simplexes``.
    """
    # plain floats, not small arrays: numpy's overhead on three-element vectors costs as much as
    # scoring a short window, and it holds the interpreter lock the looks on other threads wait
    # for. The arithmetic is numpy's, operation for operation (the centroid adds the vertices in
    # order; the sort is stable and puts NaN last, as argsort does), so the steps stay scipy's.
    K = len(simplexes)
    sims = [[[float(c) for c in v] for v in np.asarray(sx, dtype=float)] for sx in simplexes]
    flat = [(j, v) for j in range(K) for v in sims[j]]
    fl = [float(f) for f in score(flat)]
    fsims, i = [], 0
    for j in range(K):
        fsims.append(fl[i:i + len(sims[j])])
        i += len(sims[j])

    def ordered(j):
        sim, fsim = sims[j], fsims[j]
        idx = sorted(range(len(sim)), key=lambda i: (fsim[i] != fsim[i], fsim[i]))
        sims[j], fsims[j] = [sim[i] for i in idx], [fsim[i] for i in idx]

    for j in range(K):
        ordered(j)
    active = list(range(K))
    for _ in range(max_iter - 1):
        still = []
        for j in active:
            fsim = fsims[j]
            spread = [abs(fsim[0] - f) for f in fsim[1:]]
            if not (all(d == d for d in spread) and max(spread) <= fatols[j]):
                still.append(j)
        active = still
        if not active:
            break
        step = {}
        ask = []
        for j in active:
            sim = sims[j]
            N = len(sim[0])
            xbar = list(sim[0])
            for v in sim[1:-1]:
                xbar = [a + b for a, b in zip(xbar, v)]
            xbar = [a / N for a in xbar]
            worst = sim[-1]
            xr = [2.0 * a - w for a, w in zip(xbar, worst)]
            xic = [0.5 * a + 0.5 * w for a, w in zip(xbar, worst)]       # inside contraction
            step[j] = {"xbar": xbar, "worst": worst, "xr": xr, "xic": xic, "fic": None}
            ask.append((j, xr))
            if pair:
                ask.append((j, xic))
        got = [float(c) for c in score(ask)]
        for k, (j, _) in enumerate(ask):
            if pair and k % 2:
                step[j]["fic"] = got[k]
            else:
                step[j]["fr"] = got[k]
        # the expansions and contractions
        ask = []
        for j in active:
            st, fsim = step[j], fsims[j]
            xbar, worst, fr = st["xbar"], st["worst"], st["fr"]
            if fr < fsim[0]:
                st["x2"] = [3.0 * a - 2.0 * w for a, w in zip(xbar, worst)]
                st["kind"] = "expand"
            elif fr < fsim[-2]:
                st["kind"] = "reflect"
            elif fr < fsim[-1]:
                st["x2"] = [1.5 * a - 0.5 * w for a, w in zip(xbar, worst)]   # outside contraction
                st["kind"] = "outside"
            else:
                st["x2"] = st["xic"]
                st["kind"] = "inside"
                if st["fic"] is not None:
                    st["f2"] = st["fic"]
            if "x2" in st and "f2" not in st:
                ask.append((j, st["x2"]))
        if ask:
            for (j, _), c in zip(ask, score(ask)):
                step[j]["f2"] = float(c)
        # the shrinks
        ask = []
        for j in active:
            st, sim, fsim = step[j], sims[j], fsims[j]
            kind = st["kind"]
            if kind == "expand":
                sim[-1], fsim[-1] = (st["x2"], st["f2"]) if st["f2"] < st["fr"] else (st["xr"], st["fr"])
            elif kind == "reflect":
                sim[-1], fsim[-1] = st["xr"], st["fr"]
            elif (st["f2"] <= st["fr"]) if kind == "outside" else (st["f2"] < fsim[-1]):
                sim[-1], fsim[-1] = st["x2"], st["f2"]
            else:
                best = sim[0]
                sims[j] = [best] + [[b + 0.5 * (c - b) for b, c in zip(best, v)] for v in sim[1:]]
                st["shrink"] = True
                ask += [(j, v) for v in sims[j][1:]]
        if ask:
            got = [float(c) for c in score(ask)]
            k = 0
            for j in active:
                if step[j].get("shrink"):
                    n_new = len(sims[j]) - 1
                    fsims[j] = [fsims[j][0]] + got[k:k + n_new]
                    k += n_new
        for j in active:
            ordered(j)
    return [(np.array(sims[j][0]), float(fsims[j][0])) for j in range(K)]


def nelder_mead(obj: Objective, cand: Candidate, lim: Limits, cfg: PolishConfig, *,
                lags: bool = True) -> Candidate:
    """Polish S, J (and the lags, when ``lags`` and the structure is not fixed) of one candidate by
    the Nelder-Mead simplex (`simplex_minimize`). S and J stay at or below ``lim.S_cap``."""
    return nelder_mead_many(obj, [cand], lim, cfg, lags=lags)[0]


def nelder_mead_many(obj: Objective, cands, lim: Limits, cfg: PolishConfig, *,
                     lags: bool = True) -> list[Candidate]:
    """`nelder_mead` of several candidates on one objective, their simplexes in lockstep
    (`simplex_minimize_many`): each candidate's result is the one it gets alone, and each stage of
    an iteration scores every candidate's points in one kernel call, filling the kernel's lanes."""
    if not cands:
        return []
    free_lags = lags and not lim.fixed
    S_cap = lim.S_cap
    ts = obj.ts_s
    tau_max = lim.tau_max_s

    def pointer(cand):
        """The map from a simplex point of ``cand``'s polish to its valve and structure, and the
        scale of S and J in the simplex."""
        kind, t1, t2, d = cand.structure
        tau0 = max(float(t1), 1e-6)
        ratio2 = float(t2) / tau0 if kind == "soptd" else 0.0
        scale = max(cand.S_pct, 0.05)
        integ = 1.0 if kind == "integrating" else 0.0

        def point(v):
            """S, J, the lags (s) and the kernel's structure row of a simplex point."""
            S = min(abs(v[0]) * scale, S_cap)
            J = min(abs(v[1]) * scale, S_cap)
            tau = tau0 * math.exp(v[2]) if free_lags else tau0
            t1_ = min(tau, tau_max)
            t2_ = min(tau * ratio2, tau_max) if kind == "soptd" else 0.0
            a2 = lag_coefficient(t2_, ts) if kind == "soptd" else -1.0
            return S, J, t1_, t2_, (lag_coefficient(t1_, ts), a2, float(d), integ)
        return point, scale

    point_of, scales = zip(*[pointer(c) for c in cands])
    start_stem = NAN if obj.start_stem_pct is None else obj.start_stem_pct
    start_stuck = NAN if obj.start_stuck_pct is None else obj.start_stuck_pct

    def costs(pts):
        # the kernel's tables built directly (this runs thousands of times per fit): each point's
        # valve in both starting directions with that point's own structure, one paired call; the
        # valve's start state is the objective's, as `Objective.score` sets it
        k = len(pts)
        valves = np.empty((5, 2 * k))
        valves[3] = start_stem
        valves[4] = start_stuck
        structs = np.empty((4, 2 * k))
        for i, (j, v) in enumerate(pts):
            S, J, _, _, row = point_of[j](v)
            valves[0, 2 * i: 2 * i + 2] = S
            valves[1, 2 * i: 2 * i + 2] = J
            structs[:, 2 * i] = structs[:, 2 * i + 1] = row
        valves[2, 0::2] = 1.0
        valves[2, 1::2] = -1.0
        sse, _ = obj.score_table(valves, structs, paired=True)
        return sse.reshape(k, 2)

    simplexes, fatols = [], []
    x0s = []
    for c, scale in zip(cands, scales):
        x0 = np.array([c.S_pct / scale, c.J_pct / scale, 0.0])
        steps = np.array([0.15, 0.15 + 0.1 * (c.J_pct < 1e-9), 0.3])
        if not free_lags:
            x0, steps = x0[:2], steps[:2]
        x0s.append(x0)
        simplexes.append(np.vstack([x0, x0 + np.diag(steps)]))
    f0s = costs([(j, x0) for j, x0 in enumerate(x0s)]).min(axis=1)
    fatols = [cfg.tol * (abs(float(f0)) + 1e-12) for f0 in f0s]
    # a reflection paired with its inside contraction pays only where a kernel pass scores four
    # jobs for about the price of two
    found = simplex_minimize_many(lambda pts: costs(pts).min(axis=1), simplexes, cfg.max_iter, fatols,
                                  pair=kernels.lanes() >= 4)
    better = [j for j, (c, (_, f_best)) in enumerate(zip(cands, found)) if f_best < c.sse]
    out = list(cands)
    if better:
        sse = costs([(j, found[j][0]) for j in better])
        for j, row in zip(better, sse):
            kind, _, _, d = cands[j].structure
            S, J, t1_, t2_, _ = point_of[j](found[j][0])
            k = int(np.argmin(row))
            out[j] = Candidate(S, J, (1.0, -1.0)[k], (kind, t1_, t2_, d), float(row[k]))
    return out


def refine_many(obj: Objective, cands, lim: Limits, cfg: PolishConfig) -> list[Candidate]:
    """`refine` of several candidates on one objective, their Nelder-Mead polishes in lockstep
    (`nelder_mead_many`): the results are those of `refine` on each."""
    cands = list(cands)
    for rnd in range(cfg.rounds):
        if rnd > 0:
            cands = [polish_structure(obj, c, lim) for c in cands]
        cands = nelder_mead_many(obj, cands, lim, cfg)
    return cands


def refine(obj: Objective, cand: Candidate, lim: Limits, cfg: PolishConfig) -> Candidate:
    """``cfg.rounds`` rounds of Nelder-Mead, each after the first preceded by a structure polish."""
    return refine_many(obj, [cand], lim, cfg)[0]


@dataclass(frozen=True)
class BandConfig:
    """`shape_bands`: S at ``S_factors`` x the best S, J/S at ``ratios``, both f0, at lags x
    ``lag_factors`` and every dead time of the full grid or within ``delay_span`` samples of the
    best's."""

    S_factors: tuple = PROFILE_S_FACTORS
    ratios: tuple = DEFAULT_J_RATIOS
    lag_factors: tuple = (0.5, 1.0, 2.0)
    delay_span: int = 3


def shape_bands(obj: Objective, top: Candidate, lim: Limits, cfg: BandConfig) -> list[Candidate]:
    """J, S and the dead time trade off (a larger J looks like a longer delay, a larger S like a
    slower process): the best candidate of each class band (deadband, undershoot, no offset,
    overshoot) over J/S, S and the dead times near the best lags, so that no shape loses for want of
    the structure that suits it. Unrefined; `refine` each."""
    if lim.fixed or top.S_pct <= 0:
        return []
    Sp = np.unique(np.minimum(top.S_pct * np.asarray(cfg.S_factors), lim.S_cap))
    Sm, Rm, Fm = np.meshgrid(Sp, np.asarray(cfg.ratios, float), [1.0, -1.0], indexing="ij")
    Sm, Rm, Fm = Sm.ravel(), Rm.ravel(), Fm.ravel()
    Jm = Sm * Rm
    k0, t0, t2, d_top = top.structure
    r2 = float(t2) / max(float(t0), 1e-12)
    d_set = sorted({int(v) for v in lim.process.d}
                   | {dd for dd in range(d_top - cfg.delay_span, d_top + cfg.delay_span + 1)
                      if lim.dmin <= dd <= lim.dmax})
    keys = [(kd, t0 * f, t0 * f * r2 if kd == "soptd" else 0.0, dd)
            for kd in sorted({k0, "foptd"} & set(lim.kinds) | {k0}) for f in cfg.lag_factors for dd in d_set]
    grid = lim.grid(keys)
    sse, _ = obj.score(Sm, Jm, Fm, grid)
    bands = [Rm == 0.0, (Rm > 0.0) & (Rm < 0.85), (Rm >= 0.85) & (Rm <= 1.15), Rm > 1.15]
    out = []
    for sel in bands:
        if not sel.any():
            continue
        sub = np.where(sel[:, None], sse, np.inf)
        i, p = np.unravel_index(int(np.argmin(sub)), sub.shape)
        out.append(Candidate(float(Sm[i]), float(Jm[i]), float(Fm[i]), grid.keys[int(p)], float(sub[i, p])))
    return out


@dataclass(frozen=True)
class ZoomConfig:
    """`zoom`: ``rounds`` local (S, J, f0) grids of ``size`` x ``size`` x 2 over +-``span`` of S (of
    max(J, S/2) for J), shrinking by 4 each round."""

    rounds: int = 2
    size: int = 9
    span: float = 0.06


def zoom(obj: Objective, cand: Candidate, lim: Limits, cfg: ZoomConfig) -> Candidate:
    """Local (S, J, f0) grid around the candidate at its structure, shrinking each round.

    The cost is piecewise constant in S and J (the valve path changes only when a threshold
    crosses an input sample), which can stall a simplex; a grid cannot stall."""
    grid = cand.grid(obj.ts_s, lim.tau_max_s)
    dS = cfg.span * max(cand.S_pct, 0.05)
    dJ = cfg.span * max(cand.J_pct, 0.5 * cand.S_pct, 0.05)
    cap = max(lim.S_cap, 1e-6)
    for _ in range(cfg.rounds):
        Sl = np.unique(np.clip(cand.S_pct + dS * np.linspace(-1, 1, cfg.size), 1e-6, cap))
        Jl = np.unique(np.clip(cand.J_pct + dJ * np.linspace(-1, 1, cfg.size), 0.0, cap))
        Sm, Jm, Fm = np.meshgrid(Sl, Jl, [1.0, -1.0], indexing="ij")
        sse, _ = obj.score(Sm.ravel(), Jm.ravel(), Fm.ravel(), grid)
        i = int(np.argmin(sse[:, 0]))
        if sse[i, 0] < cand.sse:
            cand = cand.with_valve(Sm.ravel()[i], Jm.ravel()[i], Fm.ravel()[i], sse[i, 0])
        dS /= 4.0
        dJ /= 4.0
    return cand


def profile_intervals(obj: Objective, cand: Candidate, lim: Limits, bound_sse: float, *, span: float = 0.15,
                      steps: int = 121) -> tuple[tuple[float, float], tuple[float, float]]:
    """The ranges of S (J fixed) and of J (S fixed) whose cost stays within ``bound_sse``, scanned in
    ``steps`` steps over +-``span`` of S (of max(S, J) for J) around the candidate, both starting
    directions, at its structure; each widened by half a step and holding the candidate.

    On exact data the cost is zero on a flat cell around the truth (every (S, J) in it gives the same
    valve path) and the F-test bound collapses to it: this scan is fine enough to find the cell,
    where a coarse grid finds a single point."""
    grid = cand.grid(obj.ts_s, lim.tau_max_s)
    u = np.linspace(-span, span, steps)
    hS = span * max(cand.S_pct, 1e-6) / (steps - 1)
    hJ = span * max(cand.S_pct, cand.J_pct, 1e-6) / (steps - 1)
    S_scan = np.unique(np.clip(cand.S_pct * (1.0 + u), 0.0, lim.S_cap))
    J_scan = np.unique(np.clip(cand.J_pct + max(cand.S_pct, cand.J_pct) * u, 0.0, lim.S_cap))
    out = []
    for scan, fixed, h, centre in ((S_scan, "J", hS, cand.S_pct), (J_scan, "S", hJ, cand.J_pct)):
        m = scan.shape[0]
        S = np.concatenate([scan, scan]) if fixed == "J" else np.full(2 * m, cand.S_pct)
        J = np.full(2 * m, cand.J_pct) if fixed == "J" else np.concatenate([scan, scan])
        F = np.repeat([1.0, -1.0], m)
        sse, _ = obj.score(S, J, F, grid)
        inside = scan[np.minimum(sse[:m, 0], sse[m:, 0]) <= bound_sse]
        lo = float(inside.min()) - 0.5 * h if inside.size else centre
        hi = float(inside.max()) + 0.5 * h if inside.size else centre
        out.append((max(0.0, min(lo, centre)), max(hi, centre)))
    return out[0], out[1]


# --------------------------------------------------------------------------------------------------
# the valve's start state and where to search
# --------------------------------------------------------------------------------------------------

def start_state(obj: Objective, cand: Candidate, burn: int, lim: Limits) -> tuple[float | None, float]:
    """The valve's first stuck point (None: OP's first sample) and starting direction that fit
    ``cand`` best on ``obj``.

    A valve's state at the start of a record is unknown: started on the wrong side, or stuck at the
    wrong point, a model valve can stay stuck in the middle of the plant's limit cycle for the whole
    record. Tried: stuck at OP's first sample (both directions), near it (`START_DELTAS` x max(S, J)),
    or at an extreme of OP's travel in the burn-in, where a valve in a limit cycle waits for the
    next reversal."""
    F0 = cand.f0
    x_first = float(obj.x[0])
    starts: list[tuple[float | None, float]] = [(None, F0)]
    if cand.S_pct > 0:
        head = obj.x[: max(burn, 2)]
        pts = [x_first + dl * max(cand.S_pct, cand.J_pct) for dl in START_DELTAS] + \
              [float(head.min()), float(head.max())]
        starts += [(None, -F0)] + [(min(max(p, 0.0), 100.0), Fv) for p in pts for Fv in (F0, -F0)]
    grid = cand.grid(obj.ts_s, lim.tau_max_s)
    costs = []
    for x0, Fv in starts:
        sse, _ = obj.with_start(x0).score([cand.S_pct], [cand.J_pct], [Fv], grid)
        costs.append(float(sse[0, 0]))
    return starts[int(np.argmin(costs))]


#: Longest and shortest extra search window (`search_windows`), samples: a window shorter than this
#: is not searched (with three windows, records under 1500 samples have none).
WINDOW_MAX_SAMPLES = 2000
WINDOW_MIN_SAMPLES = 500


def widest_window(x: np.ndarray, m: int, scored: np.ndarray | None = None) -> int:
    """Start of the ``m``-sample window in which OP covers the widest robust range (the earliest of
    equals): the part of a long record that shows the valve the most. With a training mask
    ``scored``, the range of the scored samples times their share of the window counts."""
    n = x.shape[0]
    if n <= m:
        return 0
    starts = np.unique(np.r_[np.arange(0, n - m + 1, max(1, m // 4)), n - m])
    values = []
    for i in starts:
        xs = x[i:i + m] if scored is None else x[i:i + m][scored[i:i + m]]
        if xs.shape[0] < MIN_SAMPLES:
            values.append(-1.0)
            continue
        span = float(np.percentile(xs, 99.5) - np.percentile(xs, 0.5))
        values.append(span if scored is None else span * xs.shape[0] / m)
    return int(starts[int(np.argmax(values))])


def search_windows(n: int, k: int, w: np.ndarray) -> list[tuple[int, int]]:
    """(start, length) of ``k`` equal windows spread evenly over ``n`` samples (at most
    `WINDOW_MAX_SAMPLES` long), leaving out windows too short or with too few scored samples."""
    if k <= 0:
        return []
    m = min(n // k, WINDOW_MAX_SAMPLES)
    if m < WINDOW_MIN_SAMPLES or m >= n:
        return []           # too short to search, or the whole record (searched anyway)
    starts = [int(round(i * (n - m) / (k - 1))) if k > 1 else (n - m) // 2 for i in range(k)]
    return [(i0, m) for i0 in starts if np.count_nonzero(w[i0:i0 + m]) >= WINDOW_MIN_SAMPLES // 2]


# --------------------------------------------------------------------------------------------------
# the class test
# --------------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class ClassTestConfig:
    """The class test's grids.

    chi2 : 95 % quantile of chi-square with two degrees of freedom: the joint (S, J) region that also
        gives the reported intervals (a restriction, J = 0 or J = S, is accepted inside it).
    S_rel, J_ratios, deltas : local grid: S relative to the fit's, J/S, and the valve's first stuck
        point relative to OP's first sample in units of max(S, J).
    fine_S, fine_ratios, fine_near : a fine scan of S (``fine_S`` values over +-10 % of the fit's
        S at ``fine_ratios``; 0: off) and the neighbours of its best S added to the grid (with J > 0
        the cost is a needle in S).
    structures : the second stage at nearby process structures (dead time +-1 sample, lags x0.8
        and x1.25).
    """

    chi2: float = 5.991
    S_rel: tuple = tuple(1.0 + np.array([-0.1, -0.05, -0.02, 0.0, 0.02, 0.05, 0.1]))
    J_ratios: tuple = tuple(np.linspace(0.0, 2.0, 17))
    deltas: tuple = tuple(np.linspace(-1.0, 1.0, 5))
    fine_S: int = 201
    fine_ratios: tuple = (0.5, 1.0, 1.5)
    fine_near: tuple = (-0.003, -0.0015, 0.0, 0.0015, 0.003)
    structures: bool = True


def class_test(op: np.ndarray, pv: np.ndarray, ts_s: float, fit, burn_frac: float = 0.05,
               gain_sign: float | None = None, cfg: ClassTestConfig = ClassTestConfig(),
               threads: int | None = None, pct_per_unit: float = 1.0) -> dict[str, Any]:
    """Re-examine J with the valve's initial stuck point free, and test the special shapes.

    A real valve at the start of a record is stuck wherever its history left it, and a sticky valve
    keeps that memory until OP makes an excursion larger than S (in noisy closed loops this can take
    thousands of samples): with the wrong starting point even the true (S, J) scores badly. Here the
    starting stuck point is a nuisance parameter, ``x_ss = OP[0] + delta`` (OP[0]: the fit's own first
    stuck point, ``start_op_pct``, where it chose one), both starting directions, at the fitted process
    structure, over a local grid of S (plus the best S of a fine scan and its close neighbours) and
    J/S in 0..2; then, per J/S, its best start at nearby structures. The special shapes J = 0
    (deadband) and J = S (no offset) are accepted when their best cost lies within the chi-square
    bound ``cost_free (1 + chi2 / nu)`` of the free fit (``nu`` = the fit's effective residuals - 2).

    ``fit`` is a `diagnose.fit.HammersteinFit`; the grids are scored on up to ``threads`` threads
    (`diagnose.parallel.thread_count`; the result does not depend on it). ``pct_per_unit``: % of
    span per unit of OP (100 for OP logged as a fraction of span), for the classes' tolerances,
    which are in % of span.

    Returns
    -------
    dict
        ``cost_fit`` (the fit as it was), ``cost_free``, ``cost_deadband``, ``cost_no_offset``
        (PV units squared per scored sample), ``bound``, ``plausible`` (every class shape inside the
        bound, best first), and the chosen ``cls`` (a restriction, or None), ``S_pct``, ``J_pct``,
        ``f0``, ``delta_pct``, ``cost``.
    """
    x = np.asarray(op, dtype=float) + fit.op_offset_pct
    w = score_weights(x.shape[0], None, burn_in(x, burn_frac))
    if fit.start_op_pct is not None:
        x[0] = fit.start_op_pct      # the fit's own starting point is the reference
    n = x.shape[0]
    obj = Objective(x, np.asarray(pv, dtype=float), ts_s, w, fit.load_order, fit.hp_tau_s, None,
                    float(np.sign(gain_sign)) if gain_sign else None)
    p = fit.process
    d = int(round(p.delay_s / ts_s))
    grid = ProcessGrid.of([(p.kind, p.tau_s, p.tau2_s, d)], ts_s)
    scale = obj.y_std ** 2 / max(1, obj.n_scored)
    c_fit = float(obj.score([fit.S_pct], [fit.J_pct], [float(fit.f0)], grid)[0][0, 0]) * scale
    S0 = fit.S_pct
    S_set = S0 * np.asarray(cfg.S_rel)
    if cfg.fine_S:
        # stage 0: with J > 0 the cost is a needle in S (a stopped valve must beat J to move on,
        # and whether each noisy OP excursion does flips whole stretches of the simulation):
        # scan S finely at a few shapes and add the best S and its close neighbours to the grid
        Sf = S0 * (1.0 + np.linspace(-0.1, 0.1, cfg.fine_S))
        Sm, Rm, Fm = np.meshgrid(Sf, np.asarray(cfg.fine_ratios), [1.0, -1.0], indexing="ij")
        Sv, Jv, Fv = Sm.ravel(), (Sm * Rm).ravel(), Fm.ravel()
        chunks = np.array_split(np.arange(Sv.shape[0]), thread_count(threads))
        cf = np.concatenate(thread_map(lambda i: obj.score(Sv[i], Jv[i], Fv[i], grid)[0][:, 0], chunks, threads))
        S_star = float(Sm.ravel()[int(np.argmin(cf))])
        S_set = np.unique(np.concatenate([S_set, S_star * (1.0 + np.asarray(cfg.fine_near))]))
    ratios = np.asarray(cfg.J_ratios)
    Sg, Rg, Fg = np.meshgrid(S_set, ratios, [1.0, -1.0], indexing="ij")
    Sg, Rg, Fg = Sg.ravel(), Rg.ravel(), Fg.ravel()
    Jg = Sg * Rg
    x0 = float(x[0])
    best = {"free": (c_fit, S0, fit.J_pct, fit.f0, 0.0), "deadband": (np.inf,), "no_offset": (np.inf,)}
    per_ratio = [(np.inf, 1.0, x0)] * ratios.shape[0]      # best (cost, f0, first OP) per J/S
    by_class: dict[str, float] = {}      # best cost per class shape (for the plausible set)
    # the fit's own shape is plausible by construction, even where no grid point of it is as good
    fit_cls = str(stiction_classes(np.array([S0]) * pct_per_unit, np.array([fit.J_pct]) * pct_per_unit)[0])
    if fit_cls != "none":
        by_class[fit_cls] = c_fit

    def keep(c, Sv, Jv, Rv, F, xs0):
        names = stiction_classes(Sv * pct_per_unit, Jv * pct_per_unit)
        for name in np.unique(names[names != "none"]):
            cm = float(c[names == name].min())
            if cm < by_class.get(str(name), np.inf):
                by_class[str(name)] = cm
        for key, sel in (("free", np.ones(c.shape[0], bool)), ("deadband", Rv == 0.0),
                         ("no_offset", Rv == 1.0)):
            cm = np.where(sel, c, np.inf)
            i = int(np.argmin(cm))
            if cm[i] < best[key][0]:
                best[key] = (float(c[i]), float(Sv[i]), float(Jv[i]), int(F), float(xs0 - x0))
        for k, r in enumerate(ratios):
            sel = Rv == r
            if sel.any():
                ck = float(c[sel].min())
                if ck < per_ratio[k][0]:
                    per_ratio[k] = (ck, F, xs0)

    # stage 1: the fit's structure, every starting point (scored side by side, kept in order)
    starts = [(F, min(max(x0 + F * dl * max(S0, fit.J_pct), 0.0), 100.0)) for dl in cfg.deltas for F in (1.0, -1.0)]

    def stage1(start):
        F, xs0 = start
        m = Fg == F
        return obj.with_start(xs0).score(Sg[m], Jg[m], Fg[m], grid)[0][:, 0] * scale

    for (F, xs0), c in zip(starts, thread_map(stage1, starts, threads)):
        m = Fg == F
        keep(c, Sg[m], Jg[m], Rg[m], F, xs0)
    # stage 2: per J/S ratio, its best start, with nearby structures (the lags and the dead time
    # trade off against J, so a shape is not rejected for want of its own structure)
    if cfg.structures:
        keys = [(p.kind, p.tau_s, p.tau2_s, dd) for dd in sorted({max(1, d - 1), d, d + 1})]
        keys += [(p.kind, p.tau_s * f, p.tau2_s * f, d) for f in (0.8, 1.25)]
        sgrid = ProcessGrid.of(keys, ts_s)
        picks = [(r, per_ratio[k][1], per_ratio[k][2]) for k, r in enumerate(ratios)]

        def stage2(pick):
            r, F, xs0 = pick
            return obj.with_start(xs0).score(S_set, S_set * r, np.full(S_set.shape[0], F), sgrid)[0].min(axis=1) * scale

        for (r, F, xs0), c in zip(picks, thread_map(stage2, picks, threads)):
            keep(c, S_set, S_set * r, np.full(S_set.shape[0], r), F, xs0)
    nu = max((fit.n_eff if math.isfinite(fit.n_eff) else n) - 2.0, 1.0)
    c_free = best["free"][0]
    bound = c_free * (1.0 + cfg.chi2 / nu)
    out: dict[str, Any] = {"cost_fit": c_fit, "cost_free": c_free, "bound": bound,
                           "cost_deadband": best["deadband"][0], "cost_no_offset": best["no_offset"][0],
                           "free_S_pct": best["free"][1], "free_J_pct": best["free"][2]}
    out["plausible"] = sorted((k for k, v in by_class.items() if v <= bound), key=by_class.get)
    ok = [k for k in ("deadband", "no_offset") if best[k][0] <= bound]
    pick = min(ok, key=lambda k: best[k][0]) if ok else "free"
    c, S, J, F, dl = best[pick]
    out.update({"cls": None if pick == "free" else pick, "S_pct": S, "J_pct": J, "f0": F,
                "delta_pct": dl, "cost": c})
    return out
