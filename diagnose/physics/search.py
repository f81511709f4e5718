"""The searches that fit augmented models (`diagnose.physics.model.Structure`) on a `Stage`.

Small named strategies shared by the reference (the plain model refit here) and every hypothesis;
each takes the stage and a starting structure and returns a better one (or starting points), never
changing the stage. Output-error costs of stiction models are sharp (a few per cent of S move every
slip by samples) and full of local minima, so the searches are grids: global grids give starting
points, local grids and rounds of them polish.

* `best_of`, `best_distinct`: score candidates (`model.train_sse`) and keep the best, or the best
  few that differ;
* `refit_dynamics`, `sj_local`, `refine_sj`, `refine_plain`, `global_sj`: the plain model's
  dynamics and valve, locally or on a global (S, J, f0) grid;
* `fit_initial_state`, `y0_options`: the valve's unknown state at the first sample;
* `keyword_columns`: keyword sets (valves, starting states) as `Candidates` columns;
* `polish`, `fine_valve`, `profile_ratio`, `joint_process_polish`: fine polish rounds (the valve
  stage's sharp cost in S; an effect traded against the process dynamics);
* `dynamics_starts`, `valve_dynamics_starts`, `coarse_starts`, `grid_baseline`: global starts of
  valve and dynamics together (from OP/PV a plain fit's process bends to mimic what its valve
  lacks).
"""

from __future__ import annotations

import math
from typing import Sequence

import numpy as np

from ..process_model import ProcessModel
from .model import IDENTITY, Candidates, Pool, Stage, Structure, mesh, train_sse, with_times


def best_distinct(cands: Sequence[Structure], sse, key, k: int) -> list:
    """The ``k`` cheapest candidates whose ``key`` differs: on rough costs, distinct starting points
    rather than neighbours of one. ``cands``: a sequence of structures (a `Pool` or `Candidates`
    makes a structure only for those looked at)."""
    out, seen = [], set()
    for i in np.argsort(sse):
        c = cands[int(i)]
        kk = key(c)
        if kk in seen:
            continue
        seen.add(kk)
        out.append(c)
        if len(out) == k:
            break
    return out


def best_of(stage: Stage, structs) -> tuple[Structure, float]:
    """The cheapest of ``structs`` (structures and `Candidates`) and its training SSE."""
    structs = Pool(structs)
    sse = train_sse(stage, structs)
    sse = np.where(np.isfinite(sse), sse, np.inf)
    i = int(np.argmin(sse))
    return structs[i], float(sse[i])


def refit_dynamics(stage: Stage, struct: Structure, rounds: int = 2) -> tuple[Structure, float]:
    """Refit the process time constants and dead time by a local grid (coordinate rounds): the lag
    x 0.5-2 (then x 0.8-1.25) and the dead time +-2 samples, and the second lag of a SOPTD process."""
    if stage.fixed_dynamics:
        return best_of(stage, [struct])
    ts = stage.ts_s
    best, best_c = best_of(stage, [struct])
    for r in range(rounds):
        span = (0.5, 0.7, 0.85, 1.0, 1.2, 1.4, 2.0) if r == 0 else (0.8, 0.9, 1.0, 1.1, 1.25)
        p0 = best.process
        d0 = int(round(p0.delay_s / ts))
        tau0 = max(p0.tau_s, ts)
        cands = [with_times(p0, tau_s=tau0 * m, delay_s=(d0 + dd) * ts)
                 for m in span for dd in (-2, -1, 0, 1, 2) if d0 + dd >= 0]
        if p0.kind == "soptd":
            tau20 = max(p0.tau2_s, ts)
            cands += [with_times(p0, tau2_s=tau20 * m) for m in span]
        b, c = best_of(stage, [best.replace(process=p) for p in cands])
        if c < best_c:
            best, best_c = b, c
    return best, best_c


