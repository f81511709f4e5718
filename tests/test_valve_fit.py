"""The direct OP/MV valve fit: exact on noise-free stems of the two-parameter model and of Kano's
model (tests/kano.py) in every class and start state, intervals holding the truth, the actuator lag
and dead time, noisy stems, and the stem read for bounds on S and J."""

import numpy as np
import pytest

from diagnose.simulate import make_process, random_walk, simc_pi, simulate_loop, sticky_loop
from diagnose.stiction_model import stiction_batch, stiction_class
from diagnose.physics.valve import augmented_valve
from diagnose.valve_fit import ValveFit, fit_valve, slip_brackets, slip_reading
from kano import KanoValve, kano_valve


def _kano_loop(S, J, n, start, seed):
    """OP of a PI loop around Kano's valve (FOPTD), and the stem of Kano's valve started in ``start``
    applied to it: MV is exactly Kano's model of OP."""
    rng = np.random.default_rng(seed)
    proc = make_process("foptd", gain=1.5, tau_s=20.0, delay_s=3.0)
    rec = simulate_loop(n=n, ts_s=1.0, process=proc, controller=simc_pi(1.5, 20.0, 3.0, 1.0),
                        valve=KanoValve(S, J, 1), load=random_walk(n, 0.02, rng, leak=0.002), noise_std=0.2,
                        seed=seed, warmup=500)
    return rec.op, kano_valve(rec.op, S, J, **start)


def _exact(vf, S, J):
    assert vf.S_pct == pytest.approx(S, rel=0.02)
    assert abs(vf.J_pct - J) <= 0.02 * max(S, J)
    assert stiction_class(vf.S_pct, vf.J_pct) == stiction_class(S, J)
    assert vf.S_interval_pct[0] <= S <= vf.S_interval_pct[1]
    assert vf.J_interval_pct[0] <= J <= vf.J_interval_pct[1]
    assert vf.r2 > 0.999


# the third-party overshoot cases (S 2 / J 4, S 3 / J 5), one of each other class, and
# Kano's valve at rest, moving, or stuck away from OP when the record starts
@pytest.mark.parametrize("S,J", [(2.0, 4.0), (3.0, 5.0), (4.0, 0.0), (4.0, 2.0), (3.0, 3.0)])
@pytest.mark.parametrize("start", [dict(d0=1), dict(d0=-1, moving=True), dict(d0=-1, y0=52.0, us0=50.0)],
                         ids=["rest", "moving", "stuck_elsewhere"])
def test_exact_on_kanos_model_in_every_class_and_start(S, J, start):
    op, mv = _kano_loop(S, J, 4000, start, seed=int(10 * S + J))
    _exact(fit_valve(op, mv, 1.0), S, J)


def test_exact_on_a_quiet_loop_whose_valve_slips_rarely():
    # an integrating loop in which the valve moved some 50 times in 10 000 samples and started stuck
    # where the warm-up left it: the fit that started the valve at OP's first sample and searched a
    # grid returned r2 0.75 with intervals that excluded the truth
    rec = sticky_loop(4.0, 2.0, n=10000, noise_std=0.3, kind="integrating", f0=1, seed=43,
                      load_walk_std=0.03, gain=0.02)
    assert np.count_nonzero(np.diff(rec.mv)) < 80
    vf = fit_valve(rec.op, rec.mv, 1.0)
    _exact(vf, 4.0, 2.0)
    assert vf.start_pct == pytest.approx(rec.mv[0], abs=1e-6)
    np.testing.assert_allclose(vf.simulate(rec.op), rec.mv, atol=1e-6)


@pytest.mark.parametrize("S,J,kind,f0", [(3.0, 1.0, "soptd", -1), (6.0, 9.0, "foptd", 1),
                                         (2.0, 2.0, "integrating", -1), (1.0, 0.5, "foptd", 1)])
