"""The fit as model x search: the objective's contract, and each search strategy alone on it."""

import dataclasses
import math

import numpy as np
import pytest

from diagnose import kernels
from diagnose.errors import DataError
from diagnose.objective import Candidate, Objective, ProcessGrid, burn_in, score_weights
from diagnose.search import (BandConfig, DenseConfig, GridConfig, ModelSpace, PolishConfig, ZoomConfig,
                             best_structure, coarse_structures, dense_grid, global_grid, linear_fit, nelder_mead,
                             nelder_mead_many, noise_model, polish_structure, profile_intervals, refine, refine_many,
                             resolve, shape_bands, shape_profile, simplex_minimize, simplex_minimize_many,
                             start_state, zoom)
from diagnose.simulate import make_process, simc_pi, simulate_loop, steps, sticky_loop
from diagnose.stiction_model import StictionValve, stiction_batch

TRUTH = ("foptd", 20.0, 0.0, 3)


@pytest.fixture(scope="module")
def clean():
    """A noise-free sticky loop (S 3 %, J 1 %, FOPTD tau 20 s, dead time 3 s), its objective (no noise
    model, as the truth makes the output error zero) and its limits."""
    proc = make_process("foptd", gain=1.5, tau_s=20.0, delay_s=3.0)
    sp = 75.0 + steps(1500, [20, 700], [3.0, -5.0])     # setpoint moves set off a limit cycle
    rec = simulate_loop(n=1500, ts_s=1.0, process=proc, controller=simc_pi(1.5, 20.0, 3.0, 1.0),
                        valve=StictionValve(3.0, 1.0), sp=sp, noise_std=0.0)
    x = rec.op.copy()
    obj = Objective(x, rec.pv, 1.0, score_weights(x.shape[0], None, burn_in(x, 0.05)), 0, None)
    lim = resolve(x, 1.0, ModelSpace(), 12, 12)
    return rec, obj, lim


def _cost(obj, S, J, f0, key, lim):
    sse, _ = obj.score([S], [J], [f0], lim.grid([key]))
    return float(sse[0, 0])


# ---- the objective ---------------------------------------------------------------------------------

def test_the_truth_scores_zero_and_a_wrong_valve_does_not(clean):
    rec, obj, lim = clean
    assert _cost(obj, 3.0, 1.0, 1.0, TRUTH, lim) < 1e-8 * obj.n_scored
    assert _cost(obj, 3.3, 1.0, 1.0, TRUTH, lim) > 1e-3 * obj.n_scored
    assert _cost(obj, 3.0, 1.0, 1.0, ("foptd", 20.0, 0.0, 5), lim) > 1e-3 * obj.n_scored
    # no stiction at all: the linear model explains a limit cycle badly
    assert _cost(obj, 0.0, 0.0, 1.0, TRUTH, lim) > 0.05 * obj.n_scored


def test_the_objective_is_immutable_and_its_variants_are_new_objects(clean):
    rec, obj, lim = clean
    with pytest.raises(dataclasses.FrozenInstanceError):
        obj.hp_tau_s = 5.0
    with pytest.raises(ValueError):
        obj.x[0] = 1.0                   # read-only arrays
    c0 = _cost(obj, 3.0, 1.0, 1.0, TRUTH, lim)
    moved = obj.with_start(obj.x[0] + 2.0)
    noisy = obj.with_noise(10.0)
    assert moved is not obj and noisy is not obj and obj.x[0] == rec.op[0] and obj.hp_tau_s is None
    assert _cost(moved, 3.0, 1.0, 1.0, TRUTH, lim) != c0
    assert noisy.hp_tau_s == 10.0 and noisy.with_noise(None).hp_tau_s is None
    assert _cost(obj, 3.0, 1.0, 1.0, TRUTH, lim) == c0


def test_held_out_samples_do_not_count(clean):
    rec, obj, lim = clean
    w = np.array(obj.weights)
    w[800:] = 0.0
    y = np.array(obj.y)
    y[900:] += 5.0                       # a disturbance only on held-out samples
    a = obj.with_weights(w)
    b = Objective(obj.x, y, 1.0, w, 0, None)
    for S, J in ((3.0, 1.0), (2.0, 2.0)):
        assert _cost(a, S, J, 1.0, TRUTH, lim) == pytest.approx(_cost(b, S, J, 1.0, TRUTH, lim), rel=1e-9)


