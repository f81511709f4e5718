"""Hammerstein identification of valve stiction from routine closed-loop data.

Model: controller output OP --[two-parameter stiction valve (S, J, f0)]--> stem position MV
--[low-order linear process: FOPTD / SOPTD / integrating, dead time searched]--> PV, plus a constant
and a slow load (low-order Legendre polynomial in time). Candidates are scored by **simulation
(output) error**: PV is simulated from OP alone, never from measured PV, so the linear block cannot
explain PV through the controller. For fixed valve parameters, lags and dead time, the gain, the bias
and the load coefficients are linear and solved by least squares inside one compiled pass
(separable least squares); the valve and the lags are searched:

1. noise model and linear-only fit (S = J = 0) over the grid of lags, dead times and kinds;
2. global grid over (S, J/S) x a coarse set of lags and dead times;
3. the best structure for each of the best few valves, then a dense (S, J, f0) grid at those
   structures (the valley of the cost in S and J is narrow);
4. Nelder-Mead on (S, J, lags) from the best few, alternating with a local structure polish; an
   exact local (S, J, f0) zoom and a final Nelder-Mead;
5. the error surface on the global grid at the final structure, and intervals from it.

Records longer than ``max_samples`` are searched on a full-rate window and refined on the whole record.
With ``windows`` (`diagnose.identify` uses three), equal windows spread over the record are searched
as well, each result is refined on the whole record, and the cheapest whole-record fit is kept.
The cost of a candidate (the compiled simulation and least-squares pass) is in
`diagnose.output_error`; this module holds the search and its results.
PV is prefiltered with an integrated-noise model (see ``hp_tau_s``). Details: docs/fitting.md.

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
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .errors import DataError, NotFittedError
from .output_error import (MIN_SAMPLES, _burn_in, _Configs, _hp_filter, _legendre_basis, _make_configs,
                           _Problem, _score_design, _score_weights)
from .process_model import ProcessModel
from .stiction_model import stiction_batch

#: Default noise prefilter time constant, in samples (see `fit_hammerstein`, ``hp_tau_s``).
AUTO_HP_SAMPLES = 10.0
#: J/S ratios of the global grid (deadband, undershoot, no offset, overshoot).
DEFAULT_J_RATIOS = (0.0, 0.25, 0.5, 0.75, 1.0, 1.3, 1.6, 2.0)
#: Noise-model time constants (samples) tried by ``hp_tau_s="auto"``; None is pure output error.
AUTO_HP_CANDIDATES = (2.0, 5.0, 10.0, 20.0, 50.0, None)
# first stuck points tried on a long record's whole-record refinement, as multiples of max(S, J)
# around OP's first sample
START_DELTAS = (-1.0, -0.5, 0.5, 1.0)
#: Dead times (samples) of the global (S, J) grid's structures, besides the linear model's.
GLOBAL_DELAYS = (0, 2, 5, 12)
#: J/S ratios whose best valve picks its own process structure (one per class shape)
PROFILE_RATIOS = (0.0, 0.5, 1.0, 1.5, 2.0)
#: S relative to the best fit's, profiled with J/S and the dead time (step 6 of the search)
PROFILE_S_FACTORS = (0.8, 0.9, 1.0, 1.1, 1.2)
#: refinements keep S at or below this multiple of the S grid's end (OP's 0.5-99.5 % range)
S_CAP_FACTOR = 1.2
#: Longest and shortest extra search window (``windows`` of `fit_hammerstein`), samples: a window
#: shorter than this is not searched (with three windows, records under 1500 samples have none).
WINDOW_MAX_SAMPLES = 2000
WINDOW_MIN_SAMPLES = 500


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
    start_op_pct : float or None
        The valve's first stuck point, % of span (OP's first sample plus ``op_offset_pct`` unless
        the fit chose another: the valve's state at the start of a record is unknown). None: OP's
        first sample.
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
        mv = stiction_batch(x, [self.S_pct], [self.J_pct], [self.f0])[0]
        proto = ProcessModel(kind=self.process.kind, gain=1.0, tau_s=self.process.tau_s,
                             delay_s=self.process.delay_s, bias=0.0, tau2_s=self.process.tau2_s)
        z = proto.regressor(mv - mv[0], self.ts_s)
        a = math.exp(-self.ts_s / self.hp_tau_s) if self.hp_tau_s else -1.0
        A = _score_design(z, x.shape[0], self.load_order, a)
        yf = _hp_filter(y, a) if a >= 0 else y
        return (yf - A @ self.score_coef)[m]

    def simulate(self, op_pct) -> tuple[np.ndarray, np.ndarray]:
        """Simulate the fitted valve and process from any OP series.

        Returns ``(mv_hat_pct, pv_hat)``: the modelled stem position (% of span) and PV. The slow
        load is added only when ``op_pct`` has the length of the fitted record.
        """
        x = np.asarray(op_pct, dtype=float) + self.op_offset_pct
        if x.ndim != 1 or x.shape[0] == 0 or not np.all(np.isfinite(x)):
            raise DataError("op_pct must be a non-empty 1-D series of finite values")
        if x.shape[0] == self.n_fit:
            x = self._with_start(x)
        mv = stiction_batch(x, [self.S_pct], [self.J_pct], [self.f0])[0] - self.op_offset_pct
        pv = self.process.simulate(mv, self.ts_s)
        if self.load.shape[0] > 1 and x.shape[0] == self.n_fit:
            pv = pv + _legendre_basis(x.shape[0], self.load.shape[0] - 1)[:, 1:] @ self.load[1:]
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
# the search
# --------------------------------------------------------------------------------------------------

def _process_grid(ts_s: float, n: int, kinds, max_delay_s: float | None,
                  tau_range_s: tuple[float, float] | None = None, dmin: int = 0) -> list:
    span_s = n * ts_s
    lo, hi = tau_range_s if tau_range_s is not None else (0.5 * ts_s, max(span_s / 4.0, 2 * ts_s))
    taus = np.geomspace(max(lo, 1e-9), max(hi, lo * 1.01), 11)
    dmax = int(round((max_delay_s if max_delay_s is not None else min(span_s / 10.0, 60 * ts_s)) / ts_s))
    dmax = max(0, min(dmax, n // 5))
    delays = sorted(set([0, 1, 2, 3, 4] + [int(round(v)) for v in np.geomspace(5, max(dmax, 5), 8)]))
    delays = [dd for dd in delays if dmin <= dd <= dmax] or [max(dmin, 0)]
    entries = []
    for dd in delays:
        for t in taus:
            if "foptd" in kinds:
                entries.append(("foptd", float(t), 0.0, dd))
            if "soptd" in kinds:
                entries.append(("soptd", float(t), float(t) / 3.0, dd))
                entries.append(("soptd", float(t), float(t), dd))
            if "integrating" in kinds:
                entries.append(("integrating", float(t) / 4.0, 0.0, dd))
    return entries


def _local_process_entries(kind: str, tau: float, tau2: float, dd: int, dmax: int, factors,
                           dmin: int = 0) -> list:
    out = []
    for f in factors:
        for ddd in sorted({max(dmin, dd - 1), dd, max(dmin, min(dmax, dd + 1))}):
            t1 = tau * f
            t2 = tau2 * f if kind == "soptd" else 0.0
            out.append((kind, t1, t2, ddd))
    return out


def _validate(op_pct, pv, ts_s):
    x = np.asarray(op_pct, dtype=float)
    y = np.asarray(pv, dtype=float)
    if x.ndim != 1 or y.ndim != 1 or x.shape != y.shape:
        raise DataError(f"OP and PV must be 1-D series of equal length, got {x.shape} and {y.shape}")
    if x.shape[0] < MIN_SAMPLES:
        raise DataError(f"record has {x.shape[0]} samples; the fit needs at least {MIN_SAMPLES}")
    if not (np.all(np.isfinite(x)) and np.all(np.isfinite(y))):
        raise DataError("OP and PV must be finite; fill or split gaps first")
    if not (ts_s > 0 and math.isfinite(ts_s)):
        raise DataError(f"ts_s must be a positive number of seconds, got {ts_s!r}")
    if np.ptp(x) <= 0:
        raise DataError("OP is constant: the controller never moved the valve, nothing to identify")
    if np.ptp(y) <= 0:
        raise DataError("PV is constant: nothing to identify")
    return x, y


def _op_offset(x: np.ndarray) -> float:
    """Shift that brings OP into 0..100 % when it is not (e.g. mean-centred data)."""
    lo, hi = float(np.min(x)), float(np.max(x))
    if lo >= 0.0 and hi <= 100.0:
        return 0.0
    if hi - lo < 100.0:
        return 50.0 - 0.5 * (lo + hi)
    raise DataError(f"OP spans {lo:g}..{hi:g}, more than a valve's 0..100 %; scale it to % of span")


def _n_eff(res: np.ndarray) -> float:
    r = res - res.mean()
    den = float(r @ r)
    if den <= 0 or r.shape[0] < 3:
        return float(r.shape[0])
    rho = float(r[1:] @ r[:-1]) / den
    rho = min(max(rho, 0.0), 0.999)
    return max(float(r.shape[0]) * (1.0 - rho) / (1.0 + rho), 5.0)


def _interval(values: np.ndarray, inside: np.ndarray, best: float, grid: np.ndarray) -> tuple[float, float]:
    vals = values[inside]
    if vals.size == 0:
        return (best, best)
    lo, hi = float(vals.min()), float(vals.max())
    # A region of one grid cell still carries the grid's resolution.
    g = np.unique(grid)
    i_lo = np.searchsorted(g, lo)
    i_hi = np.searchsorted(g, hi)
    step_lo = (g[i_lo] - g[i_lo - 1]) / 2 if i_lo > 0 else 0.0
    step_hi = (g[i_hi + 1] - g[i_hi]) / 2 if i_hi + 1 < g.size else 0.0
    return (max(0.0, min(lo - step_lo, best)), max(hi + step_hi, best))


def _search_window(x: np.ndarray, m: int, scored: np.ndarray | None = None) -> int:
    """Start of the ``m``-sample window in which OP covers the widest robust range (the earliest
    of equals): the part of a long record that shows the valve the most. With a training mask
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


