"""The independent plant simulator (benchmarks/plantsim): friction laws, discretisation, artifacts,
determinism and the files it writes."""

import csv
import math
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from benchmarks.plantsim import (CLASSES, EFFECTS, SCENARIOS, concealed, corpus,  # noqa: E402
                                 make_loop, stiction_class)
from benchmarks.plantsim import artifacts as art  # noqa: E402
from benchmarks.plantsim import process as P  # noqa: E402
from benchmarks.plantsim.__main__ import main as cli_main  # noqa: E402
from benchmarks.plantsim.controller import PID, gain_margin, least_damped  # noqa: E402
from benchmarks.plantsim.friction import (ForceBalance, Kano, TwoParameter, force_balance_bands,  # noqa: E402
                                          run_force_balance, run_static)
from benchmarks.plantsim.loop import Signals, run_loop  # noqa: E402
from benchmarks.plantsim.valve import Lag, ValveTrain  # noqa: E402
from benchmarks.plantsim.friction import Linear  # noqa: E402


def slow_sine(n=6000, period=1500, amp=20.0):
    t = np.arange(n, dtype=float)
    return 50.0 + amp * np.sin(2 * np.pi * t / period)


def motion_starts(y, eps=1e-9):
    """Indices k where the stem moves from k-1 to k after resting from k-2 to k-1."""
    dy = np.abs(np.diff(y)) > eps
    return np.nonzero(dy[1:] & ~dy[:-1])[0] + 2


# --- friction laws -----------------------------------------------------------------------------

@pytest.mark.parametrize("S,J", [(4.0, 0.0), (4.0, 1.5), (4.0, 4.0), (4.0, 6.5)])
@pytest.mark.parametrize("law", [TwoParameter, Kano])
def test_data_driven_law_classes_on_a_slow_sine(law, S, J):
    x = slow_sine()
    y = run_static(law(S, J, 1), x)
    step = np.abs(np.diff(x)).max()
    rising = np.r_[False, np.diff(x) > 0]
    moving = np.r_[False, np.abs(np.diff(y)) > 1e-12]
    k = np.nonzero(rising & moving)[0]
    k = k[k > 1600]                         # after the first reversal
    # while moving up the stem lags the input by (S - J)/2 (leads it when J > S)
    assert np.allclose(x[k] - y[k], (S - J) / 2.0, atol=1e-9)
    falling = np.r_[False, np.diff(x) < 0]
    kd = np.nonzero(falling & moving)[0]
    kd = kd[kd > 1600]
    assert np.allclose(y[kd] - x[kd], (S - J) / 2.0, atol=1e-9)
    # after each reversal the stem rests while the input travels S, then jumps by J
    starts = [s for s in motion_starts(y) if s > 1000]
    assert len(starts) >= 6
    for s in starts:
        last = s - 1
        while abs(y[last] - y[last - 1]) < 1e-12:
            last -= 1
        travel = abs(x[s] - x[last])
        assert S - 1e-9 < travel <= S + step + 1e-9
        jump = abs(y[s] - y[s - 1])
        expected = J + (travel - S)                   # the input overshoots the band by < one step
        assert jump == pytest.approx(expected, abs=1e-9)


def test_deadband_class_never_jumps():
    x = slow_sine()
    y = run_static(TwoParameter(3.0, 0.0), x)
    # (the first step settles the stem from x0 onto the moving line x - S/2)
    assert np.abs(np.diff(y[1:])).max() <= np.abs(np.diff(x)).max() + 1e-12
    assert np.ptp(y) == pytest.approx(np.ptp(x) - 3.0, abs=0.05)


