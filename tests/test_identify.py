"""identify(): verdict, class, JSON contract, OP/MV path, oscillation context, bad input."""

import json

import numpy as np
import pytest

from diagnose.errors import DataError
from diagnose.identification import INSAMPLE_THRESHOLD, Identification, identify
from diagnose.oscillation import acf, oscillation_context
from diagnose.record import Finding, LoopRecord
from diagnose.simulate import sticky_loop
from diagnose.stiction_model import CLASSES

REQUIRED = {"loop": str, "stiction": bool, "stiction_probability": float, "class": str, "S": float, "J": float,
            "S_interval": list, "J_interval": list, "process": dict, "fit": dict, "oscillation": dict,
            "evidence": list, "warnings": list}


def _no_mv(rec):
    return rec.replace(mv=None)


@pytest.fixture(scope="module")
def sticky_result():
    rec = sticky_loop(4.0, 1.5, n=2000, gain=1.5, tau_s=20.0, delay_s=3.0, noise_std=0.02,
                      load_walk_std=0.01, seed=1, name="FIC101")
    return identify(_no_mv(rec))


def test_a_sticky_loop_is_detected_and_classed(sticky_result):
    res = sticky_result
    assert isinstance(res, Identification)
    assert res.stiction and res.cls == "undershoot"
    assert res.S_pct == pytest.approx(4.0, rel=0.1)
    assert res.method == "op_pv"
    assert res.stiction_probability >= res.verdict.threshold
    rows = {ev.test: ev for ev in res.evidence}
    assert rows["model_fit"].decision == "stiction" and rows["valve_band"].decision == "stiction"
    assert res.detection.insample_improvement > INSAMPLE_THRESHOLD
    assert res.oscillation.oscillating and res.oscillation.period_s > 0
    assert 0.5 < res.confidence <= 1.0
    assert res.fit is not None and res.valve_fit is None


def test_to_dict_holds_the_issue_contract(sticky_result):
    d = sticky_result.to_dict()
    for key, typ in REQUIRED.items():
        assert isinstance(d[key], typ), key
    assert d["class"] in CLASSES
    assert set(d["fit"]) >= {"rmse", "r2"}
    for ev in d["evidence"]:
        assert set(ev) >= {"test", "value", "threshold", "decision", "note"}
        assert ev["decision"] in ("stiction", "no_stiction", "undetermined", "cannot_judge")
    assert {ev["test"] for ev in d["evidence"]} >= {"horch_xcorr", "he_curve_fit", "choudhury_bicoherence",
                                                   "kano_stuck", "singhal_area", "model_fit", "valve_band"}
    assert d["S_interval"][0] <= d["S"] <= d["S_interval"][1]
    assert set(d["process"]) >= {"kind", "gain", "tau_s", "delay_s"}
    assert 0.0 <= d["confidence"] <= 1.0
    json.dumps(d, allow_nan=False)                       # strict JSON


def test_a_healthy_loop_reports_none_with_zero_S_and_J():
    rec = sticky_loop(0.0, 0.0, n=2000, gain=1.0, tau_s=15.0, delay_s=2.0, noise_std=0.05,
                      load_walk_std=0.02, seed=11)
    res = identify(_no_mv(rec))
    d = res.to_dict()
    assert d["stiction"] is False and d["class"] == "none"
    assert d["S"] == 0.0 and d["J"] == 0.0


def test_op_mv_record_is_fitted_directly():
    rec = sticky_loop(3.0, 3.0, n=1500, noise_std=0.02, load_walk_std=0.01, seed=3)
    res = identify(rec)
    assert res.method == "op_mv" and res.valve_fit is not None
    assert res.stiction and res.cls == "no_offset"
    assert res.S_pct == pytest.approx(3.0, abs=0.2)


def test_a_valve_that_never_moves_is_a_result_with_a_warning():
    rec = sticky_loop(3.0, 1.0, n=600, noise_std=0.02, load_walk_std=0.01, seed=3)
    stuck = rec.replace(mv=np.full(rec.n, 42.0))
    res = identify(stuck)
    d = res.to_dict()
    assert d["stiction"] is True
    warn = next(w for w in d["warnings"] if w["code"] == "valve_not_moving")
    # the stem never moved: no class can be read off it (it was reported "deadband" with
    # S in [OP's travel, 100] and J in [0, 100]); the class is not judged, and the warning says why
    assert d["class"] == "unknown" and d["class_alternatives"] == []
    assert d["S"] is None and d["J"] is None and d["S_interval"] is None and d["J_interval"] is None
    assert "class" in warn["message"] and "never moved" in warn["message"]
    assert res.valve_not_moving
    assert res.fitted_S_pct == pytest.approx(np.percentile(rec.op, 99.5) - np.percentile(rec.op, 0.5))


