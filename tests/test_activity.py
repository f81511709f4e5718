"""Valve activity (diagnose.activity): travel and reversals per day on signals with known answers,
and where they appear (identify --json, LOOP.json, the loop report, the plant summary)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from diagnose.activity import BAND_SIGMAS, DAY_S, ValveActivity, hysteresis_turns, noise_sigma, valve_activity


def triangle(n: int, period: int, amp: float, mean: float = 50.0) -> np.ndarray:
    """A triangle wave starting at its trough: ``mean - amp`` .. ``mean + amp``, ``period`` samples."""
    ph = (np.arange(n) % period) / period
    return mean + amp * (4.0 * np.abs(ph - 0.5) - 1.0)


N, PERIOD, AMP, TS = 10_000, 200, 10.0, 2.0
DAYS = N * TS / DAY_S
# from the trough at 0: every half period travels 2 AMP; the last sample lies one step short of a
# trough (the record is a whole number of periods), and every turn but the last is a reversal
EXACT_TRAVEL = (N // (PERIOD // 2)) * 2 * AMP - 4 * AMP / PERIOD
EXACT_REVERSALS = 2 * (N // PERIOD) - 1


def test_a_noiseless_triangle_gives_exact_travel_and_reversals():
    a = valve_activity(triangle(N, PERIOD, AMP), TS)
    assert a.days == pytest.approx(DAYS, rel=1e-12)
    assert a.travel_pct_per_day == pytest.approx(EXACT_TRAVEL / DAYS, rel=1e-9)
    assert a.reversals_per_day == pytest.approx(EXACT_REVERSALS / DAYS, rel=1e-12)
    # no MV, no mode signal: nothing invented
    assert a.mv_travel_pct_per_day is None and a.mv_reversals_per_day is None and a.service_factor is None
    assert a.noise_band_pct < 1e-6


def test_the_known_answer_in_physical_terms():
    """4 x amplitude per period of travel, 2 reversals per period, per day."""
    a = valve_activity(triangle(86_400, 400, 5.0), 1.0)   # one day at 1 s, period 400 s, amplitude 5 %
    assert a.days == 1.0
    assert a.travel_pct_per_day == pytest.approx(4 * 5.0 * 86_400 / 400, rel=1e-3)
    assert a.reversals_per_day == pytest.approx(2 * 86_400 / 400, abs=1)


@pytest.mark.parametrize("sigma", [0.05, 0.2, 0.5])
def test_white_noise_does_not_multiply_reversals_or_inflate_travel(sigma):
    clean = valve_activity(triangle(N, PERIOD, AMP), TS)
    for seed in range(3):
        noisy = triangle(N, PERIOD, AMP) + np.random.default_rng(seed).normal(0.0, sigma, N)
        a = valve_activity(noisy, TS)
        assert a.reversals_per_day == pytest.approx(clean.reversals_per_day, rel=0.02)
        # the extremes are the noisy extremes: travel reads high by about a noise width per turn,
        # not by the noise's own wiggles (a raw sum |diff| would be several times the answer)
        assert a.travel_pct_per_day == pytest.approx(clean.travel_pct_per_day, rel=0.1 * sigma / 0.5)
        if sigma >= 0.2:
            raw = np.abs(np.diff(noisy)).sum() / DAYS
            assert raw > 1.3 * a.travel_pct_per_day
        # the band follows the noise: BAND_SIGMAS times a robust estimate of it
        assert a.noise_band_pct == pytest.approx(BAND_SIGMAS * sigma, rel=0.1)


def test_a_constant_op_has_no_travel_and_no_reversals():
    for x in (np.full(5000, 42.0), np.full(5000, 0.0), np.full(5000, 100.0)):
        a = valve_activity(x, 1.0)
        assert (a.travel_pct_per_day, a.reversals_per_day) == (0.0, 0.0)
    # float rounding is not movement
    a = valve_activity(42.0 + 1e-13 * np.random.default_rng(0).standard_normal(5000), 1.0)
    assert (a.travel_pct_per_day, a.reversals_per_day) == (0.0, 0.0)


def test_white_noise_alone_is_not_movement():
    for seed in range(4):
        a = valve_activity(50.0 + np.random.default_rng(seed).normal(0.0, 0.3, 10_000), 1.0)
        assert (a.travel_pct_per_day, a.reversals_per_day) == (0.0, 0.0)


def test_short_records():
    a = valve_activity([50.0], 1.0)
    assert (a.travel_pct_per_day, a.reversals_per_day) == (0.0, 0.0) and a.days == 1 / DAY_S
    a = valve_activity([50.0, 53.0], 10.0)       # one step of 3 % in 20 s
    assert a.travel_pct_per_day == pytest.approx(3.0 * DAY_S / 20.0) and a.reversals_per_day == 0.0
    a = valve_activity([50.0, 53.0, 51.0], 1.0)  # up 3, down 2: one reversal
    assert a.travel_pct_per_day == pytest.approx(5.0 * DAY_S / 3.0)
    assert a.reversals_per_day == pytest.approx(DAY_S / 3.0)
    with pytest.raises(ValueError, match="no samples"):
        valve_activity([], 1.0)
    with pytest.raises(ValueError, match="ts_s"):
        valve_activity([1.0, 2.0], 0.0)


def test_steps_and_held_samples_count_once():
    # a sticky valve's stem: held, then jumps; holds do not break a run into reversals
    x = np.repeat([50.0, 52.0, 52.0, 49.0, 49.0, 53.0], 100)
    a = valve_activity(x, 1.0)
    days = x.size / DAY_S
    assert a.travel_pct_per_day == pytest.approx((2 + 3 + 4) / days)
    assert a.reversals_per_day == pytest.approx(2 / days)
    assert hysteresis_turns(x, 0.0).tolist() == [50.0, 52.0, 49.0, 53.0]


def test_the_band_drops_wiggles_smaller_than_it():
    x = np.array([0.0, 10.0, 9.5, 10.2, 0.0, 0.4, -0.1, 10.0])
    assert hysteresis_turns(x, 1.0).tolist() == [0.0, 10.2, -0.1, 10.0]
    assert hysteresis_turns(x, 0.0).tolist() == x.tolist()
    assert hysteresis_turns(x, 20.0).tolist() == [0.0]


def test_an_op_quantised_to_whole_percent_does_not_count_its_flicker():
    # an OP logged in 1 % steps: the noise makes it flicker between two levels near every value,
    # its second differences are mostly zero (no noise seen), and each flicker was a reversal
    clean = valve_activity(triangle(N, PERIOD, AMP), TS)
    for seed in range(3):
        noisy = triangle(N, PERIOD, AMP) + np.random.default_rng(seed).normal(0.0, 0.2, N)
        a = valve_activity(np.round(noisy), TS)
        assert a.reversals_per_day == pytest.approx(clean.reversals_per_day, rel=0.02)
        assert a.travel_pct_per_day == pytest.approx(clean.travel_pct_per_day, rel=0.05)
        assert a.noise_band_pct == pytest.approx(1.5)
    # moves of two steps or more still count
    x = np.repeat([50.0, 53.0, 51.0, 54.0, 52.0], 50)
    a = valve_activity(x, 1.0)
    assert a.reversals_per_day == pytest.approx(3 * DAY_S / x.size)


def test_mv_and_service_factor():
    op = triangle(N, PERIOD, AMP)
    mv = np.repeat(op[::10], 10)           # a stem that moves in steps, held in between
    auto = np.ones(N, dtype=bool)
    auto[:2500] = False
    a = valve_activity(op, TS, mv_pct=mv, mode_auto=auto)
    assert a.service_factor == 0.75
    assert a.mv_reversals_per_day == pytest.approx(a.reversals_per_day, rel=0.02)
    assert a.mv_travel_pct_per_day == pytest.approx(a.travel_pct_per_day, rel=0.01)
    assert a.mv_noise_band_pct is not None
    with pytest.raises(ValueError, match="mv_pct"):
        valve_activity(op, TS, mv_pct=mv[:-1])
    d = a.to_dict()
    assert set(d) == {f.name for f in dataclasses.fields(ValveActivity)}
    assert d["service_factor"] == 0.75 and d["reversals_per_day"] == float(f"{a.reversals_per_day:.4g}")


def test_noise_sigma_ignores_ramps_and_turns():
    assert noise_sigma(triangle(N, PERIOD, AMP)) < 1e-9
    e = np.random.default_rng(3).normal(0.0, 0.2, N)
    assert noise_sigma(triangle(N, PERIOD, AMP) + e) == pytest.approx(0.2, rel=0.05)


# ------------------------------------------------------------------------------------------------
# where it appears


@pytest.fixture(scope="module")
def diag():
    from diagnose.service.pipeline import diagnose
    from diagnose.simulate import sticky_loop

    rec = sticky_loop(3.0, 1.0, n=1500, noise_std=0.02, load_walk_std=0.02, seed=2)
    rec = rec.replace(meta={"has_mode": True, "manual_intervals": [[100, 400]]})
    return diagnose(rec, narx=False)


def test_identification_and_loop_json_carry_it(diag):
    ident = diag.identification
    act = ident.activity
    assert act is not None and act.travel_pct_per_day > 0 and act.reversals_per_day > 0
    assert act.service_factor == pytest.approx(1 - 300 / diag.record.n)
    assert act.days == pytest.approx(diag.record.n * diag.record.ts_s / DAY_S)
    assert ident.to_dict()["activity"] == act.to_dict()          # stiction identify --json
    assert diag.to_dict()["activity"] == act.to_dict()           # LOOP.json


def test_no_mode_signal_no_service_factor():
    from diagnose.identification import record_activity
    from diagnose.simulate import sticky_loop

    rec = sticky_loop(3.0, 1.0, n=600, noise_std=0.02, seed=1)
    assert record_activity(rec.replace(meta={})).service_factor is None
    # a connector that read a mode column and found the loop always in automatic
    assert record_activity(rec.replace(meta={"has_mode": True, "manual_intervals": []})).service_factor == 1.0


def test_the_report_and_the_summary_show_it(diag):
    from diagnose.service.batch import loop_row
    from diagnose.service.report import SUMMARY_COLUMNS, loop_markdown

    md = loop_markdown(diag)
    section = md.split("## Valve activity", 1)[1].split("\n## ", 1)[0]
    act = diag.identification.activity
    assert "| OP travel |" in section and "% of span per day" in section
    assert "| OP reversals |" in section and "| Service factor (time in automatic) | 80 % |" in section
    assert "Record length the rates are per | 25 min" in section
    row = loop_row(diag, None)
    assert row["travel_pct_per_day"] == act.to_dict()["travel_pct_per_day"]
    assert row["reversals_per_day"] == act.to_dict()["reversals_per_day"]
    assert {"travel_pct_per_day", "reversals_per_day"} <= set(SUMMARY_COLUMNS)
    # the report gives the number the JSON and the summary keep
    from diagnose.plain import number

    assert f"| OP travel | {number(act.to_dict()['travel_pct_per_day'])} % of span per day |" in section


def test_a_mode_column_with_no_known_value_is_not_called_no_mode_signal():
    # the file has a mode column, but its only value lies after the record: the service factor is
    # unknown, and the report does not say that no mode signal was recorded
    from diagnose.service.pipeline import diagnose
    from diagnose.service.report import loop_markdown
    from diagnose.simulate import sticky_loop

    rec = sticky_loop(3.0, 1.0, n=1500, noise_std=0.02, load_walk_std=0.02, seed=2)
    d = diagnose(rec.replace(meta={"has_mode": True, "manual_intervals": [],
                                   "mode_unknown_intervals": [[0, rec.n]]}), narx=False)
    assert d.identification.activity.service_factor is None
    row = next(ln for ln in loop_markdown(d).splitlines() if ln.startswith("| Service factor"))
    assert "no mode signal" not in row and "mode column has no known value" in row
    bare = diagnose(rec.replace(meta={}), narx=False)
    assert "| Service factor (time in automatic) | -: no mode signal recorded |" in loop_markdown(bare)


def test_an_op_logged_as_a_fraction_is_reported_in_a_fraction_of_span():
    # OP 0..1 without a stem position to scale it: the tool warns (op_fraction) and does not guess,
    # so neither the report nor the summary row may call OP's travel "% of span"
    from diagnose.service.batch import loop_row
    from diagnose.service.pipeline import diagnose
    from diagnose.service.report import S_MEANING, loop_markdown
    from diagnose.simulate import sticky_loop
    from diagnose.quality import assess

    rec = sticky_loop(3.0, 1.0, n=1500, noise_std=0.02, load_walk_std=0.02, seed=2)
    frac = rec.replace(op=rec.op / 100.0, mv=None)
    frac = frac.with_findings(*assess(frac))
    d = diagnose(frac, narx=False)
    assert "data_quality.op_fraction" in {w.code for w in d.warnings}
    section = loop_markdown(d).split("## Valve activity", 1)[1].split("\n## ", 1)[0]
    travel = next(ln for ln in section.splitlines() if ln.startswith("| OP travel |"))
    assert "fraction of span per day" in travel and "% of span" not in travel
    row = loop_row(d, None)
    assert row["sj_units"] == d.identification.op_units == "fraction of span" and row["sj_in_op_units"] is True
    # S and J are in the same fractions: no text may call them % of span
    from diagnose.service.pipeline import sj_unit

    assert d.identification.op_in_percent is False
    assert sj_unit(d.identification) == "in fractions of span, as OP was logged"
    assert "% of valve span" not in d.verdict_text
    # nor the evidence table's notes that give an amount of OP travel
    band = next(e.note for e in d.identification.evidence if e.test == "valve_band")
    assert "in fractions of span" in band and "% of span" not in band
    assert not any("% of span" in e.note or "% of OP span" in e.note for e in d.identification.evidence)
    # sized in fractions (the % floors converted), and every place that gives S says so
    assert d.identification.S_pct is not None and 0.0 < d.identification.S_pct < 0.1
    s_row = next(ln for ln in loop_markdown(d).splitlines() if ln.startswith(f"| {S_MEANING}"))
    assert f"{d.identification.S_pct:.4f} in fractions of span" in s_row and "% of span" not in s_row
    # the same loop in %: the units the summary gives every other loop
    pct = loop_row(diagnose(rec, narx=False), None)
    assert pct["sj_units"] == "% of span" and pct["sj_in_op_units"] is False


@pytest.mark.parametrize("args, kw, says", [
    (("nan_op", 1.0), {}, r"^op_pct has 1 NaN/inf value\(s\) \(the first at sample 3\)"),
    (("op", 1.0), {"mv_pct": "nan_all"}, r"^mv_pct has 400 NaN/inf"),
    (("2d", 1.0), {}, r"^op_pct must be one series of samples, got shape \(10, 2\)"),
    (("op", "1"), {}, r"^ts_s='1': the sample period must be a positive number"),
    (("op", None), {}, r"^ts_s=None: "),
    (("op", 1.0), {"mode_auto": "text"}, r"^mode_auto must hold True/False"),
])
def test_unusable_input_is_a_one_line_data_error_not_a_zero(args, kw, says):
    # a NaN used to make travel and reversals 0 (a valve at rest) instead of an error
    from diagnose.errors import DataError

    op = 50.0 + 10.0 * np.sin(np.arange(400) / 20.0)
    named = {"op": op, "nan_op": np.r_[op[:3], np.nan, op[4:]], "nan_all": np.full(400, np.nan),
             "2d": np.ones((10, 2)), "text": np.array(["AUTO"] * 400)}
    args = tuple(named.get(a, a) if isinstance(a, str) else a for a in args)
    kw = {k: named.get(v, v) for k, v in kw.items()}
    with pytest.raises(DataError, match=says):
        valve_activity(*args, **kw)