def test_exact_on_the_two_parameter_model(S, J, kind, f0):
    rec = sticky_loop(S, J, n=5000, noise_std=0.3, kind=kind, f0=f0, seed=7, load_walk_std=0.03,
                      gain=0.02 if kind == "integrating" else 1.0)
    vf = fit_valve(rec.op, rec.mv, 1.0)
    assert isinstance(vf, ValveFit) and vf.gain == 1.0
    _exact(vf, S, J)


def test_slip_brackets_hold_the_truth_and_refuse_a_noisy_stem():
    rng = np.random.default_rng(2)
    x = 50 + np.cumsum(rng.normal(0, 0.5, 3000))         # saturates at 0 and 100 % too
    mv = stiction_batch(x, [3.0], [1.0], [1])[0]
    S_lo, S_hi, J_lo, J_hi, half = slip_brackets(x, mv)
    assert S_lo <= 3.0 <= S_hi and J_lo <= 1.0 <= J_hi and half == pytest.approx(1.0)
    assert S_hi - S_lo < 0.3
    noisy = mv + rng.normal(0, 0.05, mv.shape[0])
    assert slip_brackets(x, noisy) is None


def test_slip_reading_gives_each_directions_bands_and_survives_noise():
    rng = np.random.default_rng(5)
    x = 50 + np.cumsum(rng.normal(0, 0.4, 6000))
    step = float(np.max(np.abs(np.diff(x))))
    # opening sticks more than closing: S 4 / J 1.5 opening, S 2 / J 0.5 closing
    mv = augmented_valve(x, S_up=4.0, J_up=1.5, S_dn=2.0, J_dn=0.5)
    r = slip_reading(x, mv)
    # on the model's own stem each band is read within the input's largest step
    for got, want in ((r.S_up_pct, 4.0), (r.S_dn_pct, 2.0), (r.J_up_pct, 1.5), (r.J_dn_pct, 0.5)):
        assert abs(got - want) < step
    assert r.half_up_pct == pytest.approx(1.25) and r.half_dn_pct == pytest.approx(0.75)
    assert min(r.n_reversals) >= 20 and min(r.n_restarts) >= 20
    # slips far above a 0.1 % noise (no offset, J = S: 4.4 % opening, 1.6 % closing) are read from
    # medians, where the clean stem's brackets (`slip_brackets`) contradict each other
    mv = augmented_valve(x, S_up=4.4, J_up=4.4, S_dn=1.6, J_dn=1.6) + rng.normal(0, 0.1, x.shape[0])
    assert slip_brackets(x, mv) is None
    (S_up, J_up, S_dn, J_dn), *_ = slip_reading(x, mv).valves()
    assert S_up == pytest.approx(4.4, rel=0.03) and S_dn == pytest.approx(1.6, rel=0.03)
    assert J_dn == pytest.approx(1.6, rel=0.1)
    # a stem that never slips has nothing to read
    assert slip_reading(x, np.full(x.shape[0], 40.0) + rng.normal(0, 0.1, x.shape[0])) is None


def test_noisy_and_lagged_stems_are_fitted_close():
    rec = sticky_loop(4.0, 1.5, n=4000, noise_std=0.3, seed=11, load_walk_std=0.02)
    a = np.exp(-1.0 / 2.0)
    stem = rec.mv.copy()
    for k in range(1, stem.shape[0]):
        stem[k] = a * stem[k - 1] + (1.0 - a) * rec.mv[k]
    stem += np.random.default_rng(0).normal(0.0, 0.1, stem.shape[0])
    vf = fit_valve(rec.op, stem, 1.0)
    assert vf.S_pct == pytest.approx(4.0, rel=0.03) and vf.J_pct == pytest.approx(1.5, abs=0.1)
    assert vf.lag_s == pytest.approx(2.0, rel=0.15)
    assert vf.S_interval_pct[0] <= 4.0 <= vf.S_interval_pct[1]