def test_kano_stickband_restarts_after_J_and_reverses_after_S():
    S, J = 5.0, 1.0
    # ramp up, hold, ramp on up; then back down
    up = np.arange(40.0, 60.0, 0.1)
    hold = np.full(50, up[-1])
    on = up[-1] + np.arange(1, 40) * 0.1
    down = on[-1] - np.arange(1, 120) * 0.1
    x = np.concatenate([[40.0], up, hold, on, down])
    y = run_static(Kano(S, J, 1), x)
    i_hold = 1 + up.size                      # first held sample: the valve stops here
    assert np.all(y[i_hold:i_hold + hold.size] == y[i_hold])
    # restarting in the same direction only needs the stickband J
    i_on = i_hold + hold.size
    restart = i_on + int(np.argmax(np.abs(np.diff(y[i_on - 1:])) > 1e-12))
    assert x[restart] - x[i_hold] == pytest.approx(J + 0.1, abs=1e-6)
    assert y[restart] - y[restart - 1] == pytest.approx(J + 0.1, abs=1e-6)
    # reversing needs deadband + stickband = S
    i_top = i_on + on.size - 1
    rev = i_top + int(np.argmax(np.abs(np.diff(y[i_top:])) > 1e-12)) + 1
    assert x[i_top] - x[rev] == pytest.approx(S + 0.1, abs=1e-6)
    law = Kano(S, J)
    assert (law.deadband_pct, law.stickband_pct) == (S - J, J)


def test_asymmetric_bands_differ_by_direction():
    x = slow_sine()
    y = run_static(TwoParameter(4.0, 1.0, 1, S_close_pct=2.0, J_close_pct=0.5), x)
    rising = np.r_[False, np.diff(x) > 0] & np.r_[False, np.abs(np.diff(y)) > 1e-12]
    falling = np.r_[False, np.diff(x) < 0] & np.r_[False, np.abs(np.diff(y)) > 1e-12]
    r = np.nonzero(rising)[0]
    f = np.nonzero(falling)[0]
    assert np.allclose((x - y)[r[r > 1600]], 1.5)          # opening: (4 - 1)/2
    assert np.allclose((y - x)[f[f > 1600]], 0.75)         # closing: (2 - 0.5)/2


def _stem(Fs, Fc, zeta=1.2, tau_p=0.5, h=0.01):
    k, F_span = 52500.0, 2000.0
    wn = 60.0
    m = k / wn ** 2
    return ForceBalance(m_kg=m, k_N_per_m=k, Fv_Ns_per_m=2 * zeta * math.sqrt(k * m), Fs_N=Fs, Fc_N=Fc,
                        F_span_N=F_span, tau_p_s=tau_p, h_s=h)


def test_force_balance_sticks_and_slips_with_static_above_coulomb():
    Fs, Fc = 100.0, 60.0                  # S = 8 %, J = 2 % of a 2000 N span (overdamped stem)
    S_map, J_map = force_balance_bands(Fs, Fc, 2000.0, 1.2)
    assert (S_map, J_map) == pytest.approx((8.0, 2.0))
    x = slow_sine(n=5000, period=1000)
    y = run_force_balance(_stem(Fs, Fc), x, 1.0)
    dy = np.diff(y)
    assert np.mean(np.abs(dy) < 1e-9) > 0.2              # it rests for long stretches
    moving = np.r_[False, np.abs(dy) > 1e-3]
    k = np.nonzero(moving)[0]
    k = k[k > 1000]
    # while sliding the stem trails the (lagged) input by the Coulomb force, Fc/F_span = 3 %
    lag = np.abs(x[k] - y[k])
    assert np.median(lag) == pytest.approx(3.0, abs=0.15)
    # reversals: the input swings S from where the stem stopped, then the stem jumps about J
    starts = [s for s in motion_starts(y, 1e-6) if s > 1000]
    rev = []
    for s in starts:
        last = s - 1
        while abs(y[last] - y[last - 1]) < 1e-6:
            last -= 1
        if (y[s] - y[s - 1]) * (y[last] - y[last - 1]) < 0:       # the motion reversed
            rev.append((abs(x[s] - x[last]), abs(y[s + 1] - y[s - 1])))
    assert len(rev) >= 6
    travel = np.array([r[0] for r in rev])
    jump = np.array([r[1] for r in rev])
    assert np.all(np.abs(travel - S_map) < 0.6)
    assert np.all(np.abs(jump - J_map) < 0.6)


