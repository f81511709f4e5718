"""Sticky loops with one piece of missing physics hidden in them, for scoring `stiction explain`.

`concealed(effect, seed)` draws a sticky loop (two-parameter, Kano or force-balance valve on a
FOPTD, SOPTD or third-order process), draws the effect's parameters before anything is simulated,
and simulates the loop with the effect and, for comparison, without it (the twin). Effect names
are those of `diagnose.physics`.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from scipy import signal

from . import disturbances as dist
from .controller import PID
from .draws import (MAX_DRAWS, Draws, Plan, centre_pv0, class_J, draw_noise, draw_process, draw_stem, simulate,
                    tune, warmup_samples)
from .guards import inside_span, motion_starts
from .friction import ForceBalance, Kano, TwoParameter
from .process import flow_characteristic
from .record import CLASSES, SimLoop, stiction_class

__all__ = ["EFFECTS", "concealed", "concealed_set"]

EFFECTS = ("none", "actuator_lag", "asymmetric_stiction", "valve_characteristic",
           "external_disturbance", "time_varying_friction")


def _cycle_period(op: np.ndarray, ts: float) -> float | None:
    """The dominant period of OP (from its autocorrelation's first peak), seconds."""
    x = op - np.mean(op)
    if np.std(x) < 1e-9:
        return None
    n = x.shape[0]
    f = np.fft.rfft(x, 2 * n)
    ac = np.fft.irfft(f * np.conj(f))[:n]
    ac /= ac[0]
    neg = np.nonzero(ac < 0)[0]
    if neg.size == 0:
        return None
    start = int(neg[0])
    lag = start + int(np.argmax(ac[start:n // 2])) if start < n // 2 else None
    return None if lag is None else lag * ts


def concealed(effect: str, seed: int, *, n: int = 8000, ts_s: float = 1.0, laws=None, process_kinds=None,
              twin: bool = True, min_moves: int = 6, apply_effect: bool = True) -> SimLoop:
    """A sticky loop with ``effect`` hidden in the plant (or ``"none"``).

    Parameters
    ----------
    effect : str
        One of `EFFECTS` (the names of `diagnose.physics`).
    seed : int
        Seed of every random choice.
    n : int
        Samples returned (after a warm-up).
    ts_s : float
        Sample period, seconds.
    laws : tuple of str, optional
        Friction laws to draw from (default ``two_parameter``, ``kano``, ``force_balance``).
    process_kinds : tuple of str, optional
        Process structures to draw from (default ``foptd``, ``soptd``, ``third_order``).
    twin : bool
        Also simulate the effect-free twin (same draw, effect left out) and record how much the
        effect changes PV: ``meta["effect_pv_change"]`` = RMS(PV - PV_twin) / std(PV_twin - SP_twin).
    min_moves : int
        Draw again (from a derived seed, ``meta["draw"]``) until the stem starts moving at least
        this many times in each half of the record: a valve stuck through half a record carries
        no trace of its friction there.
    apply_effect : bool
        False returns the twin itself.

    Returns
    -------
    SimLoop
        ``kind="concealed"``, ``sticky=True``; ``meta["effect"]``, ``meta["effect_size"]`` and
        ``meta["effect_size_unit"]`` say what is hidden and how big it is.
    """
    if effect not in EFFECTS:
        raise ValueError(f"unknown effect {effect!r}; choose from {', '.join(EFFECTS)}")
    laws = tuple(laws or ("two_parameter", "kano", "force_balance"))
    kinds = tuple(process_kinds or ("foptd", "soptd", "third_order"))
    for draw in range(MAX_DRAWS):
        ss = np.random.SeedSequence([int(seed), 24, EFFECTS.index(effect), draw])
        rec, clean, d = _concealed_draw(effect, ss, n, ts_s, laws, kinds)
        half = n // 2
        m1, m2 = motion_starts(rec["mv"][:half]), motion_starts(rec["mv"][half:])
        ok = m1 >= min_moves and m2 >= min_moves and inside_span(rec["pv"], d.meta["pv_span"])
        if ok:
            break
    d.set("draw", draw)
    d.set("guard_passed", ok)
    d.set("stem_moves_first_half", m1), d.set("stem_moves_second_half", m2)
    d.set("seed", int(seed))
    if twin and clean is not None:
        # against the twin's control error, not PV's spread: setpoint moves would dwarf the effect
        err = clean["pv"] - clean["sp"]
        d.set("effect_pv_change", float(np.sqrt(np.mean((rec["pv"] - clean["pv"]) ** 2)) / max(np.std(err), 1e-12)))
    out = rec if apply_effect else clean
    return SimLoop(op=out["op"], pv=out["pv"], sp=out["sp"], mv=out["mv"], ts_s=ts_s,
                   name=f"{effect}_{seed}", sticky=True, kind="concealed", meta=dict(d.meta))


def _concealed_draw(effect: str, ss: np.random.SeedSequence, n: int, ts: float, laws, kinds):
    d = Draws(np.random.default_rng(ss))
    d.set("scenario", "concealed"), d.set("effect", effect), d.set("sticky", True)
    d.set("n", n), d.set("ts_s", ts), d.set("integrating", False)
    sp_moves = effect == "valve_characteristic" or d.chance("sp_moves", 0.3)
    # a setpoint that tours 20-80 % of travel needs a gain that keeps PV inside the span
    proc = draw_process(d, ts, integrating_=False, kinds=kinds, gain_range=(0.3, 1.3) if sp_moves else (0.3, 3.0))
    for k, v in proc.describe().items():
        d.set(k, v)
    span = d.meta["pv_span"]
    law = d.choice("law", laws)
    cls = d.choice("class", CLASSES) if law != "force_balance" else None
    S = d.loguniform("S_pct", 2.0, 8.0)
    u_levels = None
    if sp_moves:
        k = d.integer("n_sp_levels", 3, 5)
        u_levels = list(np.linspace(20.0, 80.0, k + 1))
        d.rng.shuffle(u_levels)
        d.set("sp_valve_levels_pct", [float(u) for u in u_levels])
        u0 = d.set("u0_pct", float(u_levels[0]))
    else:
        u0 = d.uniform("u0_pct", 30.0, 70.0)
    pv0 = d.set("pv0", span * d.uniform("pv0_frac", 0.3, 0.7))

    # effect parameters, drawn before anything is simulated so the twin shares them
    eff: dict[str, Any] = {}
    if effect == "actuator_lag":
        eff["order"] = d.choice("lag_order", (1, 2), p=(0.6, 0.4))
        eff["tau"] = d.uniform("tau_lag_s", 2.0 * ts, 8.0 * ts) if eff["order"] == 1 else \
            d.uniform("tau_lag_s", 1.5 * ts, 5.0 * ts)
        eff["zeta"] = d.uniform("lag_zeta", 0.5, 1.0) if eff["order"] == 2 else 1.0
        d.set("lag_at", "before" if law == "force_balance" else "after")
        d.set("effect_size", eff["tau"] / ts), d.set("effect_size_unit", "lag time constant / ts")
    elif effect == "asymmetric_stiction":
        eff["ratio"] = d.uniform("asym_ratio", 0.3, 0.6)
        eff["weaker"] = d.choice("asym_weaker", ("closing", "opening"))
        d.set("effect_size", 1.0 / eff["ratio"]), d.set("effect_size_unit", "stronger / weaker friction")
    elif effect == "valve_characteristic":
        eff["kind"] = d.choice("characteristic", ("equal_percentage", "quick_opening"), p=(0.7, 0.3))
        eff["R"] = d.uniform("rangeability_R", 5.0, 40.0) if eff["kind"] == "equal_percentage" else \
            d.uniform("quick_opening_R", 2.0, 8.0)
        fch = flow_characteristic(eff["kind"], eff["R"])
        slopes = np.gradient(fch(np.linspace(20.0, 80.0, 61)), 1.0)
        d.set("effect_size", float(slopes.max() / slopes.min()))
        d.set("effect_size_unit", "largest / smallest installed gain over 20-80 % travel")
    elif effect == "external_disturbance":
        eff["wave"] = d.choice("osc_waveform", ("sine", "square", "sawtooth", "narrowband"),
                               p=(0.4, 0.2, 0.2, 0.2))
        eff["amp_pct"] = d.uniform("osc_pv_amplitude_pct", 1.0, 2.5)
        eff["entry"] = d.choice("osc_entry", ("output", "input"))
        eff["phase"] = d.uniform("osc_phase", 0.0, 2 * math.pi)
        eff["u_period"] = float(d.rng.uniform())
    elif effect == "time_varying_friction":
        eff["shape"] = d.choice("tvf_shape", ("drift", "step"), p=(0.7, 0.3))
        up = d.chance("tvf_increases", 0.75)
        eff["change"] = d.uniform("tvf_change", 0.6, 1.5) if up else -d.uniform("tvf_drop", 0.4, 0.6)
        eff["at"] = d.uniform("tvf_step_at_fraction", 0.3, 0.7) if eff["shape"] == "step" else None
        d.set("effect_size", abs(eff["change"])), d.set("effect_size_unit", "relative change of friction")
    else:
        d.set("effect_size", 0.0), d.set("effect_size_unit", "")

    # controller on the linear plant (the characteristic is what the engineer did not model)
    ctrl = tune(d, proc, ts, gm_min=2.0)
    Kc, Ti, Td, form = ctrl.Kc, ctrl.Ti, ctrl.Td, ctrl.form
    warmup = d.set("warmup", max(warmup_samples(proc, ts, Ti), 2000))
    total = n + warmup

    # valve (law and bands); J by class
    if law == "force_balance":
        stem_kw, h_fine = draw_stem(d, S, ts)
        d.set("class", stiction_class(d.meta["S_pct"], d.meta["J_pct"]))
        J = d.meta["J_pct"]
        S = d.meta["S_pct"]
    else:
        J = class_J(d, S, cls)
        direction0 = d.choice("direction0", (1, -1))
        stem_kw, h_fine = None, None
        if law == "kano":
            d.set("deadband_pct", max(S - J, 0.0)), d.set("stickband_pct", J)

    meas, out_load, in_load = draw_noise(d, total, span, proc, meas_pct=(0.03, 0.2), load_pct=(0.05, 0.5))
    sp_dev = np.zeros(total)
    if u_levels is not None:
        edges = np.linspace(warmup, total, len(u_levels) + 1).astype(int)[1:-1]
        steps_u = np.full(total, u_levels[0])
        for e, u in zip(edges, u_levels[1:]):
            steps_u[e:] = u
        d.set("sp_step_at", [int(e - warmup) for e in edges])
        fmap = flow_characteristic(eff["kind"], eff["R"]) if effect == "valve_characteristic" else (lambda y: y)
        pv0 = d.set("pv0", centre_pv0(pv0, proc.gain * (np.asarray(fmap(steps_u)) - float(fmap(u0))), span))
    else:
        steps_u = None

    def build(with_effect: bool, osc_period: float | None):
        if law == "force_balance":
            kw = dict(stem_kw)
            if with_effect and effect == "asymmetric_stiction":
                r = eff["ratio"]
                if eff["weaker"] == "closing":
                    kw.update(Fs_close_N=kw["Fs_N"] * r, Fc_close_N=kw["Fc_N"] * r)
                else:
                    kw.update(Fs_close_N=kw["Fs_N"], Fc_close_N=kw["Fc_N"], Fs_N=kw["Fs_N"] * r,
                              Fc_N=kw["Fc_N"] * r)
            if with_effect and effect == "actuator_lag":
                kw["tau_p_s"] = kw["tau_p_s"] + eff["tau"]
                kw["h_s"] = min(kw["h_s"], kw["tau_p_s"] / 4.0)
            law_obj = ForceBalance(**kw)
            bands = None
        else:
            S_o, J_o, S_c, J_c = S, J, S, J
            if with_effect and effect == "asymmetric_stiction":
                r = eff["ratio"]
                if eff["weaker"] == "closing":
                    S_c, J_c = S * r, J * r
                else:
                    S_o, J_o = S * r, J * r
            cls_obj = TwoParameter if law == "two_parameter" else Kano
            law_obj = cls_obj(S_o, J_o, direction0, S_close_pct=S_c, J_close_pct=J_c)
            bands = (S_o, J_o, S_c, J_c)
        lag = None
        if with_effect and effect == "actuator_lag" and law != "force_balance":
            lag = (eff["order"], eff["tau"], eff["zeta"])
        schedule = None
        if with_effect and effect == "time_varying_friction":
            schedule = np.ones(total)
            if eff["shape"] == "drift":
                schedule[warmup:] = 1.0 + eff["change"] * np.arange(n) / max(n - 1, 1)
            else:
                schedule[warmup + int(n * eff["at"]):] = 1.0 + eff["change"]
        flow = None
        if with_effect and effect == "valve_characteristic":
            flow = flow_characteristic(eff["kind"], eff["R"])
        # setpoint: the steady-state PV of each valve level through this plant's flow map
        if steps_u is not None:
            fmap = flow if flow is not None else (lambda y: y)
            sp = proc.gain * (np.asarray(fmap(steps_u)) - float(fmap(u0)))
        else:
            sp = sp_dev
        ol, il = out_load, in_load
        if with_effect and effect == "external_disturbance":
            shape = _oscillation(eff["wave"], total, ts, osc_period, eff["phase"],
                                 np.random.default_rng(ss_osc))
            amp_pv = abs(proc.gain) * eff["amp_pct"]
            if eff["entry"] == "output":
                ol = ol + amp_pv * shape * np.sign(proc.gain)
            else:
                att = abs(proc.frequency_response(np.array([2 * math.pi / osc_period]))[0])
                il = il + min(amp_pv / max(att, 1e-12), 15.0) * shape
        plan = Plan("concealed", True, n, ts, warmup, proc, lambda: PID(Kc, Ti, Td, ts_s=ts, form=form),
                     law_obj, lag, "after", bands, schedule, h_fine, flow, sp, ol, il, meas, u0, pv0, span)
        return simulate(plan, d)

    ss_osc = int(d.rng.integers(2 ** 31))
    clean = build(False, None) if (effect != "none") else None
    period = None
    if effect == "external_disturbance":
        plc = _cycle_period(clean["op"], ts) or 100.0 * ts
        d.set("limit_cycle_period_s", plc)
        # a period away from the limit cycle and its harmonics
        r = eff["u_period"]
        for _ in range(60):
            period = 20.0 * ts + r * 230.0 * ts
            h = max(period, plc) / min(period, plc)
            if abs(h - round(h)) > 0.2:
                break
            r = float(d.rng.uniform())
        d.set("osc_period_s", period)
        d.set("effect_size", eff["amp_pct"]), d.set("effect_size_unit", "oscillation amplitude, % of process gain")
    rec = build(True, period)
    if effect == "none":
        clean = rec
    return rec, clean, d


def _oscillation(wave: str, total: int, ts: float, period: float, phase: float,
                 rng: np.random.Generator) -> np.ndarray:
    if wave == "sine":
        return dist.sine(total, ts, period, 1.0, phase)
    if wave == "square":
        return dist.square(total, ts, period, 1.0, phase=phase, edge_tau_s=0.05 * period)
    if wave == "sawtooth":
        return dist.sawtooth(total, ts, period, 1.0, rise=0.8, phase=phase)
    # narrowband: white noise through a resonance at the period (an AR(2) with poles near the circle)
    w0 = 2 * math.pi * ts / period
    rad = 0.995
    e = rng.normal(size=total)
    y = signal.lfilter([1.0], [1.0, -2 * rad * math.cos(w0), rad * rad], e)
    return y / (np.std(y) * math.sqrt(2.0))


def concealed_set(seed: int, n_per_effect: int, *, effects=EFFECTS, **kwargs) -> list[SimLoop]:
    """``n_per_effect`` concealed-effect records per effect; record ``i`` uses seed ``seed * 1000 + i``."""
    out = []
    for eff in effects:
        for i in range(n_per_effect):
            out.append(concealed(eff, int(seed) * 1000 + i, **kwargs))
    return out
