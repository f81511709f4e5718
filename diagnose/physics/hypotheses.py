"""Missing-physics hypotheses: each one an augmented model with a few physical parameters.

The design follows pysindy's feature libraries: a small base class does what every hypothesis
shares (validation, the search bookkeeping, the parameter count for the information criterion)
and leaves one abstract step, `PhysicsHypothesis._search`, to each subclass. `REGISTRY` is built
from explicit classes; add one by subclassing and calling `register`.

A hypothesis is fitted on the training samples of one `Stage`, starting from the *reference*: the
plain model refit by the same searches (`model.refine_plain`), so that a gain is due to the added
physics and not to a different search.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Any, Mapping

import numpy as np

from ..errors import DataError
from .model import (Stage, Structure, best_of, fit_initial_state, global_sj, predict, refine_sj,
                    refit_dynamics, sj_local, train_sse)
from .valve import characteristic

#: smallest change a valve-side hypothesis must make to S or J, relative to S, to be named: a few
#: per cent is within the resolution of the plain model's own S (a slightly wrong plain S drifts
#: out of step late in the record, and a tiny drift or asymmetry can put it back)
MIN_RELATIVE_EFFECT = 0.10
#: smallest share of the plain model's training residual power an external load must carry to be named
MIN_LOAD_SHARE = 0.10

VALVE_SIDE = "valve"
PROCESS_SIDE = "process"


def _best_distinct(cands: list, sse, key, k: int) -> list:
    """The ``k`` cheapest candidates whose ``key`` differs: on rough costs, distinct starting points
    rather than neighbours of one."""
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


@dataclass(frozen=True)
class Fitted:
    """A fitted hypothesis on one stage.

    Parameters
    ----------
    name : str
        Hypothesis name.
    params : mapping str -> float
        Its physical parameters, units in the names.
    structure : Structure
        The whole augmented model (for simulation).
    n_extra : int
        Parameters added to the plain model (for the information criterion).
    train_sse : float
        Training sum of squared errors.
    stage : str
        ``loop`` (OP -> PV) or ``valve`` (OP -> MV).
    """

    name: str
    params: Mapping[str, float]
    structure: Structure
    n_extra: int
    train_sse: float
    stage: str
    notes: tuple[str, ...] = field(default_factory=tuple)


@dataclass(frozen=True)
class Context:
    """What the localisation found that a hypothesis may use (limit cycle, residual)."""

    limit_cycle_period_s: float | None = None
    residual: np.ndarray | None = None
    baseline: Structure | None = None


class PhysicsHypothesis:
    """Base class. Subclasses set `name`, `param_names`, `side`, `n_extra`, `description` and
    implement `_search(stage, reference, context) -> Structure` and `_params(structure, reference,
    stage, coef) -> dict`."""

    name: str = ""
    param_names: tuple[str, ...] = ()
    side: str = VALVE_SIDE
    n_extra: int = 1
    description: str = ""

    def applicable(self, stage: Stage) -> bool:
        """Whether the hypothesis can be tested on this stage."""
        if self.side == PROCESS_SIDE:
            return stage.name == "loop"
        return stage.name in ("loop", "valve")

    def fit(self, stage: Stage, reference: Structure, context: Context | None = None) -> Fitted:
        if not self.applicable(stage):
            raise DataError(f"hypothesis {self.name!r} cannot be tested on the {stage.name} stage")
        if int(stage.train.sum()) < 50:
            raise DataError(f"hypothesis {self.name!r} needs at least 50 training samples")
        context = context or Context()
        struct = self._search(stage, reference, context)
        if struct.y0_pct is not None:
            # the valve's initial state moves a little with the added physics
            struct, _ = fit_initial_state(stage, struct, local=True)
        # the augmented model nests the plain one: never return a worse fit than the reference
        struct, sse = best_of(stage, [struct, reference])
        _, _, coef = predict(stage, struct)
        params = {k: float(v) for k, v in self._params(struct, reference, stage, coef).items()}
        missing = set(self.param_names) - set(params)
        if missing:  # pragma: no cover - programming error in a subclass
            raise RuntimeError(f"{self.name}: params lack {sorted(missing)}")
        return Fitted(name=self.name, params=params, structure=struct, n_extra=self.n_extra,
                      train_sse=sse, stage=stage.name)

    def _search(self, stage: Stage, reference: Structure, context: Context) -> Structure:
        raise NotImplementedError

    def material(self, params: Mapping[str, float], record_s: float, residual_rms: float) -> bool:
        """Whether the fitted effect is large enough to be physics rather than a nudge within the
        plain model's own resolution (default: always). ``record_s``: record length, seconds;
        ``residual_rms``: the plain model's training residual, RMS in target units."""
        return True

    def _params(self, struct: Structure, reference: Structure, stage: Stage, coef) -> dict:
        raise NotImplementedError


def _y0_options(stage: Stage, reference: Structure) -> list:
    """Starting stem positions worth trying in a global search: the reference's and, on the valve
    stage, the first measured stem positions."""
    out = [{"y0_pct": reference.y0_pct, "xs0_pct": reference.xs0_pct}]
    if stage.name == "valve":
        y0 = float(np.median(stage.y[:3]))
        if reference.y0_pct is None or abs(reference.y0_pct - y0) > 0.05:
            out.append({"y0_pct": y0, "xs0_pct": None})
    return out


def _with_sj(struct: Structure, S: float, J: float, f0: int | None = None) -> Structure:
    return struct.replace(S_up_pct=S, S_dn_pct=S, J_up_pct=J, J_dn_pct=J,
                          f0=struct.f0 if f0 is None else f0)


