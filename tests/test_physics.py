"""Missing physics: the augmented valve, the plant parts, localisation, the hypothesis registry
contract, and explain on records with a concealed effect (few records, fast settings; the full proof
is benchmarks/validate_physics.py)."""

import json
import math
import sys
from pathlib import Path

import numpy as np
import pytest

from diagnose.errors import DataError
from diagnose.physics import REGISTRY, PhysicsHypothesis, explain, locate
from diagnose.physics.concealed import EFFECTS, concealed_loop
from diagnose.physics.hypotheses import PlainModel, register
from diagnose.physics.model import Candidates, Pool, Stage, Structure, mesh, predict, stems, train_sse
from diagnose.physics.search import fit_initial_state, refine_plain
from diagnose.physics.plant import (AsymmetricStictionValve, AugmentedValve, CharacteristicProcess,
                                    DriftingStictionValve, LaggedValve, equal_percentage)
from diagnose.physics.valve import augmented_valve, characteristic
from diagnose.plain import number
from diagnose.process_model import ProcessModel
from diagnose.simulate import make_process, simc_pi, simulate_loop
from diagnose.stiction_model import stiction_batch

KEYS = {"missing_physics", "baseline_rmse", "improved_rmse", "hypotheses", "mismatch", "explanation",
        "warnings"}


def _walk(n=2000, seed=0):
    rng = np.random.default_rng(seed)
    return 50 + np.cumsum(rng.normal(0, 0.8, n))


# --- the augmented valve ----------------------------------------------------------------------------

def test_plain_augmented_valve_equals_the_stiction_kernel():
    x = _walk()
    S = np.array([0.0, 2.0, 3.0, 4.0, 1.0])
    J = np.array([0.0, 0.0, 3.0, 6.0, 0.5])
    f0 = np.array([1, -1, 1, -1, 1])
    a = augmented_valve(x, S_up=S, J_up=J, f0=f0)
    assert np.array_equal(a, stiction_batch(x, S, J, f0))


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_kernel_equals_the_step_by_step_plant_valve(seed):
    rng = np.random.default_rng(seed)
    x = _walk(1500, seed)
    kw = dict(S_up=rng.uniform(0.5, 5), J_up=rng.uniform(0, 4), S_dn=rng.uniform(0.5, 5),
              J_dn=rng.uniform(0, 4), dS_pct_per_s=rng.uniform(-1e-3, 1e-3),
              dJ_pct_per_s=rng.uniform(-1e-3, 1e-3), tau_lag_s=rng.uniform(0, 5), ts_s=0.5,
              f0=int(rng.choice([1, -1])))
    ref = AugmentedValve(kw["S_up"], kw["J_up"], kw["S_dn"], kw["J_dn"], dS_pct_per_s=kw["dS_pct_per_s"],
                         dJ_pct_per_s=kw["dJ_pct_per_s"], tau_lag_s=kw["tau_lag_s"], ts_s=0.5, f0=kw["f0"])
    y = [ref.reset(x[0])] + [ref.step(v) for v in x[1:]]
    assert np.array_equal(np.array(y), augmented_valve(x, **kw))


