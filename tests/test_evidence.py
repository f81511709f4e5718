"""The non-invasive stiction tests of diagnose.evidence on clear simulated cases, their
cannot-judge reasons, and run_all's promise never to raise."""

from __future__ import annotations

import json

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import signal as sps

from diagnose.evidence import (
    TESTS, Evidence, choudhury_bicoherence, he_curve_fit, horch_integrating, horch_xcorr, kano_stuck,
    op_shape, pv_usable, run_all, singhal_area, yamashita_qsa,
)
from diagnose.evidence.bicoherence import apparent_stiction
from diagnose.evidence.curve_fit import stiction_index
from diagnose.evidence.d2pdf import d2_index
from diagnose.evidence.result import DECISIONS, graded
from diagnose.evidence._signals import half_cycles, oscillation, sample_range
from diagnose.simulate import PIDController, make_process, simulate_loop, sinusoid, sticky_loop

SEEDS = (0, 1, 2)


# --- clear cases ---------------------------------------------------------------------------------

def sticky_flow(seed):
    """A fast self-regulating loop (a flow) with a sticky valve (S 3 %, J 1 %) and flow-loop PI."""
    return sticky_loop(3.0, 1.0, n=3000, tau_s=2.0, delay_s=1.0, Kc=0.2, Ti_s=2.0, noise_std=0.05,
                       load_walk_std=0.01, seed=seed)


def healthy_sine_load(seed, period_s=20.0, ts_s=0.25):
    """A healthy self-regulating loop oscillating with an external sinusoidal load."""
    n = int(50 * period_s / ts_s)
    return simulate_loop(n=n, ts_s=ts_s, process=make_process("foptd", gain=1.0, tau_s=10.0, delay_s=1.0),
                         controller=PIDController(Kc=2.0, Ti_s=10.0), load=sinusoid(n, ts_s, period_s, 2.0),
                         noise_std=0.05, seed=seed, warmup=400)


def sticky_level(seed):
    """An integrating loop (a level) with a sticky valve."""
    return sticky_loop(3.0, 1.0, n=3000, kind="integrating", gain=0.02, tau_s=0.0, delay_s=2.0,
                       noise_std=0.02, load_walk_std=0.002, seed=seed)


def level_sine_inflow(seed):
    """A healthy level loop under PI with a sinusoidal inflow."""
    n = 3000
    return simulate_loop(n=n, ts_s=1.0, process=make_process("integrating", gain=0.02, tau_s=0.0, delay_s=2.0),
                         controller=PIDController(Kc=1.0 / (0.02 * 6.0), Ti_s=24.0),
                         load=sinusoid(n, 1.0, 200.0, 1.0), noise_std=0.02, seed=seed, warmup=300)


def by_name(evidence):
    return {e.test: e for e in evidence}


@pytest.fixture(scope="module")
def flow_runs():
    return [run_all(r.op, r.pv, r.ts_s, sp=r.sp, integrating=False) for r in map(sticky_flow, SEEDS)]


@pytest.fixture(scope="module")
def sine_runs():
    return [run_all(r.op, r.pv, r.ts_s, sp=r.sp, integrating=False) for r in map(healthy_sine_load, SEEDS)]


@pytest.fixture(scope="module")
def level_runs():
    return [run_all(r.op, r.pv, r.ts_s, sp=r.sp, integrating=True) for r in map(sticky_level, SEEDS)]


@pytest.fixture(scope="module")
def level_sine_runs():
    return [run_all(r.op, r.pv, r.ts_s, sp=r.sp, integrating=True) for r in map(level_sine_inflow, SEEDS)]


@pytest.mark.parametrize("test", ["horch_xcorr", "he_curve_fit", "kano_stuck", "yamashita_qsa", "op_shape"])
def test_sticky_flow_loop_is_stiction(flow_runs, test):
    for ev in flow_runs:
        e = by_name(ev)[test]
        assert e.decision == "stiction", e
        assert e.value >= e.threshold