def sj_local(S_pct: float, J_pct: float, *, s_span: float, n_s: int, j_span: float, n_j: int,
             floor_pct: float = 0.2, j_zero: bool = True) -> list[tuple[float, float]]:
    """Candidate (S, J) pairs around a centre: S (1 + linspace(-s_span, s_span, n_s)), J likewise.

    The output-error cost of a stiction model is sharp in S (a few per cent of S move every slip
    by samples), so searches step S by 1-3 %.
    """
    S0 = max(S_pct, floor_pct)
    J0 = max(J_pct, 0.25 * floor_pct)
    out = []
    for ms in 1.0 + np.linspace(-s_span, s_span, n_s):
        for mj in 1.0 + np.linspace(-j_span, j_span, n_j):
            out.append((float(S0 * ms), float(max(J0 * mj, 0.0))))
        if j_zero:
            out.append((float(S0 * ms), 0.0))
    return out


def refine_sj(stage: Stage, struct: Structure, *, s_span: float = 0.12, n_s: int = 13,
              j_span: float = 0.4, n_j: int = 9, both_f0: bool = True) -> tuple[Structure, float]:
    """Local symmetric (S, J) grid (and f0) around ``struct``, other parameters fixed."""
    S, J = struct.S_up_pct, struct.J_up_pct
    fs = (1, -1) if both_f0 else (struct.f0,)
    sj = np.array(sj_local(S, J, s_span=s_span, n_s=n_s, j_span=j_span, n_j=n_j)).reshape(-1, 2)
    i, f = mesh(np.arange(sj.shape[0]), fs)
    k = i.astype(np.intp)
    grid = Candidates(struct, S_up_pct=sj[k, 0], S_dn_pct=sj[k, 0], J_up_pct=sj[k, 1], J_dn_pct=sj[k, 1], f0=f)
    return best_of(stage, [grid, struct])


def refine_plain(stage: Stage, struct: Structure, rounds: int = 2) -> tuple[Structure, float]:
    """Local refit of the plain model (S, J, f0 and the dynamics): the null model's refit.

    Every hypothesis is compared with this refit, so an improvement is due to the added physics
    and not to a different search.
    """
    sse = math.inf
    for r in range(rounds):
        struct, sse = refine_sj(stage, struct, s_span=0.15 if r == 0 else 0.04,
                                n_s=16 if r == 0 else 9, j_span=0.4 if r == 0 else 0.12,
                                n_j=9 if r == 0 else 5)
        struct, sse = refit_dynamics(stage, struct, rounds=1)
    struct, sse = refine_sj(stage, struct, s_span=0.02, n_s=9, j_span=0.06, n_j=5, both_f0=False)
    if struct.y0_pct is not None:
        struct, sse = fit_initial_state(stage, struct, local=True)
    return struct, sse


#: J/S of `global_sj`'s grid
GLOBAL_RATIOS = (0.0, 0.2, 0.4, 0.6, 0.8, 1.0, 1.2, 1.45)


def global_sj(stage: Stage, struct: Structure, span: float | None = None, step: float = 0.025,
              ratios: Sequence[float] = GLOBAL_RATIOS) -> Structure:
    """Fine global symmetric (S, J, f0) grid at fixed other parameters (S in geometric steps of
    ``step`` from 0.2 % to 80 % of OP's range, J/S at ``ratios``), then a local polish."""
    if span is None:
        span = float(np.ptp(stage.x[: stage.n_fit]))
    hi = max(0.8 * span, 0.3)
    S_grid = np.exp(np.arange(math.log(0.2), math.log(hi) + 1e-9, math.log1p(step)))
    s, r, f = mesh(S_grid, np.asarray(ratios, float), (1, -1))
    grid = Candidates(struct, S_up_pct=s, S_dn_pct=s, J_up_pct=s * r, J_dn_pct=s * r, f0=f)
    best = best_of(stage, [grid, struct.replace(S_up_pct=0.0, S_dn_pct=0.0, J_up_pct=0.0, J_dn_pct=0.0),
                           struct])[0]
    return refine_sj(stage, best, s_span=0.03, n_s=7, j_span=0.15, n_j=7)[0]