def test_the_controllers_sign_makes_the_controller_path_no_better_than_no_process(clean):
    rec, obj, lim = clean
    wrong = Objective(obj.x, obj.y, 1.0, obj.weights, 0, None, None, -1.0)   # the plant's gain is +1.5
    sse, gain = wrong.score([3.0], [1.0], [1.0], lim.grid([TRUTH]))
    assert sse[0, 0] >= wrong.no_process_sse - 1e-9
    right = Objective(obj.x, obj.y, 1.0, obj.weights, 0, None, None, 1.0)
    assert right.score([3.0], [1.0], [1.0], lim.grid([TRUTH]))[0][0, 0] < 1e-6


def test_a_fixed_gain_and_the_mse_scale():
    rng = np.random.default_rng(0)
    x = 50 + np.cumsum(rng.normal(0, 0.5, 600))
    mv = stiction_batch(x, [2.0], [1.0], [1])[0] + 0.7           # a stem with an offset, gain 1
    obj = Objective(x, mv, 1.0, np.ones(600), 0, None, 1.0)
    grid = ProcessGrid.of([("foptd", 0.05, 0.0, 0)], 1.0)
    sse, gain = obj.score([2.0, 2.4], [1.0, 1.0], [1.0, 1.0], grid)
    # the kernel works on PV standardised by its spread: the gain in those units
    assert gain[0, 0] * obj.y_std == pytest.approx(1.0) and sse[0, 0] < 1e-10 and sse[1, 0] > 0
    # mse: the stem's error in its own units squared
    mv_hat = stiction_batch(x, [2.4], [1.0], [1])[0]
    r = mv - mv_hat
    assert float(obj.mse(sse[1, 0])) == pytest.approx(float(np.var(r)), rel=1e-6)


def test_a_start_state_scores_the_valve_started_there():
    rng = np.random.default_rng(5)
    x = 50 + np.cumsum(rng.normal(0, 0.4, 800))
    mv = stiction_batch(x, [3.0], [1.0], [-1], start_pct=x[0] + 1.2)[0]
    obj = Objective(x, mv, 1.0, np.ones(800), 0, None, 1.0)
    grid = ProcessGrid.of([("foptd", 0.05, 0.0, 0)], 1.0)
    assert obj.score([3.0], [1.0], [-1.0], grid)[0][0, 0] > 1e-3
    assert obj.with_start_stem(x[0] + 1.2).score([3.0], [1.0], [-1.0], grid)[0][0, 0] < 1e-10


def test_a_start_state_shares_the_prepared_data_and_keeps_its_noise_variants_apart():
    """`with_start_stem` reuses the record's prepared data: it scores as an objective built afresh
    with that start, and a noise variant made from it keeps the start."""
    rng = np.random.default_rng(6)
    x = 50 + np.cumsum(rng.normal(0, 0.4, 900))
    y = stiction_batch(x, [3.0], [1.0], [-1], start_pct=x[0] + 1.2)[0] + rng.normal(0, 0.05, 900)
    obj = Objective(x, y, 1.0, score_weights(900, None, 40), 1, 30.0, None)
    grid = ProcessGrid.of([("foptd", 4.0, 0.0, 1), ("foptd", 9.0, 0.0, 2)], 1.0)
    S, J, f = [3.0, 2.5, 3.5], [1.0, 1.2, 0.0], [-1.0, 1.0, -1.0]
    started = obj.with_start_stem(x[0] + 1.2, x[0] + 0.4)
    fresh = dataclasses.replace(obj, start_stem_pct=x[0] + 1.2, start_stuck_pct=x[0] + 0.4)
    for a, b in zip(started.score(S, J, f, grid), fresh.score(S, J, f, grid)):
        np.testing.assert_array_equal(a, b)
    assert obj.start_stem_pct is None and started.start_stuck_pct == x[0] + 0.4
    other = started.with_noise(None)
    assert (other.start_stem_pct, other.start_stuck_pct) == (x[0] + 1.2, x[0] + 0.4)
    for a, b in zip(other.score(S, J, f, grid), dataclasses.replace(fresh, hp_tau_s=None).score(S, J, f, grid)):
        np.testing.assert_array_equal(a, b)
    assert obj.with_noise(None).start_stem_pct is None


