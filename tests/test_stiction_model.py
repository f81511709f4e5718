"""The two-parameter stiction model: class signatures, the revised-form rules, and the compiled valve
step against Kano's model written apart from it (tests/kano.py), at every instruction-set variant."""

import numpy as np
import pytest

from diagnose.errors import DataError
from diagnose import kernels
from diagnose.stiction_model import StictionValve, simulate_valve, stiction_batch, stiction_class
from kano import kano_valve

N = 4000
T = np.arange(N)
SLOW_SINE = 50.0 + 10.0 * np.sin(2 * np.pi * T / 1000.0)   # 0.06 % per sample at most


def _steady(y):
    return y[N // 2:]   # after the first cycle, away from the starting transient


@pytest.mark.parametrize("S", [1.0, 3.0, 6.0])
def test_deadband_width_is_S(S):
    y = simulate_valve(SLOW_SINE, S, 0.0, 1)
    x = SLOW_SINE
    # While moving the valve trails the input by S/2 ...
    moving = np.flatnonzero(np.diff(y) != 0) + 1
    lag = np.abs(x[moving] - y[moving])
    np.testing.assert_allclose(lag[lag > 0], S / 2, atol=1e-9)
    # ... and after the top reversal it stays until the input has fallen S below the stuck point.
    k_top = N // 2 + int(np.argmax(x[N // 2:]))
    k_move = k_top + int(np.flatnonzero(np.diff(y[k_top:]) != 0)[0]) + 1
    assert x[k_top] - x[k_move] > S
    assert x[k_top] - x[k_move - 1] <= S


@pytest.mark.parametrize("S,J,cls", [(3.0, 1.0, "undershoot"), (4.0, 4.0, "no_offset"), (1.0, 3.0, "overshoot"),
                                     (5.0, 0.0, "deadband")])
def test_peak_offset_by_class(S, J, cls):
    y = _steady(simulate_valve(SLOW_SINE, S, J, 1))
    x = _steady(SLOW_SINE)
    offset = y.max() - x.max()           # (J - S) / 2 for every class
    assert offset == pytest.approx((J - S) / 2, abs=0.02)
    assert y.min() - x.min() == pytest.approx(-(J - S) / 2, abs=0.02)
    assert stiction_class(S, J) == cls
    if cls == "undershoot" or cls == "deadband":
        assert y.max() < x.max()          # never reaches the input's extremes
    elif cls == "no_offset":
        assert y.max() == pytest.approx(x.max(), abs=1e-6)
    else:
        assert y.max() > x.max()          # passes them by


def test_stop_without_reversal_needs_J_and_reversal_needs_S():
    S, J = 4.0, 1.5
    # ramp up (moving), hold (stop), ramp up again: only J is needed
    up = np.concatenate([np.linspace(50, 60, 101), np.full(20, 60.0), 60 + 0.01 * np.arange(1, 400)])
    y = simulate_valve(up, S, J, 1)
    k = 121 + int(np.flatnonzero(np.diff(y[120:]) != 0)[0])
    assert up[k] - 60.0 > J and up[k - 1] - 60.0 <= J
    # ramp up, then down: a reversal needs S
    rev = np.concatenate([np.linspace(50, 60, 101), 60 - 0.01 * np.arange(1, 800)])
    y = simulate_valve(rev, S, J, 1)
    k = 101 + int(np.flatnonzero(np.diff(y[100:]) != 0)[0])
    assert 60.0 - rev[k] > S and 60.0 - rev[k - 1] <= S


def test_noise_on_a_stuck_valve_does_not_recapture_the_stuck_point():
    rng = np.random.default_rng(3)
    S, J = 3.0, 2.0
    # the valve moves up to 60 and stops; then the input creeps up with noise that reverses often
    creep = 60 + 0.004 * np.arange(1, 1500) + rng.normal(0, 0.15, 1499)
    x = np.concatenate([np.linspace(50, 60, 100), [60.0], creep])   # the repeated 60 is the stop
    y, stuck, _ = simulate_valve(x, S, J, 1, return_state=True)
    k = 101 + int(np.flatnonzero(np.diff(y[100:]) != 0)[0])
    # the breakaway is measured from the original stuck point 60, not from a noisy recapture
    assert x[k] - 60.0 > J
    assert np.all(x[101:k] - 60.0 <= J)
    assert stuck[101:k].all()
    # the literal 2005 reading (capture on every sign change) would have moved x_ss with the noise
    assert np.count_nonzero(np.sign(np.diff(x[101:k])) != np.sign(np.diff(x[100:k - 1]))) > 10


def test_saturation_clips_input_and_output():
    x = np.concatenate([np.linspace(50, 120, 200), np.linspace(120, -20, 300)])
    y = simulate_valve(x, 2.0, 5.0, 1)
    assert y.min() >= 0.0 and y.max() <= 100.0
    assert y.max() == 100.0 and y.min() == 0.0


def _inputs(seed):
    rng = np.random.default_rng(seed)
    n = 3000
    kind = seed % 3
    if kind == 0:      # noisy random walk
        x = 50 + np.cumsum(rng.normal(0, 0.5, n))
    elif kind == 1:    # quantised sine with held samples and saturation
        x = np.round(50 + 70 * np.sin(np.arange(n) / 40.0) + rng.normal(0, 1, n), 0)
    else:              # staircase (repeated samples)
        x = np.repeat(50 + np.cumsum(rng.normal(0, 1, n // 5)), 5)
    m = 40
    S = rng.uniform(0, 8, m)
    J = rng.uniform(0, 8, m)
    S[:4] = [0, 3, 3, 1]
    J[:4] = [0, 0, 3, 3]   # none, deadband, no offset, overshoot
    f0 = rng.choice([-1, 1], m)
    return x, S, J, f0


@pytest.mark.parametrize("seed", range(6))
def test_batch_equals_kanos_model_on_random_inputs(seed):
    x, S, J, f0 = _inputs(seed)
    batch = stiction_batch(x, S, J, f0)
    for i in range(S.shape[0]):
        ref = kano_valve(x, S[i], J[i], int(f0[i]))
        np.testing.assert_allclose(batch[i], ref, rtol=0, atol=1e-12, err_msg=f"{i} {S[i]} {J[i]} {f0[i]}")


@pytest.mark.parametrize("seed", range(3))
def test_batch_and_stepped_valve_are_the_same_kernel_bit_for_bit(seed):
    x, S, J, f0 = _inputs(seed)
    batch = stiction_batch(x, S, J, f0)
    for i in range(0, S.shape[0], 7):
        v = StictionValve(S[i], J[i], int(f0[i]))
        stepped = np.array([v.reset(x[0])] + [v.step(u) for u in x[1:]])
        assert np.array_equal(batch[i], stepped)


def test_every_instruction_set_variant_gives_the_same_numbers():
    # the library picks the widest vector variant the CPU has; results must not depend on it
    x, S, J, f0 = _inputs(1)
    outs = []
    try:
        for level in range(kernels.max_isa_level() + 1):
            kernels.set_isa(level)
            outs.append(stiction_batch(x, S, J, f0))
    finally:
        kernels.set_isa(None)
    for o in outs[1:]:
        assert np.array_equal(o, outs[0])


def test_batch_validates_arguments():
    with pytest.raises(DataError, match="S and J"):
        stiction_batch(np.zeros(10), [-1.0], [0.0])
    with pytest.raises(DataError, match="f0"):
        stiction_batch(np.zeros(10), [1.0], [0.0], f0=[0])
    with pytest.raises(DataError, match="f0"):
        StictionValve(1.0, 0.0, f0=2)


def test_starting_direction_matters():
    x = 50 - 0.01 * np.arange(1000)      # the input falls from the start
    y_up = simulate_valve(x, 3.0, 1.0, +1)   # last motion up: falling is a reversal, needs S
    y_dn = simulate_valve(x, 3.0, 1.0, -1)   # last motion down: needs only J
    first_up = int(np.flatnonzero(np.diff(y_up))[0]) + 1
    first_dn = int(np.flatnonzero(np.diff(y_dn))[0]) + 1
    assert 50 - x[first_up] > 3.0 and 50 - x[first_dn] > 1.0
    assert first_dn < first_up
