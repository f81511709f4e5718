"""The baseline each stage starts from: the fitting stage's model, or (when it is not available or
fails) a small grid fit of the same structure.

* loop stage (OP -> PV): `diagnose.fit.fit_hammerstein` fitted on the training samples;
* valve stage (OP -> MV): the plain part (S, J, f0) of `diagnose.fit.fit_valve`, else the grid.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np

from ..errors import StictionError, StictionWarning
from ..process_model import ProcessModel
from .model import (IDENTITY, Stage, Structure, _linear_fit, global_sj, refine_plain, refit_dynamics, stems,
                    train_sse)


@dataclass(frozen=True, eq=False)
class Baseline:
    """A stage's baseline model and its whole-record simulation.

    Attributes
    ----------
    structure : Structure
        Plain model (S = S_up = S_dn, no lag, drift, characteristic or load).
    y_hat : ndarray (n,)
        Whole-record simulation of the target, linear part fitted on the training samples.
    stem_hat : ndarray (n,)
        Simulated stem position.
    source : str
        ``fit_hammerstein``, ``fit_valve``, ``grid`` or ``given``.
    """

    structure: Structure
    y_hat: np.ndarray
    stem_hat: np.ndarray
    source: str


def _global_sj(stage: Stage, struct: Structure, span: float, step: float = 0.025) -> Structure:
    return global_sj(stage, struct, span, step)


def grid_baseline(stage: Stage, start: Structure | None = None, n_starts: int = 3,
                   template: Structure | None = None, coarse: list | None = None) -> Structure:
    """Global search of the plain model: coarse (S, J, f0) x FOPTD dynamics grid, then a fine global
    (S, J, f0) grid and the dynamics in turn. ``template`` carries extra physics held fixed during
    the search (e.g. a load period); ``coarse``: the coarse grid's starts when already computed
    (`coarse_starts` with the same template)."""
    x = stage.x
    span = float(np.ptp(x[: stage.n_fit]))
    if stage.fixed_dynamics:
        best = _global_sj(stage, Structure.plain(0.0, 0.0, 1, IDENTITY), span)
        return best
    starts = [st for _, st in (coarse if coarse is not None else coarse_starts(stage, n_starts, template))]
    if start is not None:
        starts.append(start)
    results = []
    for st in starts:
        best = st
        for _ in range(2):
            best = _global_sj(stage, best, span)
            best, c = refit_dynamics(stage, best, rounds=2)
        results.append((c, best))
    return min(results, key=lambda t: t[0])[1]


def coarse_starts(stage: Stage, n_starts: int = 3, template: Structure | None = None) -> list:
    """The coarse (S, J, f0) x FOPTD dynamics grid of `grid_baseline`: the best candidate of each
    of the ``n_starts`` best dynamics, as (training SSE, Structure), cheapest first. ``template``
    carries extra physics held fixed (e.g. a load period)."""
    x = stage.x
    span = float(np.ptp(x[: stage.n_fit]))
    S_grid = [0.0] + list(np.geomspace(0.2, max(0.8 * span, 0.3), 24))
    ratios = (0.0, 0.25, 0.5, 0.75, 1.0, 1.25, 1.5)
    T = stage.train.sum() * stage.ts_s
    taus = np.geomspace(stage.ts_s, max(T / 8, 2 * stage.ts_s), 5)
    dyn = [ProcessModel("foptd", 1.0, float(t), d * stage.ts_s, 0.0) for t in taus
           for d in (0, 2, 4, 7, 12)]
    valves = [Structure.plain(s, s * r, f, IDENTITY) for s in S_grid for r in ratios for f in (1, -1)
              if not (s == 0 and (r > 0 or f < 0))]
    if template is not None:
        valves = [template.replace(S_up_pct=v.S_up_pct, S_dn_pct=v.S_dn_pct, J_up_pct=v.J_up_pct,
                                   J_dn_pct=v.J_dn_pct, f0=v.f0) for v in valves]
    cands = [v.replace(process=p) for p in dyn for v in valves]
    sse = train_sse(stage, cands).reshape(len(dyn), len(valves))
    best_per_dyn = sse.min(axis=1)
    return [(float(best_per_dyn[i]), cands[int(i) * len(valves) + int(np.argmin(sse[i]))])
            for i in np.argsort(best_per_dyn)[:n_starts]]


def _from_fit_module(stage: Stage) -> Baseline | None:
    from ..fit import fit_hammerstein
    from ..valve_fit import fit_valve
    train = stage.train
    try:
        if stage.name == "loop":
            res = fit_hammerstein(stage.x, stage.y, stage.ts_s, train=train, gain_sign=stage.gain_sign or None)
            struct = Structure.plain(float(res.S_pct), float(res.J_pct), int(res.f0), res.process)
            stem_hat, y_hat = res.simulate(stage.x)
            return Baseline(struct, np.asarray(y_hat, float), np.asarray(stem_hat, float),
                            "fit_hammerstein")
        if stage.name == "valve":
            # the plain valve: fit_valve's (S, J, f0); its own actuator lag and dead time, when it
            # fits them, are left out here (they are what the actuator_lag hypothesis tests)
            res = fit_valve(stage.x, stage.y, stage.ts_s, train=train)
            struct = Structure.plain(float(res.S_pct), float(res.J_pct), int(getattr(res, "f0", 1)),
                                     IDENTITY)
            stem = stems(stage, [struct])[0]
            y_hat, _ = _linear_fit(stage, struct, stem, stage.n)
            return Baseline(struct, y_hat, stem, "fit_valve")
    except StictionError as exc:
        warnings.warn(f"the fitting stage failed on the {stage.name} stage ({exc}); "
                      "using the grid baseline", StictionWarning, stacklevel=3)
    return None


def make_baseline(stage: Stage, given: Structure | None = None, *, use_fit_module: bool = True) -> Baseline:
    """The stage's baseline: given, from the fitting stage, or from the grid (refined locally)."""
    if given is not None:
        stem = stems(stage, [given])[0]
        y_hat, _ = _linear_fit(stage, given, stem, stage.n)
        return Baseline(given, y_hat, stem, "given")
    if use_fit_module:
        b = _from_fit_module(stage)
        if b is not None:
            return b
    struct = grid_baseline(stage)
    struct, _ = refine_plain(stage, struct)
    stem = stems(stage, [struct])[0]
    y_hat, _ = _linear_fit(stage, struct, stem, stage.n)
    return Baseline(struct, y_hat, stem, "grid")