def _one_slip_record(seed: int = 1) -> LoopRecord:
    """OP wanders over about a fifth of the span; the stem moves once, by 2 %."""
    rng = np.random.default_rng(seed)
    n = 3000
    op = np.clip(50.0 + np.cumsum(rng.normal(0.0, 0.3, n)), 30.0, 70.0)
    mv = np.full(n, 50.0)
    mv[1800:] = 52.0
    pv = 2.0 * mv + rng.normal(0.0, 0.1, n)
    return LoopRecord(name="ONE_SLIP", ts_s=1.0, op=op, pv=pv, mv=mv)


@pytest.mark.parametrize("pv_dead", [False, True])
def test_a_valve_that_slipped_once_is_sticky_but_not_sized(pv_dead):
    # one slip fits many (S, J) pairs about equally well (here an overshoot valve of S 11 % and
    # J 20 % with intervals that look tight): the verdict stands, the size and class are not given
    rec = _one_slip_record()
    if pv_dead:
        rec = rec.replace(pv=np.full(rec.n, 1.0))
    res = identify(rec)
    assert res.method == "op_mv" and res.stiction
    assert res.cls == "unknown" and res.S_pct is None and res.J_pct is None
    said = next(w.message for w in res.warnings if w.code == "size_unknown")
    assert "slips only once" in said and "needs 3" in said
    assert res.to_dict()["S_interval"] is None


def test_a_valve_with_many_slips_is_still_sized():
    rec = sticky_loop(3.0, 1.0, n=1500, noise_std=0.02, load_walk_std=0.01, seed=3)
    res = identify(rec)
    assert res.stiction and res.S_pct == pytest.approx(3.0, abs=0.2)
    assert not any(w.code == "size_unknown" for w in res.warnings)


def test_a_still_stem_under_a_small_op_travel_says_nothing_and_op_pv_judges():
    # OP wanders 0.3 % of span: a healthy valve with a positioner's deadband need not follow, so a
    # still stem is no proof of stiction; the verdict is the one the same record gets without MV
    rng = np.random.default_rng(5)
    rec = sticky_loop(0.0, 0.0, n=2000, noise_std=0.05, load_walk_std=0.01, seed=4)
    op = 50.0 + 0.3 * (rec.op - rec.op.min()) / np.ptp(rec.op) + rng.normal(0.0, 1e-4, rec.n)
    small = rec.replace(op=op, mv=np.full(rec.n, 50.0))
    res = identify(small)
    codes = {w.code for w in res.warnings}
    assert "mv_uninformative" in codes and "valve_not_moving" not in codes
    assert res.method == "op_pv"
    alone = identify(_no_mv(small))
    assert res.stiction == alone.stiction and res.stiction_probability == pytest.approx(alone.stiction_probability)
    # the same still stem under a 3 % travel is a stuck valve
    big = rec.replace(op=50.0 + 3.0 * (rec.op - rec.op.min()) / np.ptp(rec.op), mv=np.full(rec.n, 50.0))
    stuck = identify(big)
    assert stuck.valve_not_moving and stuck.stiction and stuck.method == "op_mv"


def test_a_short_record_whose_stem_never_moves_has_no_class():
    rec = sticky_loop(3.0, 1.0, n=60, noise_std=0.02, load_walk_std=0.01, seed=3)
    assert np.ptp(rec.mv) == 0.0
    # OP's own travel here (0.36 %) is under the band the verdict calls stiction (see the test
    # above): ten times that is a stem that should have moved
    rec = rec.replace(op=rec.op.mean() + 10.0 * (rec.op - rec.op.mean()))
    d = identify(rec).to_dict()
    assert {w["code"] for w in d["warnings"]} >= {"valve_not_moving", "short_record"}
    assert d["class"] == "unknown" and d["S"] is None and d["J_interval"] is None


