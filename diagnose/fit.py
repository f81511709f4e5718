"""Hammerstein identification of valve stiction from routine closed-loop data: model x search.

The model and what is scored are `diagnose.objective.Objective`: OP --[two-parameter valve (S, J,
f0)]--> stem --[low-order linear process: FOPTD / SOPTD / integrating, dead time]--> PV, plus a
constant and a slow load, scored by the (noise-prefiltered) output error of PV simulated from OP
alone. The search strategies are `diagnose.search`; `fit_hammerstein` composes them:

1. the noise model and the linear-only fit (S = J = 0) over the full grid of lags and dead times;
2. the global (S, J/S) grid at a coarse set of structures, and each start's own structure;
3. a dense (S, J, f0) grid at those structures, every valve shape picking its own structure;
4. Nelder-Mead on (S, J, lags) from the best few, alternating with a structure polish; the best of
   each class band refined with its own structure;
5. on long records (``max_samples``) and with ``windows``, the same search on windows of the record,
   each result refined on the whole record from its own start state, the cheapest kept;
6. the best valve under the process kinds of the other family, integrating or self-regulating
   (`other_kinds`), refined; those that come near go on beside the best;
7. a local (S, J, f0) zoom and a final Nelder-Mead of each, the cheapest kept; the error surface at
   the final structure, and intervals from it.

The linear block is kept low order and strictly causal with positive lags on purpose: in closed
loop an unconstrained linear model can reproduce PV from OP through the inverse of the controller
and return S = J = 0 (see docs/fitting.md).

Intervals: the set of (S, J) whose output-error cost is within the F-test bound
``cost <= cost_min * 0.05 ** (-2 / nu)`` of the minimum (exact 95 % quantile of F(2, nu) for two
parameters), with ``nu`` the effective number of independent residuals, ``n (1 - rho1) / (1 + rho1)``
from the residuals' lag-one autocorrelation.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from .errors import DataError, NotFittedError
from .objective import (Candidate, Objective, ProcessGrid, burn_in, legendre_basis, noise_prefilter,
                        op_offset, score_design, score_weights, validate_record)
from .parallel import thread_map
from .process_model import ProcessModel
from .search import (NOISE_CANDIDATES, BandConfig, DenseConfig, GridConfig, Limits, ModelSpace,
                     PolishConfig, ZoomConfig, best_structure, coarse_structures, dense_grid, global_grid, linear_fit,
                     nelder_mead, noise_costs, noise_model, other_kinds, polish_structure, refine_many, resolve,
                     search_windows, shape_bands, shape_profile, start_state, widest_window, zoom)
from .stiction_model import stiction_batch

#: Noise prefilter time constant (samples) the automatic noise model starts from.
AUTO_HP_SAMPLES = 10.0


@dataclass(frozen=True)
class SearchConfig:
    """The search of `fit_hammerstein`: each strategy's config (`diagnose.search`), and
    ``max_samples``: longer records are searched on the ``max_samples``-sample window where OP covers
    the widest range, at the full rate, and the result is refined on the whole record (None: search
    the whole record). ``kind_check``: also finish the best valve under the process kinds of the other
    family (`diagnose.search.other_kinds`); the looks at windows leave it to the whole record's
    fit, since a window's kind is refined on the record anyway and checking it there only moves
    which valley the record's refinement starts from."""

    grid: GridConfig = GridConfig()
    dense: DenseConfig = DenseConfig()
    polish: PolishConfig = PolishConfig()
    bands: BandConfig = BandConfig()
    zoom: ZoomConfig = ZoomConfig()
    final: PolishConfig = PolishConfig(max_iter=100, tol=1e-6, rounds=1)
    max_samples: int | None = 4000
    noise_candidates: tuple = NOISE_CANDIDATES
    kind_check: bool = True


# --------------------------------------------------------------------------------------------------
# results
# --------------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class ErrorSurface:
    """Output-error cost over the (S, J) grid (minimum over the starting direction).

    ``cost[i, j]`` is the mean squared simulation error (PV units squared) at ``S_grid_pct[i]``,
    ``J_grid_pct[j]`` with the final process structure (gain, bias and load re-fitted per point);
    ``bound`` is the cost level that delimits the confidence region.
    """

    S_grid_pct: np.ndarray
    J_grid_pct: np.ndarray
    cost: np.ndarray
    bound: float = float("nan")

    def to_dict(self) -> dict[str, Any]:
        return {"S_grid_pct": [float(v) for v in self.S_grid_pct],
                "J_grid_pct": [float(v) for v in self.J_grid_pct],
                "cost": [[float(c) for c in row] for row in self.cost],
                "bound": float(self.bound)}