def fit_initial_state(stage: Stage, struct: Structure, *, local: bool = False) -> tuple[Structure, float]:
    """Fit the valve's unknown state at the first sample, other parameters fixed: where the stem is
    stuck (``y0_pct``), the OP at which it stuck (``xs0_pct``) and the direction of its last motion
    (``f0``).

    A sticky valve remembers where it stuck until it slips again in step with the model; in a slow
    limit cycle that can take hundreds of samples, which the plain start (stuck at the first OP
    sample) gets wrong. ``local``: a small grid around the current state only.
    """
    s_max = max(struct.S_up_pct, struct.S_dn_pct, struct.J_up_pct, struct.J_dn_pct, 0.5)
    valve = stage.name == "valve"
    if local and struct.y0_pct is not None:
        c = struct.y0_pct
        ys = c + (np.arange(-0.1, 0.101, 0.02) if valve else np.linspace(-0.1, 0.1, 9) * s_max)
        cands = [Candidates(struct, y0_pct=ys)]
        if struct.xs0_pct is not None:
            b0 = best_of(stage, cands + [struct])[0]
            cands.append(Candidates(b0, xs0_pct=b0.xs0_pct + np.linspace(-0.1, 0.1, 11) * s_max))
        return best_of(stage, cands + [struct])
    best, sse = best_of(stage, start_grid(stage, struct))
    if best.y0_pct is None:
        return best, sse
    # the OP at which it stuck: where a moving valve stops (tied), or anywhere within reach of a
    # slip (a valve that has not moved since some other disturbance)
    y0 = best.y0_pct
    dy = np.arange(-0.2, 0.201, 0.05) if valve else np.linspace(-0.12, 0.12, 7) * s_max
    e, d, f = mesh(dy, np.linspace(-1.3, 1.3, 53), (1, -1))
    best, sse = best_of(stage, [Candidates(best, y0_pct=y0 + e, xs0_pct=y0 + e + d * s_max, f0=f), best])
    return fit_initial_state(stage, best, local=True)


def start_grid(stage: Stage, struct: Structure) -> Pool:
    """The first grid of `fit_initial_state`: the stem stuck at points around OP's first sample
    (+-1.2 times the largest S or J; on the valve stage also finely around the first measured stem
    positions), after a motion either way, with the input where a moving valve stops; at rest at
    the first OP sample; and ``struct`` itself."""
    x0 = float(np.clip(stage.x[0], 0.0, 100.0))
    s_max = max(struct.S_up_pct, struct.S_dn_pct, struct.J_up_pct, struct.J_dn_pct, 0.5)
    ys = x0 + np.linspace(-1.2, 1.2, 33) * s_max
    if stage.name == "valve":
        # the target is the stem position itself: a fine grid around its first samples (the
        # first slip's timing is sharp in where the stem stuck)
        ys = np.append(ys, float(np.median(stage.y[:3])) + np.arange(-0.4, 0.401, 0.02))
    y, f = mesh(np.clip(ys, 0.0, 100.0), (1, -1))
    return Pool([Candidates(struct, y0_pct=y, xs0_pct=np.nan, f0=f),
                 Candidates(struct, y0_pct=np.nan, xs0_pct=np.nan, f0=(1, -1)), struct])


def y0_options(stage: Stage, reference: Structure) -> list:
    """Starting stem positions worth trying in a global search: the reference's and, on the valve
    stage, the first measured stem positions."""
    out = [{"y0_pct": reference.y0_pct, "xs0_pct": reference.xs0_pct}]
    if stage.name == "valve":
        y0 = float(np.median(stage.y[:3]))
        if reference.y0_pct is None or abs(reference.y0_pct - y0) > 0.05:
            out.append({"y0_pct": y0, "xs0_pct": None})
    return out


def keyword_columns(sets: list[dict], i, reference: Structure) -> dict[str, np.ndarray]:
    """Keyword sets for `Structure.replace` as `Candidates` columns: set ``i[k]`` for candidate
    ``k``; None as NaN, and a field a set leaves out keeps ``reference``'s value."""
    i = np.asarray(i, dtype=np.intp)
    cols = {}
    for name in sorted({name for kw in sets for name in kw}):
        vals = [kw.get(name, getattr(reference, name)) for kw in sets]
        cols[name] = np.array([np.nan if v is None else v for v in vals], float)[i]
    return cols



