"""Closed-loop simulator: limit cycles with stiction, settling without, MV is the valve's output."""

import numpy as np
import pytest

from diagnose.errors import DataError
from diagnose.process_model import ProcessModel
from diagnose.simulate import (LinearValve, PIDController, make_process, simc_pi, simulate_loop, sinusoid,
                               steps, sticky_loop)
from diagnose.stiction_model import StictionValve, simulate_valve


def _zero_crossings(v):
    v = v - v.mean()
    return int(np.count_nonzero(np.diff(np.sign(v)) != 0))


@pytest.mark.parametrize("process", [make_process("foptd", gain=1.0, tau_s=20.0, delay_s=3.0),
                                     make_process("soptd", gain=1.5, tau_s=20.0, tau2_s=5.0, delay_s=3.0)])
def test_stiction_makes_a_limit_cycle_and_a_healthy_valve_settles(process):
    # noise-free: a setpoint step is the only excitation
    sp = 50.0 + steps(3000, [50], [1.0])
    runs = {}
    for label, valve in [("sticky", StictionValve(4.0, 2.0)), ("healthy", LinearValve())]:
        ctrl = simc_pi(1.0, 20.0, 3.0, 1.0)
        runs[label] = simulate_loop(n=3000, ts_s=1.0, process=process, controller=ctrl,
                                    valve=valve, sp=sp * process.gain)
    healthy, sticky = runs["healthy"], runs["sticky"]
    assert np.abs(healthy.pv[-1000:] - sp[-1] * process.gain).max() < 1e-3
    tail = sticky.pv[-2000:]
    assert tail.std() > 0.3
    assert _zero_crossings(tail) >= 8
    first, second = sticky.pv[-2000:-1000], sticky.pv[-1000:]
    assert second.std() == pytest.approx(first.std(), rel=0.3)   # sustained, not decaying


def test_healthy_valve_settles_after_a_setpoint_step():
    proc = make_process("foptd", gain=2.0, tau_s=30.0, delay_s=4.0)
    ctrl = simc_pi(2.0, 30.0, 4.0, 1.0)
    sp = 100.0 + steps(1500, [100], [5.0])
    rec = simulate_loop(n=1500, ts_s=1.0, process=proc, controller=ctrl, sp=sp, op0_pct=50.0)
    assert abs(rec.pv[-200:].mean() - 105.0) < 0.01
    assert rec.pv[-200:].std() < 0.01


def test_mv_is_the_valve_models_output():
    rec = sticky_loop(3.0, 1.0, n=2000, noise_std=0.05, load_walk_std=0.02, f0=-1, seed=4, warmup=0)
    assert np.array_equal(rec.mv, simulate_valve(rec.op, 3.0, 1.0, -1))
    healthy = sticky_loop(0.0, 0.0, n=500, noise_std=0.05, seed=2, warmup=0)
    assert np.array_equal(healthy.mv, np.clip(healthy.op, 0, 100))


def test_integrating_process_with_stiction_cycles():
    rec = sticky_loop(3.0, 3.0, n=4000, kind="integrating", gain=0.02, tau_s=5.0, noise_std=0.01,
                      load_walk_std=0.01, seed=0)
    assert rec.pv[-2000:].std() > 0.2
    assert _zero_crossings(rec.pv[-2000:]) >= 4


def test_output_limits_and_antiwindup():
    # a setpoint the valve cannot reach saturates OP at 100 without winding up:
    # when the setpoint comes back, OP leaves the limit within a few samples.
    proc = make_process("foptd", gain=1.0, tau_s=10.0, delay_s=1.0)
    ctrl = PIDController(Kc=2.0, Ti_s=10.0)
    sp = np.where(np.arange(800) < 400, 200.0, 50.0)
    rec = simulate_loop(n=800, ts_s=1.0, process=proc, controller=ctrl, sp=sp)
    assert rec.op[300:400].max() == 100.0
    assert rec.op[410] < 100.0


def test_loads_and_noise_enter_pv():
    proc = make_process("soptd", gain=1.0, tau_s=10.0, tau2_s=3.0, delay_s=1.0)
    load = sinusoid(2000, 1.0, 200.0, 1.0)
    rec = simulate_loop(n=2000, ts_s=1.0, process=proc, controller=PIDController(Kc=0.0, Ti_s=np.inf),
                        load=load, noise_std=0.1, seed=3, valve=LinearValve())
    resid = rec.pv - rec.pv[0] - load
    assert resid.std() == pytest.approx(0.1, rel=0.15)


def test_pluggable_valve_and_process():
    class HalfValve:       # any object with reset/step is a valve
        def reset(self, x0):
            return x0 / 2

        def step(self, x):
            return x / 2

    class Level:            # any object with reset/step is a process
        def reset(self, u0, ts_s):
            self.pv = 10.0
            return self.pv

        def step(self, u):
            self.pv += 0.01 * (u - 20.0)
            return self.pv

    rec = simulate_loop(n=50, ts_s=1.0, process=Level(), controller=PIDController(Kc=0.0),
                        valve=HalfValve(), op0_pct=40.0)
    assert np.all(rec.mv == 20.0)
    assert np.all(rec.pv == 10.0)
    with pytest.raises(DataError):
        simulate_loop(n=1, ts_s=1.0, process=make_process("foptd", gain=1.0, tau_s=20.0, delay_s=2.0),
                      controller=PIDController())
    with pytest.raises(DataError, match="tau_s must be > 0"):
        make_process("foptd", gain=1.0, tau_s=0.0, delay_s=2.0)
    with pytest.raises(DataError):
        StictionValve(-1.0, 0.0)
