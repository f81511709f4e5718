"""Time-varying friction: S and J drifting linearly over the record (wear, temperature) or changing
in one step (a maintenance action, a trip, a change of service)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from ..model import Candidates, Pool, Stage, Structure, mesh, train_sse
from ..search import (best_distinct, best_of, dynamics_starts, fine_valve, fit_initial_state, keyword_columns,
                      global_sj, profile_ratio, refit_dynamics, valve_dynamics_starts, y0_options)
from .base import MIN_RELATIVE_EFFECT, VALVE_SIDE, PhysicsHypothesis

#: the largest J/S the drift and step grids start from: the plain fit's own J/S up to this (a
#: valve that overshoots far, J near 2 S, is searched from its own ratio; the polish rounds move J
#: too little to get there from a lower one)
MAX_J_OVER_S = 2.0
#: J/S of the grid that fits the valve on each side of a step
SIDE_RATIOS = tuple(np.round(np.arange(0.0, MAX_J_OVER_S + 1e-9, 0.1), 2))
#: the step grid keeps pairs (S before, S after) with the smaller at most 1/this and the larger at
#: least this times the plain fit's S
STEP_BRACKET = 0.75


class TimeVaryingFriction(PhysicsHypothesis):
    """S and J drifting linearly over the record (wear, temperature), or changing in one step at a
    time the search finds (a maintenance action, a trip)."""

    name = "time_varying_friction"
    param_names = ("S_start_pct", "J_start_pct", "dS_pct_per_h", "dJ_pct_per_h", "S_end_pct", "J_end_pct",
                   "change_from_s", "change_for_s")
    side = VALVE_SIDE
    n_extra = 2
    description = "friction changing over the record"

    def n_params(self, struct) -> int:
        # a step adds its time to the two sizes of the change
        return self.n_extra + (1 if is_step(struct) else 0)

    def _search(self, stage, baseline):
        reference = baseline.structure
        # S at the start and at the end of the fitted span, both on fine geometric grids (an
        # output-error stiction fit is sharp in S: a few per cent move every slip), around the
        # plain fits' S (a drifting valve's plain fit sits near its mid-span S); J drifts alike
        centres = {round(max(reference.S_up_pct, 0.2), 6)}
        if baseline.identified is not None and baseline.identified.S_up_pct > 0.2:
            centres.add(round(baseline.identified.S_up_pct, 6))
        drift = self._drift_search(stage, baseline, reference, centres)
        step = self._step_search(stage, reference, centres)
        return best_of(stage, [drift, step])[0]

    def _drift_search(self, stage, baseline, reference, centres):
        """S and J drifting linearly from the first sample to the last."""
        T = max(stage.n_fit * stage.ts_s, stage.ts_s)
        best = self._grid(stage, reference, centres, T)
        if stage.name == "valve":
            return fine_valve(stage, best, "dS_pct_per_s")
        cost = best_of(stage, [best])[1]
        # from a joint grid of drifting valves x dynamics (the plain fit's process can be far off,
        # mimicking part of the drift, and then the search above starts outside the drift's
        # basin); the grid's two best dynamics (a third rarely wins; docs/missing-physics.md)
        for st in _coarse_drift_starts(stage, reference, k=2):
            best, cost = self._restart(stage, st, {round(st.S_up_pct, 6)}, T, best, cost)
        # valve and process co-adapt: search the drifting valve's own process globally, then the
        # drift again from it (around the drift's mid-span S and the reference's); from the best
        # other dynamics only (the second best adds little)
        mid = 0.5 * T
        for st in dynamics_starts(stage, best, k=1):
            around = centres | {round(max(best.friction_at(mid)[0], 0.2), 6)}
            best, cost = self._restart(stage, st, around, T, best, cost)
        return best

    def _restart(self, stage, st, around, T, best, cost):
        """The drift search again from ``st`` (its drift kept as a candidate): the better of its
        result and (best, cost)."""
        b = self._grid(stage, st.replace(dS_pct_per_s=0.0, dJ_pct_per_s=0.0), around, T, extra=[st])
        b, c = best_of(stage, [b])
        return (b, c) if c < cost else (best, cost)

    def _step_search(self, stage, reference, centres):
        """S and J changing in one step: a grid of the step's time (every 5 % of the scored
        training span) x S before it (0.35-2.5 times the plain fit's) x S after it (0.37-2.7 times
        that; both geometric, 7 % steps; only pairs that bracket the plain fit's S) x three J/S,
        from the reference's start; the best few distinct steps get their initial state fitted,
        the best two are polished (`_step_rounds`). A step is not a steep drift: the valve is the
        same before and after it, and a linear drift fitted to a step is wrong on both sides and
        worse beyond the fitted span."""
        ts = stage.ts_s
        T = max(stage.n_fit * ts, ts)
        # a step before the first scored sample cannot be told from the valve's start state
        t_lo = float(np.argmax(stage.train)) * ts
        times = np.round((t_lo + (T - t_lo) * np.arange(0.05, 0.951, 0.05)) / ts) * ts
        # the plain fit sits between the friction before and after the step, near the longer
        # side's: S before it from a third to two and a half times the plain fit's, S after it
        # from a third to nearly three times that, the pair bracketing the plain fit's S (within a
        # quarter either way)
        m_start = np.exp(np.arange(math.log(0.35), math.log(2.5), 0.07))
        q = np.exp(np.concatenate([np.arange(-1.0, -0.035, 0.07), np.arange(0.07, 1.01, 0.07)]))
        mm, qm = (a.ravel() for a in np.meshgrid(m_start, q))
        brackets = (np.minimum(mm, mm * qm) <= 1.0 / STEP_BRACKET) & (np.maximum(mm, mm * qm) >= STEP_BRACKET)
        pairs = np.flatnonzero(brackets)
        r0 = min(reference.J_up_pct / max(reference.S_up_pct, 1e-9), MAX_J_OVER_S)
        parts = [reference]
        for Sc in centres:
            # a no-offset valve (J = S) among the J/S: a plain fit over both sides of a step
            # compromises its J/S, and the polish rounds move J too little to get back
            t, ip, r = mesh(times, pairs, sorted({round(r0, 3), 0.5, 1.0}))
            s0, qq = Sc * mm[ip.astype(int)], qm[ip.astype(int)]
            parts.append(Candidates(reference, S_up_pct=s0, S_dn_pct=s0, J_up_pct=s0 * r, J_dn_pct=s0 * r,
                                    dS_pct_per_s=s0 * (qq - 1.0) / ts, dJ_pct_per_s=s0 * r * (qq - 1.0) / ts,
                                    drift_from_s=t, drift_for_s=ts))
        cands = Pool(parts)
        sse = train_sse(stage, cands)
        tops = best_distinct(cands, sse, lambda c: (round(c.drift_from_s / (0.05 * T)),
                                                    round(math.log(max(c.S_up_pct, 1e-3)) / 0.07),
                                                    round(math.log(max(step_after(c)[0], 1e-3)) / 0.07)), 6)
        # each with its own start state, ranked by the training SSE that fit returns
        fitted = sorted((fit_initial_state(stage, c) for c in tops if is_step(c)), key=lambda cs: cs[1])
        if not fitted:
            return reference
        starts = [c for c, _ in fitted[:2]]
        # the valve on each side of the best step fitted as a plain valve on that side alone (the
        # grid's two J/S and the rounds' small steps stop short of a J far from the plain fit's,
        # and of the S a clean stem pins to a twentieth of a per cent)
        sides = _side_fits(stage, starts[0])
        if sides is not None:
            starts.append(sides)
        best, _ = best_of(stage, [self._step_rounds(stage, c) for c in starts])
        return best

    @staticmethod
    def _step_rounds(stage, best):
        """Local polish of a step: its time with S before and after it, then J before and after,
        then the initial state and (OP -> PV) the dynamics; twice, the second finer."""
        ts = stage.ts_s
        T = max(stage.n_fit * ts, ts)
        for rnd in range(2):
            span = 0.06 if rnd == 0 else 0.02
            t0 = best.drift_from_s
            (s0, j0), (s1, j1) = (best.S_up_pct, best.J_up_pct), step_after(best)
            dt = (0.05 if rnd == 0 else 0.01) * T
            tt, ms, mq = mesh(np.clip(np.round((t0 + np.linspace(-dt, dt, 11)) / ts) * ts, ts, T),
                              1.0 + np.linspace(-span, span, 7), 1.0 + np.linspace(-span, span, 7))
            r0, r1 = j0 / max(s0, 1e-9), j1 / max(s1, 1e-9)
            grid = Candidates(best, drift_from_s=tt, S_up_pct=s0 * ms, S_dn_pct=s0 * ms, J_up_pct=r0 * s0 * ms,
                              J_dn_pct=r0 * s0 * ms, dS_pct_per_s=(s1 * mq - s0 * ms) / ts,
                              dJ_pct_per_s=(r1 * s1 * mq - r0 * s0 * ms) / ts)
            best, _ = best_of(stage, [grid, best])
            (s0, j0), (s1, j1) = (best.S_up_pct, best.J_up_pct), step_after(best)
            j0, j1 = max(j0, 0.02), max(j1, 0.02)
            a, b = mesh(1.0 + np.linspace(-3 * span, 3 * span, 9), 1.0 + np.linspace(-3 * span, 3 * span, 9))
            grid = Candidates(best, J_up_pct=j0 * a, J_dn_pct=j0 * a, dJ_pct_per_s=(j1 * b - j0 * a) / ts)
            best, _ = best_of(stage, [grid, best])
            if rnd == 1:
                # the grids above step the time by several samples and S by over half a per cent; a
                # slip's timing resolves one sample, and S on a clean stem a twentieth of a per cent
                best = _step_time_samples(stage, best, 6)
                best = _step_sizes_fine(stage, best)
            best, _ = fit_initial_state(stage, best, local=True)
            if not stage.fixed_dynamics:
                best, _ = refit_dynamics(stage, best, rounds=1)
        return best

    def _polish(self, stage, best, again=False):
        if is_step(best):
            return self._step_rounds(stage, best)
        if stage.name == "valve":
            return fine_valve(stage, best, "dS_pct_per_s", profile=not again)
        return self._rounds(stage, best, max(stage.n_fit * stage.ts_s, stage.ts_s))

    def _grid(self, stage, reference, centres, T, extra=()):
        """The drift search around one plain start: S at the start and the end of the fitted span
        on fine geometric grids around each of ``centres`` (J drifting alike), the initial state of
        the best few distinct drifts, then local polish rounds with the dynamics refit. ``extra``:
        further candidates to keep (e.g. the drift the search restarts from)."""
        m_start = np.exp(np.arange(math.log(0.55), math.log(1.35), 0.03))
        q_end = np.exp(np.concatenate([np.arange(-0.6, -0.035, 0.03), np.arange(0.04, 0.61, 0.03)]))
        r0 = min(reference.J_up_pct / max(reference.S_up_pct, 1e-9), MAX_J_OVER_S)
        # J/S 0 (a deadband) among them: the polish rounds scale J and cannot reach 0 from a band
        ratios = sorted({round(r0, 3), 0.0, 0.3, 0.6, 0.9})
        parts = [reference] + list(extra)
        y0s = y0_options(stage, reference)
        for Sc in centres:
            s0, q, r, f, iy = mesh(Sc * m_start, q_end, ratios, (1, -1), range(len(y0s)))
            parts.append(Candidates(reference, S_up_pct=s0, S_dn_pct=s0, J_up_pct=s0 * r, J_dn_pct=s0 * r, f0=f,
                                    dS_pct_per_s=s0 * (q - 1.0) / T, dJ_pct_per_s=s0 * r * (q - 1.0) / T,
                                    **keyword_columns(y0s, iy, reference)))
        cands = Pool(parts)
        sse = train_sse(stage, cands)
        # the cost is rough (the valve's initial state and every slip's timing): the best few
        # distinct drifts each get their initial state fitted. Distinct in J/S too: scored from the
        # reference's start, the reference's own J/S tops every cell of (S, rate), while the true
        # J/S, whose start state differs, only shows its lead once that state is fitted
        tops = best_distinct(cands, sse, lambda c: (round(math.log(max(c.S_up_pct, 1e-3)) / 0.06),
                                                     round(c.dS_pct_per_s * T / max(c.S_up_pct, 1e-9) / 0.06),
                                                     round(c.J_up_pct / max(c.S_up_pct, 1e-9), 1)), 8)
        cands = []
        for c in tops:
            c, _ = fit_initial_state(stage, c)
            cands += [c.replace(S_up_pct=c.S_up_pct * m, S_dn_pct=c.S_up_pct * m,
                                dS_pct_per_s=(c.S_up_pct + c.dS_pct_per_s * T) * q / T - c.S_up_pct * m / T)
                      for m in (0.985, 1.0, 1.015) for q in (0.985, 1.0, 1.015)]
        best, _ = best_of(stage, cands + tops)
        return self._rounds(stage, best, T)

    @staticmethod
    def _rounds(stage, best, T):
        """Local polish rounds: S at the start with the drift rate, then J with its rate, then the
        dynamics; twice, the second finer."""
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
        record_s = stage.n * stage.ts_s
        t0 = struct.drift_from_s
        length = min(struct.drift_for_s, max(record_s - t0, 0.0))
        S_end, J_end = struct.friction_at(record_s)
        return {"S_start_pct": struct.S_up_pct, "J_start_pct": struct.J_up_pct,
                "dS_pct_per_h": struct.dS_pct_per_s * 3600.0, "dJ_pct_per_h": struct.dJ_pct_per_s * 3600.0,
                "S_end_pct": S_end, "J_end_pct": J_end, "change_from_s": t0, "change_for_s": length}

    def shown(self, params):
        # a step's rates are those of its one sample (thousands of % per hour) and its length is
        # that sample: the friction before and after it and its time say it all. A drift starts
        # at the record's start, a step never does
        if params.get("change_from_s", 0.0) > 0.0:
            keep = ("S_start_pct", "J_start_pct", "S_end_pct", "J_end_pct", "change_from_s")
            return {k: params[k] for k in keep if k in params}
        return dict(params)

    def material(self, params, record_s, residual_rms):
        # S or J changes by at least MIN_RELATIVE_EFFECT of the starting S over the record (a step
        # by its size, however steep)
        big = max(params["S_start_pct"], 0.2)
        change = max(abs(params["S_end_pct"] - params["S_start_pct"]),
                     abs(params["J_end_pct"] - params["J_start_pct"]))
        return change >= MIN_RELATIVE_EFFECT * big


def is_step(struct) -> bool:
    """Whether a structure's friction changes in one step (a drift one sample long)."""
    return bool(math.isfinite(struct.drift_for_s)) and (struct.dS_pct_per_s != 0.0 or struct.dJ_pct_per_s != 0.0)


def step_after(struct) -> tuple[float, float]:
    """S and J after a step; S and J themselves where there is none."""
    if not is_step(struct):
        return struct.S_up_pct, struct.J_up_pct
    return struct.friction_at(math.inf)


def _side_fits(stage: Stage, step: Structure) -> Structure | None:
    """The step with the friction before and after it each fitted as a plain valve (`global_sj`:
    S and J/S on a fine grid, `profile_ratio`, and on the valve stage `fine_valve`) on the training
    samples of its own side, a margin of 3 % of the fitted span away from the step; None when a
    side is shorter than a tenth of the training part. The dynamics are the step's."""
    ts = stage.ts_s
    k = int(round(step.drift_from_s / ts))
    margin = max(int(0.03 * stage.n_fit), 1)
    idx = np.arange(stage.n)
    n_tr = int(stage.train.sum())
    plain = step.plain_part()
    fitted = []
    for side in (idx < k - margin, idx > k + margin):
        train = stage.train & side
        if int(train.sum()) < 0.1 * n_tr:
            return None
        sub = dataclasses.replace(stage, train=train)
        side_fit = global_sj(sub, plain, ratios=SIDE_RATIOS)
        # the valve's start state and J trade off: J/S again with the start fitted at each value
        side_fit = profile_ratio(sub, side_fit, None, max_ratio=MAX_J_OVER_S)
        if stage.name == "valve":
            side_fit = fine_valve(sub, side_fit, profile=False)
        fitted.append(side_fit)
    (s0, j0), (s1, j1) = ((f.S_up_pct, f.J_up_pct) for f in fitted)
    cand = step.replace(S_up_pct=s0, S_dn_pct=s0, J_up_pct=j0, J_dn_pct=j0, f0=fitted[0].f0,
                        dS_pct_per_s=(s1 - s0) / ts, dJ_pct_per_s=(j1 - j0) / ts)
    return fit_initial_state(stage, cand)[0]


def _step_time_samples(stage: Stage, best: Structure, k: int) -> Structure:
    """The step's time moved by up to ``k`` samples either way (sizes held): the better-trained."""
    ts = stage.ts_s
    T = max(stage.n_fit * ts, ts)
    times = np.clip(best.drift_from_s + ts * np.arange(-k, k + 1), ts, T)
    return best_of(stage, [Candidates(best, drift_from_s=times), best])[0]


def _step_sizes_fine(stage: Stage, best: Structure) -> Structure:
    """S after the step, then S before it, each over +-1.5 % in 0.05 % steps (J held)."""
    ts = stage.ts_s
    m = 1.0 + np.linspace(-0.015, 0.015, 61)
    s0, (s1, _) = best.S_up_pct, step_after(best)
    best, _ = best_of(stage, [Candidates(best, dS_pct_per_s=(s1 * m - s0) / ts), best])
    s1 = step_after(best)[0]
    grid = Candidates(best, S_up_pct=s0 * m, S_dn_pct=s0 * m, dS_pct_per_s=(s1 - s0 * m) / ts)
    return best_of(stage, [grid, best])[0]


def _coarse_drift_starts(stage: Stage, reference: Structure, k: int = 3) -> list[Structure]:
    """Drifting valves (S at the start within 0.5-1.7 of the reference's in 4 % steps, S at the end
    of the fitted span 0.45-2.2 times that in 8 % steps, J/S 0.3-0.8, drifting alike) x dynamics.
    The drift's basin is a few per cent wide in both S and its rate: a starting S a few per cent
    off, or a rate some ten per cent off, moves slips and costs many times the noise even with the
    true dynamics."""
    T = max(stage.n_fit * stage.ts_s, stage.ts_s)
    S = max(reference.S_up_pct, 0.2)
    valves = [{"S_up_pct": s0, "S_dn_pct": s0, "J_up_pct": s0 * r, "J_dn_pct": s0 * r,
               "dS_pct_per_s": s0 * (q - 1.0) / T, "dJ_pct_per_s": s0 * r * (q - 1.0) / T}
              for s0 in S * np.exp(np.arange(math.log(0.5), math.log(1.7), 0.04))
              for q in np.exp(np.arange(math.log(0.45), math.log(2.2), 0.08)) for r in (0.3, 0.55, 0.8)]
    return valve_dynamics_starts(stage, reference, valves, k)