def test_force_balance_without_friction_moves_smoothly():
    x = slow_sine(n=3000, period=1000)
    y = run_force_balance(_stem(0.0, 0.0), x, 1.0)
    assert np.abs(y - x).max() < 0.05                      # only the pressure lag separates them
    assert np.mean(np.abs(np.diff(y)) < 1e-9) < 0.01         # never at rest
    # a fine step that does not divide the sample period still keeps real time: a step of OP
    # reaches the stem through the pressure lag (tau_p = 2 s) and the fast mechanics
    stem = _stem(0.0, 0.0, tau_p=2.0, h=0.03)
    y = run_force_balance(stem, np.r_[40.0, np.full(12, 60.0)], 1.0)
    k = np.arange(1, 13)
    mech = 2 * 1.2 / 60.0                  # an overdamped stem trails a slow input by 2 zeta / wn
    assert np.allclose(y[1:], 60.0 - 20.0 * np.exp(-(k - mech) / 2.0), atol=0.03)


def test_lag_after_friction_smooths_the_jump():
    m, ts = 10, 1.0
    lag = Lag(1, 3.0, 1.0, ts / m, m)
    train = ValveTrain(TwoParameter(4.0, 4.0), m=m, h_s=ts / m, lag=lag, lag_at="after")
    train.reset(50.0)
    out = np.empty(m)
    ys = []
    for op in [50.0] * 3 + [55.0] * 20:
        train.fill(0, op, out)
        ys.append(out.copy())
    ys = np.concatenate(ys)
    target = 55.0                                          # J = S: no offset after the slip
    t = (np.arange(ys.size) - 3 * m + 1) * ts / m
    after = t > 0
    assert np.allclose(ys[after], target + (50.0 - target) * np.exp(-t[after] / 3.0), atol=1e-9)


# --- processes and the loop ------------------------------------------------------------------

def _analytic(kind, t, params):
    if kind == "foptd":
        K, tau = params
        return K * (1 - np.exp(-t / tau))
    if kind in ("soptd", "third"):
        K, taus = params
        out = np.ones_like(t)
        for i, ti in enumerate(taus):
            c = ti ** (len(taus) - 1) / np.prod([ti - tj for j, tj in enumerate(taus) if j != i])
            out -= c * np.exp(-t / ti)
        return K * out
    if kind == "underdamped":
        K, wn, z = params
        wd = wn * math.sqrt(1 - z * z)
        return K * (1 - np.exp(-z * wn * t) * (np.cos(wd * t) + z / math.sqrt(1 - z * z) * np.sin(wd * t)))
    if kind == "integrating":
        k, tau = params
        return k * (t - tau * (1 - np.exp(-t / tau)))
    raise AssertionError(kind)


@pytest.mark.parametrize("proc,kind,params,ts", [
    (P.foptd(2.0, 17.0, 3.5), "foptd", (2.0, 17.0), 1.0),
    (P.soptd(-1.5, 30.0, 8.0, 7.0), "soptd", (-1.5, (30.0, 8.0)), 2.0),
    (P.underdamped(0.8, 0.15, 0.35, 2.5), "underdamped", (0.8, 0.15, 0.35), 1.0),
    (P.third_order(1.2, (40.0, 15.0, 4.0), 12.5), "third", (1.2, (40.0, 15.0, 4.0)), 5.0),
    (P.integrating(0.02, 6.0, 4.0), "integrating", (0.02, 6.0), 2.0),
])
def test_discretisation_matches_the_analytic_step_response(proc, kind, params, ts):
    # delays of half-samples: the internal step (ts/10) resolves what the sample period cannot
    y = P.step_response(proc, ts, 300, m=10)
    t = np.arange(300) * ts - proc.delay_s
    expect = np.where(t > 0, _analytic(kind, np.maximum(t, 0.0), params), 0.0)
    scale = np.abs(expect).max()
    assert np.abs(y - expect).max() <= 1e-9 * max(scale, 1.0)