@pytest.mark.parametrize("test", ["horch_xcorr", "he_curve_fit", "kano_stuck", "yamashita_qsa", "singhal_area",
                                  "op_shape", "choudhury_bicoherence"])
def test_healthy_loop_with_sinusoidal_load_is_no_stiction(sine_runs, test):
    for ev in sine_runs:
        assert by_name(ev)[test].decision == "no_stiction", by_name(ev)[test]


def test_area_ratio_of_sticky_flow_exceeds_one(flow_runs):
    # the paper's inequality holds on every seed; the decision (>= 1.25) on most
    rs = [by_name(ev)["singhal_area"] for ev in flow_runs]
    assert all(e.value > 1.0 for e in rs)
    assert sum(e.decision == "stiction" for e in rs) >= 2


def test_horch_ccf_is_odd_for_stiction_and_even_for_fast_load(flow_runs, sine_runs):
    odd = [by_name(ev)["horch_xcorr"].value for ev in flow_runs]
    even = [by_name(ev)["horch_xcorr"].value for ev in sine_runs]
    assert min(odd) > 0.8 and max(even) < 0.33


def test_stuck_stretches_report_the_valve_stickband(flow_runs):
    # the horizontal side of the PV-OP parallelogram is close to S = 3 %
    s = [by_name(ev)["kano_stuck"].extras["apparent_S_pct"] for ev in flow_runs]
    assert all(1.5 < v < 3.5 for v in s), s


@pytest.mark.parametrize("test", ["horch_integrating", "he_curve_fit"])
def test_sticky_level_loop_is_stiction(level_runs, test):
    for ev in level_runs:
        assert by_name(ev)[test].decision == "stiction", by_name(ev)[test]


@pytest.mark.parametrize("test", ["horch_integrating", "he_curve_fit", "op_shape"])
def test_level_loop_with_sinusoidal_inflow_is_no_stiction(level_sine_runs, test):
    for ev in level_sine_runs:
        assert by_name(ev)[test].decision == "no_stiction", by_name(ev)[test]


@pytest.mark.parametrize("test", ["horch_xcorr", "kano_stuck", "yamashita_qsa", "singhal_area"])
def test_self_regulating_tests_leave_integrating_loops_alone(level_runs, test):
    for ev in level_runs:
        e = by_name(ev)[test]
        assert e.decision == "cannot_judge" and e.reason == "wrong_process_type"


def test_integrating_test_leaves_self_regulating_loops_alone(flow_runs):
    for ev in flow_runs:
        assert by_name(ev)["horch_integrating"].reason == "wrong_process_type"


# --- the shape fits on synthetic waves ---------------------------------------------------------

def _waves(n=3000, period=100.0, noise=0.05, seed=0):
    t = np.arange(n, dtype=float)
    rng = np.random.default_rng(seed)
    tri = sps.sawtooth(2 * np.pi * t / period, 0.5) + rng.normal(0, noise, n)
    sin = np.sin(2 * np.pi * t / period) + rng.normal(0, noise, n)
    return tri, sin


@pytest.mark.parametrize("seed", SEEDS)
def test_curve_fit_tells_triangle_from_sinusoid(seed):
    tri, sin = _waves(seed=seed)
    e_tri = he_curve_fit(tri, sin, 1.0, integrating=False)      # OP is fitted for self-regulating
    e_sin = he_curve_fit(sin, tri, 1.0, integrating=False)
    assert e_tri.decision == "stiction" and e_tri.value > 0.75
    assert e_sin.decision == "no_stiction" and e_sin.value < 0.15
    # an integrating loop's PV is fitted instead
    assert he_curve_fit(sin, tri, 1.0, integrating=True).decision == "stiction"