def with_sj(struct: Structure, S: float, J: float, f0: int | None = None) -> Structure:
    return struct.replace(S_up_pct=S, S_dn_pct=S, J_up_pct=J, J_dn_pct=J,
                          f0=struct.f0 if f0 is None else f0)


def polish(stage: Stage, struct: Structure, one_round, rounds: int = 2, tol: float = 1e-4,
            keep_small_gain: bool = False) -> Structure:
    """Up to ``rounds`` rounds of ``one_round`` (a structure -> a better structure by fine grids),
    each followed by the initial state; stops when a round gains less than ``tol`` of the cost
    (keeping that last round's result if it gained at all, with ``keep_small_gain``)."""
    best, cost = best_of(stage, [struct])
    for _ in range(rounds):
        b, c = fit_initial_state(stage, one_round(best))
        if c >= cost * (1.0 - tol):
            if keep_small_gain and c < cost:
                best = b
            break
        best, cost = b, c
    return best


def fine_valve(stage: Stage, struct: Structure, extra: str | None = None, *, profile: bool = True) -> Structure:
    """Fine polish of a symmetric valve on the valve stage (OP -> MV), where the output-error cost
    is V-shaped and sharp: 1 % off in S moves every slip by a sample or two and can cost ten times
    the noise, and the grids step S by 3 %.

    First J/S over its whole range with the initial state refit at each value (`profile_ratio`).
    Then S(t) scaled in 0.5 % steps over +-12 % with J(t)/S(t) over its whole range (and ``extra``,
    ``tau_lag_s``, ``tau_pre_s`` or ``dS_pct_per_s``, +-30 %), then S in 0.1 % and J in 1 % steps, then the
    initial state; twice. Last S (+-1 %), J (+-30 %) and the extra (+-10 %) on one grid, then the
    initial state; twice. A drift is scaled with S (J drifts in proportion). ``profile=False``
    leaves out the profile (for a start whose J/S was profiled already)."""
    def one_round(best: Structure) -> Structure:
        S0, dS0 = max(best.S_up_pct, 0.05), best.dS_pct_per_s
        e0 = getattr(best, extra) if extra else 0.0
        ems = (0.7, 0.85, 1.0, 1.15, 1.3) if e0 else (1.0,)
        cands = []
        m, r, f = mesh(1.0 + np.linspace(-0.12, 0.12, 49), np.linspace(0.0, 1.45, 30), (1, -1))
        for em in ems:
            kw, de = _extra_scale(extra, e0, em)
            dS = dS0 * de
            cands.append(Candidates(best, S_up_pct=S0 * m, S_dn_pct=S0 * m, J_up_pct=S0 * m * r,
                                    J_dn_pct=S0 * m * r, dS_pct_per_s=dS * m, dJ_pct_per_s=dS * m * r,
                                    f0=f, **kw))
        b, _ = best_of(stage, cands + [best])
        S1, J1 = b.S_up_pct, max(b.J_up_pct, 0.02)
        dS1, dJ1 = b.dS_pct_per_s, b.dJ_pct_per_s
        m, mj = mesh(1.0 + np.linspace(-0.02, 0.02, 41), 1.0 + np.linspace(-0.08, 0.08, 17))
        grid = Candidates(b, S_up_pct=S1 * m, S_dn_pct=S1 * m, J_up_pct=J1 * mj, J_dn_pct=J1 * mj,
                          dS_pct_per_s=dS1 * m, dJ_pct_per_s=dJ1 * mj)
        return best_of(stage, [grid, b])[0]

    def joint(best: Structure) -> Structure:
        # S, J and the extra together in fine steps: the one-at-a-time steps above stop short of a
        # J that needs the lag moved too (J and the lag trade off: each holds the other in place)
        S0, J0, e0 = best.S_up_pct, max(best.J_up_pct, 0.02), getattr(best, extra) if extra else 0.0
        dS0, dJ0 = best.dS_pct_per_s, best.dJ_pct_per_s
        ems = 1.0 + np.linspace(-0.1, 0.1, 11) if e0 else (1.0,)
        cands = []
        m, mj = mesh(1.0 + np.linspace(-0.01, 0.01, 9), 1.0 + np.linspace(-0.3, 0.3, 25))
        for em in ems:
            kw, de = _extra_scale(extra, e0, em)
            cands.append(Candidates(best, S_up_pct=S0 * m, S_dn_pct=S0 * m, J_up_pct=J0 * mj, J_dn_pct=J0 * mj,
                                    dS_pct_per_s=dS0 * m * de, dJ_pct_per_s=dJ0 * mj * de, **kw))
        return best_of(stage, cands + [best])[0]

    best = polish(stage, profile_ratio(stage, struct, extra) if profile else struct, one_round)
    return polish(stage, best, joint)


