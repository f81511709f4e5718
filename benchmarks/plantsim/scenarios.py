"""Labelled closed-loop records: sticky valves under three friction laws, and hard healthy negatives.

`corpus(seed, n_per_kind)` yields `SimLoop` records scenario by scenario; `concealed(effect, seed)`
builds one sticky loop with a piece of physics hidden in it (or none) and `concealed_set` a set of
them. Every random choice goes through `_Draws`, which records it, so ``SimLoop.meta`` holds every
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
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Iterator

import numpy as np

from . import artifacts as art
from . import disturbances as dist
from .controller import (PID, fopdt_of, gain_margin, imc_pid, integrating_pi, lambda_tuning, least_damped, simc,
                         spectral_radius)
from .friction import Backlash, ForceBalance, Kano, Linear, TwoParameter, force_balance_bands
from .loop import Signals, run_loop
from .process import Process, flow_characteristic, foptd, integrating, soptd, third_order, underdamped
from .valve import Lag, ValveTrain

__all__ = ["SimLoop", "SCENARIOS", "STICKY_SCENARIOS", "CLASSES", "EFFECTS", "corpus", "make_loop",
           "concealed", "concealed_set", "stiction_class"]

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
CLASSES = ("deadband", "undershoot", "no_offset", "overshoot")
EFFECTS = ("none", "actuator_lag", "asymmetric_stiction", "valve_characteristic",
           "external_disturbance", "time_varying_friction")
_MAX_DRAWS = 25


@dataclass(frozen=True)
class SimLoop:
    """One simulated record with its truth.

    Attributes
    ----------
    op, pv, sp, mv : ndarray (n,)
        Controller output (% of span), transmitted PV and setpoint (PV units), stem position
        (% of span; the true stem, before any historian artifact). Read-only.
    ts_s : float
        Sample period, seconds.
    name : str
        Loop tag (also the file stem when written).
    sticky : bool
        The label: the valve has stiction.
    kind : str
        Scenario (see `SCENARIOS`) or, for concealed-effect records, ``concealed``.
    meta : dict
        Every drawn parameter and derived truth (``S_pct``, ``J_pct``, ``law``, ``process``...).
    """

    op: np.ndarray
    pv: np.ndarray
    sp: np.ndarray
    mv: np.ndarray
    ts_s: float
    name: str
    sticky: bool
    kind: str
    meta: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        for k in ("op", "pv", "sp", "mv"):
            a = np.array(getattr(self, k), dtype=float)
            a.setflags(write=False)
            object.__setattr__(self, k, a)

    @property
    def n(self) -> int:
        return int(self.op.shape[0])


def stiction_class(S_pct: float, J_pct: float) -> str:
    """Class of a (S, J) pair, with J judged equal to S or to 0 within 15 % of S (0.1 % at least)."""
    if S_pct <= 0.1 and J_pct <= 0.1:
        return "none"
    tol = max(0.1, 0.15 * S_pct)
    if J_pct <= tol:
        return "deadband"
    if abs(J_pct - S_pct) <= tol:
        return "no_offset"
    return "undershoot" if J_pct < S_pct else "overshoot"


class _Draws:
    """A generator that writes every value it draws into ``meta`` under the given name."""

    def __init__(self, rng: np.random.Generator) -> None:
        self.rng = rng
        self.meta: dict[str, Any] = {}

    def set(self, key: str, value: Any) -> Any:
        self.meta[key] = value
        return value

    def uniform(self, key: str, lo: float, hi: float) -> float:
        return self.set(key, float(self.rng.uniform(lo, hi)))

    def loguniform(self, key: str, lo: float, hi: float) -> float:
        return self.set(key, float(math.exp(self.rng.uniform(math.log(lo), math.log(hi)))))

    def integer(self, key: str, lo: int, hi: int) -> int:
        """Uniform integer in ``lo..hi`` inclusive."""
        return self.set(key, int(self.rng.integers(lo, hi + 1)))

    def choice(self, key: str, options, p=None):
        v = options[int(self.rng.choice(len(options), p=p))]
        return self.set(key, v.item() if hasattr(v, "item") else v)

    def chance(self, key: str, p: float) -> bool:
        return self.set(key, bool(self.rng.random() < p))


# --- the plant ----------------------------------------------------------------------------------

def _timebase(d: _Draws, n: int | None, ts_s: float | None, *, n_range=(500, 10000),
              p_window: float = 0.6) -> tuple[int, float]:
    if ts_s is None:
        ts_s = d.choice("ts_s", (1.0, 2.0, 5.0, 10.0), p=(0.3, 0.15, 0.15, 0.4))
    else:
        ts_s = d.set("ts_s", float(ts_s))
    if n is None:
        if ts_s == 10.0 and d.chance("plant_window", p_window):
            n = 751                       # the real plant windows: two hours at 10 s
        else:
            n = int(round(d.loguniform("n_drawn", *n_range)))
    return d.set("n", int(n)), ts_s


def _process(d: _Draws, ts: float, *, integrating_: bool, kinds=None) -> Process:
    span = d.choice("pv_span", (10.0, 50.0, 100.0, 250.0, 1000.0))
    sign = d.choice("gain_sign", (1, -1), p=(0.8, 0.2))
    if integrating_:
        # fill time: seconds for the level to move 1 % of span per 1 % of flow imbalance
        fill = d.loguniform("fill_time_s", 3.0 * ts, 100.0 * ts)
        tau = d.uniform("tau1_s", 0.0, 3.0 * ts)
        delay = d.uniform("delay_s", 0.0, 3.0 * ts)
        return integrating(sign * span / 100.0 / fill, tau, delay)
    kinds = kinds or ("foptd", "soptd", "underdamped", "third_order")
    probs = {"foptd": 0.3, "soptd": 0.3, "underdamped": 0.15, "third_order": 0.25}
    p = np.array([probs.get(k, 0.25) for k in kinds])
    kind = d.choice("process", tuple(kinds), p=p / p.sum())
    K = sign * d.loguniform("gain_pct_per_pct", 0.3, 3.0) * span / 100.0
    T = d.loguniform("tau_s", 0.5 * ts, 30.0 * ts)
    delay = d.uniform("delay_s", 0.0, 4.0 * ts)
    if kind == "foptd":
        return foptd(K, T, delay)
    if kind == "soptd":
        return soptd(K, T, T * d.uniform("tau2_over_tau1", 0.1, 0.8), delay)
    if kind == "underdamped":
        return underdamped(K, 1.0 / T, d.uniform("zeta", 0.3, 0.7), delay)
    r2 = d.uniform("tau2_over_tau1", 0.2, 0.7)
    r3 = d.uniform("tau3_over_tau1", 0.05, 0.2)
    lead = T * d.uniform("lead_over_tau1", 0.1, 0.5) if d.chance("has_lead", 0.3) else 0.0
    return third_order(K, (T, T * r2, T * r3), delay, lead)


def _flow(d: _Draws, p_char: float):
    """An installed characteristic (or None) and its largest slope (flow % per stem %)."""
    if not d.chance("characteristic_on", p_char):
        d.set("characteristic", "linear")
        return None, 1.0
    kind = d.choice("characteristic", ("equal_percentage", "quick_opening"), p=(0.7, 0.3))
    if kind == "equal_percentage":
        R = d.uniform("rangeability_R", 5.0, 40.0)
        return flow_characteristic(kind, R), math.log(R) * R ** (0.9 - 1.0)
    R = d.uniform("quick_opening_R", 1.5, 6.0)
    return flow_characteristic(kind, R), (1.0 + R) / (1.0 + R * 0.1) ** 2


def _tune(d: _Draws, proc: Process, ts: float, *, flow_slope: float = 1.0, gm_min: float = 2.0,
          gm_target: float | None = None, level_zeta: float | None = None) -> PID:
    """A tuned PI/PID; de-tuned by a drawn factor, then held to ``gm_min`` (or set to ``gm_target``)."""
    Td = 0.0
    if proc.integrating:
        theta = proc.delay_s + proc.params["tau1_s"] + ts / 2.0
        tau_c = theta * d.loguniform("tau_c_over_theta", 1.0, 5.0)
        Kc, Ti = integrating_pi(abs(proc.gain), theta, tau_c)
        d.set("tuning", "simc_integrating")
        if level_zeta is not None:
            # a short integral time makes a level loop swing: pick the Ti whose least-damped
            # closed-loop pole pair has the drawn damping
            Ti = _ti_for_damping(proc, math.copysign(Kc, proc.gain), ts, level_zeta)
        else:
            Kc *= d.loguniform("detune", 0.6, 1.5)
    else:
        K, tau, theta = fopdt_of(proc, ts)
        d.set("fopdt_K", K), d.set("fopdt_tau_s", tau), d.set("fopdt_theta_s", theta)
        rule = d.choice("tuning", ("simc", "lambda", "imc_pid"), p=(0.45, 0.35, 0.2))
        tau_c = theta * d.loguniform("tau_c_over_theta", 0.7, 3.0)
        if rule == "simc":
            Kc, Ti = simc(abs(K), tau, theta, tau_c)
        elif rule == "lambda":
            Kc, Ti = lambda_tuning(abs(K), tau, theta, tau_c)
        else:
            Kc, Ti, Td = imc_pid(abs(K), tau, theta, tau_c)
        Kc *= d.loguniform("detune", 0.5, 1.4)
        Ti *= d.loguniform("ti_factor", 0.7, 1.5)
    Kc = math.copysign(Kc, proc.gain)
    for _ in range(40):
        gm = gain_margin(proc, Kc, Ti, Td, ts, flow_slope=flow_slope)
        if gm == 0.0:
            # unstable at every gain: the integral time is too short for this process
            Ti *= 1.5
            d.set("ti_lengthened", True)
            continue
        if gm_target is not None:
            if math.isfinite(gm):
                Kc *= gm / gm_target
                gm = gm_target
            break
        if gm >= gm_min * (1.0 - 1e-3):
            break
        Kc *= gm / gm_min
        d.set("kc_capped", True)
    form = d.choice("controller_form", ("velocity", "positional"))
    z, period = least_damped(proc, Kc, Ti, Td, ts, flow_slope=flow_slope)
    d.set("closed_loop_zeta", z), d.set("closed_loop_period_s", period)
    d.set("Kc", Kc), d.set("Ti_s", Ti), d.set("Td_s", Td), d.set("gain_margin", gm)
    return PID(Kc, Ti, Td, ts_s=ts, form=form)


def _ti_for_damping(proc: Process, Kc: float, ts: float, zeta: float) -> float:
    theta = proc.delay_s + proc.params.get("tau1_s", 0.0) + ts
    best, best_err = None, math.inf
    for Ti in np.geomspace(0.5 * theta, 200.0 * theta, 80):
        if spectral_radius(proc, Kc, Ti, 0.0, ts) >= 0.999:
            continue
        z, _ = least_damped(proc, Kc, Ti, 0.0, ts)
        if math.isfinite(z) and abs(z - zeta) < best_err:
            best, best_err = float(Ti), abs(z - zeta)
    return best if best is not None else 4.0 * theta


def _noise(d: _Draws, total: int, span: float, proc: Process, *, meas_pct=(0.02, 0.4), load_pct=(0.05, 1.0)):
    """Measurement noise (white) and a coloured load; returns (meas, out_load, in_load)."""
    rng = d.rng
    meas = dist.white(total, d.loguniform("meas_noise_pct", *meas_pct) * span / 100.0, rng)
    colour = d.choice("load_colour", dist.COLOURS)
    entry = "input" if proc.integrating else d.choice("load_entry", ("output", "input"))
    d.set("load_entry", entry)
    std = d.loguniform("load_std_pct", *load_pct)
    phi = d.uniform("ar1_phi", 0.8, 0.99) if colour == "ar1" else 0.95
    w = dist.coloured(colour, total, std, rng, phi=phi)
    if entry == "output":
        return meas, w * span / 100.0, np.zeros(total)
    return meas, np.zeros(total), w


def _sp_and_load_steps(d: _Draws, total: int, warmup: int, span: float, proc: Process, u0: float,
                       p_sp: float, p_load: float) -> tuple[np.ndarray, np.ndarray]:
    """Setpoint steps (PV units, relative) and input load steps (% flow)."""
    n = total - warmup
    sp = np.zeros(total)
    ld = np.zeros(total)
    if d.chance("sp_steps", p_sp):
        k = d.integer("n_sp_steps", 1, 4)
        at = np.sort(d.rng.integers(warmup + n // 10, total - n // 10, k))
        sizes, u = [], u0
        for _ in range(k):
            if proc.integrating:
                # a level setpoint moves by 2-12 % of span
                sizes.append(float(d.rng.uniform(2.0, 12.0)) * span / 100.0 * (1 if d.rng.random() < 0.5 else -1))
                continue
            # a step that moves the steady-state valve by 2-12 %, kept inside 10..90 % of travel
            du = float(d.rng.uniform(2.0, 12.0)) * (1 if d.rng.random() < 0.5 else -1)
            if not 10.0 <= u + du <= 90.0:
                du = -du
            u += du
            sizes.append(proc.gain * du)
        sp = dist.steps(total, list(at), sizes)
        d.set("sp_step_at", [int(a - warmup) for a in at])
        d.set("sp_step_sizes", [float(s) for s in sizes])
    if d.chance("load_steps", p_load):
        k = d.integer("n_load_steps", 1, 3)
        at = np.sort(d.rng.integers(warmup + n // 10, total - n // 10, k))
        sizes = [float(d.rng.uniform(1.0, 5.0)) * (1 if d.rng.random() < 0.5 else -1) for _ in range(k)]
        ld = dist.steps(total, list(at), sizes)
        d.set("load_step_at", [int(a - warmup) for a in at])
        d.set("load_step_sizes_flow_pct", sizes)
    return sp, ld


# --- valves -----------------------------------------------------------------------------------

def _class_J(d: _Draws, S: float, cls: str) -> float:
    if cls == "deadband":
        return d.set("J_pct", 0.0)
    if cls == "undershoot":
        return d.set("J_pct", S * d.uniform("J_over_S", 0.2, 0.75))
    if cls == "no_offset":
        return d.set("J_pct", S)
    return d.set("J_pct", S * d.uniform("J_over_S", 1.3, 2.0))


def _stem(d: _Draws, S_target: float, ts: float, *, fc_over_fs=(0.3, 1.0)) -> tuple[dict, float]:
    """Draw a force-balance stem whose bands are about ``S_target``; returns (kwargs, fine step)."""
    r = d.uniform("Fc_over_Fs", *fc_over_fs)
    F_span = d.uniform("F_span_N", 1000.0, 6000.0)
    k = d.uniform("k_N_per_m", 3.0e4, 8.0e4)
    zeta = d.uniform("stem_zeta", 0.4, 2.0)
    wn = d.loguniform("stem_wn_rad_s", 15.0, 80.0) if zeta < 1.0 else d.loguniform("stem_wn_rad_s", 30.0, 300.0)
    m_kg = d.set("m_kg", k / wn ** 2)
    Fv = d.set("Fv_Ns_per_m", 2.0 * zeta * math.sqrt(k * m_kg))
    tau_p = d.loguniform("tau_p_s", 0.1, 2.0)
    Fs = d.set("Fs_N", S_target * F_span / (100.0 * (1.0 + r)))
    Fc = d.set("Fc_N", r * Fs)
    if zeta < 1.0:
        wd = wn * math.sqrt(1.0 - zeta * zeta)
        h = 0.2 * math.pi / wd
    else:
        h = 0.05
    h = d.set("fine_step_s", min(h, tau_p / 4.0, ts / 4.0))
    S, J = force_balance_bands(Fs, Fc, F_span, zeta)
    d.set("S_pct", S), d.set("J_pct", J)
    d.set("S_J_mapping", "S=(Fs+Fc)/F_span, J=(Fs-Fc)(1+overshoot)/F_span")
    return dict(m_kg=m_kg, k_N_per_m=k, Fv_Ns_per_m=Fv, Fs_N=Fs, Fc_N=Fc, F_span_N=F_span,
                tau_p_s=tau_p, h_s=h), h


def _sticky_valve(d: _Draws, law: str, cls: str | None, ts: float, total: int, warmup: int, *,
                  p_lag=0.3, p_asym=0.2, p_tvf=0.15, S_range=(0.5, 10.0)):
    """A sticky valve of ``law`` with optional lag, asymmetry and time-varying friction."""
    d.set("law", law)
    S = d.loguniform("S_pct", *S_range)
    asym = d.chance("asymmetric", p_asym)
    ratio = d.uniform("asym_ratio", 0.3, 0.7) if asym else 1.0
    weaker = d.choice("asym_weaker", ("closing", "opening")) if asym else None
    schedule = _friction_schedule(d, total, warmup, p_tvf)
    if law == "force_balance":
        kw, h_fine = _stem(d, S, ts)
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
        J = _class_J(d, S, cls)
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


def _friction_schedule(d: _Draws, total: int, warmup: int, p: float) -> np.ndarray | None:
    if not d.chance("time_varying_friction", p):
        return None
    shape = d.choice("tvf_shape", ("drift", "step"))
    up = d.chance("tvf_increases", 0.75)
    change = d.uniform("tvf_change", 0.5, 1.5) if up else -d.uniform("tvf_drop", 0.4, 0.6)
    d.set("tvf_relative_change", change)
    n = total - warmup
    f = np.ones(total)
    if shape == "drift":
        f[warmup:] = 1.0 + change * np.arange(n) / max(n - 1, 1)
    else:
        at = warmup + int(n * d.uniform("tvf_step_at_fraction", 0.3, 0.7))
        f[at:] = 1.0 + change
    return f


def _healthy_valve(d: _Draws, ts: float):
    kind = d.choice("valve", ("linear", "positioner_lag", "backlash"), p=(0.5, 0.25, 0.25))
    d.set("law", kind)
    d.set("S_pct", 0.0), d.set("J_pct", 0.0), d.set("class", "none")
    if kind == "backlash":
        return Backlash(d.uniform("backlash_pct", 0.1, 0.2)), None
    if kind == "positioner_lag":
        order = d.choice("lag_order", (1, 2), p=(0.7, 0.3))
        return Linear(), (order, d.loguniform("tau_lag_s", 0.2, 3.0),
                          d.uniform("lag_zeta", 0.6, 1.0) if order == 2 else 1.0)
    return Linear(), None


# --- one record ------------------------------------------------------------------------------

@dataclass
class _Plan:
    kind: str
    sticky: bool
    n: int
    ts: float
    warmup: int
    proc: Process
    ctrl_factory: Any
    law: Any
    lag: tuple | None
    lag_at: str
    bands: tuple | None
    schedule: np.ndarray | None
    h_fine: float | None
    flow: Any
    sp: np.ndarray
    out_load: np.ndarray
    in_load: np.ndarray
    meas: np.ndarray
    u0: float
    pv0: float
    span: float
    sensor_tau_s: float = 0.0
    sensor_quant: float = 0.0
    hist_quant: float = 0.0
    compress_pv: float = 0.0
    compress_op: float = 0.0


def _internal_steps(ts: float, lag: tuple | None, h_fine: float | None) -> int:
    m = max(2, math.ceil(ts / 0.25))
    if lag is not None:
        m = max(m, math.ceil(4.0 * ts / lag[1]))
    return int(min(m, 80))


def _simulate(plan: _Plan, d: _Draws) -> dict[str, np.ndarray]:
    m = d.set("internal_steps", _internal_steps(plan.ts, plan.lag, plan.h_fine))
    h = plan.ts / m
    lag = None
    if plan.lag is not None:
        order, tau, zeta = plan.lag
        lag = Lag(order, tau, zeta, h, m)
    valve = ValveTrain(plan.law, m=m, h_s=h, lag=lag, lag_at=plan.lag_at, schedule=plan.schedule,
                       bands=plan.bands)
    sig = Signals(sp=plan.pv0 + plan.sp, out_load=plan.out_load, in_load=plan.in_load, meas_noise=plan.meas)
    raw = run_loop(n=plan.n, warmup=plan.warmup, ts_s=plan.ts, m=m, process=plan.proc, valve=valve,
                   controller=plan.ctrl_factory(), signals=sig, u0=plan.u0, pv0=plan.pv0, flow=plan.flow,
                   sensor_tau_s=plan.sensor_tau_s, sensor_quant=plan.sensor_quant)
    return raw


def _historian(plan: _Plan, d: _Draws, raw: dict[str, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    pv, op = raw["pv"], raw["op"]
    if plan.hist_quant > 0:
        pv = art.quantise(pv, plan.hist_quant)
    if plan.compress_pv > 0:
        pv, k = art.compress(pv, plan.compress_pv)
        d.set("pv_archived_points", k)
    if plan.compress_op > 0:
        op, k = art.compress(op, plan.compress_op)
        d.set("op_archived_points", k)
    return op, pv


def _moves(mv: np.ndarray, eps: float = 0.02) -> int:
    """Starts of stem motion: samples where the stem moves after a sample at rest."""
    moving = np.abs(np.diff(mv)) > eps
    return int(np.count_nonzero(moving[1:] & ~moving[:-1]) + (1 if moving.size and moving[0] else 0))


def _warmup(proc: Process, ts: float, Ti: float) -> int:
    if proc.integrating:
        slow = Ti + proc.params.get("tau1_s", 0.0) + proc.delay_s
    else:
        p = proc.params
        slow = max(p.get("tau1_s", 0.0), 1.0 / p["wn_rad_s"] if "wn_rad_s" in p else 0.0) + proc.delay_s
        slow = max(slow, Ti)
    return int(min(max(10.0 * slow / ts, 300), 3000))


def _draw_plan(kind: str, d: _Draws, index: int, n: int | None, ts_s: float | None) -> _Plan:
    sticky = SCENARIOS[kind]
    d.set("scenario", kind)
    d.set("sticky", sticky)
    if kind == "daily_cycle" and ts_s is None:
        ts_s = d.choice("ts_s", (5.0, 10.0))
    if kind == "daily_cycle":
        # long enough for the cycle to show: 4-28 hours
        n, ts = _timebase(d, n, ts_s, n_range=(3000, 10000), p_window=0.0)
    else:
        n, ts = _timebase(d, n, ts_s)
    if sticky:
        integ = d.set("integrating", index % 2 == 1)
    elif kind == "level_pi":
        integ = d.set("integrating", True)
    elif kind in ("overtuned", "external_sine", "external_nonsine"):
        integ = d.set("integrating", False)
    else:
        integ = d.chance("integrating", 0.25)
    proc = _process(d, ts, integrating_=integ)
    for k, v in proc.describe().items():
        d.set(k, v)
    span = d.meta["pv_span"]
    u0 = d.uniform("u0_pct", 25.0, 75.0)
    pv0 = d.set("pv0", span * d.uniform("pv0_frac", 0.3, 0.7))
    flow, slope = _flow(d, 0.25 if kind in ("healthy", *STICKY_SCENARIOS) else 0.0)

    # controller
    gm_target = d.uniform("gain_margin_target", 1.15, 1.45) if kind == "overtuned" else None
    level_zeta = d.uniform("closed_loop_zeta_target", 0.08, 0.3) if kind == "level_pi" else None
    ctrl = _tune(d, proc, ts, flow_slope=slope, gm_target=gm_target, level_zeta=level_zeta,
                 gm_min=1.1 if kind == "level_pi" else 2.0)
    Kc, Ti, Td, form = ctrl.Kc, ctrl.Ti, ctrl.Td, ctrl.form

    def ctrl_factory() -> PID:
        return PID(Kc, Ti, Td, ts_s=ts, form=form)

    warmup = d.set("warmup", _warmup(proc, ts, Ti))
    total = n + warmup

    # valve
    law, bands, schedule, lag, lag_at, h_fine = Linear(), None, None, None, "after", None
    if sticky:
        cls = CLASSES[(index // 2) % 4] if kind != "force_balance" else None
        law, bands, schedule, lag, lag_at, h_fine = _sticky_valve(d, kind, cls, ts, total, warmup)
    else:
        law, lag = _healthy_valve(d, ts)

    # signals
    meas, out_load, in_load = _noise(d, total, span, proc)
    p_sp = {"healthy": 0.6, "level_pi": 0.3}.get(kind, 0.3)
    p_ld = {"healthy": 0.5}.get(kind, 0.25)
    sp, ld = _sp_and_load_steps(d, total, warmup, span, proc, u0, p_sp, p_ld)
    in_load = in_load + ld
    plan = _Plan(kind, sticky, n, ts, warmup, proc, ctrl_factory, law, lag, lag_at, bands, schedule, h_fine,
                 flow, sp, out_load, in_load, meas, u0, pv0, span)

    rng = d.rng
    if kind in ("external_sine", "external_nonsine"):
        period = d.loguniform("osc_period_s", 15.0 * ts, 200.0 * ts)
        amp_pv = span / 100.0 * d.uniform("osc_pv_amplitude_pct", 0.5, 4.0)
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
            plan.out_load = plan.out_load + dist.sine(
                total, ts, d.loguniform("wave_period_s", 20.0 * ts, 200.0 * ts),
                dev * d.uniform("wave_amplitude_over_dev", 2.0, 6.0), d.uniform("wave_phase", 0.0, 2 * math.pi))
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
              name: str | None = None) -> SimLoop:
    """Record ``index`` of scenario ``kind`` for corpus seed ``seed`` (see `corpus`)."""
    if kind not in SCENARIOS:
        raise ValueError(f"unknown scenario {kind!r}; choose from {', '.join(SCENARIOS)}")
    pos = list(SCENARIOS).index(kind)
    for draw in range(_MAX_DRAWS):
        d = _Draws(np.random.default_rng(np.random.SeedSequence([int(seed), pos, int(index), draw])))
        plan = _draw_plan(kind, d, index, n, ts_s)
        raw = _simulate(plan, d)
        sat = float(np.mean((raw["op"] <= 0.01) | (raw["op"] >= 99.99)))
        moves = _moves(raw["mv"])
        d.set("op_saturated_fraction", sat)
        d.set("stem_moves", moves)
        d.set("pv_std", float(np.std(raw["pv"])))
        d.set("op_std", float(np.std(raw["op"])))
        if sat <= 0.05 and (not plan.sticky or moves >= 3) and np.all(np.isfinite(raw["pv"])):
            break
    d.set("draw", draw)
    d.set("seed", int(seed)), d.set("index", int(index))
    op, pv = _historian(plan, d, raw)
    return SimLoop(op=op, pv=pv, sp=raw["sp"], mv=raw["mv"], ts_s=plan.ts,
                   name=name or _name(plan.proc, plan.ts, index), sticky=plan.sticky, kind=kind,
                   meta=dict(d.meta))


def corpus(seed: int, n_per_kind: int, *, kinds=None, n: int | None = None, ts_s: float | None = None,
           start_index: int = 0) -> Iterator[SimLoop]:
    """Yield a labelled corpus: ``n_per_kind`` records of each scenario.

    Parameters
    ----------
    seed : int
        Corpus seed; the same seed gives the same records bit for bit.
    n_per_kind : int
        Records per scenario. For the sticky scenarios the record index cycles self-regulating /
        integrating (every record) and the four classes (every second record), so 8 records cover
        all eight combinations.
    kinds : iterable of str, optional
        Scenarios to include (default all of `SCENARIOS`, in that order).
    n : int, optional
        Samples per record (default drawn: 751 samples at 10 s for plant-window records, else
        500-10 000 log-uniform).
    ts_s : float, optional
        Sample period (default drawn from 1, 2, 5, 10 s).
    start_index : int
        Number of the first record (names are ``<prefix><number>``).
    """
    kinds = list(SCENARIOS) if kinds is None else list(kinds)
    for k in kinds:
        if k not in SCENARIOS:
            raise ValueError(f"unknown scenario {k!r}; choose from {', '.join(SCENARIOS)}")
    number = start_index
    for k in kinds:
        for i in range(n_per_kind):
            loop = make_loop(k, seed, i, n=n, ts_s=ts_s, name=None)
            yield SimLoop(loop.op, loop.pv, loop.sp, loop.mv, loop.ts_s,
                          _name_from(loop, number), loop.sticky, loop.kind, loop.meta)
            number += 1


def _name_from(loop: SimLoop, number: int) -> str:
    return f"{loop.name[:3]}{number:05d}"


# --- concealed effects -----------------------------------------------------------------------

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
        effect changes PV: ``meta["effect_pv_change"]`` = RMS(PV - PV_twin) / std(PV_twin).
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
    for draw in range(_MAX_DRAWS):
        ss = np.random.SeedSequence([int(seed), 24, EFFECTS.index(effect), draw])
        rec, clean, d = _concealed_draw(effect, ss, n, ts_s, laws, kinds)
        half = n // 2
        mv = rec["mv"]
        if _moves(mv[:half]) >= min_moves and _moves(mv[half:]) >= min_moves:
            break
    d.set("draw", draw)
    d.set("seed", int(seed))
    if twin and clean is not None:
        ref = clean["pv"]
        d.set("effect_pv_change", float(np.sqrt(np.mean((rec["pv"] - ref) ** 2)) / max(np.std(ref), 1e-12)))
    out = rec if apply_effect else clean
    return SimLoop(op=out["op"], pv=out["pv"], sp=out["sp"], mv=out["mv"], ts_s=ts_s,
                   name=f"{effect}_{seed}", sticky=True, kind="concealed", meta=dict(d.meta))


def _concealed_draw(effect: str, ss: np.random.SeedSequence, n: int, ts: float, laws, kinds):
    d = _Draws(np.random.default_rng(ss))
    d.set("scenario", "concealed"), d.set("effect", effect), d.set("sticky", True)
    d.set("n", n), d.set("ts_s", ts), d.set("integrating", False)
    proc = _process(d, ts, integrating_=False, kinds=kinds)
    for k, v in proc.describe().items():
        d.set(k, v)
    span = d.meta["pv_span"]
    law = d.choice("law", laws)
    cls = d.choice("class", CLASSES) if law != "force_balance" else None
    S = d.loguniform("S_pct", 2.0, 8.0)
    u_levels = None
    sp_moves = effect == "valve_characteristic" or d.chance("sp_moves", 0.3)
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
    ctrl = _tune(d, proc, ts, gm_min=2.0)
    Kc, Ti, Td, form = ctrl.Kc, ctrl.Ti, ctrl.Td, ctrl.form
    warmup = d.set("warmup", max(_warmup(proc, ts, Ti), 2000))
    total = n + warmup

    # valve (law and bands); J by class
    if law == "force_balance":
        stem_kw, h_fine = _stem(d, S, ts)
        d.set("class", stiction_class(d.meta["S_pct"], d.meta["J_pct"]))
        J = d.meta["J_pct"]
        S = d.meta["S_pct"]
    else:
        J = _class_J(d, S, cls)
        direction0 = d.choice("direction0", (1, -1))
        stem_kw, h_fine = None, None
        if law == "kano":
            d.set("deadband_pct", max(S - J, 0.0)), d.set("stickband_pct", J)

    meas, out_load, in_load = _noise(d, total, span, proc, meas_pct=(0.03, 0.2), load_pct=(0.05, 0.5))
    sp_dev = np.zeros(total)
    if u_levels is not None:
        edges = np.linspace(warmup, total, len(u_levels) + 1).astype(int)[1:-1]
        steps_u = np.full(total, u_levels[0])
        for e, u in zip(edges, u_levels[1:]):
            steps_u[e:] = u
        d.set("sp_step_at", [int(e - warmup) for e in edges])
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
        plan = _Plan("concealed", True, n, ts, warmup, proc, lambda: PID(Kc, Ti, Td, ts_s=ts, form=form),
                     law_obj, lag, "after", bands, schedule, h_fine, flow, sp, ol, il, meas, u0, pv0, span)
        return _simulate(plan, d)

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
    from scipy import signal as _sig
    y = _sig.lfilter([1.0], [1.0, -2 * rad * math.cos(w0), rad * rad], e)
    return y / (np.std(y) * math.sqrt(2.0))


def concealed_set(seed: int, n_per_effect: int, *, effects=EFFECTS, **kwargs) -> list[SimLoop]:
    """``n_per_effect`` concealed-effect records per effect; record ``i`` uses seed ``seed * 1000 + i``."""
    out = []
    for eff in effects:
        for i in range(n_per_effect):
            out.append(concealed(eff, int(seed) * 1000 + i, **kwargs))
    return out
