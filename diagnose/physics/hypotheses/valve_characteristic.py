"""Installed characteristic: an operating-point dependent gain between stem and flow."""

from __future__ import annotations

import math

import numpy as np

from ..model import Stage, Structure, train_sse, with_times
from ..search import (best_of, coarse_starts, global_sj, joint_process_polish, refine_sj, refit_dynamics,
                      sj_local, with_sj)
from ..valve import characteristic
from .base import PROCESS_SIDE, PhysicsHypothesis


class ValveCharacteristic(PhysicsHypothesis):
    """Installed characteristic: operating-point dependent gain, flow ~ (e^(c y) - 1), R = e^c."""

    name = "valve_characteristic"
    param_names = ("rangeability_R", "gain_ratio_80_20")
    side = PROCESS_SIDE
    n_extra = 1
    description = "operating-point dependent gain (installed characteristic)"

    def _search(self, stage, baseline):
        reference = baseline.structure
        # The gain change distorts the plain fit's S and J: for the most promising exponents the
        # valve is searched again globally.
        cs = [c for c in np.linspace(-4.0, 4.5, 18) if abs(c) > 1e-6]
        starts = []
        for origin in [reference] + ([baseline.identified] if baseline.identified is not None else []):
            S, J = origin.S_up_pct, origin.J_up_pct
            pairs = sj_local(S, J, s_span=0.06, n_s=7, j_span=0.2, n_j=3, j_zero=False)
            cands = [with_sj(origin, s, j).replace(char_c=float(c)) for c in cs for s, j in pairs]
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
        return self._polish(stage, min(results, key=lambda t: t[0])[1])

    def _polish(self, stage, best, again=False):
        best, _ = refine_sj(stage, best, s_span=0.04, n_s=9, j_span=0.15, n_j=5, both_f0=False)
        best, _ = refit_dynamics(stage, best, rounds=1)
        if best.char_c:
            best = joint_process_polish(stage, best, "char_c")
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
        output-error cost a needle in c and the time constant (a modest error in either costs
        orders of magnitude more than the true model), so that a coarse grid of c and dynamics
        starts nowhere near it."""
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
        lin = with_sj(reference, 0.0, 0.0).replace(char_c=float(c), y0_pct=None, xs0_pct=None)
        cands = [lin.replace(process=with_times(reference.process, tau_s=t, delay_s=d * stage.ts_s))
                 for t in np.geomspace(stage.ts_s, T / 6.0, 40) for d in range(16)]
        best, _ = best_of(stage, cands)
        best, _ = refit_dynamics(stage, best, rounds=2)
        span = float(np.ptp(stage.x[: stage.n_fit]))
        S_grid = np.geomspace(0.2, max(0.8 * span, 0.3), 40)
        cands = [with_sj(best, s, s * r, f) for s in S_grid for r in np.linspace(0.0, 1.5, 13) for f in (1, -1)]
        return best_of(stage, cands)[0]

    def _params(self, struct, reference, stage, coef):
        c = struct.char_c
        # slope of the characteristic at 80 % over that at 20 % of travel: e^(0.6 c)
        return {"rangeability_R": math.exp(c), "gain_ratio_80_20": math.exp(0.6 * c)}