@dataclass(frozen=True)
class HammersteinFit:
    """Result of `fit_hammerstein`.

    Attributes
    ----------
    S_pct, J_pct : float
        Stiction parameters, % of valve span (0, 0 for the linear-only model).
    f0 : int
        Starting direction of the valve (+1 / -1) that fits best.
    process : ProcessModel
        The linear block (its ``bias`` is the constant of the fit; the slow load is apart).
    ts_s : float
        Sample period, seconds.
    rmse : float
        Root-mean-square simulation error over the scored samples, PV units.
    r2 : float
        1 - SSE / SST over the scored samples (simulation, not one-step).
    S_interval_pct, J_interval_pct : (float, float)
        Range of S and J inside the confidence region of the error surface.
    surface : ErrorSurface
        The cost over the global (S, J) grid.
    load : ndarray
        Slow-load coefficients (Legendre polynomial in time over the fitted record, PV units).
    op_offset_pct : float
        Offset added to OP before the valve model (nonzero only when OP was not in 0..100 %).
    n_eff : float
        Effective number of independent residuals used for the interval bound.
    cost : float
        The objective's cost: mean squared prefiltered output error per scored sample, PV units^2.
    hp_tau_s : float or None
        The noise prefilter's time constant, seconds (None: plain output error).
    start_op_pct : float or None
        The valve's first stuck point, % of span (OP's first sample plus ``op_offset_pct`` unless
        the fit chose another: the valve's state at the start of a record is unknown). None: OP's
        first sample.
    start_stem_pct, start_stuck_pct : float or None
        The stem position the valve was stuck at on the first sample (the valve fit reads it from
        the recorded stem position) and the input at which it stuck (None: where a moving valve
        stops); ``start_stem_pct`` None: at rest at its first input.
    noise_costs : tuple of (float or None, float)
        The fitted model's cost under each noise model the automatic choice tries: pairs of the
        prefilter's time constant (seconds; None: plain output error) and the mean squared
        prefiltered error per scored sample (PV units^2), at the fitted parameters. The smallest is
        this model's own best noise model, which may differ from ``hp_tau_s`` (chosen for the
        linear loop) when the valve explains slow error a linear loop leaves.
    """

    S_pct: float
    J_pct: float
    f0: int
    process: ProcessModel
    ts_s: float
    rmse: float
    r2: float
    S_interval_pct: tuple[float, float]
    J_interval_pct: tuple[float, float]
    surface: ErrorSurface
    load: np.ndarray = field(default_factory=lambda: np.zeros(0))
    n_fit: int = 0
    op_offset_pct: float = 0.0
    n_eff: float = float("nan")
    cost: float = float("nan")
    hp_tau_s: float | None = None
    score_coef: np.ndarray = field(default_factory=lambda: np.zeros(0))
    load_order: int = 0
    start_op_pct: float | None = None
    start_stem_pct: float | None = None
    start_stuck_pct: float | None = None
    noise_costs: tuple = ()

    @property
    def own_noise_cost(self) -> float:
        """The smallest of `noise_costs`: this model's cost under its own best noise model (`cost`
        when no noise model was tried)."""
        return min((c for _, c in self.noise_costs), default=self.cost)

    def heldout_cost(self, op_pct, pv, mask) -> float:
        """Mean squared (prefiltered) output error on the samples in ``mask``.

        Every parameter (valve, lags, dead time, gain, load) stays as fitted: this is the error the
        fit makes on data it did not score.
        """
        r = self.heldout_residuals(op_pct, pv, mask)
        return float(r @ r) / r.shape[0]

    def heldout_residuals(self, op_pct, pv, mask) -> np.ndarray:
        """The (prefiltered) output errors on the samples in ``mask``, in time order."""
        x = np.asarray(op_pct, dtype=float) + self.op_offset_pct
        y = np.asarray(pv, dtype=float)
        m = np.zeros(x.shape[0], bool)
        m[mask] = True
        if x.shape[0] != self.n_fit or not m.any():
            raise DataError("heldout_cost needs the fitted record's OP/PV and a non-empty mask")
        x = self._with_start(x)
        mv = stiction_batch(x, [self.S_pct], [self.J_pct], [self.f0], start_pct=self.start_stem_pct,
                            stuck_at_pct=self.start_stuck_pct)[0]
        proto = replace(self.process, gain=1.0, bias=0.0, u_balance_pct=None)
        z = proto.regressor(mv - mv[0], self.ts_s)
        a = math.exp(-self.ts_s / self.hp_tau_s) if self.hp_tau_s else -1.0
        A = score_design(z, x.shape[0], self.load_order, a)
        yf = noise_prefilter(y, a) if a >= 0 else y
        return (yf - A @ self.score_coef)[m]

    def simulate(self, op_pct) -> tuple[np.ndarray, np.ndarray]:
        """Simulate the fitted valve and process from any OP series.

        Returns ``(mv_hat_pct, pv_hat)``: the modelled stem position (% of span) and PV. The slow
        load is added only when ``op_pct`` has the length of the fitted record.
        """
        x = np.asarray(op_pct, dtype=float) + self.op_offset_pct
        if x.ndim != 1 or x.shape[0] == 0 or not np.all(np.isfinite(x)):
            raise DataError("op_pct must be a non-empty 1-D series of finite values")
        start = stuck = None
        if x.shape[0] == self.n_fit:
            x = self._with_start(x)
            start, stuck = self.start_stem_pct, self.start_stuck_pct
        mv = stiction_batch(x, [self.S_pct], [self.J_pct], [self.f0], start_pct=start,
                            stuck_at_pct=stuck)[0] - self.op_offset_pct
        pv = self.process.simulate(mv, self.ts_s)
        if self.load.shape[0] > 1 and x.shape[0] == self.n_fit:
            pv = pv + legendre_basis(x.shape[0], self.load.shape[0] - 1)[:, 1:] @ self.load[1:]
        return mv, pv

    def _with_start(self, x: np.ndarray) -> np.ndarray:
        if self.start_op_pct is None:
            return x
        x = np.array(x, dtype=float)
        x[0] = self.start_op_pct
        return x

    @property
    def stiction_class(self) -> str:
        from .stiction_model import stiction_class
        return stiction_class(self.S_pct, self.J_pct)

    def to_dict(self) -> dict[str, Any]:
        return {"S_pct": self.S_pct, "J_pct": self.J_pct, "f0": self.f0,
                "process": self.process.to_dict(), "rmse": self.rmse, "r2": self.r2,
                "S_interval_pct": list(self.S_interval_pct),
                "J_interval_pct": list(self.J_interval_pct)}