def _extra_windows(n: int, k: int, w: np.ndarray) -> list[tuple[int, int]]:
    """(start, length) of ``k`` equal windows spread evenly over ``n`` samples (`fit_hammerstein`'s
    ``windows``), leaving out windows too short or with too few scored samples to search."""
    if k <= 0:
        return []
    m = min(n // k, WINDOW_MAX_SAMPLES)
    if m < WINDOW_MIN_SAMPLES or m >= n:
        return []           # too short to search, or the whole record (searched anyway)
    starts = [int(round(i * (n - m) / (k - 1))) if k > 1 else (n - m) // 2 for i in range(k)]
    return [(i0, m) for i0 in starts if np.count_nonzero(w[i0:i0 + m]) >= WINDOW_MIN_SAMPLES // 2]


def _s_grid(x: np.ndarray, n_S: int, S_max_pct: float | None) -> np.ndarray:
    if S_max_pct is None:
        lo, hi = np.percentile(x, [0.5, 99.5])
        S_max_pct = float(min(max(hi - lo, 0.2), 100.0))
    k = np.arange(1, n_S + 1) / n_S
    return S_max_pct * k ** 1.4


@dataclass
class _Best:
    S: float
    J: float
    F: float
    cfg: _Configs
    sse: float


def _nelder_mead(f, x0, steps, *, max_iter: int = 60, tol: float = 1e-3):
    """Minimise ``f`` from ``x0`` with the Nelder-Mead simplex (initial edge lengths ``steps``)."""
    x0 = np.asarray(x0, float)
    dim = x0.shape[0]
    simplex = [x0] + [x0 + np.eye(dim)[i] * steps[i] for i in range(dim)]
    values = [f(v) for v in simplex]
    for _ in range(max_iter):
        order = np.argsort(values)
        simplex = [simplex[i] for i in order]
        values = [values[i] for i in order]
        if abs(values[-1] - values[0]) <= tol * (abs(values[0]) + 1e-12):
            break
        centroid = np.mean(simplex[:-1], axis=0)
        xr = centroid + (centroid - simplex[-1])
        fr = f(xr)
        if fr < values[0]:
            xe = centroid + 2.0 * (centroid - simplex[-1])
            fe = f(xe)
            simplex[-1], values[-1] = (xe, fe) if fe < fr else (xr, fr)
        elif fr < values[-2]:
            simplex[-1], values[-1] = xr, fr
        else:
            xc = centroid + 0.5 * (simplex[-1] - centroid)
            fc = f(xc)
            if fc < values[-1]:
                simplex[-1], values[-1] = xc, fc
            else:
                for i in range(1, dim + 1):
                    simplex[i] = simplex[0] + 0.5 * (simplex[i] - simplex[0])
                    values[i] = f(simplex[i])
    i = int(np.argmin(values))
    return simplex[i], values[i]


def _nelder_mead_refine(prob: "_Problem", cur: _Best, ts_s: float, *, fixed: bool, max_iter: int = 60,
                        tol: float = 1e-3, tau_max_s: float = math.inf, S_max_pct: float = math.inf) -> _Best:
    """Refine S, J (and the lags, dead time fixed) of one candidate by Nelder-Mead.

    Both starting directions are scored at every point; the better one counts. S and J stay at or
    below ``S_max_pct``.
    """
    kind = cur.cfg.kind[0]
    d = int(cur.cfg.d[0])
    tau0 = max(float(cur.cfg.tau[0]), 1e-6)
    ratio2 = float(cur.cfg.tau2[0]) / tau0 if kind == "soptd" else 0.0
    scale = max(cur.S, 0.05)

    def unpack(v):
        S = min(abs(v[0]) * scale, S_max_pct)
        J = min(abs(v[1]) * scale, S_max_pct)
        tau = tau0 * math.exp(v[2]) if not fixed else tau0
        return S, J, tau

    def cost(v):
        S, J, tau = unpack(v)
        cfg = _make_configs([(kind, tau, tau * ratio2, d)], ts_s, tau_max_s)
        sse, _ = prob.sse([S, S], [J, J], [1.0, -1.0], cfg)
        return float(sse[:, 0].min())

    x0 = np.array([cur.S / scale, cur.J / scale, 0.0])
    steps = np.array([0.15, 0.15 + 0.1 * (cur.J < 1e-9), 0.3 if not fixed else 0.0])
    if fixed:
        x0, steps = x0[:2], steps[:2]
        f = lambda v: cost(np.concatenate([v, [0.0]]))  # noqa: E731
    else:
        f = cost
    xb, fb = _nelder_mead(f, x0, steps, max_iter=max_iter, tol=tol)
    if fixed:
        xb = np.concatenate([xb, [0.0]])
    if fb >= cur.sse:
        return cur
    S, J, tau = unpack(xb)
    cfg = _make_configs([(kind, tau, tau * ratio2, d)], ts_s, tau_max_s)
    sse, _ = prob.sse([S, S], [J, J], [1.0, -1.0], cfg)
    k = int(np.argmin(sse[:, 0]))
    return _Best(S, J, (1.0, -1.0)[k], cfg, float(sse[k, 0]))


def _zoom(prob: "_Problem", cur: _Best, *, rounds: int = 2, size: int = 9, span: float = 0.15,
          S_max_pct: float = math.inf) -> _Best:
    """Local (S, J, f0) grid around ``cur`` at its structure, shrinking by 4 each round.

    The cost is piecewise constant in S and J (the valve path changes only when a threshold
    crosses an input sample), which can stall a simplex; a grid cannot stall.
    """
    dS = span * max(cur.S, 0.05)
    dJ = span * max(cur.J, 0.5 * cur.S, 0.05)
    for _ in range(rounds):
        Sl = np.unique(np.clip(cur.S + dS * np.linspace(-1, 1, size), 1e-6, max(S_max_pct, 1e-6)))
        Jl = np.unique(np.clip(cur.J + dJ * np.linspace(-1, 1, size), 0.0, max(S_max_pct, 0.0)))
        Sm, Jm, Fm = np.meshgrid(Sl, Jl, [1.0, -1.0], indexing="ij")
        sse, _ = prob.sse(Sm.ravel(), Jm.ravel(), Fm.ravel(), cur.cfg)
        i = int(np.argmin(sse[:, 0]))
        if sse[i, 0] < cur.sse:
            cur = _Best(float(Sm.ravel()[i]), float(Jm.ravel()[i]), float(Fm.ravel()[i]), cur.cfg,
                        float(sse[i, 0]))
        dS /= 4.0
        dJ /= 4.0
    return cur


def fit_hammerstein(op_pct, pv, ts_s: float, *, train=None, stiction: bool = True,
                    kinds=("foptd", "soptd", "integrating"), max_delay_s: float | None = None,
                    n_S: int = 12, n_J: int = 12, S_max_pct: float | None = None,
                    load_order: int = 2, burn_frac: float = 0.05, refine_rounds: int = 2,
                    structure: tuple | None = None, hp_tau_s: float | str | None = "auto",
                    n_starts: int = 3, tau_range_s: tuple[float, float] | None = None,
                    min_delay_s: float | None = None, max_samples: int | None = 4000,
                    surface: bool = True, gain_fixed: float | None = None,
                    gain_sign: float | None = None,
                    J_ratios=None, dense_S: int = 36, dense_ratios: int = 17,
                    dense_structures: int = 0, n_refine: int = 3,
                    profile_ratios=PROFILE_RATIOS, windows: int = 0) -> HammersteinFit:
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
    kinds : tuple of {"foptd", "soptd", "integrating"}
        Process structures searched.
    max_delay_s : float, optional
        Largest dead time searched (default: a tenth of the record, at most 60 samples).
    n_S, n_J : int
        Size of the global (S, J) grid.
    S_max_pct : float, optional
        Largest S searched (default: OP's robust peak-to-peak range).
    load_order : int
        Order of the Legendre polynomial in time that absorbs slow load (0: a constant only).
    burn_frac : float
        Fraction of the record at its start left out of the score (unknown initial state).
    refine_rounds : int
        Alternations of process search and local (S, J) zoom after the global grid.
    structure : (kind, tau_s, tau2_s, delay_s), optional
        Fix the process structure instead of searching it (gain and bias are still fitted).
    hp_tau_s : float, None or "auto"
        Noise model: PV disturbances are taken as integrated noise, ``H = (1 - a q^-1)/(1 - q^-1)``
        with ``a = exp(-ts/hp_tau_s)``, and both sides are prefiltered by ``1/H`` (prediction error
        with a fixed noise model). None is pure output error. ``"auto"`` picks ``hp_tau_s`` from
        `AUTO_HP_CANDIDATES` (samples) by the linear model's prediction-error cost.
    n_starts : int
        Distinct starts from the global grid that are refined.
    tau_range_s : (float, float), optional
        Range of lags searched.
    min_delay_s : float, optional
        Smallest dead time searched (default one sample: logged PV cannot respond to the OP logged
        at the same instant, and allowing it lets the fit explain PV through the controller).
    max_samples : int or None
        Longer records are searched on a window of this many samples at the full rate (the one
        where OP covers the widest range), and the result is refined on the whole record (None:
        search the whole record).
    windows : int
        Also search this many equal windows spread evenly over the record (first, middle and last
        third for three; each at most `WINDOW_MAX_SAMPLES` long, none shorter than
        `WINDOW_MIN_SAMPLES`), refine each window's result on the whole record like a long record's,
        and keep the cheapest whole-record fit. With J > 0 the cost is a needle in S and which
        valley the search ends in hangs on the noise of the samples it sees: a few independent
        looks, judged on all the data, find the truth's valley far more often (docs/fitting.md,
        "Search windows"). 0: no extra windows.
    J_ratios : sequence of float, optional
        J/S ratios of the global grid (default `DEFAULT_J_RATIOS`).
    dense_S, dense_ratios : int
        Size of the dense (S, J/S in 0..2) grid run at the few process structures the global grid
        picked.
    dense_structures : int
        How many of the global grid's best structures (by their best valve) join the dense grid.
    n_refine : int
        How many of the best candidates are refined by Nelder-Mead.
    profile_ratios : sequence of float
        J/S ratios (one per class shape) whose best valve of the dense grid picks its own process
        structure from the full grid (empty: off).
    gain_sign : {+1, -1}, optional
        Sign the process gain must have (the controller's action: a reverse-acting controller,
        OP rising when PV is below SP, closes the loop negatively only on a process whose PV rises
        with the valve). Candidates with the other sign score as a model without process: in
        closed loop they are the controller path, ``PV = -OP / Kc``, not the plant.
    gain_fixed : float, optional
        Fix the process gain (PV units per %) instead of fitting it (the direct valve fit uses 1).
    surface : bool
        Compute the error surface and the intervals (False: a faster fit with point estimates;
        the surface is then a single cell and the intervals collapse to the estimate).

    Returns
    -------
    HammersteinFit
    """
    x, y = _validate(op_pct, pv, ts_s)
    n = x.shape[0]
    off = _op_offset(x)
    x = x + off
    burn = _burn_in(x, burn_frac)
    w = _score_weights(n, train, burn)
    auto_hp = isinstance(hp_tau_s, str)
    if auto_hp:
        if hp_tau_s != "auto":
            raise DataError(f"hp_tau_s must be a number of seconds, None or 'auto', got {hp_tau_s!r}")
        hp_tau_s = AUTO_HP_SAMPLES * ts_s
    def new_problem(hp: float | None) -> _Problem:
        p_ = _Problem(x, y, ts_s, w, load_order, hp, gain_fixed, gain_sign)
        p_.x = np.array(x)        # private: a long record's refinement sets the first sample
        return p_

    prob = new_problem(hp_tau_s)
    x_first = float(x[0])

    def set_start(x0: float | None) -> None:
        prob.x[0] = x_first if x0 is None else x0

    dmax = int(round((max_delay_s if max_delay_s is not None else min(n * ts_s / 10.0, 60 * ts_s)) / ts_s))
    dmax = max(0, min(dmax, n // 5))
    dmin = int(round((min_delay_s if min_delay_s is not None else ts_s) / ts_s))
    dmin = min(max(dmin, 0), dmax)

    # tau_range_s bounds every lag, the local refinements' too
    tau_max = max(tau_range_s[1], 0.0) if tau_range_s is not None else math.inf

    def make_configs(entries, ts):
        return _make_configs(entries, ts, tau_max)

    if structure is not None:
        k_, t1_, t2_, d_ = structure
        all_cfg = make_configs([(k_, t1_, t2_, int(round(d_ / ts_s)))], ts_s)
    else:
        all_cfg = make_configs(_process_grid(ts_s, n, kinds, max_delay_s, tau_range_s, dmin), ts_s)

    def best_structure(S, J, F) -> tuple[int, float]:
        sse, _ = prob.sse([S], [J], [F], all_cfg)
        p = int(np.argmin(sse[0]))
        return p, float(sse[0, p])

    def polish_structure(S, J, F, cfg: _Configs, p: int) -> tuple[_Configs, float]:
        """Finer lags (and +-1 sample of dead time) around structure p."""
        if structure is not None:
            return cfg.take(p), None
        entries = _local_process_entries(cfg.kind[p], float(cfg.tau[p]), float(cfg.tau2[p]),
                                         int(cfg.d[p]), dmax, 2.0 ** np.arange(-1.0, 1.01, 0.25), dmin)
        loc = make_configs(entries, ts_s)
        sse, _ = prob.sse([S], [J], [F], loc)
        q = int(np.argmin(sse[0]))
        return loc.take(q), float(sse[0, q])

    if auto_hp:
        # noise model by prediction-error cost of the linear model (the filters are monic, so the
        # costs of different noise models compare directly)
        p_lin, _ = best_structure(0.0, 0.0, 1.0)
        cfg_l = all_cfg.take(p_lin)
        costs = []
        for hp in AUTO_HP_CANDIDATES:
            pr = _Problem(x, y, ts_s, w, load_order, None if hp is None else hp * ts_s, gain_fixed, gain_sign)
            c, _ = pr.sse([0.0], [0.0], [1.0], cfg_l)
            costs.append(float(c[0, 0]) * pr.y_std ** 2)
        hp_best = AUTO_HP_CANDIDATES[int(np.argmin(costs))]
        hp_tau_s = None if hp_best is None else hp_best * ts_s
        if hp_tau_s != prob.hp_tau_s:
            prob = new_problem(hp_tau_s)

    S_grid = _s_grid(x, n_S, S_max_pct)
    # a valve that sticks and slips both ways needs OP to travel more than S: a larger S can only
    # fit by never reversing (a ratchet that follows a drift), so refinements stop a little past
    # the grid's end (the OP range)
    S_cap = S_CAP_FACTOR * float(S_grid[-1])
    J_grid = np.concatenate([[0.0], 1.5 * S_grid[-1] * (np.arange(1, n_J) / (n_J - 1)) ** 1.4])

    def search() -> _Best:
        # 1. linear-only
        p_lin, sse_lin = best_structure(0.0, 0.0, 1.0)
        cfg_b, sse_b = polish_structure(0.0, 0.0, 1.0, all_cfg, p_lin)
        best = _Best(0.0, 0.0, 1.0, cfg_b, sse_b if sse_b is not None else sse_lin)

        if stiction:
            # 2. global grid: (S, J/S) x a coarse set of lags and dead times
            ratios = np.asarray(J_ratios if J_ratios is not None else DEFAULT_J_RATIOS, float)
            # both starting directions for the direct valve fit (clean data: f0 matters for long);
            # the dense grid below covers both for the Hammerstein fit
            f_set = [1.0, -1.0] if gain_fixed is not None else [1.0]
            Sg0, Rg0, Fg0 = np.meshgrid(S_grid, ratios, f_set, indexing="ij")
            Sg0, Jg0, Fg0 = Sg0.ravel(), (Sg0 * Rg0).ravel(), Fg0.ravel()
            if structure is None:
                span_s = n * ts_s
                t_lo, t_hi = tau_range_s if tau_range_s is not None else (ts_s, max(span_s / 8.0, 2 * ts_s))
                taus = np.geomspace(t_lo, max(t_hi, 1.01 * t_lo), 6)
                d_lin = int(best.cfg.d[0])
                dset = sorted({max(dmin, dd) for dd in GLOBAL_DELAYS + (d_lin,) if dd <= dmax})
                entries = [("foptd", float(t), 0.0, dd) for t in taus for dd in dset]
                if "integrating" in kinds:
                    entries += [("integrating", float(ts_s), 0.0, dd) for dd in dset]
                gcfg = make_configs(entries, ts_s)
            else:
                gcfg = best.cfg
            sse_g, _ = prob.sse(Sg0, Jg0, Fg0, gcfg)
            # keep the best few distinct starts: best per valve-shape ratio, then overall order
            order = np.argsort(sse_g.min(axis=1))
            starts = []
            for i in order:
                p = int(np.argmin(sse_g[i]))
                cand = (float(Sg0[i]), float(Jg0[i]), p, float(Fg0[i]), float(sse_g[i, p]))
                if all(abs(cand[0] - c[0]) > 0.2 * cand[0] or abs(cand[1] - c[1]) > 0.2 * max(cand[0], 1e-9)
                       for c in starts):
                    starts.append(cand)
                if len(starts) >= n_starts:
                    break
            # 3. the process structure for each start's valve ...
            results = [best]
            cfgs = []
            for S0, J0, p, F0, c0 in starts:
                cur = _Best(S0, J0, F0, gcfg.take(p), c0)
                if structure is None:
                    q, sq = best_structure(cur.S, cur.J, cur.F)
                    if sq < cur.sse:
                        cur = _Best(cur.S, cur.J, cur.F, all_cfg.take(q), sq)
                results.append(cur)
                key = (cur.cfg.kind[0], float(cur.cfg.tau[0]), float(cur.cfg.tau2[0]), int(cur.cfg.d[0]))
                if key not in [k for k, _ in cfgs]:
                    cfgs.append((key, cur.cfg))
            # ... plus the linear model's structure and the global grid's best structures
            per_structure = sse_g.min(axis=0)
            top = [int(p) for p in np.argsort(per_structure)[:dense_structures]]
            extra = [best.cfg] + [gcfg.take(p) for _, _, p, _, _ in starts] + [gcfg.take(p) for p in top]
            for c in extra:
                key = (c.kind[0], float(c.tau[0]), float(c.tau2[0]), int(c.d[0]))
                if key not in [k for k, _ in cfgs]:
                    cfgs.append((key, c))
            # 4. ... a dense (S, J, f0) grid at those structures (the valley in S and J is narrow)
            ent = [k for k, _ in cfgs]
            dcfg = make_configs(ent, ts_s)
            S_dense = _s_grid(x, dense_S, float(S_grid[-1]))
            Sd, Rd, Fd = np.meshgrid(S_dense, np.linspace(0.0, 2.0, dense_ratios), [1.0, -1.0], indexing="ij")
            Sd, Jd, Fd = Sd.ravel(), (Sd * Rd).ravel(), Fd.ravel()
            sse_d, _ = prob.sse(Sd, Jd, Fd, dcfg)
            for p in range(len(dcfg)):
                i = int(np.argmin(sse_d[:, p]))
                results.append(_Best(float(Sd[i]), float(Jd[i]), float(Fd[i]), dcfg.take(p), float(sse_d[i, p])))
            # 4b. every valve shape gets its own process: the lags and the dead time trade off
            # against J, so a structure picked for one shape can hide the right one. For each
            # profiled J/S, the best valve of the dense grid picks its structure from the full
            # process grid; new structures get the dense grid too.
            if structure is None and profile_ratios:
                Rdv = Jd / np.maximum(Sd, 1e-12)
                new = []
                keys = [k for k, _ in cfgs]
                for r in profile_ratios:
                    sel = np.abs(Rdv - r) < 1e-6
                    if not sel.any():
                        continue
                    sub = np.where(sel[:, None], sse_d, np.inf)
                    i, _p = np.unravel_index(int(np.argmin(sub)), sub.shape)
                    q, _sq = best_structure(float(Sd[i]), float(Jd[i]), float(Fd[i]))
                    cq, _ = polish_structure(float(Sd[i]), float(Jd[i]), float(Fd[i]), all_cfg, q)
                    key = (cq.kind[0], float(cq.tau[0]), float(cq.tau2[0]), int(cq.d[0]))
                    if key not in keys:
                        keys.append(key)
                        new.append(key)
                if new:
                    ncfg = make_configs(new, ts_s)
                    sse_n, _ = prob.sse(Sd, Jd, Fd, ncfg)
                    for p in range(len(ncfg)):
                        for r in profile_ratios:
                            sel = np.abs(Rdv - r) < 0.07
                            col = np.where(sel, sse_n[:, p], np.inf)
                            i = int(np.argmin(col))
                            if np.isfinite(col[i]):
                                results.append(_Best(float(Sd[i]), float(Jd[i]), float(Fd[i]), ncfg.take(p),
                                                     float(col[i])))
            # 5. refine the best few: structure polish and Nelder-Mead on (S, J, lags)
            results.sort(key=lambda r: r.sse)
            def refine(cur: _Best) -> _Best:
                for rnd in range(refine_rounds):
                    if structure is None and rnd > 0:
                        cq, sq = polish_structure(cur.S, cur.J, cur.F, cur.cfg, 0)
                        if sq < cur.sse:
                            cur = _Best(cur.S, cur.J, cur.F, cq, sq)
                    cur = _nelder_mead_refine(prob, cur, ts_s, fixed=structure is not None, tau_max_s=tau_max,
                                              S_max_pct=S_cap)
                return cur

            refined = [refine(cur) for cur in results[: max(2, n_refine)]]
            # 6. J, S and the dead time trade off (a larger J looks like a longer delay, a larger S
            # like a slower process): profile the cost over J/S, S and every dead time of the grid
            # near the best lags, and refine the best candidate of each valve shape (deadband,
            # undershoot, no offset, overshoot) with its own structure, so that no shape loses for
            # want of the structure that suits it.
            if structure is None and refined:
                top_r = min(refined, key=lambda r: r.sse)
                if top_r.S > 0:
                    Jr = np.asarray(DEFAULT_J_RATIOS, float)
                    Sp_ = np.unique(np.minimum(top_r.S * np.asarray(PROFILE_S_FACTORS), S_cap))
                    Sm_, Rm_, Fm_ = np.meshgrid(Sp_, Jr, [1.0, -1.0],
                                                indexing="ij")
                    Sm_, Rm_, Fm_ = Sm_.ravel(), Rm_.ravel(), Fm_.ravel()
                    Jm_ = Sm_ * Rm_
                    k0, t0, d_top = top_r.cfg.kind[0], float(top_r.cfg.tau[0]), int(top_r.cfg.d[0])
                    r2 = float(top_r.cfg.tau2[0]) / max(t0, 1e-12)
                    d_set = sorted({int(v) for v in all_cfg.d}
                                   | {dd for dd in range(d_top - 3, d_top + 4) if dmin <= dd <= dmax})
                    ent = [(kd, t0 * f, t0 * f * r2 if kd == "soptd" else 0.0, dd)
                           for kd in sorted({k0, "foptd"} & set(kinds) | {k0}) for f in (0.5, 1.0, 2.0)
                           for dd in d_set]
                    lcfg = make_configs(ent, ts_s)
                    sse_l, _ = prob.sse(Sm_, Jm_, Fm_, lcfg)
                    bands = [Rm_ == 0.0, (Rm_ > 0.0) & (Rm_ < 0.85), (Rm_ >= 0.85) & (Rm_ <= 1.15),
                             Rm_ > 1.15]
                    for sel in bands:
                        if not sel.any():
                            continue
                        sub = np.where(sel[:, None], sse_l, np.inf)
                        i, p = np.unravel_index(int(np.argmin(sub)), sub.shape)
                        alt = _Best(float(Sm_[i]), float(Jm_[i]), float(Fm_[i]), lcfg.take(int(p)),
                                    float(sub[i, p]))
                        refined.append(refine(alt))
            results = refined + results
            best = min(results, key=lambda r: r.sse)
        return best

    def refine_from(part: "HammersteinFit") -> tuple[_Best, float | None]:
        """Refinement on the whole record of a fit made on a window of it, and the first stuck
        point it chose (None: OP's first sample); ``prob`` is left at that starting state."""
        nonlocal prob
        cp = part.process
        d0 = int(round(cp.delay_s / ts_s))
        S0, J0, F0 = part.S_pct, part.J_pct, float(part.f0)
        base = (cp.kind, cp.tau_s if cp.kind != "integrating" else max(cp.tau_s, 0.0),
                cp.tau2_s, d0)
        cfg0 = make_configs([base], ts_s)
        # the window's starting state holds at the window's start, not the record's: a valve
        # started on the wrong side, or stuck at the wrong point, can stay stuck in the middle of
        # the whole record's limit cycle. Its direction and first stuck point are nuisances (as in
        # the class test): stuck near OP's first sample, or at an extreme of OP's travel in the
        # burn-in, where a valve in a limit cycle waits for the next reversal.
        starts = [(None, F0)]
        if stiction and S0 > 0:
            head = x[: max(burn, 2)]
            pts = [x_first + dl * max(S0, J0) for dl in START_DELTAS] + [float(head.min()), float(head.max())]
            starts += [(None, -F0)] + [(min(max(p_, 0.0), 100.0), Fv) for p_ in pts for Fv in (F0, -F0)]
        cs = []
        for p_, Fv in starts:
            set_start(p_)
            cs.append(float(prob.sse([S0], [J0], [Fv], cfg0)[0][0, 0]))
        x0, F0 = starts[int(np.argmin(cs))]
        set_start(x0)
        if auto_hp:
            costs = []
            for hp in AUTO_HP_CANDIDATES:
                pr = _Problem(prob.x, y, ts_s, w, load_order, None if hp is None else hp * ts_s, gain_fixed,
                              gain_sign)
                c, _ = pr.sse([S0], [J0], [F0], cfg0)
                costs.append(float(c[0, 0]) * pr.y_std ** 2)
            hp_best = AUTO_HP_CANDIDATES[int(np.argmin(costs))]
            hp_new = None if hp_best is None else hp_best * ts_s
            if hp_new != prob.hp_tau_s:
                prob = new_problem(hp_new)
                set_start(x0)
        dset = sorted({min(dmax, max(dmin, d0 + k)) for k in range(-3, 4)})
        entries = [(cp.kind, cp.tau_s * f, cp.tau2_s * f, dd) for f in 2.0 ** np.arange(-1.0, 1.01, 0.5)
                   for dd in dset]
        loc = make_configs(entries, ts_s)
        sse, _ = prob.sse([S0], [J0], [F0], loc)
        k = int(np.argmin(sse[0]))
        cur = _Best(S0, J0, F0, loc.take(k), float(sse[0, k]))
        if stiction:
            cur = _nelder_mead_refine(prob, cur, ts_s, fixed=False, tau_max_s=tau_max, S_max_pct=S_cap)
        cq, sq = polish_structure(cur.S, cur.J, cur.F, cur.cfg, 0)
        if sq is not None and sq < cur.sse:
            cur = _Best(cur.S, cur.J, cur.F, cq, sq)
        if stiction:
            cur = _nelder_mead_refine(prob, cur, ts_s, fixed=False, tau_max_s=tau_max, S_max_pct=S_cap)
        return cur, x0

    def search_window(span: tuple[int, int]) -> "HammersteinFit":
        """The ordinary search on samples ``i0 .. i0 + m`` of the record, nothing else."""
        i0, m = span
        sl = slice(i0, i0 + m)
        tw = w[sl] > 0
        tw[: max(0, burn - i0)] = True      # the window's fit applies its own burn-in
        return fit_hammerstein(x[sl], y[sl], ts_s, train=tw, stiction=stiction, kinds=kinds,
                               max_delay_s=max_delay_s, n_S=n_S, n_J=n_J, S_max_pct=float(S_grid[-1]),
                               load_order=load_order, burn_frac=burn_frac, refine_rounds=refine_rounds,
                               hp_tau_s="auto" if auto_hp else hp_tau_s, n_starts=n_starts,
                               tau_range_s=tau_range_s, min_delay_s=min_delay_s, max_samples=None,
                               surface=False, gain_fixed=gain_fixed, gain_sign=gain_sign,
                               J_ratios=J_ratios,
                               dense_S=dense_S, dense_ratios=dense_ratios,
                               dense_structures=dense_structures, n_refine=n_refine,
                               profile_ratios=profile_ratios)

    long_record = max_samples is not None and n > max_samples and structure is None
    spans: list[tuple[int, int]] = []
    if long_record:
        # search a full-rate window, refine on the whole record: slips happen at the sample level,
        # and block means smear them (searching block means of 10 000-sample loops got J wrong by
        # half and the class wrong in a third of the simulated loops, see docs/validation.md)
        spans.append((_search_window(x, max_samples, None if train is None else w > 0), max_samples))
    spans += _extra_windows(n, windows, w) if (stiction and structure is None) else []
    parts = [search_window(sp) for sp in spans]
    base = prob
    candidates = [] if long_record else [(search(), None, base)]
    for part in parts:
        prob = base             # every window's refinement starts from the same noise model
        cand, x0c = refine_from(part)
        candidates.append((cand, x0c, prob))
    # the rest (polish, surface, result) stays at the noise model and the starting state of the
    # cheapest whole-record fit
    best, x0, prob = min(candidates, key=lambda c: c[0].sse)
    set_start(x0)

    sse0, _ = prob.sse([best.S], [best.J], [best.F], best.cfg)
    best = _Best(best.S, best.J, best.F, best.cfg, float(sse0[0, 0]))
    if stiction and best.S > 0:
        best = _zoom(prob, best, rounds=2, size=9, span=0.06, S_max_pct=S_cap)
        if structure is None:
            best = _nelder_mead_refine(prob, best, ts_s, fixed=False, max_iter=100, tol=1e-6, tau_max_s=tau_max,
                                       S_max_pct=S_cap)

    surface_cost = None
    if stiction and surface:
        Sg, Jg, Fg = np.meshgrid(S_grid, J_grid, [1.0, -1.0], indexing="ij")
        # 4. surface at the final structure
        sse_s, _ = prob.sse(Sg.ravel(), Jg.ravel(), Fg.ravel(), best.cfg)
        surface_cost = sse_s[:, 0].reshape(Sg.shape).min(axis=2)
        # the linear model is the S = 0 row
        lin_row = np.full((1, J_grid.shape[0]), float(prob.sse([0.0], [0.0], [1.0], best.cfg)[0][0, 0]))
        surface_cost = np.vstack([lin_row, surface_cost])
        # a fine local surface for the interval
        Sl = np.clip(best.S + 0.6 * max(best.S, float(S_grid[0])) * np.linspace(-1, 1, 11), 0.0, None)
        Jl = np.clip(best.J + 0.6 * max(best.J, best.S, float(S_grid[0])) * np.linspace(-1, 1, 11), 0.0, None)
        Sl, Jl = np.unique(Sl), np.unique(Jl)
        Sm, Jm, Fm = np.meshgrid(Sl, Jl, [1.0, -1.0], indexing="ij")
        sse_loc, _ = prob.sse(Sm.ravel(), Jm.ravel(), Fm.ravel(), best.cfg)
        loc_cost = sse_loc[:, 0].reshape(Sm.shape).min(axis=2)

    return _finish(prob, best, ts_s, off, S_grid, J_grid, surface_cost,
                   (Sl, Jl, loc_cost) if surface_cost is not None else None, load_order, x0)


def _finish(prob: _Problem, best: _Best, ts_s, off, S_grid, J_grid, surface_cost, local, load_order,
            start_op=None):
    cfg = best.cfg
    kind = cfg.kind[0]
    x = prob.x
    mv = stiction_batch(x, [best.S], [best.J], [best.F])[0]
    proto = ProcessModel(kind=kind, gain=1.0, tau_s=float(cfg.tau[0]), delay_s=float(cfg.d[0]) * ts_s,
                         bias=0.0, tau2_s=float(cfg.tau2[0]))
    z = proto.regressor(mv - mv[0], ts_s)
    ws = prob.w > 0
    yraw = prob.yraw
    # gain and load in the (prefiltered) scoring domain, as the search scored them
    Af = _score_design(z, prob.n, load_order, prob.ahp)
    yf = _hp_filter(yraw, prob.ahp) if prob.ahp >= 0 else yraw
    if prob.gain_fixed is not None:
        rest, *_ = np.linalg.lstsq(Af[ws][:, 1:], (yf - prob.gain_fixed * Af[:, 0])[ws], rcond=None)
        score_coef = np.concatenate([[prob.gain_fixed], rest])
    else:
        score_coef, *_ = np.linalg.lstsq(Af[ws], yf[ws], rcond=None)
    res_f = (yf - Af @ score_coef)[ws]
    gain_pv = float(score_coef[0])
    # free-run simulation with that gain: constant and slow load re-fitted on raw PV
    B = _legendre_basis(prob.n, load_order)
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
    ne = _n_eff(res_f)
    nu = max(ne - 2.0, 1.0)
    ratio = 0.05 ** (-2.0 / nu)
    n_sc = max(1, prob.n_scored)
    scale = prob.y_std ** 2 / n_sc  # sse in scaled units -> mean squared error in PV units
    if surface_cost is not None:
        S_axis = np.concatenate([[0.0], S_grid])
        cost = surface_cost * scale
        Sl, Jl, loc_cost = local
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
            S_int = _interval(np.concatenate([Sg2[inside_g], Sl2[inside_l]]), np.ones(
                int(inside_g.sum() + inside_l.sum()), bool), best.S, np.concatenate([S_axis, Sl]))
            J_int = _interval(np.concatenate([Jg2[inside_g], Jl2[inside_l]]), np.ones(
                int(inside_g.sum() + inside_l.sum()), bool), best.J, np.concatenate([J_grid, Jl]))
        else:
            S_int = _interval(Sl2, inside_l, best.S, Sl)
            J_int = _interval(Jl2, inside_l, best.J, Jl)
        surface = ErrorSurface(S_axis, J_grid, cost, bound)
    else:
        S_int = (best.S, best.S)
        J_int = (best.J, best.J)
        surface = ErrorSurface(np.zeros(1), np.zeros(1), np.array([[sse / n_sc]]), float("nan"))
    return HammersteinFit(S_pct=float(best.S), J_pct=float(best.J), f0=int(best.F), process=process,
                          ts_s=float(ts_s), rmse=rmse, r2=r2, S_interval_pct=S_int, J_interval_pct=J_int,
                          surface=surface, load=load, n_fit=prob.n, op_offset_pct=off, n_eff=ne,
                          cost=float(res_f @ res_f) / n_sc, hp_tau_s=prob.hp_tau_s,
                          score_coef=np.asarray(score_coef, float), load_order=load_order,
                          start_op_pct=start_op)


# --------------------------------------------------------------------------------------------------
# OP/MV: fit the valve directly
# --------------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class ValveFit:
    """Result of `fit_valve`: the stiction model fitted on recorded OP -> stem position MV.

    ``MV ~ offset_pct + gain * lag(valve(OP))`` with an actuator lag ``lag_s`` and dead time
    ``delay_s`` (a positioner's response), both small.
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
                "J_interval_pct": list(self.J_interval_pct)}


def fit_valve(op_pct, mv_pct, ts_s: float = 1.0, *, train=None, stiction: bool = True,
              max_lag_s: float | None = None, max_delay_s: float | None = None,
              free_gain: bool = False, **opts) -> ValveFit:
    """Fit the two-parameter valve model directly on OP -> recorded stem position MV.

    Parameters
    ----------
    op_pct, mv_pct : array (n,)
        Controller output and stem position, % of span.
    ts_s : float
        Sample period, seconds.
    train : slice or mask, optional
        Samples the fit may score.
    max_lag_s, max_delay_s : float, optional
        Largest actuator lag and dead time searched (default 5 and 3 samples).
    free_gain : bool
        Fit the stem's gain too (default: 1, OP and MV both in % of span; only an offset is
        fitted). A free gain lets a wrong (S, J) hide behind a smaller travel.
    """
    lag_hi = max_lag_s if max_lag_s is not None else 5.0 * ts_s
    opts.setdefault("load_order", 0)
    # The stem position shows the valve itself: a dense global grid is affordable (the linear part
    # is only a small actuator lag) and needed (on clean data the optimum is a narrow valley).
    opts.setdefault("n_S", 40)
    opts.setdefault("J_ratios", np.linspace(0.0, 2.0, 13))
    h = fit_hammerstein(op_pct, mv_pct, ts_s, train=train, stiction=stiction, kinds=("foptd",),
                        max_delay_s=max_delay_s if max_delay_s is not None else 3.0 * ts_s,
                        tau_range_s=(0.05 * ts_s, lag_hi), hp_tau_s=None, min_delay_s=0.0,
                        gain_fixed=None if free_gain else 1.0, **opts)
    p = h.process
    return ValveFit(S_pct=h.S_pct, J_pct=h.J_pct, f0=h.f0, lag_s=p.tau_s, delay_s=p.delay_s,
                    gain=p.gain, offset_pct=p.bias, ts_s=h.ts_s, rmse=h.rmse, r2=h.r2,
                    S_interval_pct=h.S_interval_pct, J_interval_pct=h.J_interval_pct,
                    surface=h.surface, hammerstein=h)


# --------------------------------------------------------------------------------------------------
# estimator
# --------------------------------------------------------------------------------------------------

class StictionEstimator:
    """scikit-learn style wrapper around `fit_hammerstein` (or `fit_valve` with ``use_mv``).

    Parameters are stored as given; ``fit(record)`` (a `diagnose.record.LoopRecord`) or
    ``fit(op_pct, pv, ts_s)`` validates and learns ``S_pct_``, ``J_pct_``, ``f0_``, ``process_``,
    ``class_`` and ``result_``.
    """

    def __init__(self, *, use_mv: bool = False, n_S: int = 12, n_J: int = 12, load_order: int = 2,
                 hp_tau_s: float | None | str = "auto") -> None:
        self.use_mv = use_mv
        self.n_S = n_S
        self.n_J = n_J
        self.load_order = load_order
        self.hp_tau_s = hp_tau_s

    def get_params(self) -> dict[str, Any]:
        return {"use_mv": self.use_mv, "n_S": self.n_S, "n_J": self.n_J,
                "load_order": self.load_order, "hp_tau_s": self.hp_tau_s}

    def fit(self, record_or_op, pv=None, ts_s: float | None = None) -> "StictionEstimator":
        from .stiction_model import stiction_class
        if pv is None:
            rec = record_or_op
            op, pv, ts_s = rec.op, rec.pv, rec.ts_s
            mv = rec.mv
        else:
            op, mv = record_or_op, None
            if ts_s is None:
                raise DataError("fit(op_pct, pv, ts_s): give the sample period ts_s")
        if self.use_mv:
            if mv is None:
                raise DataError("use_mv=True needs a record with a stem position (MV)")
            res = fit_valve(op, mv, ts_s, n_S=self.n_S, n_J=self.n_J)
            self.process_ = None
        else:
            res = fit_hammerstein(op, pv, ts_s, n_S=self.n_S, n_J=self.n_J, load_order=self.load_order,
                                  hp_tau_s=self.hp_tau_s)
            self.process_ = res.process
        self.result_ = res
        self.S_pct_ = res.S_pct
        self.J_pct_ = res.J_pct
        self.f0_ = res.f0
        self.class_ = stiction_class(res.S_pct, res.J_pct)
        return self

    def _check(self) -> None:
        if not hasattr(self, "result_"):
            raise NotFittedError("this StictionEstimator is not fitted yet; call fit() first")

    def simulate(self, op_pct):
        """``(mv_hat_pct, pv_hat)`` (Hammerstein) or ``mv_hat_pct`` (valve fit) for an OP series."""
        self._check()
        return self.result_.simulate(op_pct)

    predict = simulate