def test_gain_margin_marks_the_edge_of_stability_of_the_simulated_loop():
    proc = P.soptd(1.3, 25.0, 6.0, 3.3)
    ts, Kc, Ti = 1.0, 2.0, 25.0
    gm = gain_margin(proc, Kc, Ti, 0.0, ts)
    assert 1.0 < gm < 20.0

    def tail(g):
        m = 10
        n = 4000
        z = np.zeros(n)
        sp = np.zeros(n)
        sp[5:] = 1.0
        out = run_loop(n=n, warmup=0, ts_s=ts, m=m, process=proc,
                       valve=ValveTrain(Linear(), m=m, h_s=ts / m),
                       controller=PID(g * Kc, Ti, ts_s=ts, op_lo=-1e9, op_hi=1e9),
                       signals=Signals(sp, z, z, z), u0=50.0, pv0=0.0)
        e = out["pv"] - sp
        return np.abs(e[1000:1500]).max(), np.abs(e[-500:]).max()

    early, late = tail(0.97 * gm)
    assert late < 0.1 * early                              # decays
    early, late = tail(1.03 * gm)
    assert late > early                                    # grows
    zeta, period = least_damped(proc, 0.97 * gm * Kc, Ti, 0.0, ts)
    assert 0.0 < zeta < 0.05 and period > 2 * ts


# --- artifacts ---------------------------------------------------------------------------------

def test_swinging_door_reconstruction_is_straight_and_close():
    rng = np.random.default_rng(3)
    t = np.arange(3000)
    x = 50 + 5 * np.sin(2 * np.pi * t / 400) + rng.normal(0, 0.05, t.size)
    dev = 0.5
    rec, kept = art.compress(x, dev)
    assert kept < t.size / 10
    # a line from the last archive that keeps every sample within E exists; the archived chord
    # itself can sit up to 2 E from a sample (Bristol's doors bound it by the corridor width)
    assert np.abs(rec - x).max() <= 2 * dev + 1e-9
    assert np.mean(np.abs(rec - x)) < dev
    assert np.array_equal(rec[kept_idx := art.swinging_door(x, dev)], x[kept_idx])
    # long straight runs: the second difference vanishes except at archived corners
    straight = np.abs(np.diff(rec, 2)) < 1e-9
    assert straight.mean() > 0.9
    idx = art.swinging_door(x, dev)
    assert idx[0] == 0 and idx[-1] == t.size - 1 and np.all(np.diff(idx) > 0)
    assert np.array_equal(art.swinging_door(x, 0.0), np.arange(t.size))


def test_compressed_and_quantised_scenarios_carry_their_artifact():
    comp = make_loop("compressed", 11, 0, n=1500, ts_s=2.0)
    straight = np.abs(np.diff(comp.pv, 2)) < 1e-9 * max(1.0, np.abs(comp.pv).max())
    assert straight.mean() > 0.5
    assert comp.meta["pv_archived_points"] < comp.n / 3
    q = make_loop("quantised", 11, 0, n=1500, ts_s=2.0)
    step = q.meta["quant_step"]
    assert np.allclose(q.pv / step, np.round(q.pv / step), atol=1e-6)


# --- the corpus ----------------------------------------------------------------------------------

def test_same_seed_same_records_bit_for_bit():
    kinds = ["two_parameter", "force_balance", "compressed", "level_pi"]
    a = list(corpus(21, 2, kinds=kinds, n=600))
    b = list(corpus(21, 2, kinds=kinds, n=600))
    c = list(corpus(22, 2, kinds=kinds, n=600))
    for la, lb in zip(a, b):
        for k in ("op", "pv", "sp", "mv"):
            assert np.array_equal(getattr(la, k), getattr(lb, k))
        assert la.meta == lb.meta and la.name == lb.name
    assert not all(np.array_equal(la.pv, lc.pv) for la, lc in zip(a, c))
    # a record does not depend on which other scenarios are generated
    alone = next(corpus(21, 1, kinds=["compressed"], n=600))
    assert np.array_equal(alone.pv, a[4].pv)
    x1 = concealed("actuator_lag", 3, n=1500)
    x2 = concealed("actuator_lag", 3, n=1500)
    assert np.array_equal(x1.pv, x2.pv) and x1.meta == x2.meta