# --------------------------------------------------------------------------------------------------
# the composition
# --------------------------------------------------------------------------------------------------

def single_search(obj: Objective, lim: Limits, cfg: SearchConfig, stiction: bool) -> Candidate:
    """One search of a record (steps 1-4 of the module docstring): the best candidate found."""
    best = linear_fit(obj, lim)
    if not stiction:
        return best
    gcoarse = coarse_structures(lim, best)
    starts, per_structure = global_grid(obj, lim, cfg.grid, gcoarse)
    # each start's process structure from the full grid
    results = [best]
    keys: list = []
    for c in starts:
        if not lim.fixed:
            q = best_structure(obj, c.S_pct, c.J_pct, c.f0, lim.process)
            c = q if q.sse < c.sse else c
        results.append(c)
        if c.structure not in keys:
            keys.append(c.structure)
    # ... plus the linear model's structure and the coarse grid's best structures
    extra = [best.structure] + [s.structure for s in starts] + \
        [gcoarse.keys[int(p)] for p in np.argsort(per_structure)[:cfg.dense.extra_structures]]
    for k in extra:
        if k not in keys:
            keys.append(k)
    dense, sse_dense = dense_grid(obj, lim, cfg.dense, keys)
    results += dense
    results += shape_profile(obj, lim, cfg.dense, sse_dense, keys)
    results.sort(key=lambda r: r.sse)
    done: dict = {}         # the same start refines to the same result: refine it once

    def refined(starts: list[Candidate]) -> list[Candidate]:
        todo = [c for c in dict.fromkeys(starts) if c not in done]
        done.update(zip(todo, refine_many(obj, todo, lim, cfg.polish)))
        return [done[c] for c in starts]

    out = refined(results[: max(2, cfg.polish.n_refine)])
    top = min(out, key=lambda r: r.sse)
    out += refined(shape_bands(obj, top, lim, cfg.bands))
    return min(out + results, key=lambda r: r.sse)