@pytest.mark.parametrize("op,pv,match", [
    (np.full(300, 50.0), np.random.default_rng(0).normal(size=300), "OP is constant"),
    (np.linspace(40, 60, 20), np.linspace(0, 1, 20), "at least"),
])
def test_unusable_records_raise_data_errors(op, pv, match):
    with pytest.raises(DataError, match=match):
        identify(LoopRecord(name="X", ts_s=1.0, op=op, pv=pv))


def test_truncated_time_stamps_hedge_the_verdict(sticky_result):
    rec = sticky_loop(4.0, 1.5, n=2000, gain=1.5, tau_s=20.0, delay_s=3.0, noise_std=0.02,
                      load_walk_std=0.01, seed=1, name="FIC101")
    dup = Finding("duplicates", "1660 of 2000 rows share their time stamp: truncated", "warning", {"share": 0.83})
    res = identify(_no_mv(rec).replace(findings=(dup,), meta={"quality_checked": True}))
    assert res.confidence <= 0.5 < sticky_result.confidence
    assert any(w["code"] == "data_quality.duplicates" for w in res.to_dict()["warnings"])


def test_compression_hedges_the_verdict(sticky_result):
    rec = sticky_loop(4.0, 1.5, n=2000, gain=1.5, tau_s=20.0, delay_s=3.0, noise_std=0.02,
                      load_walk_std=0.01, seed=1, name="FIC101")
    comp = Finding("compression", "OP looks swinging-door compressed", "warning", {})
    rec = _no_mv(rec).replace(findings=(comp,), meta={"quality_checked": True})
    res = identify(rec)
    assert res.confidence <= 0.5 < sticky_result.confidence
    said = [w["message"] for w in res.to_dict()["warnings"] if w["code"] == "data_quality.compression"]
    # one finding, one warning (a second one counted twice in the severity's data-quality part)
    assert len(said) == 1 and said[0].startswith("OP looks swinging-door compressed") and "hedged" in said[0]


def test_oscillation_context_finds_the_period_of_a_noisy_sine():
    rng = np.random.default_rng(2)
    t = np.arange(2000.0)
    osc = oscillation_context(np.sin(2 * np.pi * t / 80) + 0.2 * rng.normal(size=t.size), 0.5)
    assert osc.oscillating
    assert osc.period_s == pytest.approx(40.0, rel=0.05)     # 80 samples at 0.5 s
    calm = oscillation_context(rng.normal(size=2000), 1.0)
    assert not calm.oscillating
    r = acf(np.sin(t / 5))
    assert r[0] == pytest.approx(1.0)


def test_class_test_keeps_the_special_shape_that_the_data_allow():
    # J = S: the restricted fit (no offset) must be accepted and reported as such
    rec = sticky_loop(3.0, 3.0, n=2000, gain=1.2, tau_s=15.0, delay_s=4.0, noise_std=0.02,
                      load_walk_std=0.01, seed=5, f0=-1)
    res = identify(_no_mv(rec))
    ct = res.detection.class_test
    assert res.stiction and res.cls == "no_offset"
    assert res.J_pct == pytest.approx(res.S_pct) and res.S_pct == pytest.approx(3.0, rel=0.1)
    assert ct.cost_no_offset <= ct.bound and ct.cost_free <= ct.cost_fit * (1 + 1e-12)
    # ... and without the test the free J is reported (the contract of class_test=False)
    res0 = identify(_no_mv(rec), class_test=False)
    assert res0.detection.class_test is None and "class_test" not in res0.to_dict()["detection"]
    assert res0.fitted_J_pct == pytest.approx(res0.fit.J_pct)


def test_class_test_does_not_force_a_shape_the_data_reject(sticky_result):
    # J = 0.375 S (undershoot): both restrictions are rejected by the F-test bound
    ct = sticky_result.detection.class_test
    assert ct.cls is None
    assert ct.cost_deadband > ct.bound and ct.cost_no_offset > ct.bound
    assert sticky_result.to_dict()["detection"]["class_test"]["cls"] is None


def test_class_alternatives_name_the_shapes_the_data_cannot_separate(sticky_result):
    # clean undershoot: one shape only
    assert sticky_result.cls == "undershoot" and sticky_result.class_alternatives == ()
    assert sticky_result.to_dict()["class_alternatives"] == []
    # J = 1.2 S, just past the no-offset tolerance, in noise: both shapes stay plausible
    rec = sticky_loop(3.0, 3.6, n=1500, noise_std=0.2, load_walk_std=0.05, tau_s=40.0, delay_s=4.0,
                      seed=2)
    res = identify(_no_mv(rec))
    assert res.stiction
    assert res.cls not in res.class_alternatives
    assert {"overshoot", "no_offset"} <= {res.cls, *res.class_alternatives}
    assert set(res.detection.class_test.plausible) == {res.cls, *res.class_alternatives}


