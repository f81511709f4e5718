"""controller_action(): the controller's action and PI tuning from OP/PV/SP, and the gain-sign
constraint it gives the OP/PV fit (the controller path ruled out)."""

import numpy as np
import pytest

from diagnose.controller import MIN_R2, controller_action
from diagnose.fit import fit_hammerstein
from diagnose.identification import identify
from diagnose.simulate import sticky_loop


@pytest.mark.parametrize("gain", [1.5, -0.8])
def test_recovers_the_action_and_the_pi_tuning_of_a_simulated_loop(gain):
    rec = sticky_loop(3.0, 1.0, n=1500, gain=gain, tau_s=15.0, delay_s=2.0, noise_std=0.02,
                      load_walk_std=0.01, seed=4)
    for sp in (rec.sp, None):      # with and without a recorded setpoint (it is constant here)
        a = controller_action(rec.op, rec.pv, rec.ts_s, sp=sp)
        assert a.sign == np.sign(gain)
        assert a.r2 > 0.99
        # the simulator's controller acts on the previous sample's PV
        assert a.lag_samples == 1
    # the same Kc/Ti the simulator used (SIMC tuning inside sticky_loop): a PI law in velocity
    # form, so the regression is exact
    assert a.to_dict()["action"] == ("reverse" if gain > 0 else "direct")
    assert np.isfinite(a.Kc) and np.isfinite(a.Ti_s) and a.Ti_s > 0


def test_no_control_law_gives_no_sign():
    rng = np.random.default_rng(0)
    op = 50 + np.cumsum(rng.normal(0, 0.3, 2000))        # OP moved by hand, unrelated to PV
    pv = rng.normal(0, 1.0, 2000)
    a = controller_action(op, pv, 1.0)
    assert a.sign == 0 and a.r2 < MIN_R2
    assert a.to_dict()["action"] == "unknown"
    assert controller_action(np.full(100, 40.0), pv[:100], 1.0).sign == 0    # OP constant


def test_the_gain_sign_rules_out_the_controller_path():
    """With the wrong sign imposed, the best model the fit can find is worse than with the right
    one; with the right sign the fitted gain has that sign and S is recovered."""
    rec = sticky_loop(4.0, 1.5, n=2000, gain=1.2, tau_s=20.0, delay_s=3.0, noise_std=0.02,
                      load_walk_std=0.01, seed=2)
    right = fit_hammerstein(rec.op, rec.pv, rec.ts_s, gain_sign=+1, surface=False)
    wrong = fit_hammerstein(rec.op, rec.pv, rec.ts_s, gain_sign=-1, surface=False)
    assert right.process.gain > 0 and wrong.process.gain < 0
    assert wrong.cost > 3.0 * right.cost
    assert abs(right.S_pct - 4.0) < 0.4


def test_identify_reports_the_controller_and_uses_its_sign():
    rec = sticky_loop(4.0, 1.5, n=2000, gain=-1.5, tau_s=20.0, delay_s=3.0, noise_std=0.02,
                      load_walk_std=0.01, seed=1)
    res = identify(rec.replace(mv=None))
    d = res.to_dict()
    assert d["controller"]["action"] == "direct"
    assert res.process.gain < 0
    assert res.stiction and res.cls == "undershoot"


def test_gaps_in_the_setpoint_do_not_break_the_estimate():
    rec = sticky_loop(3.0, 1.0, n=1500, gain=1.5, tau_s=15.0, delay_s=2.0, noise_std=0.02,
                      load_walk_std=0.01, seed=4)
    sp = rec.sp.copy()
    sp[100:130] = np.nan
    a = controller_action(rec.op, rec.pv, rec.ts_s, sp=sp)
    assert a.sign == 1 and a.r2 > 0.99


def test_a_pid_law_gives_its_sign_where_the_pi_regression_cannot():
    """A temperature loop under PID with a sensor filter (the independent simulator's TIC00024,
    seed 9): the PI regression leaves the derivative kick unexplained and finds no consistent
    sign, so the fit took the controller path (a negative gain, PV = -OP / Kc) and missed the
    sticky valve. The PID regression finds the reverse action, and the fit the plant."""
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    from benchmarks.plantsim import make_loop
    from diagnose.controller import _regression
    from diagnose.record import LoopRecord

    loop = make_loop("two_parameter", 9, 24, definition="identifiable")
    assert loop.meta["tuning"] == "imc_pid" and loop.meta["Td_s"] > 0 and loop.meta["gain_sign"] == 1
    e = loop.sp - loop.pv
    assert _regression(loop.op, e, loop.ts_s, derivative=False).sign == 0
    a = controller_action(loop.op, loop.pv, loop.ts_s, sp=loop.sp)
    assert a.sign == 1 and a.r2 > 0.9 and np.isfinite(a.Td_s) and a.Td_s > 0
    assert a.to_dict()["Td_s"] == pytest.approx(a.Td_s)
    res = identify(LoopRecord(name=loop.name, ts_s=loop.ts_s, op=loop.op, pv=loop.pv, sp=loop.sp))
    assert res.process.gain > 0 and res.stiction