def refine_on_record(obj: Objective, part: HammersteinFit, lim: Limits, cfg: SearchConfig, stiction: bool,
                     burn: int, auto_noise: bool) -> tuple[Candidate, Objective, float | None]:
    """A fit made on a window of the record, refined on the whole record (``obj``): its start state
    (`start_state`), noise model (with ``auto_noise``), then lags x 2^(-1..1) and dead time +-3
    samples, Nelder-Mead, a structure polish and Nelder-Mead again. Returns the candidate, the
    objective it was scored on, and the valve's first stuck point (None: OP's first sample)."""
    cp = part.process
    d0 = int(round(cp.delay_s / lim.ts_s))
    cand = Candidate(part.S_pct, part.J_pct, float(part.f0), (cp.kind, cp.tau_s, cp.tau2_s, d0), math.nan)
    x0, F0 = start_state(obj, cand, burn, lim)
    obj = obj.with_start(x0)
    cand = cand.with_valve(cand.S_pct, cand.J_pct, F0, math.nan)
    if auto_noise:
        hp = noise_model(obj, cand, lim, cfg.noise_candidates)
        if hp != obj.hp_tau_s:
            obj = obj.with_noise(hp)
    dset = sorted({min(lim.dmax, max(lim.dmin, d0 + k)) for k in range(-3, 4)})
    keys = [(cp.kind, cp.tau_s * f, cp.tau2_s * f, dd) for f in 2.0 ** np.arange(-1.0, 1.01, 0.5) for dd in dset]
    cur = best_structure(obj, cand.S_pct, cand.J_pct, cand.f0, lim.grid(keys))
    if stiction:
        cur = nelder_mead(obj, cur, lim, cfg.polish)
    cur = polish_structure(obj, cur, lim)
    if stiction:
        cur = nelder_mead(obj, cur, lim, cfg.polish)
    return cur, obj, x0