def test_without_stiction_the_valve_fit_is_the_reference_model():
    rec = sticky_loop(3.0, 1.0, n=2000, noise_std=0.1, seed=3)
    free = fit_valve(rec.op, rec.mv, 1.0)
    lin = fit_valve(rec.op, rec.mv, 1.0, stiction=False)
    assert (lin.S_pct, lin.J_pct) == (0.0, 0.0) and lin.rmse > 10 * free.rmse


def test_fit_valve_on_op_mv_is_exact_on_exact_data():
    rec = sticky_loop(3.0, 1.0, n=1500, noise_std=0.02, load_walk_std=0.01, seed=1)
    vf = fit_valve(rec.op, rec.mv, rec.ts_s)
    assert isinstance(vf, ValveFit)
    assert vf.S_pct == pytest.approx(3.0, abs=0.1)
    assert vf.J_pct == pytest.approx(1.0, abs=0.15)
    assert vf.rmse < 0.1
    assert vf.gain == pytest.approx(1.0, abs=0.05)
    assert vf.simulate(rec.op).shape == rec.op.shape


def test_fit_valve_keeps_the_actuator_lag_within_max_lag_s():
    # a 4 s actuator lag after the friction: the local refinements scale lags freely, and used to
    # return lags above the bound the caller asked for
    rec = sticky_loop(3.0, 1.0, n=2000, noise_std=0.05, load_walk_std=0.01, seed=1)
    a = np.exp(-1.0 / 4.0)
    stem = np.empty_like(rec.mv)
    stem[0] = rec.mv[0]
    for k in range(1, stem.shape[0]):
        stem[k] = a * stem[k - 1] + (1.0 - a) * rec.mv[k]
    free = fit_valve(rec.op, stem, rec.ts_s, max_lag_s=10.0)
    assert free.lag_s == pytest.approx(4.0, rel=0.1)
    for bound in (0.0, 2.0):
        vf = fit_valve(rec.op, stem, rec.ts_s, max_lag_s=bound)
        assert vf.lag_s <= bound + 1e-12
        assert vf.rmse > free.rmse




def test_a_long_record_whose_widest_window_lies_in_the_burn_in_is_fitted():
    # 60 000 samples: the burn-in (5 %) is 3000 samples, the search window's length, and OP's
    # widest window is the first one, so the window scores no sample at all
    rec = sticky_loop(3.0, 1.0, n=60_000, noise_std=0.02, load_walk_std=0.01, seed=1)
    vf = fit_valve(rec.op, rec.mv, rec.ts_s)
    assert vf.S_pct == pytest.approx(3.0, rel=0.02)
    assert vf.J_pct == pytest.approx(1.0, abs=0.06)


@pytest.mark.parametrize("S, J, seed", [(3.6, 0.5, 7), (3.6, 0.5, 1), (5.0, 0.5, 8), (2.0, 0.5, 8)])
def test_a_first_slip_against_the_last_direction_does_not_hide_the_valve(tmp_path, S, J, seed):
    # `stiction simulate` starts its valve where its first slip moves the stem down while OP is
    # above it: read as a stay after a downward motion, that slip gave bounds that contradicted
    # each other, and the search alone ended in the deadband valley (S 3.29, J 0, r2 0.91)
    import diagnose
    from diagnose.service.cli import main

    path = tmp_path / "loop.csv"
    assert main(["simulate", "--S", str(S), "--J", str(J), "--seed", str(seed), "--out", str(path)]) == 0
    (rec,) = diagnose.read_loops(path)
    fit = fit_valve(rec.op, rec.mv, rec.ts_s)
    assert fit.S_pct == pytest.approx(S, rel=0.02) and fit.J_pct == pytest.approx(J, abs=0.02 * S)
    assert fit.S_interval_pct[0] <= S <= fit.S_interval_pct[1] and fit.J_interval_pct[0] <= J <= fit.J_interval_pct[1]
    assert fit.r2 > 0.9999
