"""Labelled closed-loop records: sticky valves under three friction laws, and hard healthy negatives.

`corpus(seed, n_per_kind)` yields `SimLoop` records scenario by scenario (`make_loop` builds one).
Every random choice goes through `draws.Draws`, which records it, so ``SimLoop.meta`` holds every
drawn parameter under a stable name. Each record has its own generator, seeded from
``(seed, scenario, index)``, so a record does not change when others are added or removed.

Scenarios (``SimLoop.kind``) and why each negative is hard:

* ``two_parameter``, ``kano``, ``force_balance`` -- sticky valves (positives) on self-regulating and
  integrating processes; S 0.5-10 % of span; the four classes cycle with the record index.
* ``healthy`` -- a good valve (linear, a positioner lag, or play under the resolution) with
  coloured noise, setpoint and load steps.
* ``external_sine`` / ``external_nonsine`` -- a healthy valve under an oscillating load (sine;
  square wave of an upstream on/off device or a fill-and-dump saw-tooth): the loop oscillates, OP
  and PV trace a loop, and square/saw loads make the triangular or square shapes stiction makes.
* ``overtuned`` -- a healthy valve under a controller near its stability limit (gain margin
  1.15-1.45): a noise-driven, nearly sustained oscillation.
* ``quantised`` -- PV on a coarse resolution (0.2-1 % of span): staircase PV, flat runs.
* ``compressed`` -- PV (and sometimes OP) through a swinging-door historian (0.5-2 % of span),
  interpolated back: straight segments and corners, the shape of a stiction triangle.
* ``level_pi`` -- an integrating level under a lightly damped PI: a slow, regular oscillation whose
  OP-PV phase resembles a sticky level loop's.
* ``daily_cycle`` -- a healthy loop following a 24-hour load cycle: slow drift and a long ramp in OP.

Two definitions (``definition=``). ``"original"`` reproduces the corpus as first defined, seed for
seed. ``"identifiable"`` draws from its own streams and (a) redraws any record that fails a
`guards` check: OP saturated or swinging over the valve's range, a growing oscillation, a ringing
loop outside the ringing scenarios, a PV that does not hold its setpoint, and a sticky valve that
cannot show its stiction (too few slips, never stuck, or a band under twice OP's noise); (b) caps a
historian deviation or step at a quarter of PV's spread, so an artifact shapes PV without erasing it;
(c) makes a quarter of the records integrating in the sticky scenarios too; (d) makes a quarter of
the records historian-sampled fast flow loops (``historian_fast``: lags of seconds sampled at 10 s,
a detuned PI, noisy meters, operator setpoint moves).
"""

from __future__ import annotations

import math
from typing import Iterator

import numpy as np

from . import disturbances as dist
from . import guards
from .controller import PID, closed_loop_sensitivity
from .draws import (FAST, MAX_DRAWS, Draws, Plan, centre_pv0, class_J, draw_flow, draw_noise, draw_process,
                    draw_stem, friction_schedule, healthy_valve, historian, simulate, sp_and_load_steps, timebase,
                    tune, warmup_samples)
from .friction import ForceBalance, Kano, Linear, TwoParameter
from .process import Process
from .record import CLASSES, SimLoop, stiction_class

__all__ = ["SCENARIOS", "STICKY_SCENARIOS", "DEFINITIONS", "corpus", "make_loop"]

DEFINITIONS = guards.DEFINITIONS

# Order matters: a scenario's position seeds its records, so append new scenarios at the end.
SCENARIOS: dict[str, bool] = {
    "two_parameter": True,
    "kano": True,
    "force_balance": True,
    "healthy": False,
    "external_sine": False,
    "external_nonsine": False,
    "overtuned": False,
    "quantised": False,
    "compressed": False,
    "level_pi": False,
    "daily_cycle": False,
}
STICKY_SCENARIOS = tuple(k for k, v in SCENARIOS.items() if v)

# identifiable definition: share of records that are historian-sampled fast flow loops, in the
# scenarios where such a loop makes sense (not the ringing ones, which need a tuned loop), and the
# share of integrating processes; a historian deviation is at most PV's spread over ARTIFACT_CAP
P_FAST = 0.25
P_INTEGRATING = 0.25
NO_FAST = ("overtuned", "level_pi")
ARTIFACT_CAP = 4.0