def fit_hammerstein(op_pct, pv, ts_s: float, *, train=None, stiction: bool = True,
                    gain_sign: float | None = None, gain_fixed: float | None = None,
                    hp_tau_s: float | str | None = "auto", load_order: int = 2, burn_frac: float = 0.05,
                    windows: int = 0, surface: bool = True, space: ModelSpace = ModelSpace(),
                    search: SearchConfig = SearchConfig(), threads: int | None = None) -> HammersteinFit:
    """Fit valve stiction (S, J, f0) and a low-order process to closed-loop OP/PV data.

    Parameters
    ----------
    op_pct : array, shape (n,)
        Controller output, % of valve span.
    pv : array, shape (n,)
        Process variable, engineering units.
    ts_s : float
        Sample period, seconds.
    train : slice or bool mask or index array, optional
        Samples the fit may score; the others are simulated but held out.
    stiction : bool
        False fits the linear-only model (S = J = 0), the reference for detection.
    gain_sign : {+1, -1}, optional
        Sign the process gain must have (the controller's action: a reverse-acting controller,
        OP rising when PV is below SP, closes the loop negatively only on a process whose PV rises
        with the valve). Candidates with the other sign score as a model without process: in
        closed loop they are the controller path, ``PV = -OP / Kc``, not the plant.
    gain_fixed : float, optional
        Fix the process gain (PV units per %) instead of fitting it.
    hp_tau_s : float, None or "auto"
        Noise model: PV disturbances are taken as integrated noise, ``H = (1 - a q^-1)/(1 - q^-1)``
        with ``a = exp(-ts/hp_tau_s)``, and both sides are prefiltered by ``1/H`` (prediction error
        with a fixed noise model). None is pure output error. ``"auto"`` picks ``hp_tau_s`` from
        ``search.noise_candidates`` (samples) by the linear model's prediction-error cost.
    load_order : int
        Order of the Legendre polynomial in time that absorbs slow load (0: a constant only).
    burn_frac : float
        Fraction of the record at its start left out of the score at least (unknown initial
        state; `diagnose.objective.burn_in`).
    windows : int
        Also search this many equal windows spread evenly over the record (first, middle and last
        third for three; each at most `diagnose.search.WINDOW_MAX_SAMPLES` long), refine each
        window's result on the whole record, and keep the cheapest whole-record fit. With J > 0 the
        cost is a needle in S and which valley the search ends in hangs on the noise of the samples
        it sees: a few independent looks, judged on all the data, find the truth's valley far more
        often (docs/fitting.md, "Search"). 0: no extra windows.
    surface : bool
        Compute the error surface and the intervals (False: a faster fit with point estimates;
        the surface is then a single cell and the intervals collapse to the estimate).
    space : ModelSpace
        The process kinds, dead times, lags and S range searched, or a fixed process structure.
    search : SearchConfig
        The search strategies' configs.
    threads : int, optional
        Threads the independent looks at a long record's windows run on (None: up to the machine's
        cores; 1 when the caller runs fits in parallel itself). The result does not depend on it.

    Returns
    -------
    HammersteinFit
    """
    x, y = validate_record(op_pct, pv, ts_s)
    n = x.shape[0]
    off = op_offset(x)
    x = x + off
    burn = burn_in(x, burn_frac)
    w = score_weights(n, train, burn)
    auto_noise = isinstance(hp_tau_s, str)
    if auto_noise and hp_tau_s != "auto":
        raise DataError(f"hp_tau_s must be a number of seconds, None or 'auto', got {hp_tau_s!r}")
    obj = Objective(x, y, float(ts_s), w, load_order, AUTO_HP_SAMPLES * ts_s if auto_noise else hp_tau_s,
                    gain_fixed, float(np.sign(gain_sign)) if gain_sign else None)
    lim = resolve(x, ts_s, space, search.grid.n_S, search.grid.n_J)
    if auto_noise:
        hp = noise_model(obj, best_structure(obj, 0.0, 0.0, 1.0, lim.process), lim, search.noise_candidates)
        if hp != obj.hp_tau_s:
            obj = obj.with_noise(hp)

    long_record = search.max_samples is not None and n > search.max_samples and not lim.fixed
    spans: list[tuple[int, int]] = []
    if long_record:
        # search a full-rate window, refine on the whole record: slips happen at the sample level,
        # and block means would smear them (J and the class are read off the slips)
        spans.append((widest_window(x, search.max_samples, None if train is None else w > 0), search.max_samples))
    if stiction and not lim.fixed:
        spans += search_windows(n, windows, w)
    window_space = replace(space, S_max_pct=float(lim.S_grid[-1]))
    window_search = replace(search, max_samples=None, kind_check=False)

    def look(span: tuple[int, int]) -> tuple[Candidate, Objective, float | None]:
        """The search on one window, refined on the whole record."""
        i0, m = span
        sl = slice(i0, i0 + m)
        tw = w[sl] > 0
        tw[: max(0, burn - i0)] = True      # the window's fit applies its own burn-in
        part = fit_hammerstein(x[sl], y[sl], ts_s, train=tw, stiction=stiction, gain_sign=gain_sign,
                               gain_fixed=gain_fixed, hp_tau_s="auto" if auto_noise else hp_tau_s,
                               load_order=load_order, burn_frac=burn_frac, surface=False,
                               space=window_space, search=window_search, threads=1)
        return refine_on_record(obj, part, lim, search, stiction, burn, auto_noise)

    candidates: list[tuple[Candidate, Objective, float | None]] = []
    if not long_record:
        candidates.append((single_search(obj, lim, search, stiction), obj, None))
    # the looks are independent: on several cores they run side by side
    candidates += thread_map(look, spans, threads)
    best, obj, x0 = min(candidates, key=lambda c: c[0].sse)
    finalists = [best]
    if search.kind_check:
        finalists += other_kinds(obj, best, lim, search.polish, stiction)
    done = []
    for c in finalists:
        if stiction and c.S_pct > 0:
            c = zoom(obj, c, lim, search.zoom)
            if not lim.fixed:
                c = nelder_mead(obj, c, lim, search.final)
        done.append(c)
    best = min(done, key=lambda c: c.sse)
    return finish(obj, best, lim, off, surface=stiction and surface, start_op=x0)


# --------------------------------------------------------------------------------------------------
# from the best candidate to the result: coefficients, surface, intervals
# --------------------------------------------------------------------------------------------------