#: values of `profile_ratio` (J/S x the extra) given the whole start search after the first grid
PROFILE_FULL = 4


def profile_ratio(stage: Stage, struct: Structure, extra: str | None, max_ratio: float = 1.45) -> Structure:
    """J/S over 0 to ``max_ratio`` (x the extra at +-15 %), each with its own initial valve state: the
    first start grid (`start_grid`) at every value, then for the best `PROFILE_FULL` values the
    whole start search (`fit_initial_state`).

    Where the valve stuck at the first sample and J trade off: at a wrong J the best stuck point is
    another one, and at that stuck point the right J costs more than the wrong one: the true valve
    scores well only with its own start. A grid over J with the start held sees a wall."""
    S0 = max(struct.S_up_pct, 0.05)
    e0 = getattr(struct, extra) if extra else 0.0
    combos = []
    for em in ((0.85, 1.0, 1.15) if e0 else (1.0,)):
        kw, de = _extra_scale(extra, e0, em)
        combos += [struct.replace(J_up_pct=S0 * r, J_dn_pct=S0 * r, dS_pct_per_s=struct.dS_pct_per_s * de,
                                  dJ_pct_per_s=struct.dS_pct_per_s * r * de, **kw)
                   for r in np.linspace(0.0, max_ratio, max(2, round(30 * max_ratio / 1.45)))]
    # every value with the first start grid in one pass; the best few get the whole start search
    grids = [start_grid(stage, c) for c in combos]
    sse = train_sse(stage, [part for grid in grids for part in grid.parts]).reshape(len(combos), -1)
    sse = np.where(np.isfinite(sse), sse, np.inf).min(axis=1)
    fitted = [fit_initial_state(stage, combos[int(i)]) for i in np.argsort(sse, kind="stable")[:PROFILE_FULL]]
    # the start itself first: it is kept unless a profiled value trains strictly better
    return min([best_of(stage, [struct])] + fitted, key=lambda t: t[1])[0]


def _extra_scale(extra: str | None, e0: float, em: float) -> tuple[dict, float]:
    """For ``extra``'s value ``e0`` scaled by ``em``: the lag to set (``tau_lag_s`` or ``tau_pre_s``)
    and the factor on the drift rates (``dS_pct_per_s``; 1 otherwise)."""
    lag = {extra: e0 * em} if extra in ("tau_lag_s", "tau_pre_s") and e0 else {}
    return lag, (em if extra == "dS_pct_per_s" else 1.0)


