"""The compiled kernels (diagnose/csrc through diagnose.kernels): each against a plain numpy/Python
computation written here, and every vector variant (baseline, AVX2, AVX-512, as the CPU allows)
giving the same numbers bit for bit."""

import math

import numpy as np
import pytest

from diagnose import kernels
from diagnose.objective import ProcessGrid
from diagnose.physics.plant import AugmentedValve
from diagnose.physics.valve import augmented_valve
from diagnose.process_model import ProcessModel, lag_coefficient
from kano import kano_valve


def _walk(rng, n):
    return np.clip(50.0 + np.cumsum(rng.normal(0.0, 0.6, n)), 0.0, 100.0)


def _variants(fn):
    """fn() at every instruction-set variant the CPU has."""
    out = []
    try:
        for level in range(kernels.max_isa_level() + 1):
            kernels.set_isa(level)
            out.append(fn())
    finally:
        kernels.set_isa(None)
    return out


def test_the_library_is_built_and_reports_its_variant():
    assert kernels.isa().split()[0] in ("baseline", "avx2", "avx512")
    assert kernels.set_isa(0).startswith("baseline")
    kernels.set_isa(None)


def _score_case(rng, n, m, P, K, hp, gfix):
    x = _walk(rng, n)
    S = rng.uniform(0.0, 5.0, m)
    J = rng.uniform(0.0, 6.0, m)
    F = np.where(rng.random(m) < 0.5, 1.0, -1.0)
    kinds = rng.choice(["foptd", "soptd", "integrating"], P)
    keys = [(k, float(rng.uniform(0.5, 30.0)), float(rng.uniform(0.5, 10.0)), int(rng.integers(0, 9)))
            for k in kinds]
    grid = ProcessGrid.of(keys, 1.0)
    w = (rng.random(n) < 0.8).astype(float)
    w[:20] = 0.0
    y = rng.normal(size=n).cumsum() * 0.1
    Q = np.linalg.qr(rng.normal(size=(n, K)))[0] if K else np.zeros((n, 0))
    Qw = np.ascontiguousarray(Q * w[:, None])
    yw = w * y
    Qty = Qw.T @ y
    yyp = float(yw @ y - Qty @ Qty)
    ahp = 0.8 if hp else -1.0
    data = kernels.ScoreData(x, w, yw, Qw, Qty, yyp, ahp, 1.0, gfix)
    valves = np.ascontiguousarray(np.vstack([S, J, F, np.full(m, np.nan), np.full(m, np.nan)]))
    return data, valves, grid, (x, S, J, F, keys, w, yw, Qw, Qty, yyp, ahp)


def _score_reference(case, gfix):
    """SSE and gain from numpy sums: Kano's valve (tests/kano.py), the process as a `ProcessModel`
    (relative to the valve's first position), the noise prefilter as a plain loop."""
    x, S, J, F, keys, w, yw, Qw, Qty, yyp, ahp = case
    m, P = S.shape[0], len(keys)
    sse, gain = np.empty((m, P)), np.empty((m, P))
    for i in range(m):
        u = kano_valve(x, S[i], J[i], int(F[i]))
        for p, (kind, t1, t2, d) in enumerate(keys):
            proc = ProcessModel(kind, 1.0, t1, float(d), 0.0, tau2_s=t2 if kind == "soptd" else 0.0)
            z = proc.regressor(u - u[0], 1.0)
            if ahp >= 0:
                v, acc, prev = np.empty_like(z), 0.0, z[0]
                for k in range(z.shape[0]):
                    acc = ahp * acc + z[k] - prev
                    prev = z[k]
                    v[k] = acc
            else:
                v = z
            szz, szy, szq = float(np.sum(w * v * v)), float(yw @ v), Qw.T @ v
            zzp, zyp = szz - szq @ szq, szy - szq @ Qty
            if gfix == gfix:
                sse[i, p], gain[i, p] = yyp - 2 * gfix * zyp + gfix * gfix * max(zzp, 0.0), gfix
            elif zzp > 1e-10 * (szz + 1e-300):
                sse[i, p], gain[i, p] = yyp - zyp * zyp / zzp, zyp / zzp
            else:
                sse[i, p], gain[i, p] = yyp, 0.0
    return sse, gain