def test_build_validates_the_record():
    with pytest.raises(DataError, match="OP is constant"):
        Objective.build(np.full(200, 50.0), np.linspace(0, 1, 200), 1.0)
    with pytest.raises(DataError, match="at least"):
        Objective.build(np.arange(10.0), np.arange(10.0), 1.0)
    obj = Objective.build(np.linspace(-5, 5, 300), np.sin(np.arange(300) / 9.0), 1.0, gain_sign=-3.0)
    assert obj.x.min() >= 0 and obj.gain_sign == -1.0 and obj.weights[0] == 0.0


# ---- the strategies, each alone ----------------------------------------------------------------------

def test_best_structure_is_the_grids_argmin(clean):
    rec, obj, lim = clean
    keys = [("foptd", t, 0.0, d) for t in (10.0, 20.0, 40.0) for d in (1, 3, 5)]
    c = best_structure(obj, 3.0, 1.0, 1.0, lim.grid(keys))
    brute = min(keys, key=lambda k: _cost(obj, 3.0, 1.0, 1.0, k, lim))
    assert c.structure == brute == TRUTH and (c.S_pct, c.J_pct) == (3.0, 1.0)


def test_polish_structure_never_worsens_and_keeps_a_fixed_structure(clean):
    rec, obj, lim = clean
    start = Candidate(3.0, 1.0, 1.0, ("foptd", 14.0, 0.0, 2), _cost(obj, 3.0, 1.0, 1.0, ("foptd", 14.0, 0.0, 2), lim))
    c = polish_structure(obj, start, lim)
    assert c.sse < start.sse and c.structure[3] == 3 and abs(c.structure[1] - 20.0) < 5.0
    fixed = resolve(obj.x, 1.0, ModelSpace(structure=("foptd", 14.0, 0.0, 2.0)), 12, 12)
    assert polish_structure(obj, start, fixed) is start


def test_linear_fit_has_no_stiction_and_a_polished_structure(clean):
    rec, obj, lim = clean
    lin = linear_fit(obj, lim)
    assert (lin.S_pct, lin.J_pct) == (0.0, 0.0)
    assert lin.sse <= best_structure(obj, 0.0, 0.0, 1.0, lim.process).sse


def test_global_grid_returns_distinct_starts_best_first(clean):
    rec, obj, lim = clean
    lin = linear_fit(obj, lim)
    grid = coarse_structures(lim, lin)
    starts, per_structure = global_grid(obj, lim, GridConfig(n_starts=3), grid)
    assert len(starts) == 3 and per_structure.shape == (len(grid),)
    assert [s.sse for s in starts] == sorted(s.sse for s in starts)
    assert starts[0].sse == pytest.approx(per_structure.min())
    for a in starts:
        for b in starts:
            if a is not b:
                assert abs(a.S_pct - b.S_pct) > 0.2 * min(a.S_pct, b.S_pct) or abs(a.J_pct - b.J_pct) > 0.1
    assert abs(starts[0].S_pct - 3.0) < 1.0


def test_dense_grid_gives_each_structures_best_valve(clean):
    rec, obj, lim = clean
    cfg = DenseConfig(n_S=12, n_ratios=9)
    best, table = dense_grid(obj, lim, cfg, [TRUTH, ("foptd", 40.0, 0.0, 1)])
    assert len(best) == 2 and table.shape[1] == 2
    assert best[0].sse == pytest.approx(table[:, 0].min()) and best[0].structure == TRUTH
    assert best[0].sse < best[1].sse


def test_shape_profile_offers_every_valve_shape_its_own_structure(clean):
    rec, obj, lim = clean
    cfg = DenseConfig(n_S=12, n_ratios=9, profile_ratios=(0.0, 1.0, 2.0))
    _, table = dense_grid(obj, lim, cfg, [("foptd", 40.0, 0.0, 1)])
    out = shape_profile(obj, lim, cfg, table, [("foptd", 40.0, 0.0, 1)])
    assert out                                           # new structures were found and scored
    ratios = {round(c.J_pct / c.S_pct, 1) for c in out}
    assert ratios <= {0.0, 0.9, 1.0, 1.1, 1.9, 2.0}
    assert all(c.structure != ("foptd", 40.0, 0.0, 1) for c in out)