def test_curve_fit_index_is_exact_on_clean_shapes():
    t = np.arange(2000, dtype=float)
    tri = sps.sawtooth(2 * np.pi * t / 80, 0.5)
    sin = np.sin(2 * np.pi * t / 80)
    for x, lo, hi in ((tri, 0.95, 1.0), (sin, 0.0, 0.02)):
        c0, c1 = half_cycles(x, 80.0)
        si, mse_s, mse_t = stiction_index(x, *sample_range(c0, c1))
        assert lo <= si <= hi, si


def test_second_derivative_distribution_separates_triangle_and_sinusoid():
    tri, sin = _waves(noise=0.02)
    assert d2_index(tri, 100.0)[0] > 0.6
    assert d2_index(sin, 100.0)[0] < 0.2


def test_area_ratio_is_one_for_a_sinusoid_sampled_coarsely():
    # few samples per half-cycle must not tilt the ratio
    for period in (8.0, 12.0, 12.7, 20.0):
        t = np.arange(3000, dtype=float)
        x = np.sin(2 * np.pi * t / period + 0.3)
        e = singhal_area(0.5 * x, -x, 1.0, integrating=False)
        assert abs(e.value - 1.0) < 0.03, (period, e.value)


# --- bicoherence ---------------------------------------------------------------------------------

def _asymmetric_limit_cycle(seed, n=4096, period=40.0, noise=0.05):
    """A square-like PV with 30 % duty (a valve that jumps, asymmetric) and OP its integral."""
    rng = np.random.default_rng(seed)
    t = np.arange(n, dtype=float)
    pv = sps.square(2 * np.pi * t / period, 0.3) + 0.4
    pv = np.convolve(pv, np.ones(3) / 3, mode="same") + rng.normal(0, noise, n)
    op = -np.cumsum(pv - pv.mean()) * 0.1
    op = op - np.polyval(np.polyfit(t, op, 1), t) + 50.0
    return op, pv


@pytest.mark.parametrize("seed", SEEDS)
def test_bicoherence_finds_an_asymmetric_limit_cycle_nonlinear(seed):
    op, pv = _asymmetric_limit_cycle(seed)
    e = choudhury_bicoherence(op, pv, 1.0)
    assert e.decision == "stiction", e
    assert e.extras["NGI"] > 0.001 and e.extras["NLI"] > 0.01
    assert e.extras["apparent_stiction_pct"] > 0


@pytest.mark.parametrize("seed", SEEDS)
def test_bicoherence_finds_a_sinusoid_gaussian(seed):
    rng = np.random.default_rng(seed)
    t = np.arange(4096, dtype=float)
    pv = np.sin(2 * np.pi * t / 40) + rng.normal(0, 0.1, t.size)
    e = choudhury_bicoherence(50 + np.cos(2 * np.pi * t / 40), pv, 1.0)
    assert e.decision == "no_stiction" and e.extras["NGI"] <= 0.001


def test_apparent_stiction_is_the_ellipse_chord_along_op():
    # PV = sin(t), OP = cos(t) * a: a circle scaled along OP; the chord through the centre is 2a
    t = np.linspace(0, 40 * np.pi, 4000)
    chord, extent = apparent_stiction(3.0 * np.cos(t), np.sin(t))
    assert chord == pytest.approx(6.0, rel=1e-3) and extent == pytest.approx(6.0, rel=1e-3)
    # a tilted ellipse: the chord along OP is shorter than its OP extent
    chord, extent = apparent_stiction(np.cos(t), np.sin(t + 1.0))
    assert chord < extent


# --- OP only -------------------------------------------------------------------------------------

def test_op_only_judges_when_pv_is_dead(flow_runs):
    r = sticky_flow(0)
    dead = np.full_like(r.pv, 7.0)
    ev = by_name(run_all(r.op, dead, r.ts_s, sp=r.sp, integrating=False))
    assert ev["op_shape"].decision == "stiction"
    assert "OP alone" in ev["op_shape"].note
    for name in TESTS:
        if name != "op_shape":
            assert ev[name].decision == "cannot_judge" and ev[name].reason == "pv_unusable"
    assert op_shape(r.op, None, r.ts_s).decision == "stiction"