def _sticky_valve(d: Draws, law: str, cls: str | None, ts: float, total: int, warmup: int, *,
                  p_lag=0.3, p_asym=0.2, p_tvf=0.15, S_range=(0.5, 10.0)):
    """A sticky valve of ``law`` with optional lag, asymmetry and time-varying friction."""
    d.set("law", law)
    S = d.loguniform("S_pct", *S_range)
    asym = d.chance("asymmetric", p_asym)
    ratio = d.uniform("asym_ratio", 0.3, 0.7) if asym else 1.0
    weaker = d.choice("asym_weaker", ("closing", "opening")) if asym else None
    schedule = friction_schedule(d, total, warmup, p_tvf)
    if law == "force_balance":
        kw, h_fine = draw_stem(d, S, ts)
        if asym:
            if weaker == "closing":
                kw.update(Fs_close_N=kw["Fs_N"] * ratio, Fc_close_N=kw["Fc_N"] * ratio)
            else:
                kw.update(Fs_close_N=kw["Fs_N"], Fc_close_N=kw["Fc_N"])
                kw["Fs_N"] *= ratio
                kw["Fc_N"] *= ratio
            d.set("Fs_close_N", kw["Fs_close_N"]), d.set("Fc_close_N", kw["Fc_close_N"])
            d.set("Fs_open_N", kw["Fs_N"]), d.set("Fc_open_N", kw["Fc_N"])
        d.set("class", stiction_class(d.meta["S_pct"], d.meta["J_pct"]))
        law_obj = ForceBalance(**kw)
        bands = None
    else:
        d.set("class", cls)
        J = class_J(d, S, cls)
        direction0 = d.choice("direction0", (1, -1))
        S_o, J_o, S_c, J_c = S, J, S, J
        if asym:
            if weaker == "closing":
                S_c, J_c = S * ratio, J * ratio
            else:
                S_o, J_o = S * ratio, J * ratio
            d.set("S_open_pct", S_o), d.set("J_open_pct", J_o)
            d.set("S_close_pct", S_c), d.set("J_close_pct", J_c)
        cls_obj = TwoParameter if law == "two_parameter" else Kano
        law_obj = cls_obj(S_o, J_o, direction0, S_close_pct=S_c, J_close_pct=J_c)
        if isinstance(law_obj, Kano):
            d.set("deadband_pct", max(S - J, 0.0)), d.set("stickband_pct", J)
        bands = (S_o, J_o, S_c, J_c)
        h_fine = None
    lag, lag_at = None, "after"
    if d.chance("actuator_lag", p_lag):
        order = d.choice("lag_order", (1, 2), p=(0.6, 0.4))
        tau = d.loguniform("tau_lag_s", 0.5 * ts, 5.0 * ts)
        zeta = d.uniform("lag_zeta", 0.5, 1.0) if order == 2 else 1.0
        lag_at = "before" if law == "force_balance" else d.choice("lag_at", ("after", "before"))
        d.set("lag_at", lag_at)
        lag = (order, tau, zeta)
    return law_obj, bands, schedule, lag, lag_at, h_fine


def _original_integrating(kind: str, d: Draws, index: int) -> bool:
    """Original definition: sticky scenarios alternate; a quarter of most negatives are integrating."""
    if SCENARIOS[kind]:
        return d.set("integrating", index % 2 == 1)
    if kind == "level_pi":
        return d.set("integrating", True)
    if kind in ("overtuned", "external_sine", "external_nonsine"):
        return d.set("integrating", False)
    return d.chance("integrating", 0.25)


def _structure(kind: str, d: Draws, index: int) -> tuple[bool, bool]:
    """Identifiable definition: (integrating, historian_fast) of record ``index``.

    Sticky scenarios make every fourth record integrating; elsewhere a quarter of the records are
    integrating (all in ``level_pi``, none where an integrating process does not fit the
    scenario). A quarter of the records are fast flow loops (none in `NO_FAST`), drawn among the
    self-regulating ones so that both shares hold.
    """
    if SCENARIOS[kind]:
        integ = d.set("integrating", index % 4 == 3)
        p_integ = P_INTEGRATING
    elif kind == "level_pi":
        integ = d.set("integrating", True)
        p_integ = 1.0
    elif kind in ("overtuned", "external_sine", "external_nonsine"):
        integ = d.set("integrating", False)
        p_integ = 0.0
    else:
        integ = d.chance("integrating", P_INTEGRATING)
        p_integ = P_INTEGRATING
    fast = False
    if not integ and kind not in NO_FAST:
        fast = d.chance("historian_fast", P_FAST / (1.0 - p_integ))
    d.set("historian_fast", fast)
    return integ, fast