def n_eff(res: np.ndarray) -> float:
    """Effective number of independent residuals, ``n (1 - rho1) / (1 + rho1)`` (at least 5)."""
    r = res - res.mean()
    den = float(r @ r)
    if den <= 0 or r.shape[0] < 3:
        return float(r.shape[0])
    rho = float(r[1:] @ r[:-1]) / den
    rho = min(max(rho, 0.0), 0.999)
    return max(float(r.shape[0]) * (1.0 - rho) / (1.0 + rho), 5.0)


def _interval(values: np.ndarray, best: float, grid: np.ndarray) -> tuple[float, float]:
    if values.size == 0:
        return (best, best)
    lo, hi = float(values.min()), float(values.max())
    # a region of one grid cell still carries the grid's resolution
    g = np.unique(grid)
    i_lo = np.searchsorted(g, lo)
    i_hi = np.searchsorted(g, hi)
    step_lo = (g[i_lo] - g[i_lo - 1]) / 2 if i_lo > 0 else 0.0
    step_hi = (g[i_hi + 1] - g[i_hi]) / 2 if i_hi + 1 < g.size else 0.0
    return (max(0.0, min(lo - step_lo, best)), max(hi + step_hi, best))


def _surface_costs(obj: Objective, best: Candidate, lim: Limits):
    """The cost over the global (S, J) grid at the final structure (the linear model as the S = 0
    row), and a fine local grid around the best (S, J) for the interval."""
    grid = best.grid(obj.ts_s, lim.tau_max_s)
    Sg, Jg, Fg = np.meshgrid(lim.S_grid, lim.J_grid, [1.0, -1.0], indexing="ij")
    sse, _ = obj.score(Sg.ravel(), Jg.ravel(), Fg.ravel(), grid)
    cost = sse[:, 0].reshape(Sg.shape).min(axis=2)
    lin_row = np.full((1, lim.J_grid.shape[0]), float(obj.score([0.0], [0.0], [1.0], grid)[0][0, 0]))
    cost = np.vstack([lin_row, cost])
    s0 = float(lim.S_grid[0])
    Sl = np.unique(np.clip(best.S_pct + 0.6 * max(best.S_pct, s0) * np.linspace(-1, 1, 11), 0.0, None))
    Jl = np.unique(np.clip(best.J_pct + 0.6 * max(best.J_pct, best.S_pct, s0) * np.linspace(-1, 1, 11), 0.0, None))
    Sm, Jm, Fm = np.meshgrid(Sl, Jl, [1.0, -1.0], indexing="ij")
    sse_l, _ = obj.score(Sm.ravel(), Jm.ravel(), Fm.ravel(), grid)
    return cost, (Sl, Jl, sse_l[:, 0].reshape(Sm.shape).min(axis=2))


