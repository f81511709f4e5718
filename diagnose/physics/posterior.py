"""Held-out predictions averaged over the parameter sets the training data cannot tell apart.

A stiction model simulated from a closed loop's OP is hypersensitive to its friction parameters: in
a limit cycle OP passes the real valve's threshold by only what the controller adds during the
dead time before the real slip reverses it, so a model whose S is a few tenths of a per cent of
span too high misses that slip and stays out of step until the next large excursion. The training
data pin S no finer than that (a drift fit can train at the stem's noise, as well as the true model,
with its rate a few per cent off, and extrapolate several times worse; docs/missing-physics.md),
so the held-out error of one fitted parameter set says as much about which of many equally good
sets the search happened to stop at as about the physics.

`predictive_mean` therefore judges a model by its posterior-predictive mean: the whole-record
prediction averaged over parameter sets drawn around the fit, weighted by their training
likelihood. A broad cloud around the fit (per-parameter scales, three widths) locates the
directions the training data leave free, e.g. a drift rate traded against the starting friction;
then `ADAPT_ROUNDS` importance-sampling rounds each draw from a Gaussian with the previous draws'
likelihood-weighted mean and covariance (weights likelihood / proposal), so that a long ridge of
equally good fits is followed further each round (e.g. an asymmetry's opening friction can run
far from the fit's value to the true one at the same training error, with a very different
held-out error); the last round's draws are averaged. The likelihood of a set is
``exp(-n_eff / 2 * (SSE / SSE_min - 1))`` with ``n_eff`` the effective number of independent
training residuals (Gaussian errors, variance profiled at the best set). The linear coefficients
(gain, bias, load terms) are refit by least squares for every set, as in every search. The
valve's initial state is the fit's; a set far along a ridge would need its own, so the draws are
scored only from the time the cloud's valves have slipped once (after which a valve's state is set
by its input alone) plus the process's response time.

Pure computation; seeded (the same inputs give the same prediction).
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from .model import Candidates, Stage, Structure, predict, stems, train_sse

#: relative widths of the first (exploring) cloud, in units of each parameter's scale
EXPLORE_WIDTHS = (0.3, 1.0, 3.0)
#: adaptive importance-sampling rounds
ADAPT_ROUNDS = 8
#: a training RMS at or below this fraction of the target's spread is an exact fit (rounding only)
EXACT_FIT = 1e-9


@dataclass(frozen=True)
class PredictiveMean:
    """Posterior-predictive mean of one model.

    Attributes
    ----------
    y_hat : ndarray (n,)
        Whole-record prediction averaged over the drawn parameter sets (target units).
    n_distinct : int
        Distinct parameter sets in the average.
    ess : float
        Effective sample size of the importance weights (1: one set dominates).
    """

    y_hat: np.ndarray
    n_distinct: int
    ess: float


def _free_parameters(s: Structure, stage: Stage):
    """Names, values and sampling scales of a structure's free physical parameters.

    Scales are about the resolution at which the output-error cost changes: 2 % of S for S, 4 %
    of S for J, a drift that moves S by 4 % of S over the fitted span, 5 % of a lag, 0.05 in the
    characteristic's exponent, 0.5 % of a load's period, 3 % of the process time constant. Sides
    that are equal in the fit (a symmetric valve) stay tied, so a plain model stays plain."""
    T = max(stage.n_fit * stage.ts_s, stage.ts_s)
    s_ref = max(s.S_up_pct, s.S_dn_pct, 0.1)
    names, vals, scales = ["S"], [s.S_up_pct], [0.02 * s_ref]
    if s.S_dn_pct != s.S_up_pct:
        names.append("S_dn"); vals.append(s.S_dn_pct); scales.append(0.02 * s_ref)
    names.append("J"); vals.append(s.J_up_pct); scales.append(0.04 * s_ref)
    if s.J_dn_pct != s.J_up_pct:
        names.append("J_dn"); vals.append(s.J_dn_pct); scales.append(0.04 * s_ref)
    if s.dS_pct_per_s or s.dJ_pct_per_s:
        names += ["dS", "dJ"]; vals += [s.dS_pct_per_s, s.dJ_pct_per_s]; scales += [0.04 * s_ref / T] * 2
    if s.tau_lag_s:
        names.append("lag"); vals.append(s.tau_lag_s); scales.append(0.05 * max(s.tau_lag_s, stage.ts_s))
    if s.char_c:
        names.append("c"); vals.append(s.char_c); scales.append(0.05)
    if s.period_s:
        names.append("period"); vals.append(s.period_s); scales.append(0.005 * s.period_s)
    if s.process.tau_s > 0 and not stage.fixed_dynamics:
        names.append("tau"); vals.append(s.process.tau_s); scales.append(0.03 * s.process.tau_s)
    return names, np.array(vals, float), np.array(scales, float)


def _build(s: Structure, names: list[str], P: np.ndarray) -> Candidates:
    """The structures of parameter sets ``P`` (rows, in the order of ``names``) around ``s``."""
    d = dict(zip(names, np.asarray(P, dtype=float).T))
    S_up = np.maximum(d["S"], 0.0)
    J_up = np.maximum(d["J"], 0.0)
    cols = {"S_up_pct": S_up, "S_dn_pct": np.maximum(d["S_dn"], 0.0) if "S_dn" in d else S_up,
            "J_up_pct": J_up, "J_dn_pct": np.maximum(d["J_dn"], 0.0) if "J_dn" in d else J_up}
    if "dS" in d:
        cols.update(dS_pct_per_s=d["dS"], dJ_pct_per_s=d["dJ"])
    if "lag" in d:
        cols["tau_lag_s"] = np.maximum(d["lag"], 0.0)
    if "c" in d:
        cols["char_c"] = d["c"]
    if "period" in d:
        cols["period_s"] = np.maximum(d["period"], 0.1 * s.period_s)   # never collapses
    if "tau" in d:
        cols["tau_s"] = np.maximum(d["tau"], 1e-3)
    return Candidates(s, **cols)


def _log_likelihood(stage: Stage, cands: Candidates, n_eff: float, sse_min: float | None = None):
    sse = train_sse(stage, cands)
    sse = np.where(np.isfinite(sse), sse, np.inf)
    m = float(np.min(sse)) if sse_min is None else min(sse_min, float(np.min(sse)))
    return -0.5 * n_eff * (sse / max(m, 1e-300) - 1.0), m


def _weights(log_w: np.ndarray) -> np.ndarray:
    """Normalised weights from log weights (shifted by their maximum: no overflow)."""
    w = np.exp(log_w - log_w.max())
    return w / w.sum()


def _first_moves(stm: np.ndarray) -> np.ndarray:
    """Per row, the first sample at which the stem has moved (the row's length if never), looked for
    in growing blocks (most valves slip early: the whole difference array is rarely needed)."""
    m, n = stm.shape
    first = np.full(m, n)
    todo = np.arange(m)
    a, step = 0, 256
    while todo.size and a < n - 1:
        b = min(n, a + step + 1)
        moved = np.abs(np.diff(stm[todo, a:b], axis=1)) > 1e-9
        hit = moved.any(axis=1)
        first[todo[hit]] = a + np.argmax(moved[hit], axis=1) + 1
        todo = todo[~hit]
        a, step = b - 1, 2 * step
    return first


def _memory_burn(stage: Stage, cands: Candidates, w: np.ndarray) -> Stage:
    """The stage with the training samples before the valve forgets its initial state left out.

    The initial state (where the valve stuck, which way it last moved) is fitted with the centre
    set only; after its first slip a valve's state is set by the input alone. Scoring the draws
    only after that (the time by which 90 % of the cloud's weight has slipped, plus the process's
    response time) lets a set far along a ridge of equally good fits be judged without refitting
    its initial state."""
    n = stage.n_fit
    first = _first_moves(stems(stage, cands, n))
    order = np.argsort(first)
    cw = np.cumsum(w[order])
    b = int(first[order[min(int(np.searchsorted(cw, 0.9)), len(order) - 1)]])
    p = cands[0].process
    b += int(np.ceil((3.0 * max(p.tau_s, 0.0) + max(p.tau2_s, 0.0) + max(p.delay_s, 0.0)) / stage.ts_s))
    idx = np.flatnonzero(stage.train)
    if idx.size == 0 or b <= idx[0]:
        return stage
    b = min(b, int(idx[0] + 0.3 * idx.size))
    train = stage.train.copy()
    train[:b] = False
    return dataclasses.replace(stage, train=train)


def predictive_mean(stage: Stage, struct: Structure, n_eff: float, *, seed: int = 0,
                    n_explore: int = 384, n_draw: int = 384, n_average: int = 64,
                    n_adapt: int = ADAPT_ROUNDS) -> PredictiveMean:
    """Whole-record prediction of ``struct`` averaged over the parameter sets the training part
    cannot tell apart from it (see the module's docstring).

    Parameters
    ----------
    stage : Stage
        The data (training mask, target, OP).
    struct : Structure
        The fitted model (the centre of the search).
    n_eff : float
        Effective number of independent training residuals: sets the likelihood's sharpness.
    seed : int
        Seed of the draws.
    n_explore, n_draw : int
        Parameter sets in the exploring cloud and in each importance-sampling round.
    n_average : int
        Draws (with replacement, by weight) whose predictions are averaged.
    n_adapt : int
        Importance-sampling rounds, each proposal fitted to the previous round's weighted draws
        (a ridge of equally good fits is followed further each round).
    """
    point = predict(stage, struct)[0]
    e = (stage.y - point)[stage.train]
    if e.size and float(np.sqrt(np.mean(e * e))) <= EXACT_FIT * (float(np.std(stage.y[stage.train])) or 1.0):
        # a model that reproduces the training part to rounding (a noise-free stem) has no cloud of
        # equally good sets around it: the searches' scores there are the compiled least squares'
        # own rounding floor, which would spread the draws over sets the data rule out
        return PredictiveMean(y_hat=point, n_distinct=1, ess=1.0)
    rng = np.random.default_rng(seed)
    names, p0, sc = _free_parameters(struct, stage)
    k = len(p0)
    n_eff = max(n_eff, 1.0)
    widths = rng.choice(np.asarray(EXPLORE_WIDTHS), size=(n_explore, 1))
    P = np.vstack([p0, p0 + rng.standard_normal((n_explore, k)) * widths * sc])
    cands = _build(struct, names, P)
    w = _weights(_log_likelihood(stage, cands, n_eff)[0])
    if n_adapt > 0:
        stage = _memory_burn(stage, cands, w)
        w = _weights(_log_likelihood(stage, cands, n_eff)[0])
    sse_min = None
    for _ in range(max(n_adapt, 1)):
        mu = w @ P
        X = (P - mu) / sc
        # the weighted covariance (in scale units), widened so that the draws cover it
        C = 1.5 * ((X * w[:, None]).T @ X + 0.05 * np.eye(k))
        L = np.linalg.cholesky(C)
        Z = rng.standard_normal((n_draw, k))
        P = mu + (Z @ L.T) * sc
        cands = _build(struct, names, P)
        ll2, sse_min = _log_likelihood(stage, cands, n_eff, sse_min)
        w = _weights(ll2 + 0.5 * np.sum(Z ** 2, axis=1))   # likelihood / proposal density
    ess = float(1.0 / np.sum(w ** 2))
    picks = rng.choice(n_draw, size=n_average, p=w)
    idx, counts = np.unique(picks, return_counts=True)
    y = np.zeros(stage.n)
    stm = stems(stage, [cands[i] for i in idx])
    for i, c, st in zip(idx, counts, stm):
        y += c * predict(stage, cands[i], st)[0]
    return PredictiveMean(y_hat=y / counts.sum(), n_distinct=int(len(idx)), ess=ess)
