"""Actuator lag: a first-order lag of the stem after the friction element (a positioner, the stem's
own motion), or, on the valve stage, before it (a pneumatic actuator's pressure, which the friction
then resists), with a dead time of whole samples on the valve stage."""

from __future__ import annotations

import math

import numpy as np

from ..model import Candidates, Structure, mesh, train_sse, with_times
from ..search import (best_of, fine_valve, global_sj, keyword_columns, refine_sj, refit_dynamics, sj_local,
                      with_sj, y0_options)
from .base import VALVE_SIDE, PhysicsHypothesis


#: Shortest lag before the friction searched, in samples: a healthy pneumatic actuator's own
#: pressure lag is a second or two, and a shorter lag the sampling hardly resolves
PRE_MIN_SAMPLES = 2.0


class ActuatorLag(PhysicsHypothesis):
    """First-order lag of the stem after the friction element (pneumatic actuator, positioner).

    On the valve stage (OP -> MV) a dead time of whole samples is searched with it (a positioner's
    or the logging's delay), and the lag may also sit before the friction: OP drives the actuator's
    pressure through the lag and the friction resists the force, so the slips come late and whole
    rather than smoothed (``lag_before_friction`` 1). From OP/PV alone a lag after the friction is
    searched only; on the loop stage a dead time is part of the process already.
    """

    name = "actuator_lag"
    param_names = ("tau_s", "dead_time_s", "S_pct", "J_pct", "lag_before_friction")
    side = VALVE_SIDE
    n_extra = 2
    description = "first-order lag of the stem after a slip"

    def _search(self, stage, baseline):
        reference = baseline.structure
        ts = stage.ts_s
        S, J = reference.S_up_pct, reference.J_up_pct
        taus = ts * np.array([0.25, 0.5, 1.0, 1.5, 2.0, 3.0, 4.0, 6.0, 8.0, 12.0, 16.0])
        delays = (0, 1, 2, 3) if stage.name == "valve" else (None,)

        def with_delay(s: Structure, d) -> Structure:
            if d is None:
                return s
            return s.replace(process=with_times(s.process, delay_s=d * ts))

        # J relative to S over its whole range: a lag changes the plain fit's J the most
        pairs = [(S * m, S * m * r) for m in (0.85, 0.93, 1.0, 1.07, 1.15)
                 for r in (0.0, 0.25, 0.5, 0.75, 1.0, 1.25)] + [(S, J)]
        combos = [(float(t), d) for t in taus for d in delays]
        cands = [with_delay(with_sj(reference, s, j, f), d).replace(tau_lag_s=t)
                 for t, d in combos for s, j in pairs for f in (1, -1)]
        sse = train_sse(stage, cands).reshape(len(combos), -1)
        results = []
        if stage.name == "valve":
            # OP -> MV has no process: the lag x valve grid is cheap enough to search globally
            # (a lag moves the plain fit's S and J far)
            span = float(np.ptp(stage.x[: stage.n_fit]))
            S_grid = np.exp(np.arange(math.log(0.2), math.log(max(0.8 * span, 0.3)) + 1e-9, math.log1p(0.03)))
            y0s = y0_options(stage, reference)
            # behind a lag before the friction the input creeps over the band and each slip is whole:
            # J/S comes out small (the stem's own stop after a jump), so small ratios are stepped finely
            for field, grid, ratios in (("tau_lag_s", taus, (0.0, 0.2, 0.4, 0.6, 0.8, 0.9, 1.0, 1.2, 1.45)),
                                        ("tau_pre_s", taus[taus >= PRE_MIN_SAMPLES * ts],
                                         (0.0, 0.04, 0.08, 0.15, 0.25, 0.4, 0.6, 0.8, 1.0, 1.2))):
                t, s, r, f, iy = mesh(grid, S_grid, ratios, (1, -1), range(len(y0s)))
                g = Candidates(reference, S_up_pct=s, S_dn_pct=s, J_up_pct=s * r, J_dn_pct=s * r, f0=f,
                               **{field: t}, **keyword_columns(y0s, iy, reference))
                gs = train_sse(stage, g)
                for k, i in enumerate(np.argsort(gs)[:2]):
                    st = refine_sj(stage, g[int(i)], s_span=0.04, n_s=9, j_span=0.15, n_j=7)[0]
                    st = best_of(stage, [_lag(st, field, getattr(st, field) * m, ts)
                                         for m in (0.8, 0.9, 1.0, 1.12, 1.25)])[0]
                    st, c = best_of(stage, [with_delay(st, d) for d in delays])
                    if field == "tau_pre_s" and k == 0:
                        # polished before the placements are compared: behind a lag before the
                        # friction the cost is a comb in S whose teeth the grid's 3 % steps straddle
                        st = fine_valve(stage, st, field, profile=False)
                        c = best_of(stage, [st])[1]
                    results.append((c, st))
        # a lag changes which slips a plain fit had to fake: search the valve again for the best few
        for i in np.argsort(sse.min(axis=1))[:1 if results else 3]:
            st = cands[int(i) * sse.shape[1] + int(np.argmin(sse[i]))]
            st = global_sj(stage, st)
            st, c = refit_dynamics(stage, st, rounds=1)
            results.append((c, st))
        return self._polish(stage, min(results, key=lambda t: t[0])[1])

    def _polish(self, stage, best, again=False):
        field = "tau_pre_s" if best.tau_pre_s > 0 else "tau_lag_s"
        t0 = getattr(best, field)
        pairs = sj_local(best.S_up_pct, best.J_up_pct, s_span=0.04, n_s=9, j_span=0.15, n_j=5)
        cands = [_lag(with_sj(best, s, j), field, t0 * m, stage.ts_s)
                 for m in (0.75, 0.87, 1.0, 1.15, 1.3) for s, j in pairs]
        cands.append(best)
        best, _ = best_of(stage, cands)
        best, _ = refit_dynamics(stage, best, rounds=1)
        best, _ = refine_sj(stage, best, s_span=0.02, n_s=9, j_span=0.06, n_j=5, both_f0=False)
        if stage.name == "valve":
            best = fine_valve(stage, best, field, profile=not again)
            if field == "tau_pre_s" and best.tau_pre_s < PRE_MIN_SAMPLES * stage.ts_s:
                best, _ = refine_sj(stage, _lag(best, field, best.tau_pre_s, stage.ts_s), s_span=0.02, n_s=9,
                                    j_span=0.06, n_j=5, both_f0=False)
        return best

    def shown(self, params):
        # where the lag sits is said only where it is the less usual place, before the friction
        if params.get("lag_before_friction", 0.0):
            return dict(params)
        return {k: v for k, v in params.items() if k != "lag_before_friction"}

    def _params(self, struct, reference, stage, coef):
        dead = struct.process.delay_s if stage.name == "valve" else 0.0
        before = struct.tau_pre_s > 0
        return {"tau_s": struct.tau_pre_s if before else struct.tau_lag_s, "dead_time_s": float(dead),
                "S_pct": struct.S_up_pct, "J_pct": struct.J_up_pct, "lag_before_friction": 1.0 if before else 0.0}


def _lag(struct: Structure, field: str, tau_s: float, ts_s: float) -> Structure:
    """``struct`` with its actuator lag ``field`` (``tau_lag_s`` or ``tau_pre_s``) set to ``tau_s``;
    a lag before the friction no shorter than `PRE_MIN_SAMPLES`."""
    if field == "tau_pre_s":
        tau_s = max(tau_s, PRE_MIN_SAMPLES * ts_s)
    return struct.replace(**{field: tau_s})