def finish(obj: Objective, best: Candidate, lim: Limits, off: float, *, surface: bool,
           start_op: float | None = None) -> HammersteinFit:
    """The `HammersteinFit` of the best candidate: gain and load solved as the objective scored them,
    the free-run fit on raw PV, the process in `ProcessModel` form, and the error surface and
    intervals (``surface``)."""
    ts_s = obj.ts_s
    kind = best.structure[0]
    x = obj.x
    mv = stiction_batch(x, [best.S_pct], [best.J_pct], [best.f0], start_pct=obj.start_stem_pct,
                        stuck_at_pct=obj.start_stuck_pct)[0]
    proto = ProcessGrid.of([best.structure], ts_s, lim.tau_max_s).model(0)
    z = proto.regressor(mv - mv[0], ts_s)
    ws = obj.weights > 0
    yraw = obj.y
    n = obj.n
    # gain and load in the (prefiltered) scoring domain, as the search scored them
    Af = score_design(z, n, obj.load_order, obj.ahp)
    yf = noise_prefilter(yraw, obj.ahp) if obj.ahp >= 0 else yraw
    if obj.gain_fixed is not None:
        rest, *_ = np.linalg.lstsq(Af[ws][:, 1:], (yf - obj.gain_fixed * Af[:, 0])[ws], rcond=None)
        score_coef = np.concatenate([[obj.gain_fixed], rest])
    else:
        score_coef, *_ = np.linalg.lstsq(Af[ws], yf[ws], rcond=None)
    res_f = (yf - Af @ score_coef)[ws]
    gain_pv = float(score_coef[0])
    # free-run simulation with that gain: constant and slow load re-fitted on raw PV
    B = legendre_basis(n, obj.load_order)
    cb, *_ = np.linalg.lstsq(B[ws], (yraw - gain_pv * z)[ws], rcond=None)
    coef = np.concatenate([[gain_pv], cb])
    yhat = gain_pv * z + B @ cb
    res = (yraw - yhat)[ws]
    sse = float(res @ res)
    sst = float(np.sum((yraw[ws] - yraw[ws].mean()) ** 2))
    rmse = math.sqrt(sse / max(1, res.shape[0]))
    r2 = 1.0 - sse / sst if sst > 0 else 0.0
    gain = float(coef[0])
    const = float(coef[1])
    load = np.asarray(coef[1:], float)
    # ProcessModel convention: pv = bias + gain * z(u) with z from absolute u; here z used u - u0.
    u0 = float(mv[0])
    if kind == "integrating":
        # z_rel = z_abs - u0 * t  ->  pv = const + gain*(z_abs - u0 t) + load; the linear load term
        # carries the balance: keep u_balance at u0 and leave the drift in the load.
        process = ProcessModel(kind=kind, gain=gain, tau_s=proto.tau_s, delay_s=proto.delay_s,
                               bias=const, tau2_s=0.0, u_balance_pct=u0 - off)
    else:
        process = ProcessModel(kind=kind, gain=gain, tau_s=proto.tau_s, delay_s=proto.delay_s,
                               bias=const - gain * (u0 - off), tau2_s=proto.tau2_s)
    hps = tuple(None if hp is None else hp * ts_s for hp in NOISE_CANDIDATES)
    ne = n_eff(res_f)
    nu = max(ne - 2.0, 1.0)
    ratio = 0.05 ** (-2.0 / nu)
    n_sc = max(1, obj.n_scored)
    scale = obj.y_std ** 2 / n_sc  # sse in scaled units -> mean squared error in PV units
    if surface:
        surface_cost, (Sl, Jl, loc_cost) = _surface_costs(obj, best, lim)
        S_axis = np.concatenate([[0.0], lim.S_grid])
        J_grid = lim.J_grid
        cost = surface_cost * scale
        loc_cost = loc_cost * scale
        cmin = min(float(cost.min()), float(loc_cost.min()), best.sse * scale)
        bound = cmin * ratio
        inside_g = cost <= bound
        inside_l = loc_cost <= bound
        Sg2, Jg2 = np.meshgrid(S_axis, J_grid, indexing="ij")
        Sl2, Jl2 = np.meshgrid(Sl, Jl, indexing="ij")
        # the fine local grid sets the interval unless the region reaches its border
        on_border = (inside_l[0, :].any() and Sl[0] > 0) or inside_l[-1, :].any() \
            or (inside_l[:, 0].any() and Jl[0] > 0) or inside_l[:, -1].any()
        if on_border:
            S_int = _interval(np.concatenate([Sg2[inside_g], Sl2[inside_l]]), best.S_pct,
                              np.concatenate([S_axis, Sl]))
            J_int = _interval(np.concatenate([Jg2[inside_g], Jl2[inside_l]]), best.J_pct,
                              np.concatenate([J_grid, Jl]))
        else:
            S_int = _interval(Sl2[inside_l], best.S_pct, Sl)
            J_int = _interval(Jl2[inside_l], best.J_pct, Jl)
        surf = ErrorSurface(S_axis, J_grid, cost, bound)
    else:
        S_int = (best.S_pct, best.S_pct)
        J_int = (best.J_pct, best.J_pct)
        surf = ErrorSurface(np.zeros(1), np.zeros(1), np.array([[sse / n_sc]]), float("nan"))
    return HammersteinFit(S_pct=float(best.S_pct), J_pct=float(best.J_pct), f0=int(best.f0), process=process,
                          ts_s=float(ts_s), rmse=rmse, r2=r2, S_interval_pct=S_int, J_interval_pct=J_int,
                          surface=surf, load=load, n_fit=n, op_offset_pct=off, n_eff=ne,
                          cost=float(res_f @ res_f) / n_sc, hp_tau_s=obj.hp_tau_s,
                          score_coef=np.asarray(score_coef, float), load_order=obj.load_order,
                          start_op_pct=start_op, start_stem_pct=obj.start_stem_pct,
                          start_stuck_pct=obj.start_stuck_pct,
                          noise_costs=tuple(zip(hps, noise_costs(obj, best, lim, NOISE_CANDIDATES))))


