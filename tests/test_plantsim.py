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

from benchmarks.plantsim import (CLASSES, EFFECTS, SCENARIOS, STICKY_SCENARIOS, concealed, corpus,  # noqa: E402
                                 make_loop, stiction_class)
from benchmarks.plantsim import guards  # noqa: E402
from benchmarks.plantsim import scenarios as scen  # noqa: E402
from benchmarks.plantsim import artifacts as art  # noqa: E402
from benchmarks.plantsim import process as P  # noqa: E402
from benchmarks.plantsim.__main__ import main as cli_main  # noqa: E402
from benchmarks.plantsim.controller import PID, closed_loop_sensitivity, gain_margin, least_damped  # noqa: E402
from benchmarks.plantsim.draws import FAST, Draws, Plan, historian, tune  # noqa: E402
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


# --- corpus definitions and guards ------------------------------------------------------------

# sums of OP and PV of make_loop(kind, 7, 1, n=400) as the corpus was first defined: the
# "original" definition must keep reproducing them
ORIGINAL_SUMS = {
    "two_parameter": (23729.6817, 51010.5569),
    "kano": (11195.5679, 1699.19656),
    "force_balance": (19159.5433, 7103.87816),
    "healthy": (29082.6078, 14879.4132),
    "external_sine": (28330.631, 7677.70336),
    "external_nonsine": (22447.0036, 257975.474),
    "overtuned": (11157.6346, 118689.9),
    "quantised": (22311.9465, 143700.991),
    "compressed": (27249.8338, 13372.9598),
    "level_pi": (28980.2178, 25830.1664),
    "daily_cycle": (15362.7138, 1519.33109),
}


@pytest.mark.parametrize("kind", list(SCENARIOS))
def test_original_definition_reproduces_earlier_seeds(kind):
    lp = make_loop(kind, 7, 1, n=400)
    assert lp.meta["definition"] == "original"
    assert float(np.sum(lp.op)) == pytest.approx(ORIGINAL_SUMS[kind][0], rel=1e-8)
    assert float(np.sum(lp.pv)) == pytest.approx(ORIGINAL_SUMS[kind][1], rel=1e-8)
    ident = make_loop(kind, 7, 1, n=400, definition="identifiable")
    assert ident.meta["definition"] == "identifiable"
    assert not np.array_equal(ident.op, lp.op)
    with pytest.raises(ValueError, match="unknown corpus definition"):
        make_loop(kind, 7, 1, n=400, definition="strict")


def _staircase(n=2000, hold=100, jump=2.0):
    """A stick-slip stem: rests for ``hold`` samples, then jumps by ``jump``, alternately up and down."""
    y = np.full(n, 50.0)
    for k, start in enumerate(range(hold, n, hold)):
        y[start:] += jump if k % 2 == 0 else -jump
    return y


def test_slips_stuck_and_op_noise_measure_what_they_say():
    y = _staircase()
    moves, stuck = guards.slips_and_stuck(y, 2.0)
    assert moves == 19 and stuck == pytest.approx(1 - 19 / 1999)
    nudged = y.copy()
    nudged[[450, 1250, 1730]] += 0.1                      # three nudges under a quarter of S
    assert guards.slips_and_stuck(nudged, 2.0)[0] == 19
    assert guards.slips_and_stuck(nudged, 0.0)[0] == 22    # counted when any move counts
    dither = 50 + np.random.default_rng(0).normal(0, 1, 2000)
    moves, stuck = guards.slips_and_stuck(dither, 2.0)
    assert stuck == 0.0 and moves <= 1                     # moving on every sample: one long move
    rng = np.random.default_rng(1)
    op = 0.01 * np.arange(5000) + rng.normal(0, 0.5, 5000)
    op[[700, 2100, 3900]] += 30.0                          # kicks do not count as noise
    assert guards.op_noise(op) == pytest.approx(0.5, rel=0.05)


def test_growth_flags_a_growing_oscillation_only():
    t = np.arange(4000)
    cyc = np.sin(2 * np.pi * t / 97)
    grows = 50 + 0.5 * np.exp(t / 1400) * cyc
    ratio, rises = guards.growth(grows)
    assert rises >= guards.GROWTH_MIN_RISES and ratio >= guards.GROWTH_MIN_RATIO
    starts = 50 + 5 * cyc * (t > 1000)                    # a limit cycle that starts, then holds
    ratio, rises = guards.growth(starts)
    assert ratio > guards.GROWTH_MIN_RATIO and rises < guards.GROWTH_MIN_RISES
    steps = 50 + 2 * cyc + 10 * (t > 3000)                 # a setpoint step near the end
    assert guards.growth(steps)[1] < guards.GROWTH_MIN_RISES