@pytest.mark.parametrize("m,P,K,hp,gfix", [
    (5, 9, 3, True, np.nan),      # groups of jobs and leftovers
    (7, 1, 1, False, np.nan),     # many candidates at one structure (the local searches)
    (2, 4, 0, True, 1.0),         # fixed gain, no load basis
    (1, 2, 2, False, np.nan),     # fewer jobs than lanes
    (19, 5, 3, True, np.nan),     # blocks of candidates sharing a valve pass, an odd structure left over
    (1, 40, 2, True, np.nan),     # one valve, dead times shared by several structures
])
def test_score_equals_a_plain_computation_at_every_variant(m, P, K, hp, gfix):
    rng = np.random.default_rng(10 * m + P)
    data, valves, grid, case = _score_case(rng, 700, m, P, K, hp, gfix)
    outs = _variants(lambda: kernels.score(data, valves, grid.table))
    for sse, gain in outs[1:]:
        assert np.array_equal(sse, outs[0][0]) and np.array_equal(gain, outs[0][1])
    ref_sse, ref_gain = _score_reference(case, gfix)
    scale = float(case[6] @ case[6]) + abs(case[9])
    np.testing.assert_allclose(outs[0][0], ref_sse, rtol=0, atol=1e-11 * scale)
    np.testing.assert_allclose(outs[0][1], ref_gain, rtol=1e-8, atol=1e-11)


@pytest.mark.parametrize("m", [2, 4, 6, 8, 9, 16])
def test_a_job_scores_the_same_whatever_shares_its_call(m):
    # the kernel lays jobs out differently by their number (candidate blocks, shared rows, paired
    # points with one dead time); a job's numbers must not depend on it
    rng = np.random.default_rng(100 + m)
    data, valves, grid, _ = _score_case(rng, 900, m, 6, 3, True, np.nan)
    # some valves start stuck (the layouts run their start states through different code)
    valves = valves.copy()
    valves[3, ::2] = rng.uniform(30.0, 70.0, valves[3, ::2].shape)
    valves[4, ::4] = valves[3, ::4] + 1.5
    valves = np.ascontiguousarray(valves)
    table = grid.table
    same_d = np.ascontiguousarray(np.repeat(table[:, :1], m, axis=1))
    same_d[0] = np.linspace(0.2, 0.95, m)           # each point its own lag, all one dead time
    for structs in (table, same_d):
        full_sse, full_gain = kernels.score(data, valves, structs)
        alone = [kernels.score(data, np.ascontiguousarray(valves[:, i:i + 1]), structs) for i in range(m)]
        assert np.array_equal(full_sse, np.vstack([a[0] for a in alone]))
        assert np.array_equal(full_gain, np.vstack([a[1] for a in alone]))
    pairs = _variants(lambda: kernels.score(data, valves, same_d, paired=True))
    for sse, gain in pairs:
        assert sse.shape == (m,)
        assert np.array_equal(sse, np.diag(full_sse)) and np.array_equal(gain, np.diag(full_gain))


def test_score_rejects_tables_of_the_wrong_shape():
    rng = np.random.default_rng(0)
    data, valves, grid, _ = _score_case(rng, 100, 2, 2, 1, False, np.nan)
    with pytest.raises(ValueError, match="valves must be"):
        kernels.score(data, np.ascontiguousarray(valves[:3]), grid.table)
    with pytest.raises(ValueError, match="P = m when paired"):
        kernels.score(data, valves, np.ascontiguousarray(grid.table[:, :1]), paired=True)


def test_valve_run_with_a_start_state_equals_kanos_model_started_there():
    rng = np.random.default_rng(4)
    x = _walk(rng, 3000)
    for S, J, f in ((3.0, 1.0, 1), (2.0, 4.0, -1), (4.0, 0.0, 1)):
        y0, us0 = x[0] - 1.7, x[0] + 0.4
        out = np.empty((1, x.shape[0]))
        kernels.valve_run(x, [S], [J], [S], [J], [0.0], [0.0], [f], [0.0], [y0], [us0], 1.0, out)
        np.testing.assert_allclose(out[0], kano_valve(x, S, J, f, y0=y0, us0=us0), rtol=0, atol=1e-12)