def _polish(stage: Stage, struct: Structure, one_round, rounds: int = 2, tol: float = 1e-4,
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


def fine_valve(stage: Stage, struct: Structure, extra: str | None = None) -> Structure:
    """Fine polish of a symmetric valve on the valve stage (OP -> MV), where the output-error cost
    is V-shaped and sharp: 1 % off in S moves every slip by a sample or two and can cost ten times
    the noise, and the grids step S by 3 %.

    First J/S over its whole range with the initial state refit at each value (`_profile_ratio`).
    Then S(t) scaled in 0.5 % steps over +-12 % with J(t)/S(t) over its whole range (and ``extra``,
    ``tau_lag_s`` or ``dS_pct_per_s``, +-30 %), then S in 0.1 % and J in 1 % steps, then the
    initial state; twice. Last S (+-1 %), J (+-30 %) and the extra (+-10 %) on one grid, then the
    initial state; twice. A drift is scaled with S (J drifts in proportion)."""
    def one_round(best: Structure) -> Structure:
        S0, dS0 = max(best.S_up_pct, 0.05), best.dS_pct_per_s
        e0 = getattr(best, extra) if extra else 0.0
        ems = (0.7, 0.85, 1.0, 1.15, 1.3) if e0 else (1.0,)
        cands = []
        for em in ems:
            kw, de = _extra_scale(extra, e0, em)
            dS = dS0 * de
            for m in 1.0 + np.linspace(-0.12, 0.12, 49):
                for r in np.linspace(0.0, 1.45, 30):
                    cands += [best.replace(S_up_pct=S0 * m, S_dn_pct=S0 * m, J_up_pct=S0 * m * r,
                                           J_dn_pct=S0 * m * r, dS_pct_per_s=dS * m, dJ_pct_per_s=dS * m * r,
                                           f0=f, **kw) for f in (1, -1)]
        b, _ = best_of(stage, cands + [best])
        S1, J1 = b.S_up_pct, max(b.J_up_pct, 0.02)
        dS1, dJ1 = b.dS_pct_per_s, b.dJ_pct_per_s
        cands = [b.replace(S_up_pct=S1 * m, S_dn_pct=S1 * m, J_up_pct=J1 * mj, J_dn_pct=J1 * mj,
                           dS_pct_per_s=dS1 * m, dJ_pct_per_s=dJ1 * mj)
                 for m in 1.0 + np.linspace(-0.02, 0.02, 41) for mj in 1.0 + np.linspace(-0.08, 0.08, 17)]
        return best_of(stage, cands + [b])[0]

    def joint(best: Structure) -> Structure:
        # S, J and the extra together in fine steps: the one-at-a-time steps above stop short of a
        # J that needs the lag moved too (blind seed 10004 with MV: J 0.865 against the true 1.024
        # at the true lag)
        S0, J0, e0 = best.S_up_pct, max(best.J_up_pct, 0.02), getattr(best, extra) if extra else 0.0
        dS0, dJ0 = best.dS_pct_per_s, best.dJ_pct_per_s
        ems = 1.0 + np.linspace(-0.1, 0.1, 11) if e0 else (1.0,)
        cands = []
        for em in ems:
            kw, de = _extra_scale(extra, e0, em)
            cands += [best.replace(S_up_pct=S0 * m, S_dn_pct=S0 * m, J_up_pct=J0 * mj, J_dn_pct=J0 * mj,
                                   dS_pct_per_s=dS0 * m * de, dJ_pct_per_s=dJ0 * mj * de, **kw)
                      for m in 1.0 + np.linspace(-0.01, 0.01, 9) for mj in 1.0 + np.linspace(-0.3, 0.3, 25)]
        return best_of(stage, cands + [best])[0]

    best = _polish(stage, _profile_ratio(stage, struct, extra), one_round)
    return _polish(stage, best, joint)


def _profile_ratio(stage: Stage, struct: Structure, extra: str | None) -> Structure:
    """J/S over its whole range (x the extra at +-15 %), each with its own initial valve state.

    Where the valve stuck at the first sample and J trade off: at a wrong J the best stuck point is
    another one, and at that stuck point the right J costs more (blind seed 10005 with MV: training
    SSE 70 at the true valve with the fitted start, 19 with its own; the fit had stopped at J/S 0.42
    against the true 0.31). A grid over J with the start held sees a wall."""
    S0 = max(struct.S_up_pct, 0.05)
    e0 = getattr(struct, extra) if extra else 0.0
    cands = []
    for em in ((0.85, 1.0, 1.15) if e0 else (1.0,)):
        kw, de = _extra_scale(extra, e0, em)
        for r in np.linspace(0.0, 1.45, 30):
            c = struct.replace(J_up_pct=S0 * r, J_dn_pct=S0 * r, dS_pct_per_s=struct.dS_pct_per_s * de,
                               dJ_pct_per_s=struct.dS_pct_per_s * r * de, **kw)
            cands.append(fit_initial_state(stage, c))
    # the start itself first: it is kept unless a profiled value trains strictly better
    return min([best_of(stage, [struct])] + cands, key=lambda t: t[1])[0]


def _extra_scale(extra: str | None, e0: float, em: float) -> tuple[dict, float]:
    """For ``extra``'s value ``e0`` scaled by ``em``: the lag to set (``tau_lag_s``) and the factor
    on the drift rates (``dS_pct_per_s``; 1 otherwise)."""
    lag = {"tau_lag_s": e0 * em} if extra == "tau_lag_s" and e0 else {}
    return lag, (em if extra == "dS_pct_per_s" else 1.0)


def _fine_asym(stage: Stage, struct: Structure) -> Structure:
    """Fine polish of an asymmetric valve (on the loop stage with the dynamics held), as
    `fine_valve` for a symmetric one: both S scaled together in 0.5 % steps over +-6 %, then each
    side's S in 0.5 % steps over +-6 % with its J/S over the whole range, then 0.1 % and 1 % steps,
    then the initial state; twice. The one-direction scans step S by 1-2 %, and 1 % off in S moves
    every slip."""
    def one_round(best: Structure) -> Structure:
        cands = [best.replace(S_up_pct=best.S_up_pct * m, S_dn_pct=best.S_dn_pct * m,
                              J_up_pct=best.J_up_pct * m * mj, J_dn_pct=best.J_dn_pct * m * mj, f0=f)
                 for m in 1.0 + np.linspace(-0.06, 0.06, 25) for mj in (0.9, 1.0, 1.1) for f in (1, -1)]
        b, _ = best_of(stage, cands + [best])
        for side in ("up", "dn"):
            S0 = max(getattr(b, f"S_{side}_pct"), 0.05)
            cands = [b.replace(**{f"S_{side}_pct": S0 * m, f"J_{side}_pct": S0 * m * r})
                     for m in 1.0 + np.linspace(-0.06, 0.06, 25) for r in np.linspace(0.0, 1.45, 30)]
            b, _ = best_of(stage, cands + [b])
            S1, J1 = getattr(b, f"S_{side}_pct"), max(getattr(b, f"J_{side}_pct"), 0.02)
            cands = [b.replace(**{f"S_{side}_pct": S1 * m, f"J_{side}_pct": J1 * mj})
                     for m in 1.0 + np.linspace(-0.01, 0.01, 21) for mj in 1.0 + np.linspace(-0.08, 0.08, 17)]
            b, _ = best_of(stage, cands + [b])
        return b

    return _polish(stage, struct, one_round)


def _joint_process_polish(stage: Stage, struct: Structure, effect: str, rounds: int = 4) -> Structure:
    """Joint polish of a process-side effect with the process dynamics (loop stage), in rounds until
    the training error stops falling: the effect's parameter (``char_c``, or the load's frequency)
    x the time constant x the dead time on one grid, then the dynamics, S and J, and the valve's
    initial state (globally: which way it last moved and where it stuck).

    An installed characteristic and the process time constant trade off (a steeper gain change
    looks like a slower process near one operating point), as do a load's period and the dynamics
    that carry the valve's share; one at a time each stays where the other holds it. On published
    seed 1002 the characteristic stopped at c = 2.00 with tau 21 s and the wrong last direction of
    the valve (training SSE 166, the true model 57); this polish reaches SSE 58."""
    if stage.fixed_dynamics:
        return struct
    ts = stage.ts_s
    T = max(stage.train.sum() * ts, ts)
    steps = np.concatenate([np.linspace(-1.0, 1.0, 13), [-0.1, -0.05, 0.05, 0.1]])
    taus = np.exp(np.concatenate([np.linspace(-0.3, 0.3, 13), [-0.03, -0.015, 0.015, 0.03]]))

    def one_round(best: Structure) -> Structure:
        p = best.process
        if effect == "char_c":
            c0 = best.char_c
            extra = [{"char_c": float(c0 + 0.3 * d)} for d in steps if abs(c0 + 0.3 * d) > 1e-6]
        else:
            f1 = 1.0 / best.period_s
            extra = [{"period_s": float(1.0 / (f1 + 0.1 * d / T))} for d in steps if f1 + 0.1 * d / T > 0]
        d0 = int(round(p.delay_s / ts))
        tau0 = max(p.tau_s, ts)
        cands = [best.replace(process=dataclasses.replace(p, tau_s=float(tau0 * m), delay_s=float(dd * ts)), **e)
                 for m in taus for dd in range(max(d0 - 2, 0), d0 + 3)
                 for e in extra]
        b, _ = best_of(stage, cands + [best])
        b, _ = refit_dynamics(stage, b, rounds=1)
        return refine_sj(stage, b, s_span=0.06, n_s=13, j_span=0.2, n_j=9)[0]

    return _polish(stage, struct, one_round, rounds=rounds, tol=1e-3, keep_small_gain=True)


def _dynamics_starts(stage: Stage, struct: Structure, k: int = 2) -> list[Structure]:
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
    cands = [struct.replace(process=dataclasses.replace(p0, tau_s=float(t), delay_s=d * ts))
             for t in taus for d in delays]
    sse = train_sse(stage, cands)
    tops = _best_distinct(cands, sse, lambda c: (round(math.log(max(c.process.tau_s, ts)) / 0.35),
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


class ActuatorLag(PhysicsHypothesis):
    """First-order lag of the stem after the friction element (pneumatic actuator, positioner).

    On the valve stage (OP -> MV) a dead time of whole samples is searched with it (a positioner's
    or the logging's delay); on the loop stage a dead time is part of the process already.
    """

    name = "actuator_lag"
    param_names = ("tau_s", "dead_time_s", "S_pct", "J_pct")
    side = VALVE_SIDE
    n_extra = 2
    description = "first-order lag of the stem after a slip"

    def _search(self, stage, reference, context):
        ts = stage.ts_s
        S, J = reference.S_up_pct, reference.J_up_pct
        taus = ts * np.array([0.25, 0.5, 1.0, 1.5, 2.0, 3.0, 4.0, 6.0, 8.0, 12.0, 16.0])
        delays = (0, 1, 2, 3) if stage.name == "valve" else (None,)

        def with_delay(s: Structure, d) -> Structure:
            if d is None:
                return s
            return s.replace(process=dataclasses.replace(s.process, delay_s=d * ts))

        # J relative to S over its whole range: a lag changes the plain fit's J the most
        pairs = [(S * m, S * m * r) for m in (0.85, 0.93, 1.0, 1.07, 1.15)
                 for r in (0.0, 0.25, 0.5, 0.75, 1.0, 1.25)] + [(S, J)]
        combos = [(float(t), d) for t in taus for d in delays]
        cands = [with_delay(_with_sj(reference, s, j, f), d).replace(tau_lag_s=t)
                 for t, d in combos for s, j in pairs for f in (1, -1)]
        sse = train_sse(stage, cands).reshape(len(combos), -1)
        results = []
        if stage.name == "valve":
            # OP -> MV has no process: the lag x valve grid is cheap enough to search globally
            # (a lag moves the plain fit's S and J far)
            span = float(np.ptp(stage.x[: stage.n_fit]))
            S_grid = np.exp(np.arange(math.log(0.2), math.log(max(0.8 * span, 0.3)) + 1e-9, math.log1p(0.03)))
            y0s = _y0_options(stage, reference)
            g = [reference.replace(S_up_pct=s, S_dn_pct=s, J_up_pct=s * r, J_dn_pct=s * r, f0=f,
                                   tau_lag_s=float(t), **y0)
                 for t in taus for s in S_grid for r in (0.0, 0.2, 0.4, 0.6, 0.8, 0.9, 1.0, 1.2, 1.45)
                 for f in (1, -1) for y0 in y0s]
            gs = train_sse(stage, g)
            for i in np.argsort(gs)[:2]:
                st = refine_sj(stage, g[int(i)], s_span=0.04, n_s=9, j_span=0.15, n_j=7)[0]
                st = best_of(stage, [st.replace(tau_lag_s=st.tau_lag_s * m)
                                     for m in (0.8, 0.9, 1.0, 1.12, 1.25)])[0]
                st, c = best_of(stage, [with_delay(st, d) for d in delays])
                results.append((c, st))
        # a lag changes which slips a plain fit had to fake: search the valve again for the best few
        for i in np.argsort(sse.min(axis=1))[:1 if results else 3]:
            st = cands[int(i) * sse.shape[1] + int(np.argmin(sse[i]))]
            st = global_sj(stage, st)
            st, c = refit_dynamics(stage, st, rounds=1)
            results.append((c, st))
        best = min(results, key=lambda t: t[0])[1]
        t0 = best.tau_lag_s
        pairs = sj_local(best.S_up_pct, best.J_up_pct, s_span=0.04, n_s=9, j_span=0.15, n_j=5)
        cands = [_with_sj(best, s, j).replace(tau_lag_s=t0 * m)
                 for m in (0.75, 0.87, 1.0, 1.15, 1.3) for s, j in pairs]
        cands.append(best)
        best, _ = best_of(stage, cands)
        best, _ = refit_dynamics(stage, best, rounds=1)
        best, _ = refine_sj(stage, best, s_span=0.02, n_s=9, j_span=0.06, n_j=5, both_f0=False)
        if stage.name == "valve":
            best = fine_valve(stage, best, "tau_lag_s")
        return best

    def _params(self, struct, reference, stage, coef):
        dead = struct.process.delay_s if stage.name == "valve" else 0.0
        return {"tau_s": struct.tau_lag_s, "dead_time_s": float(dead), "S_pct": struct.S_up_pct,
                "J_pct": struct.J_up_pct}


class AsymmetricStiction(PhysicsHypothesis):
    """Separate (S, J) when opening and when closing."""

    name = "asymmetric_stiction"
    param_names = ("S_open_pct", "J_open_pct", "S_close_pct", "J_close_pct")
    side = VALVE_SIDE
    n_extra = 2
    description = "different stiction opening and closing"

    def _search(self, stage, reference, context):
        # Opening reversals depend on S_open, closing ones on S_close: the cost nearly separates, so
        # wide fine one-direction scans (coordinate descent) find both.
        S = max(reference.S_up_pct, 0.2)
        wide = np.exp(np.arange(math.log(0.3), math.log(1.9), math.log1p(0.02)))
        # A plain valve (and, from OP/PV alone, other process dynamics) can mimic asymmetry: a
        # coarse asymmetric-valve (x dynamics) grid gives more starting points.
        starts = [reference] + _coarse_asym_starts(stage, reference)
        # a global (S_open, S_close, J ratios) grid with the reference's dynamics is cheap (25 000
        # sets in under a second); from OP/PV the coarse grid's one J/S for both sides can miss the
        # basin (concealed asymmetry 1002: from its starts training SSE 185, from this grid's 69)
        g_s = S * np.exp(np.arange(math.log(0.3), math.log(1.9), math.log1p(0.07)))
        y0s = _y0_options(stage, reference)
        g = [reference.replace(S_up_pct=su, S_dn_pct=sd, J_up_pct=su * ru, J_dn_pct=sd * rd, f0=f, **y0)
             for su in g_s for sd in g_s for ru in (0.1, 0.4, 0.7, 1.0) for rd in (0.1, 0.4, 0.7, 1.0)
             for f in (1, -1) for y0 in y0s]
        gs = train_sse(stage, g)
        starts += _best_distinct(g, gs, lambda c: (round(c.S_up_pct, 6), round(c.S_dn_pct, 6)), 2)
        results = []
        for st in starts:
            b = self._scan(stage, st, S, wide)
            results.append((best_of(stage, [b])[1], b))
        best = min(results, key=lambda t: t[0])[1]
        if stage.name == "valve":
            # OP -> MV: the cost is sharp in S on both sides and the scans step S by 1-2 %, so a
            # scan's result is no measure of its basin: every one is polished (fresh 5005 with MV:
            # the scan from a grid start 36.7, polished 18.2; the best scan 31.1, polished 31.1)
            best = best_of(stage, [_fine_asym(stage, b) for _, b in results])[0]
        else:
            # OP -> PV: the same fine polish around the process dynamics refit once between (fresh
            # asymmetry 5001: the unpolished fit trained worse than the plain reference and was
            # refused; polished, held-out 0.205 -> 0.135, named). No net gain on the benchmark:
            # fresh 5004 and 5005 train better and extrapolate worse polished (missing-physics.md)
            best = _fine_asym(stage, best)
            best, _ = refit_dynamics(stage, best, rounds=1)
            best = _fine_asym(stage, best)
        return best

    def _scan(self, stage, start, S, wide):
        best = start
        for rnd in range(2):
            for side in ("up", "dn"):
                Sx = S if rnd == 0 else getattr(best, f"S_{side}_pct")
                Jx = getattr(best, f"J_{side}_pct")
                r = Jx / Sx if Sx > 0 else 0.5
                fs = (1, -1) if rnd == 0 else (best.f0,)
                cands = [best.replace(**{f"S_{side}_pct": Sx * m, f"J_{side}_pct": Sx * m * rr}, f0=f)
                         for m in (wide if rnd == 0 else 1.0 + np.linspace(-0.08, 0.08, 17))
                         for rr in {r, 0.5 * r, min(1.5 * r, 1.5)} for f in fs]
                cands.append(best)
                best, _ = best_of(stage, cands)
                Sx = getattr(best, f"S_{side}_pct")
                cands = [best.replace(**{f"S_{side}_pct": Sx * m, f"J_{side}_pct": Sx * rr})
                         for m in 1.0 + np.linspace(-0.03, 0.03, 5) for rr in np.linspace(0.0, 1.5, 31)]
                cands.append(best)
                best, _ = best_of(stage, cands)
            best, _ = refit_dynamics(stage, best, rounds=1)
        return best

    def _params(self, struct, reference, stage, coef):
        return {"S_open_pct": struct.S_up_pct, "J_open_pct": struct.J_up_pct,
                "S_close_pct": struct.S_dn_pct, "J_close_pct": struct.J_dn_pct}

    def material(self, params, record_s, residual_rms):
        # opening and closing differ by at least MIN_RELATIVE_EFFECT of the larger S
        big = max(params["S_open_pct"], params["S_close_pct"], 0.2)
        diff = max(abs(params["S_open_pct"] - params["S_close_pct"]),
                   abs(params["J_open_pct"] - params["J_close_pct"]))
        return diff >= MIN_RELATIVE_EFFECT * big


def _valve_dynamics_starts(stage: Stage, reference: Structure, valves: list[dict],
                           k: int = 3) -> list[Structure]:
    """Starting points from a joint grid of augmented valves x process dynamics: for each of a
    global (tau x dead time) grid the best of ``valves`` (keyword sets for `Structure.replace`, each
    tried in both starting directions), then the ``k`` best dynamics, each refit locally.

    From OP/PV a plain fit's process bends to mimic what its valve lacks (a short lag with a long
    dead time), and the augmented valve's basin, often a few per cent wide in S, is not there with
    that process: valve and dynamics are searched together."""
    from ..process_model import ProcessModel

    T = stage.train.sum() * stage.ts_s
    p0 = reference.process
    taus = sorted(set(np.geomspace(stage.ts_s, max(T / 8, 2 * stage.ts_s), 5).tolist() + [max(p0.tau_s, stage.ts_s)]))
    d0 = int(round(p0.delay_s / stage.ts_s))
    dyn = [ProcessModel("foptd", 1.0, float(t), d * stage.ts_s, 0.0)
           for t in taus for d in sorted({0, 2, 4, 7, d0})]
    if stage.fixed_dynamics:
        dyn = [reference.process]
    y0s = _y0_options(stage, reference)
    cands = [reference.replace(f0=f, process=p, **v, **y0)
             for p in dyn for v in valves for f in (1, -1) for y0 in y0s]
    sse = train_sse(stage, cands).reshape(len(dyn), -1)
    out = []
    for i in np.argsort(sse.min(axis=1))[:k]:
        st = cands[int(i) * sse.shape[1] + int(np.argmin(sse[i]))]
        st, _ = refit_dynamics(stage, st, rounds=1)
        out.append(st)
    return out


def _coarse_asym_starts(stage: Stage, reference: Structure, k: int = 3) -> list[Structure]:
    span = float(np.ptp(stage.x[: stage.n_fit]))
    S_grid = np.geomspace(0.3, max(0.8 * span, 0.4), 14)
    valves = [{"S_up_pct": su, "S_dn_pct": su * r, "J_up_pct": su * jr, "J_dn_pct": su * r * jr}
              for su in S_grid for r in (0.35, 0.55, 0.8, 1.25, 1.8, 2.8) for jr in (0.3, 0.75)]
    return _valve_dynamics_starts(stage, reference, valves, k)


def _coarse_drift_starts(stage: Stage, reference: Structure, k: int = 3) -> list[Structure]:
    """Drifting valves (S at the start within 0.5-1.7 of the reference's in 4 % steps, S at the end
    of the fitted span 0.45-2.2 times that in 8 % steps, J/S 0.3-0.8, drifting alike) x dynamics.
    The drift's basin is a few per cent wide in both S and its rate (concealed drift 8003 with the
    true dynamics: training SSE 3.7 at the true drift, 70 with the starting S 4 % low, 53 with the
    rate 10 % low)."""
    T = max(stage.n_fit * stage.ts_s, stage.ts_s)
    S = max(reference.S_up_pct, 0.2)
    valves = [{"S_up_pct": s0, "S_dn_pct": s0, "J_up_pct": s0 * r, "J_dn_pct": s0 * r,
               "dS_pct_per_s": s0 * (q - 1.0) / T, "dJ_pct_per_s": s0 * r * (q - 1.0) / T}
              for s0 in S * np.exp(np.arange(math.log(0.5), math.log(1.7), 0.04))
              for q in np.exp(np.arange(math.log(0.45), math.log(2.2), 0.08)) for r in (0.3, 0.55, 0.8)]
    return _valve_dynamics_starts(stage, reference, valves, k)


class ValveCharacteristic(PhysicsHypothesis):
    """Installed characteristic: operating-point dependent gain, flow ~ (e^(c y) - 1), R = e^c."""

    name = "valve_characteristic"
    param_names = ("rangeability_R", "gain_ratio_80_20")
    side = PROCESS_SIDE
    n_extra = 1
    description = "operating-point dependent gain (installed characteristic)"

    def _search(self, stage, reference, context):
        from .baseline import coarse_starts

        # The gain change distorts the plain fit's S and J: for the most promising exponents the
        # valve is searched again globally.
        cs = [c for c in np.linspace(-4.0, 4.5, 18) if abs(c) > 1e-6]
        starts = []
        for origin in [reference] + ([context.baseline] if context.baseline is not None else []):
            S, J = origin.S_up_pct, origin.J_up_pct
            pairs = sj_local(S, J, s_span=0.06, n_s=7, j_span=0.2, n_j=3, j_zero=False)
            cands = [_with_sj(origin, s, j).replace(char_c=float(c)) for c in cs for s, j in pairs]
            sse = train_sse(stage, cands).reshape(len(cs), len(pairs))
            for i in np.argsort(sse.min(axis=1))[:3 if origin is reference else 2]:
                starts.append(cands[int(i) * len(pairs) + int(np.argmin(sse[i]))])
        # a plain fit bent far off by the curved gain (on a record whose OP visits several operating
        # points it can ratchet with S of tens of %) is no start at all: the coarse valve x FOPTD
        # grid of the baseline, with the characteristic in the model, for a few exponents
        grid = [coarse_starts(stage, n_starts=1, template=reference.replace(char_c=c))[0]
                for c in (-2.0, 1.0, 2.0, 3.0)]
        starts += [s for _, s in sorted(grid, key=lambda t: t[0])[:2]]
        # where the loop settled at several operating points, their means give the exponent without
        # the dynamics; with it, a linear valve fixes the dynamics and then a valve grid the valve
        starts += [self._linear_start(stage, reference, c) for c in self.static_exponents(stage, reference)]
        results = []
        for st in starts:
            st, _ = refit_dynamics(stage, st, rounds=1)
            st = global_sj(stage, st)
            st, _ = refit_dynamics(stage, st, rounds=1)
            c0 = st.char_c
            st, c = best_of(stage, [st.replace(char_c=float(c0 + d)) for d in np.linspace(-0.4, 0.4, 9)
                                    if abs(c0 + d) > 1e-6])
            results.append((c, st))
        best = min(results, key=lambda t: t[0])[1]
        best, _ = refine_sj(stage, best, s_span=0.04, n_s=9, j_span=0.15, n_j=5, both_f0=False)
        best, _ = refit_dynamics(stage, best, rounds=1)
        if best.char_c:
            best = _joint_process_polish(stage, best, "char_c")
        return best

    @staticmethod
    def static_exponents(stage: Stage, reference: Structure, spread: tuple = (-0.5, -0.25, 0.0, 0.25, 0.5)
                         ) -> list[float]:
        """Exponents c around the one that the loop's settled operating points prefer: the mean OP
        and mean PV of training windows whose PV stays within a quarter of its training range,
        PV ~ a + b characteristic(OP, c) by least squares over a grid of c. Empty when the settled
        windows' mean OPs fall in fewer than three 10 % bins of travel or span less than 20 %, or
        when the process integrates (no settled operating points).

        Setpoint changes over much of the travel expose a characteristic best, and make the
        output-error cost a needle in c and the time constant (blind seed 10005: training SSE 45 at
        the true c and dynamics, 1200-2000 with c off by 0.4, 27 000 with the lag 60 % short), so
        that a coarse grid of c and dynamics starts nowhere near it."""
        p = reference.process
        idx = np.flatnonzero(stage.train)
        if p.kind == "integrating" or idx.size < 60:
            return []
        w = int(np.clip(5.0 * (p.tau_s + p.delay_s) / stage.ts_s, 20, idx.size / 6))
        a = int(idx[0])
        n = (int(idx[-1]) + 1 - a) // w
        x = stage.x[a:a + n * w].reshape(n, w)
        y = stage.y[a:a + n * w].reshape(n, w)
        steady = np.ptp(y, axis=1) < 0.25 * max(float(np.ptp(stage.y[idx])), 1e-9)
        xm, ym = x.mean(axis=1)[steady], y.mean(axis=1)[steady]
        if np.unique(np.round(xm / 10.0)).size < 3 or np.ptp(xm) < 20.0:
            return []
        cs = np.arange(-4.0, 4.5001, 0.05)
        res = []
        for c in cs:
            X = np.column_stack([np.ones_like(xm), characteristic(xm, float(c))])
            coef, *_ = np.linalg.lstsq(X, ym, rcond=None)
            res.append(float(np.sum((ym - X @ coef) ** 2)))
        c0 = float(cs[int(np.argmin(res))])
        return [c0 + d for d in spread if abs(c0 + d) > 1e-6]

    @staticmethod
    def _linear_start(stage: Stage, reference: Structure, c: float) -> Structure:
        """For an exponent c: the dynamics of a linear valve (tau x dead time grid, refit), then a
        (S, J/S, direction) grid with those dynamics."""
        T = max(stage.train.sum() * stage.ts_s, 12.0 * stage.ts_s)
        lin = _with_sj(reference, 0.0, 0.0).replace(char_c=float(c), y0_pct=None, xs0_pct=None)
        cands = [lin.replace(process=dataclasses.replace(reference.process, tau_s=float(t), delay_s=float(d * stage.ts_s)))
                 for t in np.geomspace(stage.ts_s, T / 6.0, 40) for d in range(16)]
        best, _ = best_of(stage, cands)
        best, _ = refit_dynamics(stage, best, rounds=2)
        span = float(np.ptp(stage.x[: stage.n_fit]))
        S_grid = np.geomspace(0.2, max(0.8 * span, 0.3), 40)
        cands = [_with_sj(best, s, s * r, f) for s in S_grid for r in np.linspace(0.0, 1.5, 13) for f in (1, -1)]
        return best_of(stage, cands)[0]

    def _params(self, struct, reference, stage, coef):
        c = struct.char_c
        # slope of the characteristic at 80 % over that at 20 % of travel: e^(0.6 c)
        return {"rangeability_R": math.exp(c), "gain_ratio_80_20": math.exp(0.6 * c)}


class ExternalDisturbance(PhysicsHypothesis):
    """An oscillating load not caused by the valve: an additive sinusoid (period, amplitude)."""

    name = "external_disturbance"
    param_names = ("period_s", "amplitude")
    side = PROCESS_SIDE
    n_extra = 3
    description = "oscillating external load"

    @staticmethod
    def _peaks(sig: np.ndarray, ts_s: float, plc: float | None, k: int) -> list[float]:
        m = sig.shape[0]
        sig = sig - np.polyval(np.polyfit(np.arange(m), sig, 1), np.arange(m))
        nfft = 4 * int(2 ** math.ceil(math.log2(m)))
        P = np.abs(np.fft.rfft(sig * np.hanning(m), nfft)) ** 2
        f = np.fft.rfftfreq(nfft, ts_s)
        T = m * ts_s
        ok = (f >= 3.0 / T) & (f <= 0.4 / ts_s)
        if plc:
            flc = 1.0 / plc
            # harmonics only: a load can entrain the loop so that the oscillation runs at its period
            for h in range(2, 12):
                ok &= np.abs(f - h * flc) > max(0.07 * h * flc, 1.5 / T)
        idx = np.flatnonzero(ok[1:-1] & (P[1:-1] >= P[:-2]) & (P[1:-1] >= P[2:])) + 1
        if idx.size == 0:
            return []
        return [float(1.0 / f[i]) for i in idx[np.argsort(P[idx])[::-1][:k]]]

    def candidate_periods(self, stage: Stage, reference: Structure, context: Context) -> list[float]:
        """Periods of the largest spectral peaks away from the limit cycle's harmonics: of the plain
        model's residual, and of OP (a well-rejected load shows in OP more than in the residual,
        because the plain fit bends to follow it)."""
        if context.residual is not None:
            r = np.asarray(context.residual, float)
        else:
            y_hat, _, _ = predict(stage, reference)
            r = stage.y - y_hat
        n = stage.n_fit
        tr = stage.train[:n]
        T = tr.sum() * stage.ts_s
        plc = context.limit_cycle_period_s
        cands = self._peaks(r[:n][tr], stage.ts_s, plc, 3) + self._peaks(stage.x[:n][tr], stage.ts_s, plc, 2)
        out: list[float] = []
        for p in cands:
            if all(abs(1.0 / p - 1.0 / q) > 1.5 / T for q in out):
                out.append(p)
        return out

    @staticmethod
    def rank_periods(stage: Stage, reference: Structure, periods: list[float]) -> list[tuple]:
        """Candidate load periods, best first, as (training SSE, the reference with the load at its
        best nearby period, the coarse grid's starts with that load).

        Ranked by what the load does for the plain fit *and* for the coarse valve x dynamics grid
        of the baseline (`baseline.coarse_starts`): the plain fit bent its valve and process to
        follow the load through OP, and a load added to it alone barely helps at any period
        (published seed 1003: an integrating plain fit; the true period ranked 4th of 5 on it,
        first on the grid)."""
        from .baseline import coarse_starts

        T = stage.train.sum() * stage.ts_s
        first = []
        for p in periods:
            f0 = 1.0 / p
            cands = [reference.replace(period_s=float(1.0 / f)) for f in f0 + np.linspace(-1.0, 1.0, 21) / T
                     if f > 0]
            c, st = best_of(stage, cands)[::-1]
            coarse = [] if stage.fixed_dynamics else coarse_starts(stage, 3, template=st)
            first.append((min([c] + [k for k, _ in coarse]), st, coarse))
        first.sort(key=lambda t: t[0])
        return first

    def _search(self, stage, reference, context):
        periods = self.candidate_periods(stage, reference, context)
        if not periods:
            return reference
        T = stage.train.sum() * stage.ts_s
        first = self.rank_periods(stage, reference, periods)
        results, top = [], []
        for i, (_, st, coarse) in enumerate(first):
            starts = [st]
            if i < 1 and coarse:
                # the plain fit bent its valve and process to follow the load through OP (its S and
                # dynamics can be far off): search the valve and the dynamics globally with the load
                # for the period that helps most (from the plain fit and from the coarse grid)
                from .baseline import grid_baseline
                starts.append(grid_baseline(stage, start=st, n_starts=3, template=st, coarse=coarse))
            for st in starts:
                st, _ = refit_dynamics(stage, st, rounds=1)
                st = global_sj(stage, st)
                st, _ = refit_dynamics(stage, st, rounds=1)
                f1 = 1.0 / st.period_s
                st, c = best_of(stage, [st.replace(period_s=float(1.0 / f))
                                        for f in f1 + np.linspace(-0.15, 0.15, 13) / T])
                results.append((c, st))
                if i < 1:
                    top.append(st)
        best = min(results, key=lambda t: t[0])[1]
        if not stage.fixed_dynamics:
            # backfit from every start of the best period, not only from the best training fit:
            # where the fitting stage lands depends on the load taken out, and the best joint fit
            # can hold a load estimate that leads it nowhere (development seed 2011: from the best
            # start, training SSE 155, no gain; from the plain fit's start, 49)
            bfs = [b for b in (self._backfit(stage, st) for st in top) if b is not None]
            best = best_of(stage, [best] + bfs)[0]
        best, _ = refine_sj(stage, best, s_span=0.04, n_s=9, j_span=0.15, n_j=5)
        if best.period_s is not None:
            best = _joint_process_polish(stage, best, "period_s")
            if not stage.fixed_dynamics:
                # the polished load is a better estimate to take out: backfit once more
                bf = self._backfit(stage, best)
                if bf is not None and best_of(stage, [bf])[1] < best_of(stage, [best])[1]:
                    best = _joint_process_polish(stage, bf, "period_s")
        return best

    @staticmethod
    def _backfit(stage: Stage, start: Structure, rounds: int = 3) -> Structure | None:
        """Backfitting: take the fitted load out of PV, fit the plain valve and process on what is
        left with the fitting stage, put the load back; repeat. A strong load bends a joint search
        of valve, process and load far off; the fitting stage's own global search on the cleaned PV
        does not see it."""
        try:
            from ..fit import fit_hammerstein
        except ImportError:  # pragma: no cover - the fitting stage is part of the package
            return None
        import warnings

        from ..errors import StictionError, StictionWarning

        t = np.arange(stage.n) * stage.ts_s
        w = 2.0 * np.pi / start.period_s
        best, best_c = start, best_of(stage, [start])[1]
        cur = start
        for _ in range(rounds):
            _, _, coef = predict(stage, cur)
            y = stage.y - coef[-2] * np.sin(w * t) - coef[-1] * np.cos(w * t)
            try:
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore", StictionWarning)
                    res = fit_hammerstein(stage.x, y, stage.ts_s, train=stage.train,
                                          gain_sign=stage.gain_sign or None)
            except (StictionError, ValueError, np.linalg.LinAlgError):
                break
            cur = start.replace(S_up_pct=float(res.S_pct), S_dn_pct=float(res.S_pct), J_up_pct=float(res.J_pct),
                                J_dn_pct=float(res.J_pct), f0=int(res.f0), process=res.process)
            cur, _ = refit_dynamics(stage, cur, rounds=1)
            if cur.y0_pct is not None:
                cur, _ = fit_initial_state(stage, cur)
            cur, c = best_of(stage, [cur])
            if c < best_c:
                best, best_c = cur, c
        return best

    def _params(self, struct, reference, stage, coef):
        if struct.period_s is None:
            return {"period_s": float("nan"), "amplitude": 0.0}
        a, b = coef[-2], coef[-1]
        return {"period_s": struct.period_s, "amplitude": float(math.hypot(a, b))}

    def material(self, params, record_s, residual_rms):
        # the load carries at least MIN_LOAD_SHARE of the plain model's training residual power: a
        # sinusoid far below the noise cannot be what the plain model misses (clean 1003: a load of
        # 0.03 under noise of 0.13, fitted to the slow random-walk load, was named)
        return 0.5 * params["amplitude"] ** 2 >= MIN_LOAD_SHARE * residual_rms ** 2

    @staticmethod
    def at_limit_cycle(period_s: float | None, limit_cycle_period_s: float | None) -> bool:
        """Whether a load period sits on the loop's own oscillation period (within 8 %)."""
        if not period_s or not limit_cycle_period_s or not math.isfinite(period_s):
            return False
        return abs(period_s / limit_cycle_period_s - 1.0) < 0.08


class TimeVaryingFriction(PhysicsHypothesis):
    """S and J drifting linearly over the record (wear, temperature, maintenance)."""

    name = "time_varying_friction"
    param_names = ("S_start_pct", "J_start_pct", "dS_pct_per_h", "dJ_pct_per_h")
    side = VALVE_SIDE
    n_extra = 2
    description = "friction drifting over the record"

    def _search(self, stage, reference, context):
        T = max(stage.n_fit * stage.ts_s, stage.ts_s)
        # S at the start and at the end of the fitted span, both on fine geometric grids (an
        # output-error stiction fit is sharp in S: a few per cent move every slip), around the
        # plain fits' S (a drifting valve's plain fit sits near its mid-span S); J drifts alike
        centres = {round(max(reference.S_up_pct, 0.2), 6)}
        if context.baseline is not None and context.baseline.S_up_pct > 0.2:
            centres.add(round(context.baseline.S_up_pct, 6))
        best = self._grid(stage, reference, centres, T)
        if stage.name == "valve":
            return fine_valve(stage, best, "dS_pct_per_s")
        cost = best_of(stage, [best])[1]

        def restart(st: Structure, around: set) -> None:
            nonlocal best, cost
            b = self._grid(stage, st.replace(dS_pct_per_s=0.0, dJ_pct_per_s=0.0), around, T, extra=[st])
            b, c = best_of(stage, [b])
            if c < cost:
                best, cost = b, c

        # from a joint grid of drifting valves x dynamics (the plain fit's process can be far off:
        # concealed drift 5004, training SSE 37 from the search above, 11 from this grid; held-out
        # 0.22 -> 0.12)
        for st in _coarse_drift_starts(stage, reference):
            restart(st, {round(st.S_up_pct, 6)})
        # valve and process co-adapt: search the drifting valve's own process globally, then the
        # drift again from it (around the drift's mid-span S and the reference's)
        mid = 0.5 * T
        for st in _dynamics_starts(stage, best):
            restart(st, centres | {round(max(best.S_up_pct + best.dS_pct_per_s * mid, 0.2), 6)})
        return best

    def _grid(self, stage, reference, centres, T, extra=()):
        """The drift search around one plain start: S at the start and the end of the fitted span
        on fine geometric grids around each of ``centres`` (J drifting alike), the initial state of
        the best few distinct drifts, then local polish rounds with the dynamics refit. ``extra``:
        further candidates to keep (e.g. the drift the search restarts from)."""
        m_start = np.exp(np.arange(math.log(0.55), math.log(1.35), 0.03))
        q_end = np.exp(np.concatenate([np.arange(-0.6, -0.035, 0.03), np.arange(0.04, 0.61, 0.03)]))
        r0 = min(reference.J_up_pct / max(reference.S_up_pct, 1e-9), 1.45)
        ratios = sorted({round(r0, 3), 0.3, 0.6, 0.9})
        cands = [reference] + list(extra)
        y0s = _y0_options(stage, reference)
        for Sc in centres:
            cands += [reference.replace(S_up_pct=s0, S_dn_pct=s0, J_up_pct=s0 * r, J_dn_pct=s0 * r, f0=f,
                                        dS_pct_per_s=s0 * (q - 1.0) / T, dJ_pct_per_s=s0 * r * (q - 1.0) / T,
                                        **y0)
                      for s0 in Sc * m_start for q in q_end for r in ratios for f in (1, -1)
                      for y0 in y0s]
        sse = train_sse(stage, cands)
        # the cost is rough (the valve's initial state and every slip's timing): the best few
        # distinct drifts each get their initial state fitted
        tops = _best_distinct(cands, sse, lambda c: (round(math.log(max(c.S_up_pct, 1e-3)) / 0.06),
                                                     round(c.dS_pct_per_s * T / max(c.S_up_pct, 1e-9) / 0.06)), 4)
        cands = []
        for c in tops:
            c, _ = fit_initial_state(stage, c)
            cands += [c.replace(S_up_pct=c.S_up_pct * m, S_dn_pct=c.S_up_pct * m,
                                dS_pct_per_s=(c.S_up_pct + c.dS_pct_per_s * T) * q / T - c.S_up_pct * m / T)
                      for m in (0.985, 1.0, 1.015) for q in (0.985, 1.0, 1.015)]
        best, _ = best_of(stage, cands + tops)
        for rnd in range(2):
            s0, j0 = best.S_up_pct, max(best.J_up_pct, 0.05)
            rs = best.dS_pct_per_s * T / max(s0, 1e-9)
            rj = best.dJ_pct_per_s * T / max(j0, 1e-9)
            span = 0.06 if rnd == 0 else 0.02
            cands = [best.replace(S_up_pct=s0 * ms, S_dn_pct=s0 * ms, dS_pct_per_s=s0 * ms * (rs + d) / T)
                     for ms in 1.0 + np.linspace(-span, span, 9) for d in np.linspace(-0.25, 0.25, 11) * (span / 0.06)]
            cands.append(best)
            best, _ = best_of(stage, cands)
            cands = [best.replace(J_up_pct=j0 * mj, J_dn_pct=j0 * mj, dJ_pct_per_s=j0 * mj * (rj + d) / T)
                     for mj in 1.0 + np.linspace(-3 * span, 3 * span, 7) for d in np.linspace(-0.5, 0.5, 7)]
            cands.append(best)
            best, _ = best_of(stage, cands)
            best, _ = refit_dynamics(stage, best, rounds=1)
        return best

    def _params(self, struct, reference, stage, coef):
        return {"S_start_pct": struct.S_up_pct, "J_start_pct": struct.J_up_pct,
                "dS_pct_per_h": struct.dS_pct_per_s * 3600.0, "dJ_pct_per_h": struct.dJ_pct_per_s * 3600.0}

    def material(self, params, record_s, residual_rms):
        # S or J changes by at least MIN_RELATIVE_EFFECT of the starting S over the record
        big = max(params["S_start_pct"], 0.2)
        change = max(abs(params["dS_pct_per_h"]), abs(params["dJ_pct_per_h"])) * record_s / 3600.0
        return change >= MIN_RELATIVE_EFFECT * big


REGISTRY: dict[str, PhysicsHypothesis] = {}


def register(hypothesis: PhysicsHypothesis) -> PhysicsHypothesis:
    """Add a hypothesis to the registry (its `name` must be new)."""
    if not hypothesis.name or hypothesis.name in REGISTRY:
        raise ValueError(f"hypothesis name {hypothesis.name!r} is empty or already registered")
    REGISTRY[hypothesis.name] = hypothesis
    return hypothesis


for _cls in (ActuatorLag, AsymmetricStiction, ValveCharacteristic, ExternalDisturbance, TimeVaryingFriction):
    register(_cls())


def get(names: Any = None) -> list[PhysicsHypothesis]:
    """Registered hypotheses by name (all when ``names`` is None)."""
    if names is None:
        return list(REGISTRY.values())
    out = []
    for nm in names:
        if nm not in REGISTRY:
            raise DataError(f"unknown hypothesis {nm!r}; choose from {', '.join(REGISTRY)}")
        out.append(REGISTRY[nm])
    return out