# --------------------------------------------------------------------------------------------------
# estimator
# --------------------------------------------------------------------------------------------------

class StictionEstimator:
    """scikit-learn-style estimator over `diagnose.identification.identify` (the same identification
    as `diagnose.identify` and ``stiction identify``, on a record).

    Parameters are those of `identify`, stored as given; `get_params` reads them from this
    signature. ``fit(record)`` (a `diagnose.record.LoopRecord`, or ``fit(op_pct, pv, ts_s)``)
    learns ``identification_`` and, from it, ``stiction_``, ``stiction_probability_``, ``S_pct_``,
    ``J_pct_``, ``class_`` and ``process_``.

    Parameters
    ----------
    use_mv : bool
        Fit the valve directly on OP -> MV when the record has a stem position.
    class_test : bool
        Test the special shapes J = 0 and J = S against the free fit.
    integrating : bool, optional
        Whether the process is integrating, for the evidence tests that read other signals in an
        integrating loop (default: the fit or a level tag decides). The fit searches the process
        kinds either way: ``process_`` is what the data say, not this flag.
    """

    def __init__(self, *, use_mv: bool = True, class_test: bool = True, integrating: bool | None = None) -> None:
        self.use_mv = use_mv
        self.class_test = class_test
        self.integrating = integrating

    def get_params(self, deep: bool = True) -> dict[str, Any]:
        """The constructor's parameters and their values."""
        import inspect

        names = [n for n in inspect.signature(type(self).__init__).parameters if n != "self"]
        return {n: getattr(self, n) for n in names}

    def set_params(self, **params: Any) -> "StictionEstimator":
        """Set constructor parameters by name (as scikit-learn's estimators do); returns self."""
        valid = self.get_params()
        for k, v in params.items():
            if k not in valid:
                raise DataError(f"invalid parameter {k!r} for StictionEstimator; valid: {', '.join(valid)}")
            setattr(self, k, v)
        return self

    def fit(self, record_or_op: Any, pv: Any = None, ts_s: float | None = None) -> "StictionEstimator":
        """Identify stiction in one loop; returns self.

        Parameters
        ----------
        record_or_op : LoopRecord or array (n,)
            The loop's record (`diagnose.read_loops` reads files and DataFrames into records), or
            the controller output OP in % of valve span, uniformly sampled.
        pv : array (n,), optional
            Process variable in engineering units, sampled with OP (needed with OP as an array).
        ts_s : float, optional
            Sample period in seconds (needed with OP as an array).

        Returns
        -------
        StictionEstimator
            ``self``, with ``identification_`` and the attributes read from it.

        Raises
        ------
        DataError
            Not a record, no sample period, arrays of different lengths or with gaps, or a record
            that cannot be judged (too short, OP constant).
        """
        from .identification import identify
        from .record import LoopRecord

        if pv is None:
            rec = record_or_op
            if not isinstance(rec, LoopRecord):
                raise DataError("fit(record): give a LoopRecord (diagnose.read_loops reads files and "
                                "DataFrames), or fit(op_pct, pv, ts_s)")
        else:
            if ts_s is None:
                raise DataError("fit(op_pct, pv, ts_s): give the sample period ts_s")
            rec = LoopRecord(name="LOOP", ts_s=ts_s, op=record_or_op, pv=pv)
        ident = identify(rec, **self.get_params())
        self.identification_ = ident
        self.stiction_ = ident.stiction
        self.stiction_probability_ = ident.stiction_probability
        self.S_pct_ = ident.S_pct
        self.J_pct_ = ident.J_pct
        self.class_ = ident.cls
        self.process_ = ident.process
        return self

    def _check(self) -> None:
        if not hasattr(self, "identification_"):
            raise NotFittedError("this StictionEstimator is not fitted yet; call fit() first")

    def simulate(self, op_pct: Any) -> tuple[np.ndarray | None, np.ndarray | None]:
        """``(mv_hat_pct, pv_hat)`` of the identified model for an OP series (`Identification.model_path`:
        the valve path is None on a no-stiction verdict)."""
        self._check()
        return self.identification_.model_path(np.asarray(op_pct, dtype=float))

    def predict(self, op_pct: Any) -> np.ndarray | None:
        """PV of the identified model for an OP series."""
        return self.simulate(op_pct)[1]