def test_corpus_labels_and_coverage():
    loops = list(corpus(5, 8, kinds=["two_parameter", "kano"], n=800, ts_s=2.0))
    for kind in ("two_parameter", "kano"):
        sub = [lp for lp in loops if lp.kind == kind]
        assert all(lp.sticky for lp in sub)
        combos = {(lp.meta["class"], lp.meta["integrating"]) for lp in sub}
        assert combos == {(c, i) for c in CLASSES for i in (False, True)}
        for lp in sub:
            S, J = lp.meta["S_pct"], lp.meta["J_pct"]
            assert 0.5 <= S <= 10.0
            assert stiction_class(S, J) == lp.meta["class"]
            assert lp.meta["stem_moves"] >= 3
    neg = list(corpus(5, 1, kinds=[k for k, v in SCENARIOS.items() if not v], n=800, ts_s=2.0))
    assert not any(lp.sticky for lp in neg)
    assert all(lp.meta["S_pct"] == 0.0 for lp in neg)
    over = next(corpus(5, 1, kinds=["overtuned"], n=800))
    assert 1.15 <= over.meta["gain_margin"] <= 1.45
    level = next(corpus(5, 1, kinds=["level_pi"], n=800))
    assert level.meta["integrating"] and level.meta["closed_loop_zeta"] < 0.4
    with pytest.raises(ValueError, match="unknown scenario"):
        next(corpus(5, 1, kinds=["sticky"]))
    lp = loops[0]
    with pytest.raises(ValueError):
        lp.pv[0] = 0.0


def test_concealed_effects_are_recorded_and_change_the_record():
    for eff in EFFECTS:
        lp = concealed(eff, 4, n=2000)
        assert lp.sticky and lp.kind == "concealed" and lp.meta["effect"] == eff
        assert lp.n == 2000 and "effect_size" in lp.meta
        if eff == "none":
            assert lp.meta["effect_size"] == 0.0 and lp.meta["effect_pv_change"] == 0.0
        else:
            assert lp.meta["effect_size"] > 0.0 and lp.meta["effect_pv_change"] > 0.0
    twin = concealed("valve_characteristic", 4, n=2000, apply_effect=False)
    real = concealed("valve_characteristic", 4, n=2000)
    for key in ("S_pct", "J_pct", "law", "gain", "Kc", "rangeability_R", "quick_opening_R"):
        assert twin.meta.get(key) == real.meta.get(key)
    assert not np.array_equal(twin.pv, real.pv)
    with pytest.raises(ValueError, match="unknown effect"):
        concealed("backlash", 1)


# --- files -----------------------------------------------------------------------------------

def test_cli_writes_files_the_connectors_read(tmp_path, capsys):
    from connectors import read_records

    out = tmp_path / "corpus"
    rc = cli_main(["--out", str(out), "--seed", "2", "--n-per-kind", "1", "--n", "400",
                   "--kinds", "kano,healthy,compressed", "--mv"])
    assert rc == 0
    assert "wrote 3 records (1 sticky)" in capsys.readouterr().out
    with open(out / "labels.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert [r["scenario"] for r in rows] == ["kano", "healthy", "compressed"]
    assert [r["label"] for r in rows] == ["sticky", "not_sticky", "not_sticky"]
    regen = list(corpus(2, 1, kinds=["kano", "healthy", "compressed"], n=400))
    for row, loop in zip(rows, regen):
        recs = read_records(str(out / row["file"]))
        assert len(recs) == 1
        rec = recs[0]
        assert rec.name == loop.name == row["name"]
        assert rec.ts_s == pytest.approx(loop.ts_s)
        assert rec.op.shape[0] == loop.n == int(row["n"])
        assert np.allclose(rec.op, loop.op, rtol=1e-8, atol=1e-8)
        assert np.allclose(rec.pv, loop.pv, rtol=1e-8, atol=1e-8)
        assert np.allclose(rec.mv, loop.mv, rtol=1e-8, atol=1e-8)
        assert float(row["S_pct"]) == pytest.approx(loop.meta["S_pct"])
    assert cli_main(["--out", str(out), "--kinds", "sticky"]) == 1
    assert "unknown scenario sticky" in capsys.readouterr().err
