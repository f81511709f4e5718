"""Drawing a plant: every random choice a record makes, and the simulation of one drawn record.

`Draws` wraps a generator and writes every value it draws into ``meta`` under the name given, so a
record's labels hold every parameter. The functions here draw the parts a scenario is made of
(timebase, process, tuning, noise, valves) and run one `Plan` through the closed loop.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from . import artifacts as art
from . import disturbances as dist
from .controller import (PID, fopdt_of, gain_margin, imc_pid, integrating_pi, lambda_tuning, least_damped, simc,
                         spectral_radius)
from .friction import Backlash, Linear, force_balance_bands
from .loop import Signals, run_loop
from .process import Process, flow_characteristic, foptd, integrating, soptd, third_order, underdamped
from .valve import Lag, ValveTrain

# a record is drawn again (from a derived seed) at most this many times when its guard fails
MAX_DRAWS = 25

#: The historian-sampled fast flow loop (``historian_fast``): ranges of the drawn process, tuning
#: and noise. The process settles within one 10 s sample; the PI is detuned the way flow loops
#: are left in plants (slow integral action, gain well under 1 %/%); flow meters are noisy.
FAST = {
    "ts_s": 10.0,
    "gain_pct_per_pct": (0.5, 2.0),
    "tau_s": (0.5, 5.0),
    "delay_s": (0.0, 3.0),
    "Kc_pct_per_pct": (0.1, 1.0),
    "Ti_s": (30.0, 300.0),
    "closed_loop_tau_s": (20.0, 300.0),
    "meas_noise_pct": (0.3, 2.0),
    "p_sp_steps": 0.8,
}


class Draws:
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


def timebase(d: Draws, n: int | None, ts_s: float | None, *, n_range=(500, 10000),
             p_window: float = 0.6) -> tuple[int, float]:
    """Sample period and record length: plant windows of 751 x 10 s, or 500-10 000 samples."""
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


def draw_process(d: Draws, ts: float, *, integrating_: bool, kinds=None, gain_range=(0.3, 3.0),
                 fast: bool = False) -> Process:
    """A process structure and its parameters, time constants in units of ``ts``.

    ``fast``: a flow loop that responds faster than the historian samples it: a first- or
    second-order lag of 0.5-5 s and a dead time of 0-3 s, whatever ``ts`` is (see `FAST`).
    """
    span = d.choice("pv_span", (10.0, 50.0, 100.0, 250.0, 1000.0))
    sign = d.choice("gain_sign", (1, -1), p=(0.8, 0.2))
    if fast:
        kind = d.choice("process", ("foptd", "soptd"), p=(0.6, 0.4))
        K = sign * d.loguniform("gain_pct_per_pct", *FAST["gain_pct_per_pct"]) * span / 100.0
        T = d.loguniform("tau_s", *FAST["tau_s"])
        delay = d.uniform("delay_s", *FAST["delay_s"])
        if kind == "foptd":
            return foptd(K, T, delay)
        return soptd(K, T, T * d.uniform("tau2_over_tau1", 0.1, 0.5), delay)
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
    K = sign * d.loguniform("gain_pct_per_pct", *gain_range) * span / 100.0
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


def draw_flow(d: Draws, p_char: float):
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


def tune(d: Draws, proc: Process, ts: float, *, flow_slope: float = 1.0, gm_min: float = 2.0,
          gm_target: float | None = None, level_zeta: float | None = None, fast: bool = False,
          zeta_min: float | None = None) -> PID:
    """A tuned PI/PID; de-tuned by a drawn factor, then held to ``gm_min`` (or set to ``gm_target``).

    ``fast``: the detuned PI of a historian-sampled flow loop, gain and integral time drawn
    directly (`FAST`) rather than from a tuning rule. ``zeta_min``: the gain is lowered and the
    integral time lengthened (``detuned_for_damping``) until the least-damped closed-loop pole pair
    has at least this damping ratio (a healthy loop does not ring).
    """
    Td = 0.0
    if fast:
        # gain and integral time drawn together until the loop settles in minutes: the closed
        # loop's time constant Ti / (Kc K) inside FAST["closed_loop_tau_s"]
        K_norm = abs(proc.gain) * 100.0 / d.meta["pv_span"]
        lo, hi = FAST["closed_loop_tau_s"]
        for _ in range(100):
            kc_norm = d.loguniform("fast_Kc_pct_per_pct", *FAST["Kc_pct_per_pct"])
            Ti = d.loguniform("fast_Ti_s", *FAST["Ti_s"])
            if lo <= Ti / (kc_norm * K_norm) <= hi:
                break
        d.set("fast_closed_loop_tau_s", Ti / (kc_norm * K_norm))
        Kc = kc_norm * 100.0 / d.meta["pv_span"]
        d.set("tuning", "detuned_pi")
    elif proc.integrating:
        theta = proc.delay_s + proc.params["tau1_s"] + ts / 2.0
        tau_c = theta * d.loguniform("tau_c_over_theta", 1.0, 5.0)
        Kc, Ti = integrating_pi(abs(proc.gain), theta, tau_c)
        d.set("tuning", "simc_integrating")
        if level_zeta is not None:
            # a short integral time makes a level loop swing: pick the Ti whose least-damped
            # closed-loop pole pair has the drawn damping
            Ti = ti_for_damping(proc, math.copysign(Kc, proc.gain), ts, level_zeta)
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
    if zeta_min is not None and z < zeta_min:
        for _ in range(30):
            Kc *= 0.85
            Ti *= 1.15
            z, period = least_damped(proc, Kc, Ti, Td, ts, flow_slope=flow_slope)
            if z >= zeta_min:
                break
        d.set("detuned_for_damping", True)
        gm = gain_margin(proc, Kc, Ti, Td, ts, flow_slope=flow_slope)
    d.set("closed_loop_zeta", z), d.set("closed_loop_period_s", period)
    d.set("Kc", Kc), d.set("Ti_s", Ti), d.set("Td_s", Td), d.set("gain_margin", gm)
    return PID(Kc, Ti, Td, ts_s=ts, form=form)


def ti_for_damping(proc: Process, Kc: float, ts: float, zeta: float) -> float:
    """The integral time (on a log grid) whose least-damped closed-loop pole pair has damping ``zeta``."""
    theta = proc.delay_s + proc.params.get("tau1_s", 0.0) + ts
    best, best_err = None, math.inf
    for Ti in np.geomspace(0.5 * theta, 200.0 * theta, 80):
        if spectral_radius(proc, Kc, Ti, 0.0, ts) >= 0.999:
            continue
        z, _ = least_damped(proc, Kc, Ti, 0.0, ts)
        if math.isfinite(z) and abs(z - zeta) < best_err:
            best, best_err = float(Ti), abs(z - zeta)
    return best if best is not None else 4.0 * theta


def draw_noise(d: Draws, total: int, span: float, proc: Process, *, meas_pct=(0.02, 0.4), load_pct=(0.05, 1.0)):
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


def sp_and_load_steps(d: Draws, total: int, warmup: int, span: float, proc: Process, u0: float,
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


def class_J(d: Draws, S: float, cls: str) -> float:
    """A slip jump of class ``cls`` for deadband-plus-stickband ``S``."""
    if cls == "deadband":
        return d.set("J_pct", 0.0)
    if cls == "undershoot":
        return d.set("J_pct", S * d.uniform("J_over_S", 0.2, 0.75))
    if cls == "no_offset":
        return d.set("J_pct", S)
    return d.set("J_pct", S * d.uniform("J_over_S", 1.3, 2.0))


def draw_stem(d: Draws, S_target: float, ts: float, *, fc_over_fs=(0.3, 1.0)) -> tuple[dict, float]:
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


def friction_schedule(d: Draws, total: int, warmup: int, p: float) -> np.ndarray | None:
    """With probability ``p``, a friction factor per sample (a drift or a step); else None."""
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


def healthy_valve(d: Draws, ts: float):
    """A healthy valve law and its positioner lag (order, tau, zeta) or None."""
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


@dataclass
class Plan:
    """Everything drawn for one record, ready to simulate."""

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
    artifact_cap: float = 0.0


def internal_steps(ts: float, lag: tuple | None, h_fine: float | None) -> int:
    """Internal steps per sample: at most 0.25 s each and 4 per valve-lag time constant (2-80)."""
    m = max(2, math.ceil(ts / 0.25))
    if lag is not None:
        m = max(m, math.ceil(4.0 * ts / lag[1]))
    return int(min(m, 80))


def simulate(plan: Plan, d: Draws) -> dict[str, np.ndarray]:
    """Run a plan through the closed loop (see `loop.run_loop`)."""
    m = d.set("internal_steps", internal_steps(plan.ts, plan.lag, plan.h_fine))
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


def historian(plan: Plan, d: Draws, raw: dict[str, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """OP and PV as the historian exports them (quantised and/or compressed).

    With ``plan.artifact_cap`` > 0 a historian deviation or step is at most PV's spread about its
    setpoint (5-95 % range of the transmitted PV - SP, so setpoint moves do not count) divided by
    the cap, so the artifact shapes PV without erasing it (a deviation wider than everything PV
    does exports a straight line between the first and the last sample). The applied values are recorded (``compress_pv_applied_pct``, ``quant_applied_pct``,
    % of span).
    """
    pv, op = raw["pv"], raw["op"]
    hist_quant, compress_pv = plan.hist_quant, plan.compress_pv
    if plan.artifact_cap > 0 and (hist_quant > 0 or compress_pv > 0):
        dev = pv - raw["sp"]
        spread = float(np.percentile(dev, 95) - np.percentile(dev, 5))
        top = spread / plan.artifact_cap
        pct = 100.0 / plan.span
        d.set("pv_spread_pct", spread * pct)
        if hist_quant > 0:
            hist_quant = min(hist_quant, top)
            d.set("quant_applied_pct", hist_quant * pct)
        if compress_pv > 0:
            compress_pv = min(compress_pv, top)
            d.set("compress_pv_applied_pct", compress_pv * pct)
    if hist_quant > 0:
        pv = art.quantise(pv, hist_quant)
    if compress_pv > 0:
        pv, k = art.compress(pv, compress_pv)
        d.set("pv_archived_points", k)
    if plan.compress_op > 0:
        op, k = art.compress(op, plan.compress_op)
        d.set("op_archived_points", k)
    return op, pv


def warmup_samples(proc: Process, ts: float, Ti: float) -> int:
    """10 times the slowest lag plus dead time (or the integral time), 300-3000 samples."""
    if proc.integrating:
        slow = Ti + proc.params.get("tau1_s", 0.0) + proc.delay_s
    else:
        p = proc.params
        slow = max(p.get("tau1_s", 0.0), 1.0 / p["wn_rad_s"] if "wn_rad_s" in p else 0.0) + proc.delay_s
        slow = max(slow, Ti)
    return int(min(max(10.0 * slow / ts, 300), 3000))


def centre_pv0(pv0: float, sp_dev: np.ndarray, span: float) -> float:
    """Move the starting PV so the setpoint excursion stays 10 % inside the transmitter span."""
    lo, hi = min(0.0, float(sp_dev.min())), max(0.0, float(sp_dev.max()))
    a, b = 0.1 * span - lo, 0.9 * span - hi
    return float(min(max(pv0, a), b)) if a <= b else 0.5 * span - 0.5 * (lo + hi)