def _draw_plan(kind: str, d: Draws, index: int, n: int | None, ts_s: float | None,
               definition: str = "original") -> Plan:
    sticky = SCENARIOS[kind]
    ident = definition == "identifiable"
    d.set("scenario", kind)
    d.set("sticky", sticky)
    fast = False
    if ident:
        integ, fast = _structure(kind, d, index)
        if fast and ts_s is None:
            ts_s = FAST["ts_s"]
    if kind == "daily_cycle" and ts_s is None:
        ts_s = d.choice("ts_s", (5.0, 10.0))
    if kind == "daily_cycle":
        # long enough for the cycle to show: 4-28 hours
        n, ts = timebase(d, n, ts_s, n_range=(3000, 10000), p_window=0.0)
    else:
        n, ts = timebase(d, n, ts_s)
    if not ident:
        integ = _original_integrating(kind, d, index)
    proc = draw_process(d, ts, integrating_=integ, fast=fast)
    for k, v in proc.describe().items():
        d.set(k, v)
    span = d.meta["pv_span"]
    u0 = d.uniform("u0_pct", 25.0, 75.0)
    pv0 = d.set("pv0", span * d.uniform("pv0_frac", 0.3, 0.7))
    flow, slope = draw_flow(d, 0.25 if kind in ("healthy", *STICKY_SCENARIOS) else 0.0)

    # controller
    gm_target = d.uniform("gain_margin_target", 1.15, 1.45) if kind == "overtuned" else None
    level_zeta = d.uniform("closed_loop_zeta_target", 0.08, 0.3) if kind == "level_pi" else None
    ctrl = tune(d, proc, ts, flow_slope=slope, gm_target=gm_target, level_zeta=level_zeta,
                gm_min=1.1 if kind == "level_pi" else 2.0, fast=fast,
                zeta_min=guards.MIN_ZETA if ident and kind not in guards.RINGING else None)
    Kc, Ti, Td, form = ctrl.Kc, ctrl.Ti, ctrl.Td, ctrl.form

    def ctrl_factory() -> PID:
        return PID(Kc, Ti, Td, ts_s=ts, form=form)

    warmup = d.set("warmup", warmup_samples(proc, ts, Ti))
    total = n + warmup

    # valve
    law, bands, schedule, lag, lag_at, h_fine = Linear(), None, None, None, "after", None
    if sticky:
        # original: the class changes every second record; identifiable: every record, so that
        # each four records hold all classes and sixteen hold every class x structure
        cycle = (index + index // 4) if ident else index // 2
        cls = CLASSES[cycle % 4] if kind != "force_balance" else None
        law, bands, schedule, lag, lag_at, h_fine = _sticky_valve(d, kind, cls, ts, total, warmup)
    else:
        law, lag = healthy_valve(d, ts)

    # signals
    if fast:
        meas, out_load, in_load = draw_noise(d, total, span, proc, meas_pct=FAST["meas_noise_pct"])
    else:
        meas, out_load, in_load = draw_noise(d, total, span, proc)
    p_sp = {"healthy": 0.6, "level_pi": 0.3}.get(kind, 0.3)
    if fast:
        # the operator moves a flow setpoint now and then
        p_sp = FAST["p_sp_steps"]
    p_ld = {"healthy": 0.5}.get(kind, 0.25)
    sp, ld = sp_and_load_steps(d, total, warmup, span, proc, u0, p_sp, p_ld)
    in_load = in_load + ld
    pv0 = d.set("pv0", centre_pv0(pv0, sp, span))
    plan = Plan(kind, sticky, n, ts, warmup, proc, ctrl_factory, law, lag, lag_at, bands, schedule, h_fine,
                flow, sp, out_load, in_load, meas, u0, pv0, span)
    if ident and (sticky or kind == "compressed"):
        plan.artifact_cap = ARTIFACT_CAP

    rng = d.rng
    if kind in ("external_sine", "external_nonsine"):
        period = d.loguniform("osc_period_s", 15.0 * ts, 200.0 * ts)
        lo, hi = 0.5, 4.0
        if ident:
            # the load must stand out of the measurement noise (a noisy fast flow loop) to fake
            # a stiction cycle
            noise = d.meta["meas_noise_pct"]
            lo, hi = max(lo, 2.0 * noise), max(hi, 5.0 * noise)
        amp_pv = span / 100.0 * d.uniform("osc_pv_amplitude_pct", lo, hi)
        entry = d.choice("osc_entry", ("input", "output"))
        phase = d.uniform("osc_phase", 0.0, 2 * math.pi)
        if kind == "external_sine":
            wave = d.set("osc_waveform", "sine")
            shape = dist.sine(total, ts, period, 1.0, phase)
        else:
            wave = d.choice("osc_waveform", ("square", "sawtooth"))
            if wave == "square":
                shape = dist.square(total, ts, period, 1.0, duty=d.uniform("osc_duty", 0.3, 0.7), phase=phase,
                                    edge_tau_s=period * d.uniform("osc_edge_tau_over_period", 0.0, 0.08))
            else:
                shape = dist.sawtooth(total, ts, period, 1.0, rise=d.uniform("osc_rise_fraction", 0.6, 0.95),
                                      phase=phase)
        if entry == "output":
            plan.out_load = plan.out_load + amp_pv * shape
        else:
            att = abs(proc.frequency_response(np.array([2 * math.pi / period]))[0])
            amp_in = d.set("osc_flow_amplitude_pct", min(amp_pv / max(att, 1e-12), 15.0))
            plan.in_load = plan.in_load + amp_in * shape
    elif kind == "quantised":
        q = span / 100.0 * d.uniform("quant_pct", 0.2, 1.0)
        plan.meas = dist.white(total, q * d.uniform("meas_noise_over_quant", 0.05, 0.4), rng)
        d.set("meas_noise_pct", float(np.std(plan.meas)) / span * 100.0)
        if d.choice("quant_at", ("sensor", "historian")) == "sensor":
            plan.sensor_quant = q
        else:
            plan.hist_quant = q
        d.set("quant_step", q)
        if d.chance("slow_wave_on", 0.5):
            # a slow wave a few steps high turns into a staircase of square-ish steps
            plan.out_load = plan.out_load + dist.sine(
                total, ts, d.loguniform("wave_period_s", 20.0 * ts, 200.0 * ts),
                q * d.uniform("wave_amplitude_over_quant", 1.0, 4.0), d.uniform("wave_phase", 0.0, 2 * math.pi))
    elif kind == "compressed":
        dev = span / 100.0 * d.uniform("compress_pv_pct", 0.5, 2.0)
        plan.meas = dist.white(total, dev * d.uniform("meas_noise_over_dev", 0.05, 0.3), rng)
        d.set("meas_noise_pct", float(np.std(plan.meas)) / span * 100.0)
        # PV must move several deviations for compression to shape it rather than flatten it
        base = d.choice("compress_base", ("sine_load", "coloured_load"))
        if base == "sine_load":
            period = d.loguniform("wave_period_s", 20.0 * ts, 200.0 * ts)
            amp = dev * d.uniform("wave_amplitude_over_dev", 2.0, 6.0)
            if ident:
                # the amplitude is what PV shows: the load is raised by what the controller
                # rejects at that period, as long as OP needs under 15 % of travel to reject it
                w = 2 * math.pi / period
                S = closed_loop_sensitivity(proc, Kc, Ti, Td, ts, w)
                reach = 15.0 * abs(proc.frequency_response(np.array([w]))[0])
                amp = d.set("wave_load_amplitude", min(amp / max(S, 1e-6), max(amp, reach)))
            plan.out_load = plan.out_load + dist.sine(total, ts, period, amp,
                                                      d.uniform("wave_phase", 0.0, 2 * math.pi))
        else:
            colour = d.choice("compress_load_colour", ("ar1", "random_walk", "pink"))
            plan.out_load = plan.out_load + dist.coloured(
                colour, total, dev * d.uniform("load_std_over_dev", 1.5, 5.0), rng, phi=0.98)
        plan.compress_pv = dev
        if d.chance("compress_op_on", 0.5):
            plan.compress_op = d.uniform("compress_op_pct", 0.2, 1.0)
    elif kind == "daily_cycle":
        amp = span / 100.0 * d.uniform("daily_amplitude_pct", 1.0, 6.0)
        phase = d.uniform("daily_phase", 0.0, 2 * math.pi)
        plan.out_load = plan.out_load + dist.daily(total, ts, amp, phase)
    if kind not in ("quantised", "compressed"):
        if d.chance("sensor_filter_on", 0.2):
            plan.sensor_tau_s = d.loguniform("sensor_tau_s", 0.5 * ts, 3.0 * ts)
        if sticky and d.chance("historian_compression_on", 0.15):
            plan.compress_pv = span / 100.0 * d.uniform("compress_pv_pct", 0.2, 1.0)
        elif sticky and d.chance("historian_quantisation_on", 0.1):
            plan.hist_quant = span / 100.0 * d.uniform("quant_pct", 0.05, 0.5)
    return plan


def _name(proc: Process, ts: float, index: int) -> str:
    if proc.integrating:
        prefix = "LIC"
    else:
        tau = proc.params.get("tau1_s", 1.0 / proc.params.get("wn_rad_s", 1.0))
        prefix = "FIC" if tau <= 3 * ts else ("TIC" if tau > 15 * ts else "PIC")
    return f"{prefix}{index:05d}"


def make_loop(kind: str, seed: int, index: int, *, n: int | None = None, ts_s: float | None = None,
              name: str | None = None, definition: str = "original") -> SimLoop:
    """Record ``index`` of scenario ``kind`` for corpus seed ``seed`` (see `corpus`)."""
    if kind not in SCENARIOS:
        raise ValueError(f"unknown scenario {kind!r}; choose from {', '.join(SCENARIOS)}")
    if definition not in DEFINITIONS:
        raise ValueError(f"unknown corpus definition {definition!r}; choose from {', '.join(DEFINITIONS)}")
    pos = list(SCENARIOS).index(kind)
    # the identifiable corpus draws from its own streams: a record of it is not a redraw of the original
    tag = [1] if definition == "identifiable" else []
    reasons: list[str] = []
    for draw in range(MAX_DRAWS):
        d = Draws(np.random.default_rng(np.random.SeedSequence([int(seed), pos, int(index), draw] + tag)))
        plan = _draw_plan(kind, d, index, n, ts_s, definition)
        raw = simulate(plan, d)
        op, pv = historian(plan, d, raw)
        failed = guards.check(definition, kind=kind, sticky=plan.sticky, raw=raw, op=op, pv=pv, span=plan.span,
                              meta=d.meta)
        if not failed:
            break
        reasons.append("+".join(failed))
    d.set("draw", draw)
    d.set("guard_passed", not failed)
    d.set("seed", int(seed)), d.set("index", int(index))
    d.set("definition", definition)
    if definition != "original":
        d.set("redraw_reasons", reasons)
    return SimLoop(op=op, pv=pv, sp=raw["sp"], mv=raw["mv"], ts_s=plan.ts,
                   name=name or _name(plan.proc, plan.ts, index), sticky=plan.sticky, kind=kind,
                   meta=dict(d.meta))


def corpus(seed: int, n_per_kind: int, *, kinds=None, n: int | None = None, ts_s: float | None = None,
           start_index: int = 0, definition: str = "original") -> Iterator[SimLoop]:
    """Yield a labelled corpus: ``n_per_kind`` records of each scenario.

    Parameters
    ----------
    seed : int
        Corpus seed; the same seed gives the same records bit for bit.
    n_per_kind : int
        Records per scenario. In the original definition the sticky scenarios alternate
        self-regulating / integrating records and change class every second record (8 records
        cover all eight combinations); in the identifiable one every fourth record is
        integrating and the class changes every record (4 records cover the classes, 16 every
        combination).
    kinds : iterable of str, optional
        Scenarios to include (default all of `SCENARIOS`, in that order).
    n : int, optional
        Samples per record (default drawn: 751 samples at 10 s for plant-window records, else
        500-10 000 log-uniform).
    ts_s : float, optional
        Sample period (default drawn from 1, 2, 5, 10 s).
    start_index : int
        Number of the first record (names are ``<prefix><number>``).
    definition : {"original", "identifiable"}
        ``"original"`` reproduces the corpus as first defined, seed for seed. ``"identifiable"``
        redraws records a plant would not produce or whose stiction cannot show (see
        `guards`), makes a quarter of the sticky records integrating, and adds fast flow loops
        sampled by a historian (docs/plantsim.md).
    """
    if definition not in DEFINITIONS:
        raise ValueError(f"unknown corpus definition {definition!r}; choose from {', '.join(DEFINITIONS)}")
    kinds = list(SCENARIOS) if kinds is None else list(kinds)
    for k in kinds:
        if k not in SCENARIOS:
            raise ValueError(f"unknown scenario {k!r}; choose from {', '.join(SCENARIOS)}")
    number = start_index
    for k in kinds:
        for i in range(n_per_kind):
            loop = make_loop(k, seed, i, n=n, ts_s=ts_s, name=None, definition=definition)
            yield SimLoop(loop.op, loop.pv, loop.sp, loop.mv, loop.ts_s,
                          _name_from(loop, number), loop.sticky, loop.kind, loop.meta)
            number += 1


def _name_from(loop: SimLoop, number: int) -> str:
    return f"{loop.name[:3]}{number:05d}"
