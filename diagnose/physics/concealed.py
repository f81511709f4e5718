"""Closed-loop records with one piece of physics hidden in them (or none), for the proofs.

`concealed_loop(effect, seed)` draws random plant, controller and effect parameters from the seed,
simulates a PI loop on a sticky valve with the effect built into the plant
(`diagnose.physics.plant`), and returns the record (OP/PV/SP, and MV when asked) with the truth.
The baseline model (two-parameter stiction + linear process) does not have the effect.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..errors import DataError
from ..record import LoopRecord
from ..process_model import ProcessModel
from ..simulate import random_walk, simc_pi, simulate_loop, sinusoid
from .locate import limit_cycle_period, slips_and_reversals
from .plant import AugmentedValve, CharacteristicProcess

EFFECTS = ("none", "actuator_lag", "asymmetric_stiction", "valve_characteristic",
           "external_disturbance", "time_varying_friction")
VALVE_EFFECTS = ("actuator_lag", "asymmetric_stiction", "time_varying_friction")


def _sp_steps(n: int, rng: np.random.Generator, gain: float, levels_pct: tuple[float, float],
              n_steps: int) -> tuple[np.ndarray, float]:
    """Setpoint moves that take the valve across ``levels_pct`` (steady-state valve positions)."""
    lo, hi = levels_pct
    # alternate low/high so the record visits the whole range
    lv = np.linspace(lo, hi, n_steps + 1)
    rng.shuffle(lv)
    edges = np.linspace(0, n, n_steps + 2).astype(int)[1:-1]
    u = np.full(n, lv[0])
    for k, e in enumerate(edges):
        u[e:] = lv[k + 1]
    return u, float(lv[0])


def concealed_loop(effect: str, seed: int, *, n: int = 3000, ts_s: float = 1.0, with_mv: bool = False,
                   name: str | None = None, apply_effect: bool = True,
                   min_moves: tuple[float, int, int] | None = None) -> tuple[LoopRecord, dict[str, Any]]:
    """One closed-loop record with ``effect`` hidden in the plant.

    With ``min_moves=(train_fraction, k_train, k_heldout)`` a draw whose (noise-free) stem moves
    fewer than ``k_train`` times in the leading ``train_fraction`` of the record, or fewer than
    ``k_heldout`` times in the rest, is drawn again from a derived seed (``seed * 1000 + k``,
    ``truth["draw"] = k``): a valve that stays stuck through a part carries no trace of its
    friction there, so no method can learn or judge a valve-side effect from it (a PI loop whose
    valve sticks where PV meets the setpoint, with a small load, can stay stuck for an hour).
    The effect-free twin (``apply_effect=False``) follows its effect record's draw.

    Parameters
    ----------
    effect : str
        One of `EFFECTS` (``"none"``: a clean loop, the baseline's own structure).
    seed : int
        Seed for every random choice.
    n : int
        Samples returned (after a warm-up that lets the limit cycle establish itself).
    ts_s : float
        Sample period, seconds.
    with_mv : bool
        Keep the (noisy) measured stem position in the record.
    apply_effect : bool
        False: draw everything as for ``effect`` (same plant, controller, noise, setpoints) but
        leave the effect out of the plant -- the record's effect-free twin, to measure how much the
        effect changes what is recorded.
    min_moves : (train_fraction, k_train, k_heldout), optional
        Draw again until the stem moves often enough in both parts (see above); None keeps the
        seed's first draw whatever its valve does.

    Returns
    -------
    record : LoopRecord
    truth : dict
        ``effect``, the plant parameters and the effect's parameters.
    """
    if effect not in EFFECTS:
        raise DataError(f"unknown effect {effect!r}; choose from {', '.join(EFFECTS)}")
    if min_moves is None:
        return _draw(effect, seed, n, ts_s, with_mv, name, apply_effect)
    frac, k_tr, k_ho = min_moves
    n_tr = int(round(frac * n))
    for k in range(_MAX_DRAWS):
        s = seed if k == 0 else seed * 1000 + k
        rec, truth = _draw(effect, s, n, ts_s, True, name, True)
        stem = rec.mv - _mv_noise(s, n)
        if _moves(stem[:n_tr]) >= k_tr and _moves(stem[n_tr:]) >= k_ho:
            break
    else:
        raise DataError(f"{effect} seed {seed}: no draw in {_MAX_DRAWS} moves its valve {k_tr} times in "
                        f"the training part and {k_ho} in the held-out part")
    rec, truth = _draw(effect, s, n, ts_s, with_mv, name or f"{effect}-{seed}", apply_effect)
    truth.update(seed=seed, draw=k)
    return rec, truth


_MAX_DRAWS = 50


def _moves(stem_pct: np.ndarray) -> int:
    # a lagged stem's glide after a slip counts once: motion below 0.01 % of span per sample is rest
    return int(slips_and_reversals(stem_pct, eps=0.01)[0].size)


def _mv_noise(seed: int, n: int) -> np.ndarray:
    return np.random.default_rng(seed + 3).normal(0.0, 0.1, n)


def _draw(effect: str, seed: int, n: int, ts_s: float, with_mv: bool, name: str | None,
          apply_effect: bool) -> tuple[LoopRecord, dict[str, Any]]:
    rng = np.random.default_rng(seed)
    S = float(rng.uniform(2.5, 6.0))
    J = float(S * rng.uniform(0.2, 1.0))
    gain = float(rng.uniform(0.6, 2.0))
    tau = float(rng.uniform(10.0, 35.0))
    delay = float(rng.integers(1, 6)) * ts_s
    f0 = int(rng.choice([1, -1]))
    noise = float(gain * rng.uniform(0.04, 0.12))
    warmup = 3000
    truth: dict[str, Any] = {"effect": effect, "S_pct": S, "J_pct": J, "gain": gain, "tau_s": tau,
                             "delay_s": delay, "noise_std": noise, "seed": seed}
    sp_moves = effect == "valve_characteristic" or (effect == "none" and rng.random() < 0.4)
    if sp_moves:
        u_lv, u0 = _sp_steps(n, rng, gain, (20.0, 80.0), int(rng.integers(3, 6)))
    else:
        u0 = float(rng.uniform(30.0, 70.0))
        u_lv = np.full(n, u0)
    valve_kw: dict[str, Any] = {}
    process: Any = ProcessModel("foptd", gain=gain, tau_s=tau, delay_s=delay, bias=0.0)
    sp = gain * u_lv
    load = random_walk(n, gain * 0.004, np.random.default_rng(seed + 1), leak=0.005)
    if effect == "actuator_lag":
        valve_kw["tau_lag_s"] = float(rng.uniform(3.0, 8.0) * ts_s)
        truth["tau_lag_s"] = valve_kw["tau_lag_s"]
    elif effect == "asymmetric_stiction":
        r_s, r_j = float(rng.uniform(0.3, 0.55)), float(rng.uniform(0.3, 0.7))
        if rng.random() < 0.5:
            valve_kw.update(S_dn_pct=S * r_s, J_dn_pct=min(J * r_j, S * r_s))
        else:
            valve_kw.update(S_dn_pct=S, J_dn_pct=J)
            S, J = S * r_s, min(J * r_j, S * r_s)
        truth.update(S_open_pct=S, J_open_pct=J, S_close_pct=valve_kw["S_dn_pct"],
                     J_close_pct=valve_kw["J_dn_pct"])
    elif effect == "time_varying_friction":
        ch = float(rng.uniform(0.8, 1.6)) if rng.random() < 0.75 else float(rng.uniform(-0.6, -0.45))
        T = (n + warmup) * ts_s
        valve_kw.update(dS_pct_per_s=S * ch / T, dJ_pct_per_s=J * ch / T)
        truth.update(relative_change=ch, dS_pct_per_h=S * ch / T * 3600, dJ_pct_per_h=J * ch / T * 3600)
    elif effect == "valve_characteristic":
        R = float(rng.uniform(4.0, 15.0))
        process = CharacteristicProcess(process, R)
        # the steady state now needs flow = u_lv: setpoint in flow terms
        sp = gain * 100.0 * R ** (u_lv / 100.0 - 1.0)
        truth["rangeability_R"] = R
    elif effect == "external_disturbance":
        # period away from the limit cycle's harmonics (measured on the clean loop of the same seed)
        clean, _ = _draw("none", seed, min(n, 1500), ts_s, True, None, True)
        plc = limit_cycle_period(clean.mv, clean.op, ts_s) or 100.0
        for _ in range(50):
            period = float(rng.uniform(20.0, 250.0) * ts_s)
            h = plc / period if period < plc else period / plc
            if abs(h - round(h)) > 0.2:
                break
        amp = float(gain * rng.uniform(1.0, 2.5))
        load = load + np.concatenate([sinusoid(n + warmup, ts_s, period, amp,
                                               float(rng.uniform(0, 2 * np.pi)))[warmup:]])
        truth.update(period_s=period, amplitude=amp, limit_cycle_period_s=plc)
    if not apply_effect:
        valve_kw = {}
        S, J = truth["S_pct"], truth["J_pct"]
        if effect == "valve_characteristic":
            process = ProcessModel("foptd", gain=gain, tau_s=tau, delay_s=delay, bias=0.0)
            sp = gain * u_lv
        if effect == "external_disturbance":
            load = random_walk(n, gain * 0.004, np.random.default_rng(seed + 1), leak=0.005)
    valve = AugmentedValve(S, J, ts_s=ts_s, f0=f0, **valve_kw)
    ctrl = simc_pi(gain, tau, delay, ts_s)
    rec = simulate_loop(n=n, ts_s=ts_s, process=process, controller=ctrl, valve=valve,
                        op0_pct=u0, sp=sp, load=load, noise_std=noise, seed=seed + 2, warmup=warmup,
                        name=name or f"{effect}-{seed}")
    mv = None
    if with_mv:
        mv = rec.mv + _mv_noise(seed, n)
    rec = rec.replace(mv=mv, meta={**rec.meta, "concealed": effect})
    return rec, truth