def test_a_backlash_on_a_slow_process_is_found_by_its_likelihood_ratio():
    # deadband valve, slow process, noisy: the in-sample gain (about 1 %) is below the in-sample
    # threshold and S is not sharp, but the deadband-shaped fit's likelihood ratio is clear; the
    # combined probability lands between the fit rule's floor and the threshold, and the fit rule
    # settles it
    kw = dict(n=3000, noise_std=0.2, load_walk_std=0.02, tau_s=60.0, delay_s=8.0, seed=1)
    res = identify(_no_mv(sticky_loop(2.5, 0.0, **kw)))
    det = res.detection
    assert det.insample_improvement < 0.05
    rows = {ev.test: ev for ev in res.evidence}
    assert res.stiction and res.cls == "deadband" and rows["deadband_fit"].decision == "stiction"
    assert res.verdict.by_fit_rule and res.stiction_probability < res.verdict.threshold
    assert res.to_dict()["combination"]["by_fit_rule"] is True
    assert det.backlash_lr > 10.83
    assert res.S_pct == pytest.approx(2.5, rel=0.15)
    # the same loop with a healthy valve is left alone
    healthy = identify(_no_mv(sticky_loop(0.0, 0.0, **kw)))
    assert not healthy.stiction and healthy.stiction_probability < healthy.verdict.threshold


def test_class_test_finds_the_needle_in_S():
    """With J > 0 the cost is a needle in S: started from an S 7 % off, the fine scan lands within
    0.5 % of the true S at a far lower cost than the coarse grid alone."""
    import dataclasses

    from diagnose.fit import fit_hammerstein
    from diagnose.search import ClassTestConfig, class_test

    rec = sticky_loop(5.0, 5.0, n=2000, gain=1.5, tau_s=30.0, delay_s=5.0, noise_std=0.05,
                      load_walk_std=0.01, seed=3)
    fit = fit_hammerstein(rec.op, rec.pv, rec.ts_s, gain_sign=1)
    off = dataclasses.replace(fit, S_pct=fit.S_pct * 1.07, J_pct=fit.J_pct * 1.07)
    fine = class_test(rec.op, rec.pv, rec.ts_s, off, gain_sign=1)
    coarse = class_test(rec.op, rec.pv, rec.ts_s, off, gain_sign=1, cfg=ClassTestConfig(fine_S=0))
    assert abs(fine["S_pct"] - 5.0) < 0.025
    assert fine["cost"] < 0.8 * coarse["cost"]
    assert fine["cls"] == "no_offset"
    # the grids scored on one thread or on several: the same answer to the last bit
    assert class_test(rec.op, rec.pv, rec.ts_s, off, gain_sign=1, threads=1) == fine
    assert class_test(rec.op, rec.pv, rec.ts_s, off, gain_sign=1, threads=3) == fine


def test_a_stem_that_follows_op_exactly_shows_no_gain_rather_than_a_ratio_of_rounding_errors():
    # healthy valve, MV = OP to the last bit: both valve fits cost next to nothing, so the valve
    # model's gain over the linear one is 0, not a ratio of two rounding errors
    rec = sticky_loop(0.0, 0.0, n=2000, noise_std=0.05, seed=3)
    assert np.array_equal(rec.mv, rec.op)
    res = identify(rec)
    row = {ev.test: ev for ev in res.evidence}["model_fit"]
    assert res.method == "op_mv" and row.value == 0.0 and row.decision == "no_stiction"
    assert not res.stiction


def _fraction_op(rec):
    return rec.replace(op=rec.op / 100.0)