def test_nelder_mead_polishes_to_the_truth_and_never_worsens(clean):
    rec, obj, lim = clean
    key = ("foptd", 17.0, 0.0, 3)
    start = Candidate(2.8, 1.2, 1.0, key, _cost(obj, 2.8, 1.2, 1.0, key, lim))
    c = nelder_mead(obj, start, lim, PolishConfig(max_iter=200, tol=1e-9))
    assert c.sse < 0.1 * start.sse
    assert c.S_pct == pytest.approx(3.0, rel=0.02) and c.structure[1] == pytest.approx(20.0, rel=0.1)
    worse = dataclasses.replace(start, sse=0.0)         # a start that cannot be beaten is kept
    assert nelder_mead(obj, worse, lim, PolishConfig()) is worse
    assert refine(obj, start, lim, PolishConfig()).sse <= start.sse


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_simplex_takes_the_same_steps_as_scipys_nelder_mead(seed):
    # the polish is written here only to keep scipy.optimize out of the command's start-up: on
    # the same start it must take scipy's steps, stop where scipy stops, and land where scipy lands
    from scipy.optimize import minimize

    rng = np.random.default_rng(seed)
    A = rng.normal(size=(3, 3))
    target = rng.normal(size=3)
    calls = {"ours": 0, "scipy": 0}

    def cost(who):
        def f(v):
            calls[who] += 1
            r = A @ (np.asarray(v) - target)
            # a rough, flat-bottomed valley, as the stiction cost is (piecewise constant in S, J)
            return float(r @ r + 0.3 * np.sum(np.abs(np.sin(5 * v))) + np.floor(4 * abs(v[0])) / 10)
        return f

    x0 = rng.normal(size=3)
    simplex = np.vstack([x0, x0 + np.diag([0.15, 0.25, 0.3])])
    for max_iter, fatol in [(60, 1e-3), (200, 1e-9), (5, 0.0)]:
        calls.update(ours=0, scipy=0)
        x, fx = simplex_minimize(cost("ours"), simplex, max_iter, fatol)
        res = minimize(cost("scipy"), x0, method="Nelder-Mead",
                       options={"initial_simplex": simplex, "maxiter": max_iter, "xatol": math.inf, "fatol": fatol})
        assert np.array_equal(x, res.x) and fx == res.fun
        assert calls["ours"] == calls["scipy"]
        # scoring points in batches (the start, reflection with inside contraction, shrinks) takes
        # the same steps in fewer calls
        batches = {"n": 0}

        def costs(points):
            batches["n"] += 1
            return np.array([cost("inner")(v) for v in points])

        calls.update(batched=0, inner=0)
        xb, fb = simplex_minimize(cost("batched"), simplex, max_iter, fatol, costs=costs)
        assert np.array_equal(xb, x) and fb == fx
        assert batches["n"] + calls["batched"] < calls["ours"]


def test_the_polish_scores_the_same_with_and_without_batched_points(clean, monkeypatch):
    # nelder_mead batches points only where the kernels have lanes to spare: its result must be
    # the same either way, to the bit
    rec, obj, lim = clean
    key = ("soptd", 15.0, 4.0, 3)
    start = Candidate(2.5, 1.4, 1.0, key, _cost(obj, 2.5, 1.4, 1.0, key, lim))
    results = []
    for lanes in (8, 2):
        monkeypatch.setattr(kernels, "lanes", lambda lanes=lanes: lanes)
        results.append(nelder_mead(obj, start, lim, PolishConfig(max_iter=80, tol=1e-6)))
    assert results[0] == results[1]
    assert results[0].sse < start.sse


def test_simplexes_in_lockstep_each_take_the_steps_they_take_alone():
    rng = np.random.default_rng(11)
    problems = []
    for k in range(4):
        A = rng.normal(size=(3, 3))
        target = rng.normal(size=3)
        x0 = rng.normal(size=3)
        problems.append((A, target, np.vstack([x0, x0 + np.diag([0.15, 0.25, 0.3])])))

    def f(k, v):
        A, target, _ = problems[k]
        r = A @ (np.asarray(v) - target)
        return float(r @ r + 0.3 * np.sum(np.abs(np.sin(5 * np.asarray(v)))) + np.floor(4 * abs(v[0])) / 10)

    for max_iter, fatol in [(60, 1e-3), (200, 1e-9), (7, 0.0)]:
        alone = [simplex_minimize(lambda v, k=k: f(k, v), problems[k][2], max_iter, fatol) for k in range(4)]
        calls = {"n": 0}

        def score(pts):
            calls["n"] += 1
            return [f(k, v) for k, v in pts]

        fatols = [fatol, fatol * 10, fatol, fatol]      # each simplex stops on its own rule
        together = simplex_minimize_many(score, [p[2] for p in problems], max_iter, fatols)
        again = simplex_minimize(lambda v: f(1, v), problems[1][2], max_iter, fatol * 10)
        for k, ((x, fx), (xa, fa)) in enumerate(zip(together, [alone[0], again, alone[2], alone[3]])):
            assert np.array_equal(x, xa) and fx == fa, k
        # one call per stage for all of them: fewer calls than one simplex alone makes points
        assert calls["n"] <= 3 * max_iter + 1


