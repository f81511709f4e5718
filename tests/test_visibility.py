"""How much of a sticky valve PV shows (benchmarks/visibility.py): the stem's deviance over OP."""

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from benchmarks import visibility as V  # noqa: E402
from diagnose.simulate import sticky_loop  # noqa: E402


def test_the_stem_explains_pv_of_a_sticky_loop_far_better_than_op():
    # a clear stick-slip cycle: the stem, not OP, drives PV, so a linear loop from the stem wins
    sim = sticky_loop(3.0, 1.0, n=1500, noise_std=0.05, load_walk_std=0.05, seed=3)
    d, ne = V.stem_deviance(sim.op, sim.mv, sim.pv, sim.ts_s)
    assert ne > 50
    assert d > 100.0


def test_a_stem_that_is_op_shows_nothing_and_faint_friction_little():
    sim = sticky_loop(3.0, 1.0, n=1500, noise_std=0.05, load_walk_std=0.05, seed=3)
    same, _ = V.stem_deviance(sim.op, sim.op, sim.pv, sim.ts_s)
    assert abs(same) < 1e-6
    # the same stem under PV noise ten times the cycle's size: PV hides the valve
    rng = np.random.default_rng(7)
    loud = sim.pv + rng.normal(0.0, 10.0 * np.std(sim.pv), sim.pv.shape)
    hidden, _ = V.stem_deviance(sim.op, sim.mv, loud, sim.ts_s)
    assert hidden < 10.0


def test_summary_splits_sensitivity_by_what_pv_shows():
    rows = [{"kind": "kano", "deviance": d, "called": c}
            for d, c in [(80.0, True), (60.0, True), (30.0, False), (2.0, True), (1.0, False)]]
    lines = V.summarise(rows, [10.0, 50.0])
    kano10 = next(ln for ln in lines[2:] if ln.split()[0] == "kano")
    # 3 of 5 shown; 2 of 3 shown called, 1 of 2 hidden called
    assert kano10.split()[1:] == ["5", "0.600", "0.600", "0.667", "0.500"]
    kano50 = [ln for ln in lines if ln.split()[0] == "kano"][1]
    assert kano50.split()[1:] == ["5", "0.400", "0.600", "1.000", "0.333"]