def test_augmented_valve_batch_and_stepped_valve_are_the_same_kernel_at_every_variant():
    rng = np.random.default_rng(7)
    x = _walk(rng, 1500)
    # the last two drift within a window: a ramp from 300 s for 400 s, and a step at 700 s (one sample)
    params = dict(S_up=[3.0, 1.0, 2.5, 2.0, 2.0], J_up=[1.0, 0.5, 3.0, 1.0, 1.0], S_dn=[2.0, 1.0, 4.0, 2.0, 2.0],
                  J_dn=[0.4, 0.5, 1.0, 1.0, 1.0], dS_pct_per_s=[0.0, 1e-3, -5e-4, 4e-3, 1.5],
                  dJ_pct_per_s=[0.0, 5e-4, 0.0, 2e-3, 0.5], f0=[1, -1, 1, 1, -1], tau_lag_s=[0.0, 3.0, 1.0, 0.0, 2.0],
                  drift_from_s=[0.0, 0.0, 0.0, 300.0, 700.0], drift_for_s=[math.inf, math.inf, math.inf, 400.0, 1.0])
    outs = _variants(lambda: augmented_valve(x, **params, ts_s=1.0))
    for o in outs[1:]:
        assert np.array_equal(o, outs[0])
    for i in range(5):
        ref = AugmentedValve(params["S_up"][i], params["J_up"][i], params["S_dn"][i], params["J_dn"][i],
                             dS_pct_per_s=params["dS_pct_per_s"][i], dJ_pct_per_s=params["dJ_pct_per_s"][i],
                             tau_lag_s=params["tau_lag_s"][i], ts_s=1.0, f0=params["f0"][i],
                             drift_from_s=params["drift_from_s"][i], drift_for_s=params["drift_for_s"][i])
        y = [ref.reset(x[0])] + [ref.step(v) for v in x[1:]]
        assert np.array_equal(outs[0][i], np.asarray(y))


def test_the_friction_schedule_drifts_within_its_window_steps_and_clips_at_zero():
    # the one schedule every valve path runs (valve_step.h); values written out by hand
    f = kernels.valve_friction
    inf = math.inf
    # S drifts +0.01 %/s from 100 s for 50 s, closing side 1 % below, J still
    for t, S in ((0.0, 3.0), (100.0, 3.0), (120.0, 3.2), (150.0, 3.5), (1e6, 3.5), (inf, 3.5)):
        su, ju, sd, jd = f(3.0, 1.0, 2.0, 1.0, 0.01, 0.0, 100.0, 50.0, t)
        assert su == pytest.approx(S, abs=1e-12) and sd == pytest.approx(S - 1.0, abs=1e-12) and ju == jd == 1.0
    # a step: one second long at 700 s, 1.5 %/s
    assert f(3.0, 1.0, 3.0, 1.0, 1.5, 0.5, 700.0, 1.0, 700.0)[:2] == (3.0, 1.0)
    assert f(3.0, 1.0, 3.0, 1.0, 1.5, 0.5, 700.0, 1.0, 701.0)[:2] == (4.5, 1.5)
    assert f(3.0, 1.0, 3.0, 1.0, 1.5, 0.5, 700.0, 1.0, inf)[:2] == (4.5, 1.5)
    # a falling drift stops at zero; a zero rate leaves its value at any time (no 0 * inf)
    assert f(1.0, 1.0, 1.0, 1.0, -0.1, 0.0, 0.0, inf, 20.0) == (0.0, 1.0, 0.0, 1.0)
    assert f(1.0, 1.0, 1.0, 1.0, -0.1, 0.0, 0.0, inf, inf) == (0.0, 1.0, 0.0, 1.0)
    assert f(2.0, 1.0, 2.0, 1.0, 0.0, 0.0, 0.0, inf, inf) == (2.0, 1.0, 2.0, 1.0)


def test_the_stepped_valve_runs_the_kernels_drift_and_lag():
    # a friction step at 700 s in the simulator's stepped valve is the plain valve with the new
    # friction from then on: the same stem as a valve_run candidate with that step, and different
    # from the valve without it once the valve slips after the step
    rng = np.random.default_rng(11)
    x = _walk(rng, 1500)
    step = kernels.ValveState(2.0, 1.0, 2.0, 1.0, dS=1.5, dJ=0.5, drift_from_s=700.0, drift_for_s=1.0,
                              a_lag=0.6, ts_s=1.0)
    plain = kernels.ValveState(2.0, 1.0, 2.0, 1.0, a_lag=0.6, ts_s=1.0)
    ys = np.array([step.start(x[0], 1.0)] + [step.step(v) for v in x[1:]])
    yp = np.array([plain.start(x[0], 1.0)] + [plain.step(v) for v in x[1:]])
    out = np.empty((1, x.shape[0]))
    kernels.valve_run(x, [2.0], [1.0], [2.0], [1.0], [1.5], [0.5], [1.0], [0.6], [math.nan], [math.nan], 1.0, out,
                      t0=[700.0], tw=[1.0])
    assert np.array_equal(ys, out[0])
    assert np.array_equal(ys[:701], yp[:701]) and not np.array_equal(ys, yp)


@pytest.mark.parametrize("kind,a2,d,integ", [("foptd", -1.0, 0, False), ("soptd", 0.7, 3, False),
                                              ("integrating", -1.0, 2, True)])
