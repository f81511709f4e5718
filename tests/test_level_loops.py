"""The level-loop check (benchmarks/level_loops.py): its records and its summary."""

import math
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from benchmarks import level_loops as L  # noqa: E402
from diagnose.identification import identify  # noqa: E402


def test_records_are_seeded_and_sticky_ones_carry_their_truth():
    a, ta = L.level_loop(2, 4)
    b, tb = L.level_loop(2, 4)
    assert ta == tb and np.array_equal(a.pv, b.pv) and np.array_equal(a.op, b.op)
    assert ta["sticky"] and ta["S_pct"] in (0.3, 0.5, 1.0, 2.0) and a.n == ta["n"]
    healthy, th = L.level_loop(2, 3)
    assert not th["sticky"] and th["S_pct"] == 0.0
    # a healthy valve follows OP exactly: the stem moves whenever OP does
    assert np.allclose(healthy.mv, healthy.op)


def test_stem_moves_counts_runs_of_motion_not_moving_samples():
    mv = np.array([0, 0, 1, 2, 2, 2, 3, 3, 4, 5, 6, 6], float)
    assert L.stem_moves(mv) == 3
    assert L.stem_moves(np.zeros(10)) == 0


def test_summary_counts_calls_by_class_and_leaves_out_stuck_valves():
    rows = [
        {"sticky": True, "S_pct": 0.5, "load_step": 0.0, "n": 751, "called": True, "lr": 30.0},
        {"sticky": True, "S_pct": 0.5, "load_step": 0.05, "n": 751, "called": False, "lr": 5.0},
        {"sticky": True, "S_pct": 2.0, "load_step": 0.05, "n": 3000, "called": True, "lr": 40.0},
        {"sticky": False, "S_pct": 0.0, "load_step": 0.0, "n": 751, "called": False, "lr": 8.0},
        {"sticky": False, "S_pct": 0.0, "load_step": 0.0, "n": 751, "called": True, "lr": 2.0},
        {"sticky": True, "S_pct": 1.0, "load_step": 0.0, "n": 751, "moves": 0},   # valve never free
    ]
    lines = L.summarise(rows)
    assert lines[0].startswith("3 sticky records") and "1 sticky records left out" in lines[0]
    assert "called sticky: 0.667" in lines[1] and "left alone: 0.500" in lines[1]
    # lr: 30 and 40 beat both healthy, 5 beats one of two -> (2 + 2 + 1) / 6
    assert f"{5 / 6:.3f}" in lines[2]
    assert "0.5: 1/2" in lines[3] and "2: 1/1" in lines[3]


def test_auc_handles_ties_and_missing_values():
    assert L.auc([1.0, None], [1.0]) == 0.5
    assert np.isnan(L.auc([], [1.0]))


def test_detuned_family_is_seeded_apart_from_the_load_family():
    a, ta = L.level_loop(1, 7, "detuned")
    b, _ = L.level_loop(1, 7, "detuned")
    c, _ = L.level_loop(1, 7, "load")
    assert np.array_equal(a.pv, b.pv) and not np.array_equal(a.pv[:100], c.pv[:100])
    assert ta["family"] == "detuned" and ta["Kc_x"] in (0.3, 0.5, 1.0) and ta["Ti_x"] in (1.0, 2.0, 4.0)
    with pytest.raises(ValueError, match="unknown level-loop family"):
        L.level_loop(1, 7, "surge")


def _lr_and_shared(rec):
    res = identify(rec.replace(mv=None))
    mf = next(ev for ev in res.evidence if ev.test == "model_fit")
    # the likelihood ratio under the linear loop's noise model, from the shared improvement
    return mf.extras["lr"], res.fit.n_eff * -math.log1p(-max(mf.value, 0.0))


def test_likelihood_ratio_scores_each_model_under_its_own_noise_model():
    # a detuned sticky level loop: slow stick-slip error the linear loop's noise model filters out
    sticky, truth = L.level_loop(1, 7, "detuned")
    assert truth["sticky"] and truth["moves"] >= L.MIN_MOVES
    lr, shared = _lr_and_shared(sticky)
    assert lr > 2.0 * shared > 0
    note = next(ev.note for ev in identify(sticky.replace(mv=None)).evidence if ev.test == "model_fit")
    assert "with each model under its own noise model" in note
    # a healthy one: both models want the same noise model, and the ratio stays small
    healthy, truth = L.level_loop(1, 3, "detuned")
    assert not truth["sticky"]
    lr, shared = _lr_and_shared(healthy)
    assert lr == pytest.approx(shared, rel=1e-6) and lr < 10.0


def test_summary_splits_calls_by_what_pv_shows_of_the_stem():
    rows = [{"sticky": True, "S_pct": 0.5, "load_step": 0.0, "n": 751, "called": c, "lr": 1.0, "deviance": d}
            for d, c in [(2.0, False), (5.0, True), (20.0, True), (80.0, True), (60.0, False)]]
    rows.append({"sticky": False, "S_pct": 0.0, "load_step": 0.0, "n": 751, "called": False, "lr": 0.0})
    line = next(ln for ln in L.summarise(rows) if "deviance" in ln)
    assert line.endswith("D < 10: 1/2, 10 <= D < 50: 1/1, D >= 50: 1/2")