def test_a_fraction_op_beside_a_stem_position_in_percent_is_scaled_by_it():
    # OP logged 0..1 with the stem in %: the valve fit saw OP -> MV with a gain of 100 and found no band
    # (size unknown, confidence held at 50 %), while the same data in % give S = 3, J = 1
    rec = sticky_loop(3.0, 1.0, n=3000, noise_std=0.02, load_walk_std=0.01, seed=0)
    res = identify(_fraction_op(rec))
    codes = {w.code for w in res.warnings}
    assert res.method == "op_mv" and res.stiction and res.cls == "undershoot"
    assert res.S_pct == pytest.approx(3.0, abs=0.2) and res.J_pct == pytest.approx(1.0, abs=0.2)
    assert "op_rescaled" in codes and "data_quality.op_fraction" not in codes and "size_unknown" not in codes
    assert res.confidence > 0.9
    frac = next(f for f in res.data_quality if f.code == "op_fraction")
    assert frac.severity == "info" and frac.data["rescaled"] == 100.0
    np.testing.assert_allclose(res.record.op, rec.op)   # plots and reports read OP in %
    # the verdict agrees with the same data without the stem position (warned, not scaled there)
    no_mv = identify(_no_mv(_fraction_op(rec)))
    assert no_mv.stiction and "data_quality.op_fraction" in {w.code for w in no_mv.warnings}
    assert "op_rescaled" not in {w.code for w in no_mv.warnings}


def test_a_fraction_op_without_a_stem_position_is_sized_in_fractions_of_span():
    # OP logged 0..1 and nothing to scale it by: the tool does not rescale it, but the floors and
    # the class tolerances are in % of span, so S, J and the class must come out as for the same
    # data in %, in fractions (they used to be "size unknown": S = 0.03 lay under every % floor)
    from diagnose.service.pipeline import recommended_action, severity, verdict_text

    for S, J, seed, cls in ((3.0, 1.0, 5, "undershoot"), (2.0, 3.0, 7, "overshoot")):
        rec = sticky_loop(S, J, n=3000, noise_std=0.05, load_walk_std=0.02, seed=seed,
                          kind="soptd" if J > S else "foptd").replace(mv=None)
        pct, frac = identify(rec), identify(_fraction_op(rec))
        codes = {w.code for w in frac.warnings}
        assert "data_quality.op_fraction" in codes and "size_unknown" not in codes
        assert frac.op_units == "fraction of span" and frac.pct_per_op_unit == 100.0
        assert frac.stiction and frac.cls == pct.cls == cls
        assert frac.S_pct == pytest.approx(S / 100, rel=0.05) and frac.J_pct == pytest.approx(J / 100, rel=0.3)
        text = verdict_text(frac)
        assert f"S = {frac.S_pct:.4f}, J = {frac.J_pct:.4f} in fractions of span" in text and "(minor)" not in text
        assert "Have the valve inspected" in recommended_action(frac)
        # ranked as the same valve in % would be (the probability and S weigh alike)
        assert severity(frac).size == pytest.approx(severity(pct).size, abs=1.0)


def test_the_report_pipeline_uses_the_scaled_op():
    from diagnose.service import pipeline

    rec = sticky_loop(3.0, 1.0, n=1500, noise_std=0.02, load_walk_std=0.01, seed=2, name="FV5")
    diag = pipeline.diagnose(_fraction_op(rec), narx=False)
    assert diag.identification.cls == "undershoot"
    np.testing.assert_allclose(diag.record.op, rec.op)
    assert "size unknown" not in diag.verdict_text


def test_op_is_scaled_only_when_the_stem_position_shows_the_scale():
    from diagnose.quality import fraction_op_tracks_mv

    rng = np.random.default_rng(0)
    op = 0.5 + 0.02 * np.sin(np.arange(500) / 20.0)
    assert fraction_op_tracks_mv(op, 100.0 * op + rng.normal(0, 0.5, 500))
    assert not fraction_op_tracks_mv(op, op)                  # both fractions: nothing to go by
    near_shut = 0.5 + 0.4 * np.sin(np.arange(500) / 20.0)     # OP in % near 0, MV following it in %
    assert not fraction_op_tracks_mv(near_shut, np.clip(near_shut + 0.2, 0, None) + 0.5)
    assert not fraction_op_tracks_mv(op, np.full(500, 20.0) + rng.normal(0, 0.5, 500))   # MV elsewhere