def test_lag_filter_equals_the_simulators_process_stepper(kind, a2, d, integ):
    rng = np.random.default_rng(1)
    u = _walk(rng, 400)
    tau2 = -1.0 / math.log(a2) if a2 > 0 else 0.0
    model = ProcessModel(kind, 1.0, 6.0, float(d), 0.0, tau2_s=tau2, u_balance_pct=float(u[0]))
    z = kernels.lag_filter(u, lag_coefficient(6.0, 1.0), a2, d, integ, 1.0)
    step = model.stepper()
    ref = [step.reset(u[0], 1.0)] + [step.step(v) for v in u[1:]]
    if integ:
        # the stepper integrates gain * (u - u_balance); the filter the unit-gain sum of u
        np.testing.assert_allclose(z - u[0] * np.arange(1, u.shape[0] + 1), ref, atol=1e-9)
    else:
        np.testing.assert_allclose(z, ref, atol=1e-9)


def test_noise_prefilter_equals_its_difference_equation():
    rng = np.random.default_rng(2)
    v = rng.normal(size=(300, 3))
    out = kernels.hp_filter(v, 0.9)
    ref = np.zeros_like(v)
    for j in range(3):
        acc = 0.0
        for k in range(300):
            acc = 0.9 * acc + v[k, j] - (v[k - 1, j] if k else v[0, j])
            ref[k, j] = acc
    np.testing.assert_allclose(out, ref, atol=1e-12)
    np.testing.assert_allclose(kernels.hp_filter(v[:, 0], 0.9), ref[:, 0], atol=1e-12)


def test_fused_kernel_equals_a_plain_least_squares_fit():
    # the augmented model of `stiction explain`: valve, lag, characteristic, process, [z, 1, E] by
    # least squares on the training samples
    rng = np.random.default_rng(3)
    n = 800
    x = _walk(rng, n)
    y = rng.normal(size=n).cumsum() * 0.05 + 0.3 * x
    w = (np.arange(n) > 50).astype(float)
    E = np.column_stack([np.sin(np.arange(n) / 30.0)])
    # S_up, J_up, S_dn, J_dn, dS, dJ, drift start and length (s), f0, a_lag, y0, xs0; the last a step
    params = np.array([[3.0, 1.0, 2.0, 0.5, 0.0, 0.0, 0.0, np.inf, 1.0, 0.5, np.nan, np.nan],
                       [2.0, 2.0, 2.0, 2.0, 1e-3, 0.0, 0.0, np.inf, -1.0, 0.0, x[0] - 1.0, np.nan],
                       [2.0, 1.0, 2.0, 1.0, 1.2, 0.4, 400.0, 1.0, 1.0, 0.0, np.nan, np.nan]])
    cc = np.array([0.0, 1.5, 0.0])
    a1 = np.array([0.9, 0.8, 0.85])
    a2 = np.array([-1.0, 0.5, -1.0])
    d = np.array([2, 0, 1])
    integ = np.array([False, False, False])
    out = kernels.fused_sse(x, params, cc, a1, a2, d, integ, 1.0, E, y, w, 0.0)
    for i in range(3):
        S_up, J_up, S_dn, J_dn, dS, dJ, t0, tw, f0, a, y0, xs0 = params[i]
        stem = augmented_valve(x, S_up=S_up, J_up=J_up, S_dn=S_dn, J_dn=J_dn, dS_pct_per_s=dS, dJ_pct_per_s=dJ,
                               f0=f0, tau_lag_s=-1.0 / math.log(a) if a > 0 else 0.0, ts_s=1.0, y0_pct=y0,
                               drift_from_s=t0, drift_for_s=tw)
        u = stem if cc[i] == 0 else 100.0 * np.expm1(cc[i] * stem / 100.0) / math.expm1(cc[i])
        ud = np.r_[np.full(d[i], u[0]), u[: n - d[i]]]
        z1 = np.empty(n)
        z2 = np.empty(n)
        p1 = p2 = u[0]
        for k in range(n):
            p1 = a1[i] * p1 + (1 - a1[i]) * ud[k]
            p2 = a2[i] * p2 + (1 - a2[i]) * p1 if a2[i] >= 0 else p1
            z1[k], z2[k] = p1, p2
        X = np.column_stack([z2, np.ones(n), E])
        tr = w > 0
        coef, *_ = np.linalg.lstsq(X[tr], y[tr], rcond=None)
        r = (y - X @ coef)[tr]
        # the kernel adds a ridge of 1e-9 of each diagonal term (a singular design stays solvable)
        assert out[i] == pytest.approx(float(r @ r), rel=1e-5)