def joint_process_polish(stage: Stage, struct: Structure, effect: str, rounds: int = 4) -> Structure:
    """Joint polish of a process-side effect with the process dynamics (loop stage), in rounds until
    the training error stops falling: the effect's parameter (``char_c``, or the load's frequency)
    x the time constant x the dead time on one grid, then the dynamics, S and J, and the valve's
    initial state (globally: which way it last moved and where it stuck).

    An installed characteristic and the process time constant trade off (a steeper gain change
    looks like a slower process near one operating point), as do a load's period and the dynamics
    that carry the valve's share; one at a time each stays where the other holds it (a
    characteristic can stop at a wrong exponent with a wrong time constant and the wrong last
    direction of the valve, far above the true model's cost; the joint grid moves them together)."""
    if stage.fixed_dynamics:
        return struct
    ts = stage.ts_s
    T = max(stage.train.sum() * ts, ts)
    steps = np.concatenate([np.linspace(-1.0, 1.0, 13), [-0.1, -0.05, 0.05, 0.1]])
    taus = np.exp(np.concatenate([np.linspace(-0.3, 0.3, 13), [-0.03, -0.015, 0.015, 0.03]]))

    def one_round(best: Structure) -> Structure:
        p = best.process
        if effect == "char_c":
            c = best.char_c + 0.3 * steps
            name, values = "char_c", c[np.abs(c) > 1e-6]
        else:
            f = 1.0 / best.period_s + 0.1 * steps / T
            name, values = "period_s", 1.0 / f[f > 0]
        d0 = int(round(p.delay_s / ts))
        tau0 = max(p.tau_s, ts)
        m, dd, e = mesh(taus, range(max(d0 - 2, 0), d0 + 3), values)
        b, _ = best_of(stage, [Candidates(best, tau_s=tau0 * m, delay_s=dd * ts, **{name: e}), best])
        b, _ = refit_dynamics(stage, b, rounds=1)
        return refine_sj(stage, b, s_span=0.06, n_s=13, j_span=0.2, n_j=9)[0]

    return polish(stage, struct, one_round, rounds=rounds, tol=1e-3, keep_small_gain=True)