def test_op_only_judges_only_the_longest_stretch_between_setpoint_steps():
    from diagnose.evidence.op_shape import setpoint_steps, steady_stretch
    from diagnose.simulate import LinearValve, StictionValve, make_process, simc_pi, simulate_loop

    def loop(valve, sp, seed):
        return simulate_loop(n=sp.shape[0], ts_s=1.0, process=make_process("foptd", gain=1.0, tau_s=20.0,
                                                                            delay_s=3.0),
                             controller=simc_pi(1.0, 20.0, 3.0, 1.0), valve=valve, sp=sp, noise_std=0.02,
                             seed=seed)

    n = 3000
    # a healthy valve under a square setpoint: OP ramps between sharp turns like a sticky valve's
    square = np.where((np.arange(n) // 250) % 2 == 0, 1.0, -1.0)
    rec = loop(LinearValve(), square, 4)
    assert np.array_equal(setpoint_steps(rec.sp), np.arange(250, n, 250))
    ev = op_shape(rec.op, None, rec.ts_s, sp=rec.sp)
    assert ev.decision == "cannot_judge" and "the setpoint steps 11 times" in ev.note
    # without the setpoint the same OP reads as a sticky valve's saw-tooth
    assert op_shape(rec.op, None, rec.ts_s).decision == "stiction"
    # a sticky valve whose loop had one setpoint step: its stick-slip cycle after the step is judged
    step = np.where(np.arange(n) < 700, 0.0, 2.0)
    assert steady_stretch(n, setpoint_steps(step)) == (700 + 230, n)
    # the record's own start is no step: nothing to settle from there
    assert steady_stretch(n, np.array([2000])) == (0, 2000)
    ev = op_shape(loop(StictionValve(3.0, 1.0, 1), step, 1).op, None, 1.0, sp=step)
    assert ev.decision == "stiction" and "in samples 930-3000" in ev.note and "steps once" in ev.note
    # a setpoint that moves on every sample (a cascade master's output) does not step
    assert setpoint_steps(np.sin(np.arange(n) / 50.0)).shape[0] == 0
    assert setpoint_steps(np.full(n, 3.0)).shape[0] == 0 and setpoint_steps(None).shape[0] == 0


def test_op_only_says_no_for_a_smooth_op(sine_runs):
    r = healthy_sine_load(0)
    assert op_shape(r.op, None, r.ts_s).decision == "no_stiction"


# --- cannot judge --------------------------------------------------------------------------------

@pytest.mark.parametrize("n", [0, 1, 2, 10, 31])
def test_too_short_records_say_so(n):
    x = np.arange(n, dtype=float)
    for e in run_all(x, x, 1.0, integrating=False):
        assert e.decision == "cannot_judge" and e.reason == "too_short", e


def test_constant_pv_is_unusable_and_said_so():
    op = 50 + np.sin(np.arange(500) / 10)
    ok, why = pv_usable(np.full(500, 3.0))
    assert not ok and "constant" in why
    ev = by_name(run_all(op, np.full(500, 3.0), 1.0, integrating=False))
    assert ev["horch_xcorr"].reason == "pv_unusable" and "constant" in ev["horch_xcorr"].note


def test_constant_op_cannot_show_stiction():
    pv = np.sin(np.arange(500) / 10)
    for e in run_all(np.full(500, 40.0), pv, 1.0, integrating=False):
        assert e.reason == "op_flat"


@pytest.mark.parametrize("test", [horch_xcorr, he_curve_fit, singhal_area])
def test_no_oscillation_is_said(test):
    rng = np.random.default_rng(3)
    op = 50 + rng.normal(0, 1, 2000)
    pv = rng.normal(0, 1, 2000)
    e = test(op, pv, 1.0, integrating=False)
    assert e.decision == "cannot_judge"
    assert e.reason in ("no_oscillation", "irregular_oscillation", "too_few_cycles")


def test_too_few_cycles_is_said():
    t = np.arange(300, dtype=float)
    x = np.sin(2 * np.pi * t / 200)        # 1.5 cycles
    e = he_curve_fit(50 + x, x, 1.0, integrating=False)
    assert e.decision == "cannot_judge" and e.reason in ("too_few_cycles", "no_oscillation")


@pytest.mark.parametrize("test", [horch_xcorr, horch_integrating, he_curve_fit, kano_stuck, yamashita_qsa,
                                  singhal_area])
def test_unknown_process_type_is_said(test):
    r = sticky_flow(0)
    e = test(r.op, r.pv, r.ts_s, sp=r.sp, integrating=None)
    assert e.decision == "cannot_judge" and e.reason == "process_type_unknown"


def test_bicoherence_needs_enough_segments():
    t = np.arange(200, dtype=float)
    x = np.sin(2 * np.pi * t / 20)
    assert choudhury_bicoherence(50 + x, x, 1.0).reason == "too_short"


def test_bad_sample_period_and_mismatched_lengths():
    x = np.sin(np.arange(400) / 5)
    assert all(e.reason == "bad_sample_period" for e in run_all(x, x, 0.0, integrating=False))
    ev = by_name(run_all(50 + x, x[:300], 1.0, integrating=False))
    assert ev["he_curve_fit"].reason == "pv_unusable" and "300" in ev["he_curve_fit"].note


@pytest.mark.parametrize("pv,word", [
    (np.r_[np.full(450, 2.0), np.linspace(2, 3, 50)], "frozen"),
    (np.tile([0.0, 1.0, 2.0], 200), "distinct"),
    (np.r_[np.full(100, np.nan), np.sin(np.arange(400))], "non-finite"),
    (np.repeat(np.sin(np.arange(30)), 30), "changes in only"),
])
def test_pv_usable_names_what_is_wrong(pv, word):
    ok, why = pv_usable(pv)
    assert not ok and word in why


def test_pv_usable_accepts_a_noisy_pv():
    assert pv_usable(np.random.default_rng(0).normal(0, 1, 500)) == (True, "")


# --- the result type and run_all -----------------------------------------------------------------

def test_graded_decisions_include_both_thresholds():
    # the grey zone is open: a value on either threshold is decided, one between them is not
    notes = {"stiction": "s", "no_stiction": "n", "undetermined": "u"}
    got = [graded("t", v, 0.6, 0.4, notes, {"k": 1.0}) for v in (0.7, 0.6, 0.5, 0.4, 0.3)]
    assert [e.decision for e in got] == ["stiction", "stiction", "undetermined", "no_stiction", "no_stiction"]
    assert [e.note for e in got] == ["s", "s", "u", "n", "n"]
    assert all(e.threshold == 0.6 and e.extras == {"k": 1.0} for e in got)


def test_evidence_to_dict_is_json_and_drops_non_finite():
    e = Evidence("x", float("nan"), 0.5, "undetermined", "n", extras={"a": 1.0, "b": float("inf")})
    d = e.to_dict()
    assert d["value"] is None and d["extras"] == {"a": 1.0}
    json.dumps(d, allow_nan=False)
    with pytest.raises(ValueError, match="decision"):
        Evidence("x", 1.0, 1.0, "maybe", "n")


def test_run_all_returns_every_test_in_order(flow_runs):
    for ev in flow_runs:
        assert tuple(e.test for e in ev) == TESTS
        json.dumps([e.to_dict() for e in ev], allow_nan=False)


@settings(max_examples=60, deadline=None, derandomize=True)
@given(st.integers(0, 600), st.integers(0, 2 ** 32 - 1), st.sampled_from([None, True, False]),
       st.sampled_from(["noise", "sine", "steps", "const", "spikes"]), st.booleans())
def test_run_all_never_raises(n, seed, integrating, kind, with_sp):
    rng = np.random.default_rng(seed)
    t = np.arange(n, dtype=float)
    if kind == "noise":
        pv = rng.normal(0, 1, n)
    elif kind == "sine":
        pv = np.sin(2 * np.pi * t / rng.uniform(2, 200)) + rng.normal(0, 0.1, n)
    elif kind == "steps":
        pv = np.round(rng.normal(0, 1, n).cumsum())
    elif kind == "const":
        pv = np.full(n, rng.normal())
    else:
        pv = np.zeros(n)
        if n:
            pv[rng.integers(0, n, 3)] = 1e6
    op = 50 + rng.normal(0, 1, n).cumsum() * rng.uniform(0, 1)
    sp = rng.normal(0, 1, n).round() if with_sp else None
    ev = run_all(op, pv, rng.uniform(0.1, 60), sp=sp, integrating=integrating)
    assert tuple(e.test for e in ev) == TESTS
    for e in ev:
        assert e.decision in DECISIONS
        assert e.reason != "internal_error", e
        assert (e.value is None) == (e.decision == "cannot_judge")
        json.dumps(e.to_dict(), allow_nan=False)


def test_oscillation_reads_a_three_cycle_window():
    # the evidence tests judge short plant windows: three cycles give a period
    t = np.arange(300, dtype=float)
    o = oscillation(np.sin(2 * np.pi * t / 100))
    assert o.period == pytest.approx(100, rel=0.05) and o.cycles == pytest.approx(3, rel=0.05)


def test_the_filters_and_peaks_match_scipy_signal():
    # the evidence tests carry their own Butterworth filters and peak finder so that the command
    # does not import scipy.signal at start-up; they must give scipy's numbers
    from scipy import signal as sps

    from diagnose import kernels
    from diagnose.evidence import _signals
    from diagnose.evidence.stuck import _prominent_peaks

    rng = np.random.default_rng(3)
    for order in (2, 4):
        for _ in range(20):
            x = rng.standard_normal(int(rng.integers(40, 2000))).cumsum()
            w = float(rng.uniform(0.005, 0.9))
            ours = _signals._sosfiltfilt(_signals._butter(order, (w,), "lowpass"), x)
            ref = sps.sosfiltfilt(sps.butter(order, w, output="sos"), x)
            assert np.max(np.abs(ours - ref)) <= 1e-9 * np.max(np.abs(ref))
            lo = float(rng.uniform(0.005, 0.4))
            hi = float(rng.uniform(1.2 * lo, 0.9))
            ours = _signals._sosfiltfilt(_signals._butter(order, (lo, hi), "bandpass"), x)
            ref = sps.sosfiltfilt(sps.butter(order, [lo, hi], btype="bandpass", output="sos"), x)
            assert np.max(np.abs(ours - ref)) <= 1e-9 * np.max(np.abs(ref))
    for k in range(100):
        x = np.round(rng.standard_normal(int(rng.integers(3, 500))).cumsum(), 1 if k % 2 else 6)  # plateaus too
        peaks, prom = kernels.peak_prominences(x)
        ref, _ = sps.find_peaks(x)
        assert np.array_equal(peaks, ref)
        if ref.size:
            assert np.array_equal(prom, sps.peak_prominences(x, ref)[0])
        p_min = float(rng.uniform(0.0, 3.0))
        assert np.array_equal(_prominent_peaks(x, p_min), sps.find_peaks(x, prominence=p_min)[0])
    y, zf = kernels.sosfilt(np.array([[0.2, 0.3, 0.1, 1.0, -0.5, 0.2]]), np.arange(10.0), np.zeros((1, 2)))
    ref, ref_zf = sps.sosfilt(np.array([[0.2, 0.3, 0.1, 1.0, -0.5, 0.2]]), np.arange(10.0), zi=np.zeros((1, 2)))
    assert np.allclose(y, ref, rtol=1e-14, atol=0) and np.allclose(zf, ref_zf, rtol=1e-14, atol=1e-15)