def test_the_kernel_scores_a_candidate_the_same_alone_or_in_a_batch(clean):
    # the lockstep polishes rely on it: a candidate's cost does not depend on its batch
    rec, obj, lim = clean
    rng = np.random.default_rng(2)
    k = 11
    valves = np.full((5, 2 * k), np.nan)
    structs = np.empty((4, 2 * k))
    for i in range(k):
        S, J = rng.uniform(0.5, 5.0), rng.uniform(0.0, 5.0)
        tau = rng.uniform(5.0, 40.0)
        row = lim.grid([("foptd" if i % 3 else "soptd", tau, tau / 4 if i % 3 == 0 else 0.0,
                         int(rng.integers(0, 6)))]).table[:, 0]
        valves[0, 2 * i: 2 * i + 2], valves[1, 2 * i: 2 * i + 2] = S, J
        structs[:, 2 * i] = structs[:, 2 * i + 1] = row
    valves[2, 0::2], valves[2, 1::2] = 1.0, -1.0
    try:
        for level in range(kernels.max_isa_level() + 1):     # every vector variant this CPU has
            kernels.set_isa(level)
            together, _ = obj.score_table(valves, structs, paired=True)
            for i in range(k):
                alone, _ = obj.score_table(np.ascontiguousarray(valves[:, 2 * i: 2 * i + 2]),
                                           np.ascontiguousarray(structs[:, 2 * i: 2 * i + 2]), paired=True)
                assert np.array_equal(alone, together[2 * i: 2 * i + 2]), (level, i)
    finally:
        kernels.set_isa(None)


def test_polishes_in_lockstep_give_each_candidate_its_own_result(clean, monkeypatch):
    rec, obj, lim = clean
    starts = [Candidate(2.5, 1.4, 1.0, ("soptd", 15.0, 4.0, 3), 0.0),
              Candidate(2.8, 1.2, 1.0, ("foptd", 17.0, 0.0, 3), 0.0),
              Candidate(4.0, 0.0, -1.0, ("foptd", 30.0, 0.0, 2), 0.0)]
    starts = [dataclasses.replace(c, sse=_cost(obj, c.S_pct, c.J_pct, c.f0, c.structure, lim)) for c in starts]
    starts.append(dataclasses.replace(starts[1], sse=0.0))     # unbeatable: kept as it is
    cfg = PolishConfig(max_iter=80, tol=1e-6)
    for lanes in (8, 2):
        monkeypatch.setattr(kernels, "lanes", lambda lanes=lanes: lanes)
        together = nelder_mead_many(obj, starts, lim, cfg)
        assert together == [nelder_mead(obj, c, lim, cfg) for c in starts]
        assert together[3] is starts[3]
        assert refine_many(obj, starts, lim, cfg) == [refine(obj, c, lim, cfg) for c in starts]


def test_the_polish_scores_with_the_objectives_valve_start(clean):
    # the valve fit starts the valve stuck where the recorded stem was: the polish must score that
    # start too, or it compares costs of two different objectives
    rec, obj, lim = clean
    key = ("foptd", 17.0, 0.0, 3)
    moved = obj.with_start_stem(float(obj.x[0]) + 4.0)
    start = Candidate(2.8, 1.2, 1.0, key, math.inf)
    one = PolishConfig(max_iter=1, tol=0.0)       # the start simplex only: its best vertex
    vertices = [(2.8, 1.2), (2.8 + 0.15 * 2.8, 1.2), (2.8, 1.2 + 0.15 * 2.8)]
    for o in (obj, moved):
        best = min(o.cost(Candidate(S, J, f0, key, 0.0)) for S, J in vertices for f0 in (1.0, -1.0))
        assert nelder_mead(o, start, lim, one, lags=False).sse == pytest.approx(best, rel=1e-12)
    assert moved.cost(start) != obj.cost(start)