def _loop_signals(n=2000):
    """A running sticky loop: OP ramps across the band between slips, PV cycles about SP."""
    rng = np.random.default_rng(4)
    fr = _staircase(n)
    op = fr + np.tile(np.linspace(-1.0, 1.0, 100), n // 100) + rng.normal(0, 0.05, n)
    sp = np.full(n, 40.0)
    pv = sp + 0.5 * np.sign(np.sin(2 * np.pi * np.arange(n) / 200 + 0.3)) + rng.normal(0, 0.05, n)
    return {"op": op, "pv": pv, "sp": sp, "mv": fr, "friction": fr}


def _check(raw, *, kind="two_parameter", sticky=True, S=2.0, zeta=0.5, definition="identifiable"):
    meta = {"S_pct": S, "closed_loop_zeta": zeta}
    return guards.check(definition, kind=kind, sticky=sticky, raw=raw, op=raw["op"], pv=raw["pv"], span=100.0,
                        meta=meta), meta


def test_each_guard_fires_on_the_record_it_describes():
    raw = _loop_signals()
    failed, meta = _check(raw)
    assert failed == []
    assert meta["slips"] == 19 and meta["S_over_op_noise"] > 20 and meta["stuck_fraction"] > 0.9

    def altered(**kw):
        r = {k: v.copy() for k, v in raw.items()}
        r.update(kw)
        return r

    n = raw["op"].size
    sat = raw["op"].copy()
    sat[:10] = 100.0                                       # 0.5 % of the samples
    assert _check(altered(op=sat))[0] == ["saturation"]
    assert _check(altered(op=sat), definition="original")[0] == []
    swing = 50 + 45 * np.sin(2 * np.pi * np.arange(n) / 150)
    assert "op_range" in _check(altered(op=swing))[0]
    t = np.arange(n)
    grow = 50 + 0.3 * np.exp(t / 700) * np.sin(2 * np.pi * t / 97)
    assert "growing" in _check(altered(op=grow))[0]
    assert _check(raw, zeta=0.1)[0] == ["damping"]
    assert _check(raw, zeta=0.1, kind="overtuned", sticky=False)[0] == []
    assert _check(altered(pv=raw["pv"] + 1.0))[0] == ["pv_follows"]
    assert "pv_span" in _check(altered(pv=raw["pv"] + 70.0))[0]
    # sticky records that cannot show stiction
    few = np.full(n, 50.0)
    few[[500, 1200, 1700]] = 0.0
    few = 50.0 + np.cumsum(few == 0.0) * 2.0               # three slips only
    assert _check(altered(friction=few, mv=few))[0] == ["identifiable"]
    assert _check(altered(friction=few, mv=few), definition="original")[0] == []
    dith = raw["friction"] + np.random.default_rng(2).normal(0, 0.5, n)   # moves on every sample
    assert _check(altered(friction=dith))[0] == ["identifiable"]
    noisy = raw["op"] + np.random.default_rng(3).normal(0, 1.5, n)       # S under twice OP's noise
    failed, meta = _check(altered(op=noisy))
    assert failed == ["identifiable"] and meta["S_over_op_noise"] < guards.MIN_S_OVER_OP_NOISE
    assert _check(altered(op=noisy), sticky=False, kind="healthy")[0] == []
    wild = raw["op"] + np.random.default_rng(6).normal(0, 4.0, n)          # amplified noise
    assert _check(altered(op=wild), sticky=False, kind="healthy")[0] == ["op_noise"]


def _bare_plan(**kw):
    from dataclasses import MISSING, fields
    plan = Plan(**{f.name: None for f in fields(Plan) if f.default is MISSING})
    for k, v in kw.items():
        setattr(plan, k, v)
    return plan


def test_historian_cap_keeps_a_small_pv_cycle_from_becoming_a_straight_line():
    t = np.arange(3000)
    rng = np.random.default_rng(5)
    cycle = 0.3 * np.sin(2 * np.pi * t / 150) + rng.normal(0, 0.02, t.size)
    flat_sp = np.full(t.size, 50.0)
    raw = {"pv": 50 + cycle, "op": 40 + np.sin(2 * np.pi * t / 150), "sp": flat_sp}
    # a deviation wider than everything PV does exports a line from the first to the last sample
    d = Draws(np.random.default_rng(0))
    _, flat = historian(_bare_plan(span=100.0, hist_quant=0.0, compress_pv=1.0, compress_op=0.0), d, raw)
    assert d.meta["pv_archived_points"] == 2
    assert np.abs(np.diff(flat, 2)).max() < 1e-9
    # capped at a quarter of PV's spread about its setpoint (a setpoint move does not widen it)
    sp = np.where(t < 1500, 50.0, 55.0)
    raw = {"pv": sp + cycle, "op": raw["op"], "sp": sp}
    spread = np.percentile(cycle, 95) - np.percentile(cycle, 5)
    d = Draws(np.random.default_rng(0))
    _, kept = historian(_bare_plan(span=100.0, hist_quant=0.0, compress_pv=1.0, compress_op=0.0,
                                   artifact_cap=scen.ARTIFACT_CAP), d, raw)
    assert d.meta["compress_pv_applied_pct"] == pytest.approx(spread / scen.ARTIFACT_CAP)
    assert d.meta["pv_archived_points"] > 40
    assert np.corrcoef(kept - sp, cycle)[0, 1] > 0.75
    d = Draws(np.random.default_rng(0))
    _, q = historian(_bare_plan(span=100.0, hist_quant=1.0, compress_pv=0.0, compress_op=0.0,
                                artifact_cap=scen.ARTIFACT_CAP), d, raw)
    assert d.meta["quant_applied_pct"] == pytest.approx(spread / scen.ARTIFACT_CAP)
    assert np.unique(q[:1500]).size >= 5


def test_identifiable_sticky_records_can_show_their_stiction():
    loops = list(corpus(5, 8, kinds=STICKY_SCENARIOS, n=1000, ts_s=2.0, definition="identifiable"))
    assert len(loops) == 24
    for lp in loops:
        m = lp.meta
        assert m["guard_passed"] and m["definition"] == "identifiable"
        assert len(m["redraw_reasons"]) == m["draw"]
        assert m["slips"] >= guards.MIN_SLIPS and m["stuck_fraction"] >= guards.MIN_STUCK_FRACTION
        assert m["S_over_op_noise"] >= guards.MIN_S_OVER_OP_NOISE
        assert m["op_noise_pct"] == pytest.approx(guards.op_noise(lp.op))
        assert m["op_saturated_fraction"] <= guards.MAX_SATURATED and m["op_range_pct"] <= guards.MAX_OP_RANGE_PCT
        assert m["op_noise_pct"] <= guards.MAX_OP_NOISE_PCT
        assert m["pv_offset_over_std"] <= guards.MAX_PV_OFFSET
        assert m["integrating"] == (m["index"] % 4 == 3)
        if m.get("lag_at") != "after" or not m.get("actuator_lag"):
            # no lag behind the friction: the recorded stem is the friction element
            assert m["slips"] == guards.slips_and_stuck(lp.mv, m["S_pct"])[0]
    for kind in ("two_parameter", "kano"):
        first4 = [lp.meta["class"] for lp in loops if lp.kind == kind][:4]
        assert sorted(first4) == sorted(CLASSES)
    # the guard did turn draws away here
    assert any("identifiable" in r for lp in loops for r in lp.meta["redraw_reasons"])


def test_identifiable_structure_shares():
    draws = 3000
    for kind in SCENARIOS:
        integ = fast = 0
        for i in range(draws):
            d = Draws(np.random.default_rng([11, i]))
            a, b = scen._structure(kind, d, i)
            assert not (a and b)                           # a fast flow loop is self-regulating
            integ += a
            fast += b
        if SCENARIOS[kind]:
            assert integ == draws // 4
        elif kind == "level_pi":
            assert integ == draws
        elif kind in ("overtuned", "external_sine", "external_nonsine"):
            assert integ == 0
        else:
            assert abs(integ / draws - 0.25) < 0.03
        if kind in scen.NO_FAST:
            assert fast == 0
        else:
            assert abs(fast / draws - 0.25) < 0.03, kind


def _first_fast(kind, seed, count):
    out, i = [], 0
    while len(out) < count:
        lp = make_loop(kind, seed, i, definition="identifiable")
        if lp.meta["historian_fast"]:
            out.append(lp)
        i += 1
    return out


def test_fast_loops_are_flow_loops_sampled_slower_than_they_respond():
    for lp in _first_fast("two_parameter", 2, 2) + _first_fast("healthy", 2, 2):
        m = lp.meta
        assert lp.ts_s == FAST["ts_s"] and lp.name.startswith("FIC")
        assert m["process"] in ("foptd", "soptd") and not m["integrating"]
        assert FAST["tau_s"][0] <= m["tau_s"] <= FAST["tau_s"][1] and m["delay_s"] < lp.ts_s
        assert FAST["Kc_pct_per_pct"][0] <= m["fast_Kc_pct_per_pct"] <= FAST["Kc_pct_per_pct"][1]
        assert FAST["Ti_s"][0] <= m["fast_Ti_s"] <= FAST["Ti_s"][1]
        lo, hi = FAST["closed_loop_tau_s"]
        assert lo <= m["fast_closed_loop_tau_s"] <= hi
        assert FAST["meas_noise_pct"][0] <= m["meas_noise_pct"] <= FAST["meas_noise_pct"][1]
        assert m["guard_passed"]
        if lp.sticky:
            # no quick limit cycle: the valve rests for several samples between slips
            rest = m["stuck_fraction"] * lp.n / m["slips"]
            assert rest >= 5.0


def test_tuning_detunes_a_ringing_loop_to_the_damping_floor():
    proc = P.underdamped(1.0, 1 / 20.0, 0.3, 2.0)
    detuned = 0
    for seed in range(6):
        plain = Draws(np.random.default_rng(seed))
        plain.meta["pv_span"] = 100.0
        tune(plain, proc, 1.0)
        floor = Draws(np.random.default_rng(seed))
        floor.meta["pv_span"] = 100.0
        tune(floor, proc, 1.0, zeta_min=guards.MIN_ZETA)
        assert floor.meta["closed_loop_zeta"] >= guards.MIN_ZETA
        assert floor.meta["gain_margin"] >= 2.0
        if plain.meta["closed_loop_zeta"] < guards.MIN_ZETA:
            detuned += 1
            assert floor.meta["detuned_for_damping"] and abs(floor.meta["Kc"]) < abs(plain.meta["Kc"])
    assert detuned >= 3


def test_closed_loop_sensitivity_matches_the_simulated_loop():
    proc = P.foptd(1.3, 25.0, 3.3)
    ts, Kc, Ti, m, n = 1.0, 1.0, 25.0, 10, 4000
    period = 120.0
    t = np.arange(n) * ts
    load = np.sin(2 * np.pi * t / period)
    z = np.zeros(n)
    out = run_loop(n=n, warmup=0, ts_s=ts, m=m, process=proc, valve=ValveTrain(Linear(), m=m, h_s=ts / m),
                   controller=PID(Kc, Ti, ts_s=ts, op_lo=-1e9, op_hi=1e9), signals=Signals(z, load, z, z),
                   u0=50.0, pv0=0.0)
    tail = slice(2000, None)
    basis = np.column_stack([np.sin(2 * np.pi * t[tail] / period), np.cos(2 * np.pi * t[tail] / period)])
    coef, *_ = np.linalg.lstsq(basis, out["pv"][tail], rcond=None)
    S = closed_loop_sensitivity(proc, Kc, Ti, 0.0, ts, 2 * np.pi / period)
    assert 0.3 < S < 1.5
    assert np.hypot(*coef) == pytest.approx(S, rel=0.05)


def test_identifiable_compressed_records_keep_pv_several_deviations_high():
    for i in range(4):
        lp = make_loop("compressed", 8, i, n=1500, ts_s=2.0, definition="identifiable")
        m = lp.meta
        assert m["compress_pv_applied_pct"] <= m["compress_pv_pct"] + 1e-12
        assert m["pv_spread_pct"] >= scen.ARTIFACT_CAP * m["compress_pv_applied_pct"] - 1e-9
        assert m["closed_loop_zeta"] >= guards.MIN_ZETA


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
    ident = tmp_path / "ident"
    assert cli_main(["--out", str(ident), "--seed", "2", "--n-per-kind", "1", "--n", "600", "--kinds", "kano",
                     "--definition", "identifiable"]) == 0
    with open(ident / "labels.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert [r["definition"] for r in rows] == ["identifiable"]
    assert int(rows[0]["slips"]) >= guards.MIN_SLIPS