def dynamics_starts(stage: Stage, struct: Structure, k: int = 2) -> list[Structure]:
    """The ``k`` best distinct process dynamics for a fixed (augmented) valve, from a global
    (tau x dead time) grid, each refit locally and with its own initial valve state.

    Valve and process co-adapt: a plain fit's process (often a short lag with a long dead time)
    wants a wrong valve, and a local search of the valve from it stays in that basin; the
    augmented valve's own best process is searched again globally."""
    if stage.fixed_dynamics:
        return []
    p0 = struct.process
    ts = stage.ts_s
    T = stage.train.sum() * ts
    taus = sorted(set(np.geomspace(ts, max(T / 6.0, 2 * ts), 12).tolist()
                      + [max(p0.tau_s, ts) * m for m in (0.7, 1.0, 1.4)]))
    d0 = int(round(p0.delay_s / ts))
    delays = sorted(set(range(0, 16)) | {d0})
    cands = [struct.replace(process=with_times(p0, tau_s=t, delay_s=d * ts))
             for t in taus for d in delays]
    sse = train_sse(stage, cands)
    tops = best_distinct(cands, sse, lambda c: (round(math.log(max(c.process.tau_s, ts)) / 0.35),
                                                 int(round(c.process.delay_s / ts)) // 3), k + 1)
    out = []
    for c in tops:
        if abs(c.process.tau_s - p0.tau_s) < 1e-9 and abs(c.process.delay_s - p0.delay_s) < 1e-9:
            continue
        c, _ = refit_dynamics(stage, c, rounds=1)
        if c.y0_pct is not None:
            c, _ = fit_initial_state(stage, c)
        out.append(c)
    return out[:k]


def valve_dynamics_starts(stage: Stage, reference: Structure, valves: list[dict],
                           k: int = 3) -> list[Structure]:
    """Starting points from a joint grid of augmented valves x process dynamics: for each of a
    global (tau x dead time) grid the best of ``valves`` (keyword sets for `Structure.replace`, each
    tried in both starting directions), then the ``k`` best dynamics, each refit locally.

    From OP/PV a plain fit's process bends to mimic what its valve lacks (a short lag with a long
    dead time), and the augmented valve's basin, often a few per cent wide in S, is not there with
    that process: valve and dynamics are searched together."""
    T = stage.train.sum() * stage.ts_s
    p0 = reference.process
    taus = sorted(set(np.geomspace(stage.ts_s, max(T / 8, 2 * stage.ts_s), 5).tolist() + [max(p0.tau_s, stage.ts_s)]))
    d0 = int(round(p0.delay_s / stage.ts_s))
    if stage.fixed_dynamics:
        base, tau, delay = reference, [reference.process.tau_s], [reference.process.delay_s]
    else:
        tau, delay = mesh(taus, sorted({0, 2, 4, 7, d0}))
        delay = delay * stage.ts_s
        base = reference.replace(process=ProcessModel("foptd", 1.0, float(tau[0]), 0.0, 0.0))
    y0s = y0_options(stage, reference)
    # a valve's and a start's keys never overlap, as in ``replace(**v, **y0)``
    iv, f, iy = mesh(range(len(valves)), (1, -1), range(len(y0s)))
    cols = {**keyword_columns(valves, iv, reference), **keyword_columns(y0s, iy, reference)}
    n_v = iv.size
    parts = [Candidates(base, tau_s=t, delay_s=d, f0=f, **cols) for t, d in zip(tau, delay)]
    cands = Pool(parts)
    sse = train_sse(stage, cands).reshape(len(parts), n_v)
    out = []
    for i in np.argsort(sse.min(axis=1))[:k]:
        st = cands[int(i) * sse.shape[1] + int(np.argmin(sse[i]))]
        st, _ = refit_dynamics(stage, st, rounds=1)
        out.append(st)
    return out


def grid_baseline(stage: Stage, start: Structure | None = None, n_starts: int = 3,
                   template: Structure | None = None, coarse: list | None = None) -> Structure:
    """Global search of the plain model: coarse (S, J, f0) x FOPTD dynamics grid, then a fine global
    (S, J, f0) grid and the dynamics in turn. ``template`` carries extra physics held fixed during
    the search (e.g. a load period); ``coarse``: the coarse grid's starts when already computed
    (`coarse_starts` with the same template)."""
    x = stage.x
    span = float(np.ptp(x[: stage.n_fit]))
    if stage.fixed_dynamics:
        best = global_sj(stage, Structure.plain(0.0, 0.0, 1, IDENTITY), span)
        return best
    starts = [st for _, st in (coarse if coarse is not None else coarse_starts(stage, n_starts, template))]
    if start is not None:
        starts.append(start)
    results = []
    for st in starts:
        best = st
        for _ in range(2):
            best = global_sj(stage, best, span)
            best, c = refit_dynamics(stage, best, rounds=2)
        results.append((c, best))
    return min(results, key=lambda t: t[0])[1]


def coarse_starts(stage: Stage, n_starts: int = 3, template: Structure | None = None) -> list:
    """The coarse (S, J, f0) x FOPTD dynamics grid of `grid_baseline`: the best candidate of each
    of the ``n_starts`` best dynamics, as (training SSE, Structure), cheapest first. ``template``
    carries extra physics held fixed (e.g. a load period)."""
    x = stage.x
    span = float(np.ptp(x[: stage.n_fit]))
    S_grid = [0.0] + list(np.geomspace(0.2, max(0.8 * span, 0.3), 24))
    ratios = (0.0, 0.25, 0.5, 0.75, 1.0, 1.25, 1.5)
    T = stage.train.sum() * stage.ts_s
    taus = np.geomspace(stage.ts_s, max(T / 8, 2 * stage.ts_s), 5)
    dyn = [ProcessModel("foptd", 1.0, float(t), d * stage.ts_s, 0.0) for t in taus
           for d in (0, 2, 4, 7, 12)]
    s, r, f = mesh(S_grid, ratios, (1, -1))
    keep = ~((s == 0) & ((r > 0) | (f < 0)))
    s, r, f = s[keep], r[keep], f[keep]
    base = (template if template is not None else Structure.plain(0.0, 0.0, 1, IDENTITY)).replace(process=dyn[0])
    cands = Pool([Candidates(base, S_up_pct=s, S_dn_pct=s, J_up_pct=s * r, J_dn_pct=s * r, f0=f,
                             tau_s=p.tau_s, delay_s=p.delay_s) for p in dyn])
    n_v = s.size
    sse = train_sse(stage, cands).reshape(len(dyn), n_v)
    best_per_dyn = sse.min(axis=1)
    return [(float(best_per_dyn[i]), cands[int(i) * n_v + int(np.argmin(sse[i]))])
            for i in np.argsort(best_per_dyn)[:n_starts]]