def test_a_verdict_no_test_could_judge_says_so_rather_than_no_stiction():
    # PV dead and OP a slow wander: every test cannot judge, and the combiner's prior is not a
    # finding that the valve is healthy
    from diagnose.service.commands.identify import summary
    from diagnose.service.pipeline import verdict_text

    rng = np.random.default_rng(3)
    op = 50.0 + np.cumsum(rng.normal(0.0, 0.05, 3000))
    rec = LoopRecord(name="FIC9", ts_s=1.0, op=op, pv=np.full(3000, 60.0))
    ident = identify(rec)
    assert ident.method == "op_only" and not ident.stiction and not ident.verdict.judged
    assert "nothing_judged" in {w.code for w in ident.warnings}
    assert summary(ident).startswith("FIC9: no evidence either way (")
    assert verdict_text(ident).startswith("No evidence either way") and "follows" not in verdict_text(ident)
    # where a test does judge, the verdict is the test's
    saw = identify(sticky_loop(4.0, 1.0, n=3000, seed=2, noise_std=0.05).replace(pv=np.full(3000, 60.0), mv=None))
    assert saw.verdict.judged == ("op_shape",) and saw.stiction
    assert "nothing_judged" not in {w.code for w in saw.warnings}
    assert ": STICTION (" in summary(saw).splitlines()[0]


def test_a_flow_tag_is_self_regulating_whatever_the_fit_chose():
    # the tests for integrating loops read a flow loop wrongly: the tag's process type wins
    from diagnose.identification import _integrating_hint

    rec = sticky_loop(3.0, 1.0, n=1500, kind="integrating", gain=0.02, noise_std=0.02, load_walk_std=0.01,
                      seed=2, u_balance_pct=51.0)
    res = identify(rec.replace(name="LOOP7"))
    assert res.process.kind == "integrating" and res.detection.integrating is True
    for name, want in (("2111FIC46005", False), ("FC12.PV", False), ("FRC3", False), ("LIC4", True),
                       ("LOOP7", True), ("PIC9", True), ("DIFIC1", True)):
        assert _integrating_hint(rec.replace(name=name), res.fit) is want, name
    flow = identify(rec.replace(name="FIC7"))
    assert flow.detection.integrating is False
    ev = {e.test: e for e in flow.evidence}
    assert ev["horch_integrating"].decision == "cannot_judge" and ev["horch_xcorr"].reason != "wrong_process_type"
    # PV unusable, the stem recorded: no fit says what the process is, the tag alone does (one
    # rule for every path: a flow tag is not left unknown there)
    stem = rec.replace(pv=np.full(rec.n, 1.0))
    for name, want in (("FIC7", False), ("LIC7", True), ("LOOP7", None)):
        res = identify(stem.replace(name=name))
        assert res.method == "op_mv" and res.detection.pv_unusable and res.detection.integrating is want, name


def test_a_band_within_a_positioners_resolution_seen_on_the_stem_alone_is_no_stiction():
    # PV unusable (two levels), the stem recorded: a 0.2 % backlash is fitted exactly, and against
    # a noiseless OP ramp (no noise to weigh the band by) the fit's rows alone, with no PV test to
    # weigh in, give a probability of 0.99
    from diagnose.stiction_model import simulate_valve

    n = 2000
    t = np.arange(n)
    op = 50.0 + 5.0 * (2.0 * np.abs((t / 400.0) % 1.0 - 0.5) * 2.0 - 1.0)
    mv = simulate_valve(op, 0.2, 0.0, 1) + np.random.default_rng(5).normal(0.0, 0.02, n)
    pv = np.where(t % 400 < 200, 10.0, 11.0)
    res = identify(LoopRecord(name="PIC3", ts_s=1.0, op=op, pv=pv, mv=mv))
    assert res.method == "op_mv" and res.detection.pv_unusable
    assert not res.stiction and res.cls == "none" and res.stiction_probability < 0.5
    said = next(w.message for w in res.warnings if w.code == "band_below_resolution")
    assert "0.2" in said and "0.5 %" in said
    assert res.fitted_S_pct == pytest.approx(0.2, abs=0.05)
    # the band the stem showed still bounds S: "at most" that, not at most 0
    assert res.to_dict()["S_interval"][1] >= res.fitted_S_pct
    # the same stem with a band a positioner would not allow is stiction
    big = identify(LoopRecord(name="PIC3", ts_s=1.0, op=op, pv=pv, mv=simulate_valve(op, 2.0, 0.0, 1)))
    assert big.stiction and big.S_pct == pytest.approx(2.0, abs=0.05)
    assert not any(w.code == "band_below_resolution" for w in big.warnings)