def test_shape_bands_give_one_candidate_per_class_band(clean):
    rec, obj, lim = clean
    top = Candidate(3.0, 1.0, 1.0, TRUTH, _cost(obj, 3.0, 1.0, 1.0, TRUTH, lim))
    bands = shape_bands(obj, top, lim, BandConfig())
    assert len(bands) == 4
    r = [c.J_pct / c.S_pct for c in bands]
    assert r[0] == 0.0 and 0.0 < r[1] < 0.85 and 0.85 <= r[2] <= 1.15 and r[3] > 1.15
    assert min(bands, key=lambda c: c.sse) is bands[1]      # the true shape (undershoot) fits best


def test_zoom_never_worsens_and_finds_the_cell(clean):
    rec, obj, lim = clean
    start = Candidate(3.1, 0.9, -1.0, TRUTH, _cost(obj, 3.1, 0.9, -1.0, TRUTH, lim))
    c = zoom(obj, start, lim, ZoomConfig(rounds=3, size=9, span=0.1))
    assert c.sse <= start.sse and abs(c.S_pct - 3.0) < 0.05


def test_noise_model_prefers_a_prefilter_under_a_drifting_load():
    rng = np.random.default_rng(3)
    proc = make_process("foptd", gain=1.0, tau_s=15.0, delay_s=2.0)
    load = np.cumsum(rng.normal(0, 0.05, 3000))
    rec = simulate_loop(n=3000, ts_s=1.0, process=proc, controller=simc_pi(1.0, 15.0, 2.0, 1.0),
                        valve=StictionValve(3.0, 1.0), load=load, noise_std=0.02, seed=3)
    x = rec.op.copy()
    obj = Objective(x, rec.pv, 1.0, score_weights(3000, None, burn_in(x, 0.05)), 2, None)
    lim = resolve(x, 1.0, ModelSpace(), 12, 12)
    cand = Candidate(3.0, 1.0, 1.0, ("foptd", 15.0, 0.0, 2), math.nan)
    assert noise_model(obj, cand, lim) is not None
    clean_rec = sticky_loop(3.0, 1.0, n=2000, noise_std=0.3, load_walk_std=0.0, seed=2)
    xc = clean_rec.op.copy()
    objc = Objective(xc, clean_rec.pv, 1.0, score_weights(2000, None, burn_in(xc, 0.05)), 2, None)
    assert noise_model(objc, Candidate(3.0, 1.0, 1.0, ("foptd", 20.0, 0.0, 3), math.nan), lim) is None


def test_start_state_finds_where_the_valve_stuck_before_the_record():
    # the plant's valve was stuck 2 % above OP's first sample: started there, the model fits
    proc = make_process("foptd", gain=1.5, tau_s=20.0, delay_s=3.0)
    rec = simulate_loop(n=1500, ts_s=1.0, process=proc, controller=simc_pi(1.5, 20.0, 3.0, 1.0),
                        valve=StictionValve(3.0, 1.0, -1), noise_std=0.05, seed=4, warmup=700)
    x = rec.op.copy()
    obj = Objective(x, rec.pv, 1.0, score_weights(1500, None, 10), 0, None)
    lim = resolve(x, 1.0, ModelSpace(), 12, 12)
    cand = Candidate(3.0, 1.0, 1.0, TRUTH, math.nan)
    x0, f0 = start_state(obj, cand, 10, lim)
    c_start = obj.with_start(x0).score([3.0], [1.0], [f0], lim.grid([TRUTH]))[0][0, 0]
    c_plain = min(obj.score([3.0], [1.0], [f], lim.grid([TRUTH]))[0][0, 0] for f in (1.0, -1.0))
    assert c_start <= c_plain


def test_profile_intervals_hold_the_truth_on_exact_data(clean):
    rec, obj, lim = clean
    best = Candidate(3.0, 1.0, 1.0, TRUTH, _cost(obj, 3.0, 1.0, 1.0, TRUTH, lim))
    (s_lo, s_hi), (j_lo, j_hi) = profile_intervals(obj, best, lim, best.sse + 1e-9 * obj.n_scored)
    assert s_lo <= 3.0 <= s_hi and j_lo <= 1.0 <= j_hi
    assert s_hi - s_lo < 0.1 and j_hi - j_lo < 0.2      # the flat cell is narrow