def test_fused_training_sse_equals_simulate_then_least_squares():
    # train_sse runs valve, characteristic, lags and least squares in one pass per candidate; it must
    # equal the plain route: simulate the stem, filter it, solve the least squares, sum the errors
    rng = np.random.default_rng(7)
    x = _walk(1200, 7)
    y = 0.8 * x + rng.normal(0, 0.5, x.size)
    train = np.zeros(x.size, bool)
    train[100:800] = True
    stage = Stage("loop", x, y, 1.0, train)
    structs = []
    for i, kind in enumerate(["foptd", "soptd", "integrating", "foptd", "soptd", "foptd"]):
        proc = ProcessModel(kind, 1.0, float(rng.uniform(1, 20)), float(i % 4), 0.0,
                            **({"tau2_s": 3.0} if kind == "soptd" else {}))
        S = float(rng.uniform(0.5, 4))
        structs.append(Structure(S_up_pct=S, J_up_pct=0.5 * S, S_dn_pct=0.7 * S, J_dn_pct=0.2 * S,
                                 dS_pct_per_s=1e-4 * (i - 2), f0=1 if i % 2 else -1,
                                 tau_lag_s=[0.0, 3.0][i % 2], char_c=[0.0, 1.5, -1.0][i % 3], process=proc,
                                 period_s=[None, 60.0][i // 3],
                                 y0_pct=[None, float(x[0]) + 1.0, float(x[0]) - 2.0][i % 3],
                                 xs0_pct=[None, None, float(x[0]) - 0.5, None, float(x[0]) + 1.5, None][i]))
    got = train_sse(stage, structs)
    for s, g in zip(structs, got):
        y_hat, _, _ = predict(stage, s)
        e = (y - y_hat)[: stage.n_fit][train[: stage.n_fit]]
        assert g == pytest.approx(float(e @ e), rel=1e-6)


def test_a_lag_before_the_friction_is_the_valve_driven_by_the_lagged_input():
    # the actuator's pressure lags OP and the friction acts on what it drives: the stem is the plain
    # valve of the input through a first-order lag (at rest at the first sample), scored and
    # simulated per group of candidates sharing a lag, mixed freely with candidates without one
    x = _walk(1500, 5)
    rng = np.random.default_rng(5)
    y = x + rng.normal(0, 0.1, x.size)
    train = np.zeros(x.size, bool)
    train[100:1000] = True
    stage = Stage("valve", x, y, 1.0, train)
    a = math.exp(-1.0 / 3.0)
    lagged = np.empty_like(x)
    lagged[0] = x[0]
    for k in range(1, x.size):
        lagged[k] = a * lagged[k - 1] + (1.0 - a) * x[k]
    base = Structure.plain(3.0, 1.0, 1, Structure().process)
    structs = [base.replace(tau_pre_s=3.0), base, base.replace(tau_pre_s=3.0, tau_lag_s=1.0),
               base.replace(tau_pre_s=5.0)]
    stm = stems(stage, structs)
    np.testing.assert_allclose(stm[0], augmented_valve(lagged, S_up=3.0, J_up=1.0), rtol=0, atol=1e-9)
    assert np.array_equal(stm[1], augmented_valve(x, S_up=3.0, J_up=1.0))
    assert not np.allclose(stm[0], stm[3])
    got = train_sse(stage, Pool(structs))
    for s_, g in zip(structs, got):
        y_hat, _, _ = predict(stage, s_)
        e = (y - y_hat)[: stage.n_fit][train[: stage.n_fit]]
        # normal equations in the kernel, a QR solve in predict
        assert g == pytest.approx(float(e @ e), rel=1e-5)
    assert len(set(np.round(got, 6))) == len(structs)
    assert base.replace(tau_pre_s=3.0).plain_part().tau_pre_s == 0.0


@pytest.mark.parametrize("kind, period", [("foptd", None), ("soptd", 45.0), ("integrating", None),
                                          ("integrating", 80.0)])
def test_candidate_columns_score_and_read_back_as_the_structures_they_stand_for(kind, period):
    # a grid held as columns must score bit for bit as the same structures one by one, read back
    # as those structures, and list them in the order of the nested loops
    rng = np.random.default_rng(11)
    x = _walk(900, 11)
    y = 0.6 * x + rng.normal(0, 0.4, x.size)
    train = np.zeros(x.size, bool)
    train[50:700] = True
    stage = Stage("loop", x, y, 1.0, train, gain_sign=1)
    proc = ProcessModel(kind, 1.0, 8.0, 2.0, 0.0, **({"tau2_s": 3.0} if kind == "soptd" else {}))
    base = Structure(S_up_pct=2.0, J_up_pct=1.0, S_dn_pct=2.0, J_dn_pct=1.0, tau_lag_s=2.0, char_c=0.5,
                     process=proc, period_s=period, y0_pct=float(x[0]) + 0.5, xs0_pct=float(x[0]) + 1.0)
    S = np.array([1.5, 2.0, 3.1])
    r = np.array([0.0, 0.5])
    y0 = np.array([np.nan, float(x[0]) - 0.3])
    tau = np.array([4.0, 9.5])
    s_, r_, f_, y_, t_ = mesh(S, r, (1, -1), y0, tau)
    cols = dict(S_up_pct=s_, S_dn_pct=0.8 * s_, J_up_pct=s_ * r_, J_dn_pct=s_ * r_, f0=f_, y0_pct=y_,
                tau_s=t_, delay_s=3.0)
    if period is not None:
        cols["period_s"] = period * (1.0 + 0.1 * r_)
    grid = Candidates(base, **cols)
    loops = [base.replace(S_up_pct=s, S_dn_pct=0.8 * s, J_up_pct=s * rr, J_dn_pct=s * rr, f0=f,
                          y0_pct=None if np.isnan(yy) else float(yy),
                          process=ProcessModel(kind, 1.0, t, 3.0, 0.0, **({"tau2_s": 3.0} if kind == "soptd" else {})),
                          **({} if period is None else {"period_s": period * (1.0 + 0.1 * rr)}))
             for s in S for rr in r for f in (1, -1) for yy in y0 for t in tau]
    assert len(grid) == len(loops) == 48
    for i in (0, 7, 30, -1):
        got, want = grid[i], loops[i]
        assert got.process.tau_s == want.process.tau_s and got.process.kind == kind
        assert (got.S_up_pct, got.J_up_pct, got.f0, got.y0_pct, got.xs0_pct, got.period_s) == \
            (want.S_up_pct, want.J_up_pct, want.f0, want.y0_pct, want.xs0_pct, want.period_s)
    one_by_one = train_sse(stage, loops)
    assert np.array_equal(train_sse(stage, grid), one_by_one)
    # mixed with single structures, in a pool: the same numbers in the pool's flat order
    pool = Pool([loops[5], grid, base])
    assert len(pool) == 50 and pool[0] is loops[5] and pool[-1] is base and pool[6].S_up_pct == loops[5].S_up_pct
    assert np.array_equal(train_sse(stage, pool), np.concatenate([one_by_one[5:6], one_by_one,
                                                                  train_sse(stage, [base])]))


def test_candidate_columns_refuse_what_a_structure_would_not_take():
    base = Structure.plain(1.0, 0.5, 1, ProcessModel("foptd", 1.0, 5.0, 1.0, 0.0))
    with pytest.raises(TypeError, match="cannot vary"):
        Candidates(base, process=[1.0])
    with pytest.raises(TypeError, match="load period"):
        Candidates(base, period_s=[30.0])
    with pytest.raises(TypeError, match="soptd"):
        Candidates(base, tau2_s=[3.0])
    with pytest.raises(DataError, match=">= 0 seconds"):
        Candidates(base, delay_s=[-1.0])
    with pytest.raises(IndexError):
        Candidates(base, S_up_pct=[1.0, 2.0])[2]
    stage = Stage("loop", _walk(300), _walk(300, 1), 1.0, np.ones(300, bool))
    with pytest.raises(DataError, match="S and J"):
        train_sse(stage, Candidates(base, S_up_pct=[1.0, -0.5]))


@pytest.mark.parametrize("gain_sign", [0, 1, -1])
def test_fused_kernel_is_the_same_at_every_vector_width(gain_sign):
    # the lanes run the process and the sums of LANES candidates at once; a candidate's SSE must not
    # depend on the width, nor on the other candidates sharing its vector (different dead times,
    # lags, characteristics, integrators and extra columns side by side)
    from diagnose import kernels

    rng = np.random.default_rng(21)
    x = _walk(900, 21)
    y = 0.5 * x + rng.normal(0, 0.3, x.size)
    train = np.zeros(x.size, bool)
    train[50:600] = True
    stage = Stage("loop", x, y, 1.0, train, gain_sign)
    structs = []
    for i in range(23):
        kind = ["foptd", "soptd", "integrating"][i % 3]
        proc = ProcessModel(kind, 1.0, float(rng.uniform(0, 25)), float(rng.integers(0, 9)), 0.0,
                            **({"tau2_s": float(rng.uniform(0, 6))} if kind == "soptd" else {}))
        S = float(rng.uniform(0.3, 5))
        structs.append(Structure(S_up_pct=S, J_up_pct=rng.uniform(0, 1.5) * S, S_dn_pct=S, J_dn_pct=0.3 * S,
                                 f0=1 if i % 2 else -1, tau_lag_s=[0.0, 2.0][i % 2], char_c=[0.0, 2.0, -1.5][i % 3],
                                 process=proc, period_s=[None, 77.0 + 3.0 * i][(i // 3) % 2]))
    out = {}
    try:
        for level in range(kernels.max_isa_level() + 1):
            kernels.set_isa(level)
            out[level] = train_sse(stage, structs)
    finally:
        kernels.set_isa(None)
    for level in out:
        assert np.array_equal(out[level], out[0])
    for s, g in zip(structs, out[0]):
        y_hat, _, _ = predict(stage, s)
        e = (y - y_hat)[train]
        assert g == pytest.approx(float(e @ e), rel=1e-6)
    # a load's sine and cosine made in the kernel (rotated between exact values) are the columns
    # numpy makes: the same SSE as the kernel with those columns given
    loaded = [s for s in structs if s.period_s is not None]
    n = stage.n_fit
    t = np.arange(n) * 1.0
    for s, g in zip(loaded, train_sse(stage, loaded)):
        wl = 2.0 * np.pi / s.period_s
        cols = ([t] if s.process.kind == "integrating" else []) + [np.sin(wl * t), np.cos(wl * t)]
        got = train_sse(stage, [s.replace(period_s=None)])   # the same model without its load ...
        assert got[0] >= g * (1 - 1e-9)                     # ... trains no better
        row = [s.S_up_pct, s.J_up_pct, s.S_dn_pct, s.J_dn_pct, 0.0, 0.0, 0.0, np.inf, s.f0,
               math.exp(-1.0 / s.tau_lag_s) if s.tau_lag_s else 0.0, np.nan, np.nan]
        P = kernels.fused_sse(x[:n], np.array([row]), [s.char_c],
                              [math.exp(-1.0 / s.process.tau_s) if s.process.tau_s else 0.0],
                              [(math.exp(-1.0 / s.process.tau2_s) if s.process.tau2_s else 0.0)
                               if s.process.kind == "soptd" else -1.0],
                              [int(round(s.process.delay_s))], [s.process.kind == "integrating"], 1.0,
                              np.column_stack(cols), y[:n], train[:n].astype(float), float(gain_sign))
        assert g == pytest.approx(P[0], rel=1e-12)


def test_initial_valve_state_is_recovered():
    # a valve stuck at the start away from OP (stem at 45.5 % after closing, OP at 47 %): the default
    # start (stuck at the first OP sample) misses the first slips; the fitted state does not
    x = _walk(1500, 11)
    x = x - x[0] + 47.0
    kw = dict(S_up=3.0, J_up=1.0, f0=-1, ts_s=1.0)
    truth = augmented_valve(x, y0_pct=45.5, **kw)
    rng = np.random.default_rng(11)
    y = truth + rng.normal(0, 0.05, x.size)
    train = np.zeros(x.size, bool)
    train[:1000] = True
    stage = Stage("valve", x, y, 1.0, train)
    plain = Structure.plain(3.0, 1.0, -1, ProcessModel("foptd", 1.0, 0.0, 0.0, 0.0))
    naive = float(train_sse(stage, [plain])[0])
    fitted, sse = fit_initial_state(stage, plain)
    assert sse < 0.2 * naive
    assert sse / train.sum() < 2.0 * 0.05 ** 2
    assert fitted.y0_pct == pytest.approx(45.5, abs=0.1)
    # without a state the kernel starts stuck at the first input sample, as before
    assert np.array_equal(augmented_valve(x, **kw), augmented_valve(x, y0_pct=np.nan, **kw))


def test_fine_valve_polish_reaches_the_sharp_minimum():
    # OP -> MV with an actuator lag: the output-error cost is V-shaped in S (1 % off moves slips by
    # samples); a start 5 % off in S and J (the 3 % grids' typical miss) is polished to the truth
    from diagnose.physics.search import fine_valve

    x = _walk(1500, 12)
    kw = dict(S_up=3.157, J_up=1.28, f0=1, ts_s=1.0, tau_lag_s=6.0)
    rng = np.random.default_rng(12)
    y = augmented_valve(x, **kw) + rng.normal(0, 0.1, x.size)
    train = np.zeros(x.size, bool)
    train[:1000] = True
    stage = Stage("valve", x, y, 1.0, train)
    start = Structure.plain(3.32, 1.34, 1, ProcessModel("foptd", 1.0, 0.0, 0.0, 0.0)).replace(tau_lag_s=6.0)
    start, c0 = fit_initial_state(stage, start)
    best = fine_valve(stage, start, "tau_lag_s")
    c1 = float(train_sse(stage, [best])[0])
    assert c1 < 0.5 * c0
    assert c1 / train.sum() < 1.5 * 0.1 ** 2
    assert best.S_up_pct == pytest.approx(3.157, rel=0.01)


def test_fine_asymmetric_polish_reaches_the_sharp_minimum():
    # OP -> MV with asymmetric stiction: a start 4-5 % off on each side (the one-direction scans step
    # S by 1-2 %, the coarse grid by 7 %) is polished to the truth on both sides
    from diagnose.physics.hypotheses.asymmetric_stiction import fine_asym

    x = _walk(1500, 13)
    kw = dict(S_up=3.4, J_up=1.5, S_dn=1.8, J_dn=0.6, f0=1, ts_s=1.0)
    rng = np.random.default_rng(13)
    y = augmented_valve(x, **kw) + rng.normal(0, 0.1, x.size)
    train = np.zeros(x.size, bool)
    train[:1000] = True
    stage = Stage("valve", x, y, 1.0, train)
    start = Structure(S_up_pct=3.55, J_up_pct=1.6, S_dn_pct=1.72, J_dn_pct=0.66, f0=1,
                      process=ProcessModel("foptd", 1.0, 0.0, 0.0, 0.0))
    start, c0 = fit_initial_state(stage, start)
    best = fine_asym(stage, start)
    c1 = float(train_sse(stage, [best])[0])
    assert c1 < 0.5 * c0
    assert c1 / train.sum() < 1.5 * 0.1 ** 2
    assert best.S_up_pct == pytest.approx(3.4, rel=0.015)
    # the closing side slips less often in this record: its S is less sharp (the cost is at the
    # noise, within 1 % of the true model's, from 1.75 % to 1.8 %)
    assert best.S_dn_pct == pytest.approx(1.8, rel=0.04)


def test_dynamics_restart_leaves_a_plain_fits_basin():
    # OP -> PV: the valve fixed at the truth but the process far off (a short lag with a long dead
    # time, as a plain fit of an augmented loop often has); the global dynamics grid finds the true
    # process's basin, which the local refit from the wrong one does not reach
    from diagnose.physics.search import dynamics_starts, refit_dynamics

    x = _walk(2000, 14)
    true = Structure(S_up_pct=3.0, J_up_pct=1.0, S_dn_pct=1.6, J_dn_pct=0.5, f0=1,
                     process=ProcessModel("foptd", 1.0, 25.0, 4.0, 0.0))
    rng = np.random.default_rng(14)
    train = np.zeros(x.size, bool)
    train[:1400] = True
    stem = augmented_valve(x, S_up=3.0, J_up=1.0, S_dn=1.6, J_dn=0.5, f0=1, ts_s=1.0)
    y = 1.3 * true.process.regressor(stem, 1.0) + 10.0 + rng.normal(0, 0.05, x.size)
    stage = Stage("loop", x, y, 1.0, train)
    wrong = true.replace(process=ProcessModel("foptd", 1.0, 4.0, 12.0, 0.0))
    _, c_local = refit_dynamics(stage, wrong, rounds=1)
    starts = dynamics_starts(stage, wrong, k=2)
    assert 1 <= len(starts) <= 2
    costs = [float(train_sse(stage, [s])[0]) for s in starts]
    best = starts[int(np.argmin(costs))]
    assert min(costs) < 0.5 * c_local
    assert best.process.tau_s == pytest.approx(25.0, rel=0.25)
    assert abs(best.process.delay_s - 4.0) <= 2.0


def test_joint_process_polish_trades_the_characteristic_against_the_dynamics():
    # OP -> PV through an installed characteristic: a start with the characteristic's exponent and
    # the process lag both off (and the valve's last direction wrong) is polished to the noise; the
    # one-at-a-time refits it replaced (exponent, then S and J, then dynamics) stay far above it
    from diagnose.physics.search import best_of, joint_process_polish, refine_sj, refit_dynamics

    rng = np.random.default_rng(15)
    n = 2000
    x = np.clip(np.repeat([30.0, 70.0, 45.0, 80.0, 25.0], n // 5) + 0.5 * np.cumsum(rng.normal(0, 0.6, n)),
                2.0, 98.0)
    true = Structure(S_up_pct=3.8, J_up_pct=1.9, S_dn_pct=3.8, J_dn_pct=1.9, f0=1, char_c=2.13,
                     process=ProcessModel("foptd", 1.0, 20.0, 4.0, 0.0))
    stem = augmented_valve(x, S_up=3.8, J_up=1.9, f0=1, ts_s=1.0)
    y = 1.5 * true.process.regressor(characteristic(stem, 2.13), 1.0) + 5.0 + rng.normal(0, 0.1, n)
    train = np.zeros(n, bool)
    train[:1300] = True
    stage = Stage("loop", x, y, 1.0, train)
    start = true.replace(char_c=1.6, f0=-1, process=ProcessModel("foptd", 1.0, 25.0, 4.0, 0.0))
    one, _ = best_of(stage, [start.replace(char_c=float(1.6 + d)) for d in np.linspace(-0.4, 0.4, 9)])
    one, _ = refine_sj(stage, one, s_span=0.04, n_s=9, j_span=0.15, n_j=5, both_f0=False)
    _, c_one = refit_dynamics(stage, one, rounds=1)
    best = joint_process_polish(stage, start, "char_c")
    c = float(train_sse(stage, [best])[0])
    assert c / train.sum() < 1.3 * 0.1 ** 2
    assert c < 0.2 * c_one
    assert best.char_c == pytest.approx(2.13, abs=0.06)
    assert best.process.tau_s == pytest.approx(20.0, rel=0.05)


def test_load_periods_ranked_with_the_coarse_grid():
    # published seed 1003: the plain fit is an integrating process that follows the load through OP;
    # a load added to it helps at no period (the true one ranks last on it), the coarse valve x
    # dynamics grid with the load ranks the true period first
    rec, truth = concealed_loop("external_disturbance", 1003, n=3000)
    train = np.zeros(rec.n, bool)
    train[60:1950] = True
    stage = Stage("loop", np.asarray(rec.op, float), np.asarray(rec.pv, float), rec.ts_s, train)
    plain = Structure.plain(2.926, 1.219, 1, ProcessModel("integrating", 1.0, 14.9, 0.0, 0.0))
    plain = plain.replace(y0_pct=35.48)
    hyp = REGISTRY["external_disturbance"]
    y_hat, _, _ = predict(stage, plain)
    periods = hyp.candidate_periods(stage, PlainModel(plain, limit_cycle_period_s=truth["limit_cycle_period_s"],
                                                      residual=stage.y - y_hat))
    ranked = hyp.rank_periods(stage, plain, periods)
    assert ranked[0][1].period_s == pytest.approx(truth["period_s"], rel=0.02)
    on_plain = [float(train_sse(stage, [st])[0]) for _, st, _ in ranked]
    assert on_plain[0] > min(on_plain[1:])


def test_loop_stage_carries_the_controllers_sign():
    from diagnose.physics.explain import _stage_for

    rec, _ = concealed_loop("none", 5, n=1500)
    train = np.zeros(rec.n, bool)
    train[:1000] = True
    assert _stage_for(rec, "loop", train).gain_sign == 1
    # the same loop on a process whose PV falls as the valve opens (direct-acting controller)
    flipped = rec.replace(pv=-rec.pv, sp=-rec.sp)
    assert _stage_for(flipped, "loop", train).gain_sign == -1


def test_a_fraction_of_span_op_is_explained_in_percent_of_span():
    """OP logged as a fraction (0..1) with no stem position: explained as identify reads it, with
    OP x 100, so the valve's parameters come out in % of span and the warning says so."""
    from diagnose.record import LoopRecord

    rec, truth = concealed_loop("asymmetric_stiction", 11, n=1500)
    pct = LoopRecord(name="L", ts_s=rec.ts_s, op=rec.op, pv=rec.pv, sp=rec.sp)
    frac = LoopRecord(name="L", ts_s=rec.ts_s, op=rec.op / 100.0, pv=rec.pv, sp=rec.sp)
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")     # the explanations' own warnings are checked below
        a = explain(pct, hypotheses=["asymmetric_stiction"], threads=1)
        b = explain(frac, hypotheses=["asymmetric_stiction"], threads=1)
    pa, pb = a.hypotheses[0].params, b.hypotheses[0].params
    assert pa["S_open_pct"] > 0.5      # the valve's band in % of span ...
    for k in ("S_open_pct", "J_open_pct", "S_close_pct", "J_close_pct"):
        assert pb[k] == pytest.approx(pa[k], rel=0.02, abs=1e-3), k    # ... from the fraction too
    assert b.missing_physics == a.missing_physics
    (note,) = [w for w in b.warnings if w.code == "op_rescaled"]
    assert "fraction of span" in note.message and "% of span" in note.message
    assert not any(w.code == "op_rescaled" for w in a.warnings)


def test_concealed_twin_differs_only_by_the_effect():
    rec, _ = concealed_loop("asymmetric_stiction", 7, n=800, with_mv=True)
    twin, _ = concealed_loop("asymmetric_stiction", 7, n=800, with_mv=True, apply_effect=False)
    clean_like, _ = concealed_loop("actuator_lag", 7, n=800, with_mv=True, apply_effect=False)
    assert not np.array_equal(rec.pv, twin.pv)
    # same plant, controller, loads and noise: the two effect-free twins are the same record
    assert np.array_equal(twin.pv, clean_like.pv) and np.array_equal(twin.mv, clean_like.mv)


def test_plant_parts_hide_their_effect():
    x = _walk(3000, 4)
    plain = stiction_batch(x, [3.0], [1.0], [1])[0]
    lag = LaggedValve(3.0, 1.0, 4.0)
    y_lag = np.array([lag.reset(x[0])] + [lag.step(v) for v in x[1:]])
    # the lag smooths jumps: the largest one-sample move shrinks
    assert np.abs(np.diff(y_lag)).max() < 0.6 * np.abs(np.diff(plain)).max()
    asym = AsymmetricStictionValve(4.0, 1.0, 1.0, 0.5)
    y_a = np.array([asym.reset(x[0])] + [asym.step(v) for v in x[1:]])
    assert not np.array_equal(y_a, stiction_batch(x, [4.0], [1.0], [1])[0])
    drift = DriftingStictionValve(1.0, 0.5, dS_pct_per_s=2e-3, dJ_pct_per_s=1e-3)
    y_d = np.array([drift.reset(x[0])] + [drift.step(v) for v in x[1:]])
    # friction grows: the valve sits stuck more of the time late in the record
    still = np.diff(y_d) == 0
    assert still[2000:].mean() > still[:1000].mean()
    proc = CharacteristicProcess(make_process("foptd", gain=1.0, tau_s=5.0, delay_s=0.0), R=20.0)
    assert proc.reset(50.0, 1.0) == pytest.approx(equal_percentage(50.0, 20.0))
    with pytest.raises(DataError, match="rangeability"):
        CharacteristicProcess(make_process("foptd", gain=1.0, tau_s=20.0, delay_s=2.0), R=0.5)


def test_characteristic_is_affine_in_the_plant_equal_percentage():
    y = np.linspace(0, 100, 51)
    c = math.log(25.0)
    ours = characteristic(y, c)
    plant = np.array([equal_percentage(v, 25.0) for v in y])
    A = np.column_stack([ours, np.ones_like(ours)])
    coef, res, *_ = np.linalg.lstsq(A, plant, rcond=None)
    assert np.allclose(A @ coef, plant, atol=1e-9)
    assert characteristic(y, 0.0)[10] == y[10]


# --- localisation -----------------------------------------------------------------------------------

def test_locate_finds_slips_direction_and_a_foreign_peak():
    n, ts = 4000, 1.0
    t = np.arange(n)
    # a stem that jumps every 50 samples, alternating direction (limit cycle of 100 s)
    stem = np.repeat(np.where(np.arange(n // 50) % 2 == 0, 40.0, 44.0), 50)
    rng = np.random.default_rng(0)
    r = rng.normal(0, 0.1, n)
    slips = np.flatnonzero(np.diff(stem)) + 1
    for s in slips:
        r[s:s + 3] += 1.0                         # energy just after slips
    r[(t // 50) % 2 == 1] += 0.3                  # residual mean depends on direction
    r += 0.5 * np.sin(2 * np.pi * t / 37.0)       # a load at 37 s, not a harmonic of 100 s
    m = locate(r, stem, stem, ts, response_s=0.0)
    assert m.events.n_slips == slips.size
    assert m.events.after_slip_energy_ratio > 2.0
    assert abs(m.direction.mean_difference) > 0.2
    assert m.frequency.limit_cycle_period_s == pytest.approx(100.0)
    assert m.frequency.residual_peak_period_s == pytest.approx(37.0, rel=0.03)
    assert not m.frequency.peak_at_limit_cycle_harmonic
    d = m.to_dict()
    json.dumps(d, allow_nan=False)
    assert d["events"]["n_slips"] == slips.size and d["direction"]["opening"]["n"] > 10


def test_locate_marks_a_drifting_residual_and_its_windows():
    n = 3000
    rng = np.random.default_rng(1)
    r = rng.normal(0, 0.1, n) * np.linspace(0.5, 4.0, n)
    stem = np.full(n, 50.0)
    m = locate(r, stem, stem + rng.normal(0, 1, n), 1.0)
    assert m.drift.last_over_first > 2.0
    assert m.windows and m.windows[0].start_s > 1500


# --- hypothesis registry contract ---------------------------------------------------------------------

@pytest.fixture(scope="module")
def small_stage():
    rec, truth = concealed_loop("none", 7, n=1500)
    n = rec.n
    train = np.zeros(n, bool)
    train[100:1000] = True
    stage = Stage("loop", rec.op, rec.pv, rec.ts_s, train)
    proc = ProcessModel("foptd", truth["gain"], truth["tau_s"], truth["delay_s"], 0.0)
    ref, sse = refine_plain(stage, Structure.plain(truth["S_pct"], truth["J_pct"], 1, proc), rounds=1)
    return stage, ref, sse


def test_registry_holds_the_five_hypotheses():
    assert {"actuator_lag", "asymmetric_stiction", "valve_characteristic", "external_disturbance",
            "time_varying_friction"} <= set(REGISTRY)
    with pytest.raises(ValueError, match="already registered"):
        register(REGISTRY["actuator_lag"])


@pytest.mark.parametrize("name", sorted(REGISTRY))
def test_every_registered_hypothesis_keeps_the_contract(name, small_stage):
    stage, ref, ref_sse = small_stage
    h = REGISTRY[name]
    assert isinstance(h, PhysicsHypothesis)
    assert h.name == name and h.param_names and h.n_extra >= 1 and h.side in ("valve", "process")
    fitted = h.fit(stage, PlainModel(ref))
    assert fitted.name == name and fitted.stage == "loop"
    assert set(h.param_names) <= set(fitted.params)
    assert all(isinstance(v, float) for v in fitted.params.values())
    with pytest.raises(TypeError):
        fitted.params["x"] = 1.0          # results are read-only
    # the augmented model nests the plain one: its search must not train (much) worse
    assert fitted.train_sse <= ref_sse * 1.02
    assert fitted.train_sse == pytest.approx(train_sse(stage, [fitted.structure])[0], rel=1e-6)
    y_hat, _, _ = predict(stage, fitted.structure)
    assert y_hat.shape == (stage.n,) and np.all(np.isfinite(y_hat))
    # polished again from a plain model that trains better (S nudged onto a better plain fit): no
    # worse than that plain model, and never worse than the fit it starts from
    better, better_sse = refine_plain(stage, ref.replace(S_up_pct=ref.S_up_pct * 1.03, S_dn_pct=ref.S_dn_pct * 1.03))
    again = h.refit(stage, fitted, PlainModel(better))
    assert again.name == name and set(h.param_names) <= set(again.params)
    assert again.train_sse <= min(better_sse, ref_sse) * (1 + 1e-9)
    assert again.train_sse == pytest.approx(train_sse(stage, [again.structure])[0], rel=1e-6)


def test_hypotheses_refuse_a_stage_they_cannot_test(small_stage):
    stage, ref, _ = small_stage
    vstage = Stage("valve", stage.x, stage.x, stage.ts_s, stage.train)
    with pytest.raises(DataError, match="cannot be tested"):
        REGISTRY["external_disturbance"].fit(vstage, PlainModel(ref))


# --- explain on concealed data (a few records; the benchmark runs many) -------------------------------

def _check_json(ex):
    d = ex.to_dict()
    assert KEYS <= set(d)
    text = json.dumps(d, allow_nan=False)
    back = json.loads(text)
    for h in back["hypotheses"]:
        assert {"name", "params", "heldout_rmse", "accepted"} <= set(h)
    if back["missing_physics"] is None:
        assert back["improved_rmse"] == back["baseline_rmse"]
    else:
        assert back["improved_rmse"] < back["baseline_rmse"]
    return back


def test_explain_leaves_a_clean_loop_alone():
    from diagnose.physics import ExplainWarning, HypothesisResult, StageMismatch

    rec, _ = concealed_loop("none", 3, n=1500)
    ex = explain(rec, target="pv")
    d = _check_json(ex)
    # typed results: the JSON is to_dict() of the frozen objects, nothing else
    assert isinstance(ex.mismatch, StageMismatch) and all(isinstance(h, HypothesisResult) for h in ex.hypotheses)
    assert d["mismatch"]["reference_rmse"] == pytest.approx(ex.mismatch.reference_rmse)
    assert d["mismatch"]["windows"] == [w.to_dict() for w in ex.mismatch.windows]
    assert [h["name"] for h in d["hypotheses"]] == [h.name for h in ex.hypotheses]
    note = ExplainWarning("segments", "the longest segment was explained")
    more = ex.with_warnings((note,))
    assert more.warnings[0] == note and more.warnings[1:] == ex.warnings
    assert more.to_dict()["warnings"][0] == {"code": "segments", "message": "the longest segment was explained"}
    with pytest.raises(AttributeError):
        ex.missing_physics = "actuator_lag"   # frozen
    assert d["missing_physics"] is None
    assert not any(h["accepted"] for h in d["hypotheses"])
    # each refused hypothesis says which rule refused it, and the explanation quotes the best one's
    assert all(h["refused"] for h in d["hypotheses"])
    best = min(d["hypotheses"], key=lambda h: h["heldout_rmse"])
    assert f"refused: {best['refused']}." in ex.explanation


@pytest.mark.parametrize("effect,seed,with_mv,n", [
    ("asymmetric_stiction", 100, True, 3000),
    ("time_varying_friction", 101, False, 3000),
    ("valve_characteristic", 100, False, 2000),
])
def test_explain_names_a_concealed_effect_and_the_error_falls(effect, seed, with_mv, n):
    rec, truth = concealed_loop(effect, seed, n=n, with_mv=with_mv)
    # with MV: the valve stage alone (tests/test_explain_cli.py runs the same record with "auto")
    ex = explain(rec, target="mv" if with_mv else "pv")
    d = _check_json(ex)
    assert d["missing_physics"] == effect
    assert all((h["refused"] == "") == h["accepted"] for h in d["hypotheses"])
    assert d["improved_rmse"] < 0.7 * d["baseline_rmse"]
    fd = ex.figure_data()
    assert fd["observed"].shape == fd["improved"].shape == (rec.n,)
    assert 0 < fd["train_end_s"] < rec.duration_s
    # the localisation's arrays reach the drawing code under their own names
    assert "mismatch" not in fd and fd["window_rms"].shape == fd["window_t_s"].shape
    assert fd["window_rms"] is ex.arrays.mismatch.window_rms


def test_explain_scales_a_fraction_op_by_the_stem_position():
    # OP logged 0..1 beside a stem in %: explain scales it as identify does, so the valve stage
    # sees OP -> MV in one unit and the concealed asymmetry is still named, S in % of span
    rec, truth = concealed_loop("asymmetric_stiction", 100, n=3000, with_mv=True)
    frac = rec.replace(op=rec.op / 100.0)
    ex = explain(frac, target="mv", hypotheses=["asymmetric_stiction"])
    assert "op_rescaled" in {w.code for w in ex.warnings}
    assert ex.missing_physics == "asymmetric_stiction"
    (valve,) = ex.stages
    assert valve.baseline.S_up_pct == pytest.approx(max(truth["S_open_pct"], truth["S_close_pct"]), rel=0.6)
    # in % already: nothing scaled, nothing said
    assert "op_rescaled" not in {w.code for w in explain(rec, target="mv", hypotheses=["asymmetric_stiction"]).warnings}


def test_a_healthy_sample_loop_is_left_alone_without_an_unexplained_warning():
    # FIC101: a healthy valve whose stem follows OP exactly and a PV that is mostly noise. The
    # residual is the noise, so nothing is unexplained, and an exact stem model leaves nothing to
    # improve: no relative change of the stem's error may read as millions of per cent
    from pathlib import Path

    import diagnose

    (rec,) = diagnose.read_loops(Path(__file__).resolve().parents[1] / "sample_logs" / "FIC101.csv")
    ex = explain(rec)
    assert ex.missing_physics is None
    assert "physics.unexplained" not in {w.code for w in ex.warnings}
    mv = [h for h in ex.hypotheses if h.stage == "valve"]
    assert mv and all(abs(h.reduction) < 0.05 for h in mv)
    assert "-0 %" not in ex.explanation


def test_a_noise_free_stem_keeps_its_exact_reference():
    # FIC103: a sticky valve whose recorded stem is exactly the two-parameter model of OP. The exact
    # plain valve must stay the valve stage's reference (the searches' scores have a rounding floor
    # far above its error: a refit that looks a hair better there predicts the stem worse), and
    # its held-out prediction is the fit itself, not an average over sets the data rule out
    import diagnose

    (rec,) = diagnose.read_loops(Path(__file__).resolve().parents[1] / "sample_logs" / "FIC103.csv")
    ex = explain(rec)
    (valve,) = [o for o in ex.mismatch.other_stages if o.stage == "valve"]
    assert valve.baseline_rmse < 1e-9 and valve.reference_rmse < 1e-9
    assert ex.missing_physics is None


def test_explain_rejects_what_it_cannot_use():
    rec, _ = concealed_loop("none", 1, n=200)
    with pytest.raises(DataError, match="at least"):
        explain(rec)
    rec, _ = concealed_loop("none", 1, n=600)
    with pytest.raises(DataError, match="stem position"):
        explain(rec, target="mv")
    with pytest.raises(DataError, match="unknown hypothesis"):
        explain(rec, hypotheses=["gremlins"])
    with pytest.raises(DataError, match="train_fraction"):
        explain(rec, train_fraction=0.99)


def test_explain_reuses_an_identification():
    # the identification a caller already has is the baseline: its valve, process and start state,
    # not a second fit on the training part
    from diagnose.identification import identify
    from diagnose.physics.baseline import from_hammerstein

    rec, _ = concealed_loop("time_varying_friction", 101, n=3000)
    ident = identify(rec)
    ex = explain(rec, target="pv", hypotheses=["time_varying_friction"], identification=ident)
    assert ex.baseline_source == "identify"
    (loop,) = ex.stages
    assert loop.baseline == from_hammerstein(ident.fit)
    assert ex.missing_physics == "time_varying_friction"


def test_concealed_generator_is_seeded_and_complete():
    for e in EFFECTS:
        a, ta = concealed_loop(e, 5, n=400)
        b, tb = concealed_loop(e, 5, n=400)
        assert np.array_equal(a.pv, b.pv) and ta == tb and ta["effect"] == e
    with pytest.raises(DataError, match="unknown effect"):
        concealed_loop("gremlins", 0)


def _true_stem(rec, seed):
    # the generator adds N(0, 0.1) % measurement noise to the simulated stem from seed + 3
    return rec.mv - np.random.default_rng(seed + 3).normal(0.0, 0.1, rec.n)


def test_concealed_generator_draws_a_stuck_valve_again():
    from diagnose.physics.locate import slips_and_reversals

    def moves(stem):
        return slips_and_reversals(stem, eps=0.01)[0].size

    moves_needed = (0.65, 10, 5)
    # drift seed 5002: friction grows until the valve sticks where PV meets the setpoint, for good
    raw, _ = concealed_loop("time_varying_friction", 5002, n=3000, with_mv=True)
    assert moves(_true_stem(raw, 5002)[:1950]) < 10
    rec, truth = concealed_loop("time_varying_friction", 5002, n=3000, with_mv=True, min_moves=moves_needed)
    assert truth["draw"] >= 1 and truth["seed"] == 5002
    stem = _true_stem(rec, 5002 * 1000 + truth["draw"])
    assert moves(stem[:1950]) >= 10 and moves(stem[1950:]) >= 5
    twin, _ = concealed_loop("time_varying_friction", 5002, n=3000, with_mv=True, apply_effect=False,
                             min_moves=moves_needed)
    assert np.array_equal(twin.sp, rec.sp) and not np.array_equal(twin.mv, rec.mv)
    # a draw whose valve moves is kept as it is
    a, ta = concealed_loop("none", 5001, n=3000, with_mv=True)
    b, tb = concealed_loop("none", 5001, n=3000, with_mv=True, min_moves=moves_needed)
    assert tb["draw"] == 0 and np.array_equal(a.pv, b.pv) and np.array_equal(a.mv, b.mv)


def test_explain_warns_when_the_valve_never_moves():
    stuck, _ = concealed_loop("time_varying_friction", 5002, n=3000, with_mv=True)
    ex = explain(stuck, target="mv", hypotheses=["actuator_lag"])
    idle = [w for w in ex.warnings if w.code == "physics.valve_idle"]
    assert len(idle) == 1 and "0 times in the training part" in idle[0].message
    moving, _ = concealed_loop("time_varying_friction", 5002, n=3000, with_mv=True, min_moves=(0.65, 10, 5))
    ex = explain(moving, target="mv", hypotheses=["actuator_lag"])
    assert not any(w.code == "physics.valve_idle" for w in ex.warnings)


def test_physics_models_hold_the_controllers_gain_sign():
    # PV that falls as OP rises, as through a reverse-acting controller (PV = -OP / Kc): a plant
    # with a positive gain (the controller's action says so) cannot explain it
    rng = np.random.default_rng(4)
    x = _walk(1200, seed=4)
    y = 20.0 - 0.5 * x + rng.normal(0, 0.05, x.size)
    train = np.zeros(x.size, bool)
    train[:800] = True
    plain = Structure.plain(0.0, 0.0, 1, ProcessModel("foptd", 1.0, 0.0, 0.0, 0.0))
    free = Stage(name="loop", x=x, y=y, ts_s=1.0, train=train, gain_sign=0)
    held = Stage(name="loop", x=x, y=y, ts_s=1.0, train=train, gain_sign=1)
    _, _, coef_free = predict(free, plain)
    _, _, coef_held = predict(held, plain)
    assert coef_free[0] == pytest.approx(-0.5, abs=0.01)
    assert coef_held[0] == 0.0
    # the compiled training error agrees with the prediction: the mean of PV, no valve term
    y_hat, _, _ = predict(held, plain)
    sse_held = float(np.sum((y - y_hat)[train] ** 2))
    assert train_sse(held, [plain])[0] == pytest.approx(sse_held, rel=1e-6)
    assert sse_held == pytest.approx(float(np.sum((y[train] - y[train].mean()) ** 2)), rel=1e-9)
    assert train_sse(free, [plain])[0] < 0.01 * sse_held


def test_installed_characteristic_found_from_a_plain_fit_that_ratchets():
    # blind seed 6003: the plain fit bends to S 37 %, J 68 % (a valve that ratchets between the
    # setpoint's operating points); the characteristic's search starts from the coarse grid too
    rec, truth = concealed_loop("valve_characteristic", 6003, n=3000, min_moves=(0.65, 10, 5))
    ex = explain(rec, target="pv", hypotheses=["valve_characteristic"])
    assert ex.missing_physics == "valve_characteristic"
    (h,) = ex.hypotheses
    assert 3.0 < h.params["rangeability_R"] < 12.0 and truth["rangeability_R"] == pytest.approx(6.05, abs=0.01)
    assert ex.improved_rmse < 0.2 * ex.mismatch.reference_rmse


def test_asymmetry_from_op_pv_is_polished_with_the_dynamics():
    # fresh seed 5001 (OP/PV): without the loop-stage fine polish the asymmetric fit is refused (in
    # the full benchmark run it trained worse than the plain reference and a drift was named)
    rec, _ = concealed_loop("asymmetric_stiction", 5001, n=3000, min_moves=(0.65, 10, 5))
    ex = explain(rec, target="pv", hypotheses=["asymmetric_stiction"])
    assert ex.missing_physics == "asymmetric_stiction"
    assert ex.improved_rmse < 0.8 * ex.mismatch.reference_rmse


# --- judged by the posterior-predictive mean ----------------------------------------------------------

def _valve_stage(n=1500, seed=13, noise=0.1, **kw):
    x = _walk(n, seed)
    rng = np.random.default_rng(seed)
    y = augmented_valve(x, ts_s=1.0, **kw) + rng.normal(0, noise, n)
    train = np.zeros(n, bool)
    train[:int(0.65 * n)] = True
    return Stage("valve", x, y, 1.0, train)


def test_predictive_mean_is_seeded_and_keeps_a_plain_model_plain():
    from diagnose.physics.posterior import _build, _free_parameters, predictive_mean

    stage = _valve_stage(S_up=3.0, J_up=1.0, f0=1)
    plain = Structure.plain(3.0, 1.0, 1, ProcessModel("foptd", 1.0, 0.0, 0.0, 0.0))
    a = predictive_mean(stage, plain, 50.0)
    b = predictive_mean(stage, plain, 50.0)
    assert np.array_equal(a.y_hat, b.y_hat) and a.y_hat.shape == (stage.n,)
    names, p0, scales = _free_parameters(plain, stage)
    assert names == ["S", "J"] and np.all(scales > 0)
    draws = _build(plain, names, np.vstack([p0 * 1.1, p0 * 0.9]))
    assert len(draws) == 2 and draws[1].S_up_pct == pytest.approx(0.9 * p0[0])
    for drawn in draws:
        assert drawn.S_up_pct == drawn.S_dn_pct and drawn.J_up_pct == drawn.J_dn_pct
    asym = plain.replace(S_dn_pct=2.0, dS_pct_per_s=1e-4, dJ_pct_per_s=2e-5)
    names, p0, _ = _free_parameters(asym, stage)
    assert names == ["S", "S_dn", "J", "dS", "dJ"]
    assert _build(asym, names, p0[None])[0].S_dn_pct == 2.0


def test_predictive_mean_averages_only_what_the_training_data_leave_free():
    # a sharp likelihood (a pinned valve): the average collapses onto one or two sets that train as
    # well as the fit (scored after the valve's first slip, the best set there need not be the fit
    # itself); the same fit with almost no independent training residuals (flat likelihood) averages
    # many visibly other valves
    from diagnose.physics.posterior import predictive_mean

    stage = _valve_stage(S_up=3.0, J_up=1.0, f0=1, noise=0.05)
    plain, _ = fit_initial_state(stage, Structure.plain(3.0, 1.0, 1, ProcessModel("foptd", 1.0, 0.0, 0.0, 0.0)))
    point, _, _ = predict(stage, plain)
    tr = stage.train
    fit_rmse = np.sqrt(np.mean((stage.y - point)[tr] ** 2))
    sharp = predictive_mean(stage, plain, 1e6)
    flat = predictive_mean(stage, plain, 1.0)
    # (ess, not the count of distinct picks, measures the collapse: 64 picks by weight can touch a
    # few sets of tiny weight, and how many depends on the last bits of the linear algebra)
    assert sharp.ess < 3.0 and sharp.n_distinct <= 6
    assert np.sqrt(np.mean((stage.y - sharp.y_hat)[tr] ** 2)) < 1.01 * fit_rmse
    assert flat.n_distinct > 30 and flat.ess > 50.0
    assert np.sqrt(np.mean((flat.y_hat - point) ** 2)) > 0.04


def test_drift_with_the_stem_is_named_by_its_predictive_mean():
    # fresh seed 5001 with MV (friction falling by 59 %): the drift fit trains at the MV noise, as
    # the true model does, but its rate is 8 % off and that one parameter set extrapolates four
    # times worse than the truth; judged by its posterior-predictive mean it is named
    rec, truth = concealed_loop("time_varying_friction", 5001, n=3000, with_mv=True, min_moves=(0.65, 10, 5))
    ex = explain(rec, target="mv", hypotheses=["time_varying_friction"])
    assert ex.missing_physics == "time_varying_friction"
    (h,) = ex.hypotheses
    assert h.params["dS_pct_per_h"] < 0 and truth["dS_pct_per_h"] < 0
    assert ex.improved_rmse < 0.8 * ex.mismatch.reference_rmse


def test_memory_burn_leaves_out_the_start_until_the_valve_has_slipped():
    # a valve held stuck at the start by its initial state: the draws are scored only after the
    # cloud has slipped (plus the process response), so the fitted initial state of the centre does
    # not penalise sets far along a ridge; a valve that slips at once loses only those samples
    from diagnose.physics.posterior import _memory_burn

    n = 1500
    x = np.concatenate([np.full(300, 50.0), 50.0 + 8.0 * np.sin(np.arange(n - 300) * 2 * np.pi / 100)])
    train = np.zeros(n, bool)
    train[:1200] = True
    stage = Stage("valve", x, x.copy(), 1.0, train)
    stuck = Structure.plain(3.0, 1.0, 1, ProcessModel("foptd", 1.0, 0.0, 0.0, 0.0))
    cands = [stuck.replace(S_up_pct=s, S_dn_pct=s) for s in (2.5, 3.0, 3.5)]
    w = np.full(3, 1 / 3)
    burnt = _memory_burn(stage, cands, w)
    first = int(np.argmax(burnt.train))
    assert 300 < first < 330 and burnt.train[first:1200].all() and not burnt.train[1200:].any()
    moving = Stage("valve", x[300:], x[300:].copy(), 1.0, train[:n - 300])
    assert int(np.argmax(_memory_burn(moving, cands, w).train)) < 10


def test_asymmetry_along_a_ridge_is_named_by_its_predictive_mean():
    # fresh seed 5003 (OP/PV): the asymmetric fit (S open 2.5 % against the true 1.8 %) trains as
    # well as the true valve, along a ridge of equally good fits whose held-out errors run from 0.37
    # to 0.13; its own prediction is worse than the plain reference on the held-out part. Averaged
    # along the ridge (adaptive rounds, scored after the valve has forgotten its initial state) it
    # is named
    rec, _ = concealed_loop("asymmetric_stiction", 5003, n=3000, min_moves=(0.65, 10, 5))
    ex = explain(rec, target="pv", hypotheses=["asymmetric_stiction"])
    assert ex.missing_physics == "asymmetric_stiction"
    assert ex.improved_rmse < 0.8 * ex.mismatch.reference_rmse


# --- searched jointly with the process dynamics from OP/PV ---------------------------------------------

def _repo_on_path() -> Path:
    """The repository root, on sys.path so that `benchmarks` imports (the tests use its
    independent simulator and scripts); returned for tests that need its files."""
    root = Path(__file__).resolve().parents[1]
    if str(root) not in sys.path:
        sys.path.insert(0, str(root))
    return root


def _named_from_op_pv(effect, seed):
    """explain on one concealed OP/PV record with only the hidden effect's hypothesis: named, with
    the held-out error well below the plain reference's; returns (hypothesis result, truth)."""
    rec, truth = concealed_loop(effect, seed, n=3000, min_moves=(0.65, 10, 5))
    ex = explain(rec, target="pv", hypotheses=[effect])
    assert ex.missing_physics == effect
    assert ex.improved_rmse < 0.6 * ex.mismatch.reference_rmse
    (h,) = ex.hypotheses
    return h, truth


def test_drift_from_op_pv_is_searched_with_the_dynamics():
    # concealed drift 5004 (OP/PV; S rising from 10.3 % by 5.5 %/h): the plain fit's process (a
    # 7 s lag) cannot carry the drifting valve, and the drift searched from it trains at SSE 37
    # against the plain 38 (refused); the joint grid of drifting valves x dynamics finds the basin
    h, truth = _named_from_op_pv("time_varying_friction", 5004)
    assert abs(h.params["dS_pct_per_h"] / truth["dS_pct_per_h"] - 1.0) < 0.2


def test_a_drifting_deadband_is_found_from_op_pv():
    # plantsim's concealed drift 42001 (OP/PV, 8000 samples): a deadband valve (J = 0) whose S
    # rises 2.36-fold over the record. The drift search's J/S candidates must hold 0: its local
    # polish scales J and cannot reach 0 from a J/S of 0.2, and from there it trained to a drift a
    # third of the truth's, refused on the held-out part
    _repo_on_path()
    from benchmarks.plantsim import concealed
    from diagnose.record import LoopRecord

    loop = concealed("time_varying_friction", 42001, n=8000)
    assert loop.meta["J_pct"] == 0.0
    true_rate = loop.meta["S_pct"] * loop.meta["tvf_change"] / (loop.n * loop.ts_s) * 3600.0
    rec = LoopRecord(name=loop.name, ts_s=loop.ts_s, op=loop.op, pv=loop.pv, sp=loop.sp)
    ex = explain(rec, target="pv", hypotheses=["time_varying_friction"])
    assert ex.missing_physics == "time_varying_friction"
    (h,) = ex.hypotheses
    assert h.params["J_start_pct"] < 0.2
    assert abs(h.params["dS_pct_per_h"] / true_rate - 1.0) < 0.25


def test_asymmetry_from_op_pv_is_searched_on_a_global_grid():
    # concealed asymmetry 1002 (OP/PV; J/S 0.49 opening, 0.94 closing): from the coarse grid's
    # one J/S for both sides the search trained at SSE 185 and was refused; from the global
    # (S_open, S_close, J/S each side) grid it is named. How far the opening/closing ratio lands
    # from the truth's 3.0 hangs on the plain fit it starts from (1.3 and 4.5 from two equally good
    # plain fits); the side that sticks more is found either way
    h, truth = _named_from_op_pv("asymmetric_stiction", 1002)
    assert h.params["S_open_pct"] > 1.2 * h.params["S_close_pct"]
    assert truth["S_open_pct"] > 2.0 * truth["S_close_pct"]


def test_an_asymmetric_valve_with_slips_near_s_is_read_off_the_stem():
    # plantsim's concealed asymmetry 58001 with the stem recorded (0.1 % noise): Kano's valve with
    # no offset (J = S), S 4.44 % opening and 1.59 % closing. Each slip jumps the whole band, so 1 %
    # off in S on either side misplaces slips and the cost is a comb of narrow basins; the grids'
    # best points all lay outside the truth's (trained worse than a wrong valve with J/S 0.3 closing),
    # and the fit was refused. The bands read off the stem's slips start a polish into it
    _repo_on_path()
    from benchmarks.plantsim import concealed
    from diagnose.record import LoopRecord

    loop = concealed("asymmetric_stiction", 58001, n=8000)
    S, r = loop.meta["S_pct"], loop.meta["asym_ratio"]
    assert loop.meta["law"] == "kano" and loop.meta["J_pct"] == S and loop.meta["asym_weaker"] == "closing"
    mv = loop.mv + np.random.default_rng(1).normal(0.0, 0.1, loop.n)
    rec = LoopRecord(name=loop.name, ts_s=loop.ts_s, op=loop.op, pv=loop.pv, sp=loop.sp, mv=mv)
    ex = explain(rec, target="mv", hypotheses=["asymmetric_stiction"])
    assert ex.missing_physics == "asymmetric_stiction"
    (h,) = ex.hypotheses
    p = h.params
    assert p["S_open_pct"] == pytest.approx(S, rel=0.02) and p["J_open_pct"] == pytest.approx(S, rel=0.02)
    assert p["S_close_pct"] == pytest.approx(S * r, rel=0.02) and p["J_close_pct"] == pytest.approx(S * r, rel=0.03)
    assert h.heldout_rmse < 0.3 * ex.mismatch.reference_rmse


def test_a_completed_friction_step_outranks_an_asymmetry_on_the_training_part():
    # plantsim's concealed friction step 75000 with the stem recorded (0.1 % noise): a force-balance
    # stem whose friction changes in one step inside the training part. Both the step (judged on the
    # training part) and an asymmetry (on the held-out part) are accepted. The held-out part lies
    # after the step, where an asymmetry between the two friction levels predicts the valve as well,
    # so ranking on it named the asymmetry; on the training part the step explains far more
    _repo_on_path()
    from benchmarks.plantsim import concealed
    from diagnose.record import LoopRecord

    loop = concealed("time_varying_friction", 75000, n=8000)
    assert loop.meta["law"] == "force_balance" and loop.meta["tvf_shape"] == "step"
    mv = loop.mv + np.random.default_rng([75, 0, 5, 7]).normal(0.0, 0.1, loop.n)
    rec = LoopRecord(name=loop.name, ts_s=loop.ts_s, op=loop.op, pv=loop.pv, sp=loop.sp, mv=mv)
    ex = explain(rec, target="mv", hypotheses=["asymmetric_stiction", "time_varying_friction"])
    h = {x.name: x for x in ex.hypotheses}
    step, asym = h["time_varying_friction"], h["asymmetric_stiction"]
    assert step.accepted and asym.accepted
    # held-out ranking favours the asymmetry, training ranking the step
    assert asym.delta_bic < step.delta_bic and step.train_delta_bic < asym.train_delta_bic
    assert ex.missing_physics == "time_varying_friction"
    assert step.params["change_for_s"] == 1.0
    # the warning says why the better held-out prediction did not win
    (amb,) = [w for w in ex.warnings if w.code == "physics.ambiguous"]
    assert "after the friction step" in amb.message and "asymmetric_stiction" in amb.message


def test_a_friction_step_early_in_the_training_part_is_named_from_op_and_pv():
    # plantsim's concealed friction step 94000 from OP and PV alone: a Kano valve whose friction
    # grows 2.14-fold (S 2.67 -> 5.70 %) at 30 % of the record. The plain valve fitted on the whole
    # training part is the valve after the step; it stays stuck through the smaller cycles before
    # the step, and that stretch was dropped as an unknown initial state (up to half the training
    # part), so the step left no trace to fit. Dropped now only for a few of the loop's cycles,
    # the step is found, and with the held-out part lying after it, judged on the training part
    _repo_on_path()
    from benchmarks.plantsim import concealed
    from diagnose.record import LoopRecord

    loop = concealed("time_varying_friction", 94000, n=8000)
    m = loop.meta
    assert m["law"] == "kano" and m["tvf_shape"] == "step" and m["tvf_step_at_fraction"] < 0.65 * 0.5
    S0, S1, at_s = m["S_pct"], m["S_pct"] * (1.0 + m["tvf_change"]), m["tvf_step_at_fraction"] * loop.n * loop.ts_s
    rec = LoopRecord(name=loop.name, ts_s=loop.ts_s, op=loop.op, pv=loop.pv, sp=loop.sp)
    ex = explain(rec, target="pv", hypotheses=["time_varying_friction"])
    assert ex.missing_physics == "time_varying_friction"
    (h,) = ex.hypotheses
    p = h.params
    assert h.evidence == "training" and p["change_for_s"] == loop.ts_s
    assert p["S_start_pct"] == pytest.approx(S0, rel=0.02) and p["S_end_pct"] == pytest.approx(S1, rel=0.02)
    assert abs(p["change_from_s"] - at_s) <= 30.0
    # the scored training part starts within the first cycles, well before the step
    assert ex.figure_data()["train_start_s"] < 0.2 * at_s


def test_the_loop_stages_start_is_forgotten_after_a_few_cycles_of_its_valve():
    from diagnose.physics.explain import FORGET_PERIODS, _state_forgotten

    ts, n = 2.0, 3000
    t = np.arange(n) * ts
    op = 50.0 + 3.0 * np.sin(2 * np.pi * t / 80.0)
    train = np.zeros(n, bool)
    train[: int(0.65 * n)] = True
    stage = Stage(name="loop", x=op, y=op.copy(), ts_s=ts, train=train, gain_sign=1)
    proc = ProcessModel(kind="foptd", gain=1.0, tau_s=10.0, delay_s=4.0, bias=0.0)
    s = Structure(S_up_pct=1.0, J_up_pct=0.5, S_dn_pct=1.0, J_dn_pct=0.5, process=proc)
    # a valve that reverses every half of an 80 s cycle: three cycles and the process's response
    cycling = np.round(op)
    assert _state_forgotten(stage, cycling, s) == pytest.approx(FORGET_PERIODS * 80.0 / ts + (4.0 + 20.0) / ts, abs=2)
    # a valve that reverses fewer than five times is no cycle to count: the start is not capped
    still = np.where(t < 1000.0, 50.0, np.where(t < 2000.0, 52.0, 51.0))
    assert _state_forgotten(stage, still, s) == n


def test_a_force_balance_stems_pressure_lag_is_named_before_the_friction():
    # plantsim's concealed actuator lag 42000 with the stem recorded (0.1 % noise): a force-balance
    # stem whose actuator pressure lags OP by 2.7 s (its own 0.25 s and the hidden 2.4 s), before the
    # friction. A lag after the friction smooths the stem's jumps, this one delays whole jumps: the
    # lag after was refused (held-out RMSE as the plain valve's) and nothing was named
    _repo_on_path()
    from benchmarks.plantsim import concealed
    from diagnose.record import LoopRecord

    loop = concealed("actuator_lag", 42000, n=8000)
    assert loop.meta["law"] == "force_balance" and loop.meta["lag_at"] == "before"
    tau = loop.meta["tau_p_s"] + loop.meta["effect_size"] * loop.ts_s
    mv = loop.mv + np.random.default_rng([42, 0, 1, 7]).normal(0.0, 0.1, loop.n)
    rec = LoopRecord(name=loop.name, ts_s=loop.ts_s, op=loop.op, pv=loop.pv, sp=loop.sp, mv=mv)
    ex = explain(rec, target="mv", hypotheses=["actuator_lag"])
    assert ex.missing_physics == "actuator_lag"
    (h,) = ex.hypotheses
    assert h.params["lag_before_friction"] == 1.0 and h.params["tau_s"] == pytest.approx(tau, rel=0.15)
    assert h.reduction > 0.5
    assert "lag_before_friction" in ex.explanation


def test_an_external_load_far_below_the_residual_is_not_named():
    # clean 1003: a 413 s sinusoid of amplitude 0.03 (noise 0.13) fitted to the slow random-walk
    # load was named with a held-out fall of 41 % that came from the predictive mean, not the load
    hyp = REGISTRY["external_disturbance"]
    assert not hyp.material({"period_s": 413.0, "amplitude": 0.033}, 3000.0, 0.13)
    assert hyp.material({"period_s": 413.0, "amplitude": 0.5}, 3000.0, 0.13)
    rec, _ = concealed_loop("none", 1003, n=3000, min_moves=(0.65, 10, 5))
    ex = explain(rec, target="pv", hypotheses=["external_disturbance"])
    assert ex.missing_physics is None


def test_installed_characteristic_started_from_settled_operating_points():
    # blind seed 10005 (OP/PV; R 4.2): setpoint steps take the loop to operating points 20 % of
    # travel apart; the cost is a needle in c and the time constant (c off by 0.4: 30 times the
    # noise floor), so the coarse grid of c and dynamics started nowhere near it (the plain fit
    # ratchets with S 35 %). The operating points' means give c within 0.05 before any dynamics
    rec, truth = concealed_loop("valve_characteristic", 10005, n=3000, min_moves=(0.65, 10, 5))
    stage = Stage("loop", rec.op, rec.pv, rec.ts_s, np.arange(rec.n) < int(0.65 * rec.n))
    plain = Structure.plain(3.0, 1.0, 1, ProcessModel("foptd", 1.0, 15.0, 2.0, 0.0))
    cs = REGISTRY["valve_characteristic"].static_exponents(stage, plain, spread=(0.0,))
    assert len(cs) == 1 and abs(cs[0] - np.log(truth["rangeability_R"])) < 0.15
    # a record that settles at one operating point only gives no exponent
    flat = Stage("loop", rec.op[:600], rec.pv[:600], rec.ts_s, np.arange(600) < 500)
    assert REGISTRY["valve_characteristic"].static_exponents(flat, plain) == []
    h, _ = _named_from_op_pv("valve_characteristic", 10005)
    assert 2.5 < h.params["rangeability_R"] < 7.0


def test_actuator_lag_with_the_stem_polishes_j_with_the_lag():
    # blind seed 10004 with MV (lag 7.9 s, J 1.02 %): the one-at-a-time fine steps stopped at J
    # 0.865 (training SSE 20.19, the true valve 19.71; held out 0.48 against 0.10); S, J and the lag
    # polished together (after J/S profiled with the valve's starting state refit at each value)
    rec, truth = concealed_loop("actuator_lag", 10004, n=3000, with_mv=True, min_moves=(0.65, 10, 5))
    ex = explain(rec, target="mv", hypotheses=["actuator_lag"])
    assert ex.missing_physics == "actuator_lag"
    (h,) = ex.hypotheses
    assert abs(h.params["J_pct"] / truth["J_pct"] - 1.0) < 0.05
    assert abs(h.params["tau_s"] / truth["tau_lag_s"] - 1.0) < 0.05


@pytest.mark.parametrize("script", ["validate_physics", "validate_physics_plantsim", "bench_explain"])
def test_physics_benchmark_scripts_print_their_help(script, capsys):
    # argparse formats help strings with %: a bare "%" in one made --help crash with a TypeError
    import importlib

    _repo_on_path()
    mod = importlib.import_module(f"benchmarks.{script}")
    with pytest.raises(SystemExit) as exit_:
        mod.main(["--help"])
    assert exit_.value.code == 0
    assert "usage:" in capsys.readouterr().out


def test_plantsim_validation_lists_friction_steps_and_reads_record_specs(capsys):
    # --list-steps prints the friction-step records of a range of sets as --records arguments: each
    # is a time_varying_friction record whose friction changes in one step
    _repo_on_path()
    from benchmarks.plantsim import concealed
    from benchmarks.validate_physics_plantsim import _record_spec, main

    assert main(["--list-steps", "60-62", "--per-effect", "2", "--n", "1000"]) == 0
    specs = capsys.readouterr().out.split()
    assert specs == ["time_varying_friction:60:0", "time_varying_friction:62:1"]
    assert concealed("time_varying_friction", 60001, n=1000).meta["tvf_shape"] == "drift"
    assert _record_spec("asymmetric_stiction:57:2") == ("asymmetric_stiction", 57, 2)
    with pytest.raises(SystemExit, match="EFFECT:SET:INDEX"):
        _record_spec("asymmetric:57:2")
    with pytest.raises(SystemExit, match="FIRST-LAST"):
        main(["--list-steps", "60"])
    # --stem-only keeps the explains with the stem recorded: valve-side effects and clean records;
    # --pv-only those from OP/PV alone, every effect
    from argparse import Namespace

    from benchmarks.validate_physics_plantsim import MV_SETS, make_jobs

    args = Namespace(records=None, seed=90, per_effect=2, n=1000, restricted=False, mv_noise=0.1, stem_only=False,
                     pv_only=False)
    every = make_jobs(args, 1)
    stem = make_jobs(Namespace(**{**vars(args), "stem_only": True}), 1)
    pv = make_jobs(Namespace(**{**vars(args), "pv_only": True}), 1)
    assert len(every) == 2 * (6 + len(MV_SETS)) and len(stem) == 2 * len(MV_SETS)
    assert all(j[4] and j[0] in MV_SETS for j in stem) and set(stem) < set(every)
    assert len(pv) == 2 * 6 and not any(j[4] for j in pv) and set(pv) == set(every) - set(stem)
    args.records, args.stem_only = ["valve_characteristic:90:0", "none:90:1"], True
    assert [j[:5] for j in make_jobs(args, 1)] == [("none", 90, 1, 1000, True)]


def test_plantsim_validation_runs_the_baseline_tree_in_the_same_worker(monkeypatch):
    # the baseline tree's explain runs right after this tree's, in the same worker, so that the
    # two are timed under the same load
    _repo_on_path()
    import benchmarks.validate_physics_plantsim as v

    calls = []
    monkeypatch.setattr(v, "run_one", lambda job: calls.append(("this", job)) or {"named": "none"})
    monkeypatch.setattr(v, "run_baseline", lambda job, tree: calls.append((tree, job)) or {"named": "x"})
    job = ("none", 90, 0, 1000, False, False, 0.1, 1)
    assert v.run_pair(job) == ({"named": "none"}, None) and calls == [("this", job)]
    calls.clear()
    assert v.run_pair(job, baseline="/tree") == ({"named": "none"}, {"named": "x"})
    assert calls == [("this", job), ("/tree", job)]


def test_explain_benchmark_times_a_tree_without_the_independent_simulator(tmp_path):
    # a baseline tree may predate benchmarks/plantsim: the record is drawn by this checkout's
    root = _repo_on_path()
    from benchmarks.bench_explain import run_one

    (tmp_path / "diagnose").symlink_to(root / "diagnose")
    r = run_one(tmp_path, "none", 24000, False, 400, "1")
    assert set(r) == {"named", "wall_s", "cpu_s"} and r["cpu_s"] > 0


def test_the_fitting_stages_baseline_is_simulated_like_every_other_model():
    # the sample overshoot loop: on this training span the fitting stage picks an integrating
    # process with a slow polynomial load, which carried on past the training part misses the
    # held-out PV by many times its spread
    from diagnose import read_loops
    from diagnose.physics.baseline import make_baseline

    rec = read_loops(Path(__file__).resolve().parents[1] / "sample_logs" / "TIC105.csv")[0]
    n = len(rec.op)
    train = np.zeros(n, bool)
    train[322:int(round(0.65 * n))] = True
    stage = Stage(name="loop", x=np.asarray(rec.op, float), y=np.asarray(rec.pv, float), ts_s=rec.ts_s,
                  train=train, gain_sign=1)
    base = make_baseline(stage)
    assert base.source == "fit_hammerstein"
    y_hat, stem, _ = predict(stage, base.structure)
    assert np.allclose(base.y_hat, y_hat) and np.allclose(base.stem_hat, stem)
    ho = stage.heldout
    assert np.sqrt(np.mean((stage.y - base.y_hat)[ho] ** 2)) < 3.0 * np.std(stage.y[ho])


def test_the_text_picks_the_best_refused_hypothesis_by_its_relative_change_not_across_units():
    # the valve stage's RMSEs are in % of span, the loop stage's in PV units: a tiny MV RMSE is
    # not a better hypothesis than a PV one
    from types import SimpleNamespace

    from diagnose.physics import HypothesisResult
    from diagnose.physics.explain import _text

    def run(stage, rmse, red):
        h = HypothesisResult(name=f"h_{stage}", params={}, heldout_rmse=rmse, accepted=False, stage=stage,
                             train_rmse=rmse, reduction=red, delta_bic=1.0, n_extra=2, refused="some rule")
        plant = SimpleNamespace(process=SimpleNamespace(kind="foptd"))
        return SimpleNamespace(baseline=SimpleNamespace(source="fit_hammerstein", structure=plant), ref_rmse=1.0,
                               stage=SimpleNamespace(name=stage), reference=plant,
                               mismatch=SimpleNamespace(hints=()), fitted=[(None, None, h)])

    runs = {"loop": run("loop", 0.5, 0.30), "valve": run("valve", 1e-5, 0.02)}
    text = _text(SimpleNamespace(name="X"), None, runs, "loop", 1.0, 1.0)
    assert "(h_loop) changes the held-out RMSE of PV by -30 %" in text and "h_valve" not in text


def _stem_loop(valve, *, gain: float, tau_s: float, rng_seed: int, seed: int, mv_noise: float, n: int = 3000):
    """A PI loop on FOPTD (dead time 2 s, 1 s sampling, 300 warm-up samples) around ``valve``,
    with a random-walk load and the stem measured through ``mv_noise`` % of noise."""
    ts, warmup = 1.0, 300
    rng = np.random.default_rng(rng_seed)
    load = np.cumsum(rng.normal(0.0, 0.02, n))
    rec = simulate_loop(n=n, ts_s=ts, process=make_process("foptd", gain=gain, tau_s=tau_s, delay_s=2.0),
                        controller=simc_pi(gain, tau_s, 2.0, ts), valve=valve, load=load, noise_std=0.05, seed=seed,
                        warmup=warmup)
    return rec.replace(mv=rec.mv + rng.normal(0.0, mv_noise, n))


def _step_stem_loop(S_pct: float, J_pct: float, dS_pct: float, dJ_pct: float, at_s: float, **loop):
    """`_stem_loop` around a valve whose S and J change by ``dS_pct`` and ``dJ_pct`` in one step
    ``at_s`` seconds into the record (after the warm-up)."""
    ts, warmup = 1.0, 300
    valve = AugmentedValve(S_pct, J_pct, dS_pct_per_s=dS_pct / ts, dJ_pct_per_s=dJ_pct / ts, ts_s=ts,
                           drift_from_s=at_s + warmup, drift_for_s=ts)
    return _stem_loop(valve, **loop)


def test_a_step_in_friction_is_named_with_its_time_from_the_stem():
    # friction that changes in one step (a valve repacked or re-tightened mid-record: S 5 -> 2.5 %,
    # J 2 -> 1 % at 900 s of the record) is neither the plain valve nor a linear drift: a drift
    # fitted to it is wrong on both sides of the step and worse beyond the fitted span. The step's
    # time and the friction before and after it are found, and the held-out part (after 1950 s)
    # is predicted better than by the plain valve
    ts = 1.0
    rec = _step_stem_loop(5.0, 2.0, -2.5, -1.0, 900.0, gain=1.2, tau_s=15.0, rng_seed=11, seed=4, mv_noise=0.1)
    ex = explain(rec, target="mv", hypotheses=["time_varying_friction"])
    assert ex.missing_physics == "time_varying_friction"
    (h,) = ex.hypotheses
    p = h.params
    assert p["change_for_s"] == ts and h.n_extra == 3
    # the stem slips at 887-888 s and again from 901 s: any time between them is the same fit
    assert 887.0 <= p["change_from_s"] <= 901.0
    assert p["S_start_pct"] == pytest.approx(5.0, rel=0.05) and p["S_end_pct"] == pytest.approx(2.5, rel=0.05)
    assert p["J_end_pct"] < p["J_start_pct"]
    # the text gives the friction before and after the step and its time, not the one-sample rates
    assert "dS_pct_per_h" not in ex.explanation and "change_for_s" not in ex.explanation
    assert f"S_end_pct = {number(p['S_end_pct'])}" in ex.explanation and "change_from_s = " in ex.explanation
    # a linear drift over the whole record reports the record as the change's length
    drift = {x.name: x for x in explain(concealed_loop("time_varying_friction", 5001, n=3000, with_mv=True,
                                                       min_moves=(0.65, 10, 5))[0],
                                        target="mv", hypotheses=["time_varying_friction"]).hypotheses}
    d = drift["time_varying_friction"]
    assert d.n_extra == 2 and d.params["change_from_s"] == 0.0 and d.params["change_for_s"] == 3000.0


def test_a_step_inside_the_training_part_is_named_on_the_training_evidence():
    # friction that doubles at 700 s of a 3000-sample record (S 3 -> 6 %, J 1.5 -> 3 %) and holds:
    # the held-out part (after 1950 s) is the valve after the step, which the plain valve refit on
    # the training part predicts as well as the step does (refused at -1 % before). The plain
    # valve cannot follow the first 700 s, and that stretch was cut as an unknown start; the
    # recorded stem slips many times in it, so only the start up to its third slip is cut, and
    # the step is judged on the training part
    rec = _step_stem_loop(3.0, 1.5, 3.0, 1.5, 700.0, gain=1.2, tau_s=15.0, rng_seed=11, seed=4, mv_noise=0.1)
    ex = explain(rec, target="mv", hypotheses=["time_varying_friction"])
    assert ex.missing_physics == "time_varying_friction"
    (h,) = ex.hypotheses
    p = h.params
    assert h.evidence == "training" and h.to_dict()["evidence"] == "training"
    assert h.train_delta_bic <= -60.0 and p["change_for_s"] == 1.0
    assert p["S_start_pct"] == pytest.approx(3.0, rel=0.03) and p["S_end_pct"] == pytest.approx(6.0, rel=0.03)
    assert p["J_start_pct"] == pytest.approx(1.5, rel=0.05) and p["J_end_pct"] == pytest.approx(3.0, rel=0.05)
    assert 640.0 <= p["change_from_s"] <= 710.0
    # the held-out part is reported as well as the plain valve after the step predicts it
    assert ex.improved_rmse <= ex.mismatch.reference_rmse
    assert "judged on the training part" in ex.explanation
    # the command's summary and the report's table say so on the hypothesis's own row
    from diagnose.service.commands.explain import summary
    from diagnose.service.report import _named_text

    (row,) = [ln for ln in summary(ex.to_dict()).splitlines() if ln.startswith("  * time_varying_friction")]
    assert "judged on the training part" in row
    assert _named_text(h) == "yes, on the training part"
    # the same loop without the step: nothing to name
    plain = _step_stem_loop(3.0, 1.5, 0.0, 0.0, 700.0, gain=1.2, tau_s=15.0, rng_seed=11, seed=4, mv_noise=0.1)
    ex0 = explain(plain, target="mv", hypotheses=["time_varying_friction"])
    assert ex0.missing_physics is None


def test_a_drift_shows_its_rates_and_a_step_its_sides_and_time():
    from diagnose.physics.hypotheses import shown_params

    drift = {"S_start_pct": 3.0, "J_start_pct": 1.0, "dS_pct_per_h": 1.2, "dJ_pct_per_h": 0.4, "S_end_pct": 4.0,
             "J_end_pct": 1.33, "change_from_s": 0.0, "change_for_s": 3000.0}
    assert shown_params("time_varying_friction", drift) == drift
    step = dict(drift, dS_pct_per_h=-9000.0, dJ_pct_per_h=-3600.0, S_end_pct=0.5, J_end_pct=0.0,
                change_from_s=900.0, change_for_s=1.0)
    assert shown_params("time_varying_friction", step) == {
        "S_start_pct": 3.0, "J_start_pct": 1.0, "S_end_pct": 0.5, "J_end_pct": 0.0, "change_from_s": 900.0}
    assert shown_params("actuator_lag", {"tau_s": 2.0}) == {"tau_s": 2.0}
    assert shown_params("not_registered", {"x": 1.0}) == {"x": 1.0}


def test_a_step_that_more_than_doubles_the_friction_is_found():
    # friction that rises 2.5-fold in one step (S 2 -> 5 %, J 0.2 -> 0.5 % at 1400 s of the 1950 s
    # fitted): S after the step is more than twice S before it, beyond a grid of half to twice the
    # friction before. The plain fit follows the longer side before the step and predicts the
    # held-out part, all after it, badly; the step is found to the stem's slips
    ts = 1.0
    rec = _step_stem_loop(2.0, 0.2, 3.0, 0.3, 1400.0, gain=1.2, tau_s=15.0, rng_seed=11, seed=4, mv_noise=0.1)
    ex = explain(rec, target="mv", hypotheses=["time_varying_friction"])
    assert ex.missing_physics == "time_varying_friction"
    p = ex.hypotheses[0].params
    assert p["change_for_s"] == ts
    assert p["S_start_pct"] == pytest.approx(2.0, rel=0.05) and p["S_end_pct"] == pytest.approx(5.0, rel=0.03)
    # the stem slips at 1382-1383 s and next at 1447 s: any time between them is the same fit
    assert 1382.0 <= p["change_from_s"] <= 1447.0


def test_a_step_on_a_valve_that_overshoots_far_is_found_to_the_stems_precision():
    # an overshooting valve (J 1.9 S) whose friction rises by 70 % at 1100 s, seen on a nearly
    # noise-free stem: the valve on each side of the step is fitted on its own side, J/S up to 2
    # with the valve's start state fitted at each value, so that the model trains at the stem's
    # noise
    ts = 1.0
    rec = _step_stem_loop(3.0, 5.7, 2.1, 3.99, 1100.0, gain=1.0, tau_s=10.0, rng_seed=23, seed=5, mv_noise=0.02)
    ex = explain(rec, target="mv", hypotheses=["time_varying_friction"])
    assert ex.missing_physics == "time_varying_friction"
    (h,) = ex.hypotheses
    p = h.params
    assert p["change_for_s"] == ts and abs(p["change_from_s"] - 1100.0) <= 20.0
    assert p["S_start_pct"] == pytest.approx(3.0, rel=0.01) and p["S_end_pct"] == pytest.approx(5.1, rel=0.01)
    assert p["J_start_pct"] == pytest.approx(5.7, rel=0.03) and p["J_end_pct"] == pytest.approx(9.69, rel=0.03)
    assert h.train_rmse < 0.04 and h.heldout_rmse < 0.2 * ex.baseline_rmse


def test_a_lag_small_against_the_stems_noise_is_named_on_overwhelming_evidence():
    # a 2 s lag of the stem seen through 0.1 % of measurement noise lowers the held-out RMSE by
    # less than the usual 10 %, but held-out and training BIC both give odds beyond e^30: the
    # effect is named (and the message of a refusal would say which rule applied)
    from diagnose.physics.explain import DECISIVE_BIC

    valve = AugmentedValve(3.0, 0.0, tau_lag_s=2.0, ts_s=1.0)
    rec = _stem_loop(valve, gain=1.0, tau_s=10.0, rng_seed=3, seed=3, mv_noise=0.1)
    ex = explain(rec, target="mv", hypotheses=["actuator_lag"])
    (h,) = ex.hypotheses
    assert ex.missing_physics == "actuator_lag" and h.accepted
    assert 0.1 / 3.0 <= h.reduction < 0.1
    assert h.delta_bic <= DECISIVE_BIC and h.train_delta_bic <= DECISIVE_BIC
    assert h.params["tau_s"] == pytest.approx(2.0, rel=0.1)


def test_the_plain_projections_of_a_step_are_the_valve_before_and_after_it():
    # a refit plain model may start from either side of a fitted step (never from the step's rate
    # carried on to mid-record, which would be a valve hundreds of times stickier)
    from diagnose.physics.explain import _plain_projections

    proc = ProcessModel(kind="foptd", gain=1.0, tau_s=10.0, delay_s=2.0, bias=0.0)
    step = Structure(S_up_pct=3.0, J_up_pct=1.0, S_dn_pct=3.0, J_dn_pct=1.0, dS_pct_per_s=2.0, dJ_pct_per_s=0.5,
                     drift_from_s=700.0, drift_for_s=1.0, process=proc)
    sides = [(p.S_up_pct, p.J_up_pct, p.dS_pct_per_s) for p in _plain_projections(step, n_mid=1000, ts_s=1.0)]
    assert sides == [(3.0, 1.0, 0.0), (5.0, 1.5, 0.0)]
    # plain: without the step's window too
    assert all(p.drift_from_s == 0.0 and p.drift_for_s == math.inf
               for p in _plain_projections(step, n_mid=1000, ts_s=1.0))
    drift = step.replace(dS_pct_per_s=0.001, dJ_pct_per_s=0.0, drift_from_s=0.0, drift_for_s=math.inf)
    mids = [p.S_up_pct for p in _plain_projections(drift, n_mid=1000, ts_s=1.0)]
    assert mids == pytest.approx([3.0, 4.0])
