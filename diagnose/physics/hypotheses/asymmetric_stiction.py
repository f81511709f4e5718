"""Asymmetric stiction: separate (S, J) when opening and when closing."""

from __future__ import annotations

import math

import numpy as np

from ...valve_fit import delayed, slip_reading
from ..model import Candidates, Stage, Structure, mesh, train_sse
from ..search import (best_distinct, best_of, keyword_columns, polish, refit_dynamics, valve_dynamics_starts,
                      y0_options)
from .base import MIN_RELATIVE_EFFECT, VALVE_SIDE, PhysicsHypothesis


class AsymmetricStiction(PhysicsHypothesis):
    """Separate (S, J) when opening and when closing."""

    name = "asymmetric_stiction"
    param_names = ("S_open_pct", "J_open_pct", "S_close_pct", "J_close_pct")
    side = VALVE_SIDE
    n_extra = 2
    description = "different stiction opening and closing"

    def _search(self, stage, baseline):
        reference = baseline.structure
        # Opening reversals depend on S_open, closing ones on S_close: the cost nearly separates, so
        # wide fine one-direction scans (coordinate descent) find both.
        S = max(reference.S_up_pct, 0.2)
        wide = np.exp(np.arange(math.log(0.3), math.log(1.9), math.log1p(0.02)))
        # A plain valve (and, from OP/PV alone, other process dynamics) can mimic asymmetry: a
        # coarse asymmetric-valve (x dynamics) grid gives more starting points.
        starts = [reference] + _coarse_asym_starts(stage, reference)
        # a global (S_open, S_close, J ratios) grid with the reference's dynamics is cheap (one
        # compiled pass over the grid); from OP/PV the coarse grid's one J/S for both sides can
        # miss the basin, which a J/S of its own on each side reaches. The basin is a few per cent
        # wide in S on each side and the grid steps 7 %: its best 8 points each start a scan (the
        # best two can both sit beside another basin)
        g_s = S * np.exp(np.arange(math.log(0.3), math.log(1.9), math.log1p(0.07)))
        y0s = y0_options(stage, reference)
        ratios = (0.1, 0.4, 0.7, 1.0)
        su, sd, ru, rd, f, iy = mesh(g_s, g_s, ratios, ratios, (1, -1), range(len(y0s)))
        g = Candidates(reference, S_up_pct=su, S_dn_pct=sd, J_up_pct=su * ru, J_dn_pct=sd * rd, f0=f,
                       **keyword_columns(y0s, iy, reference))
        gs = train_sse(stage, g)
        grid_starts = best_distinct(g, gs, lambda c: (round(c.S_up_pct, 6), round(c.S_dn_pct, 6)), 8)
        n_first = len(starts) + 2
        starts += grid_starts
        results = []
        for st in starts:
            b = self._scan(stage, st, S, wide)
            results.append((best_of(stage, [b])[1], b))
        best = min(results, key=lambda t: t[0])[1]
        # the best scan of the reference, the coarse grid and the global grid's best two also gets
        # polished from OP/PV: the best scan of all need not polish to the best fit
        first = min(results[:n_first], key=lambda t: t[0])[1]
        if stage.name == "valve":
            # OP -> MV: the cost is sharp in S on both sides and the scans step S by 1-2 %, so a
            # scan's result is no measure of its basin: every one is polished, and the best scan
            # need not polish to the best fit. The bands read off the stem's slips start polishes of
            # their own: with a slip jump J near S the cost is a comb of basins a few tenths of a per
            # cent wide in S on each side, which the grids step over
            best = best_of(stage, [fine_asym(stage, b) for _, b in results]
                           + [fine_asym(stage, r) for r in read_starts(stage, reference)])[0]
        else:
            # OP -> PV: the same fine polish around the process dynamics refit once between: an
            # unpolished scan can train worse than the plain reference and be refused although the
            # asymmetry is there. A polished fit trains better but need not extrapolate better, so
            # this is no net gain on every record (docs/missing-physics.md)
            best = best_of(stage, [self._polish(stage, b) for b in ([best] if first is best else [best, first])])[0]
        return best

    def _polish(self, stage, best, again=False):
        best = fine_asym(stage, best)
        if not stage.fixed_dynamics:
            best, _ = refit_dynamics(stage, best, rounds=1)
            best = fine_asym(stage, best)
        return best

    def _scan(self, stage, start, S, wide):
        best = start
        for rnd in range(2):
            for side in ("up", "dn"):
                Sx = S if rnd == 0 else getattr(best, f"S_{side}_pct")
                Jx = getattr(best, f"J_{side}_pct")
                r = Jx / Sx if Sx > 0 else 0.5
                fs = (1, -1) if rnd == 0 else (best.f0,)
                m, rr, f = mesh(wide if rnd == 0 else 1.0 + np.linspace(-0.08, 0.08, 17),
                                list({r, 0.5 * r, min(1.5 * r, 1.5)}), fs)
                grid = Candidates(best, **{f"S_{side}_pct": Sx * m, f"J_{side}_pct": Sx * m * rr}, f0=f)
                best, _ = best_of(stage, [grid, best])
                Sx = getattr(best, f"S_{side}_pct")
                m, rr = mesh(1.0 + np.linspace(-0.03, 0.03, 5), np.linspace(0.0, 1.5, 31))
                grid = Candidates(best, **{f"S_{side}_pct": Sx * m, f"J_{side}_pct": Sx * rr})
                best, _ = best_of(stage, [grid, best])
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


def _coarse_asym_starts(stage: Stage, reference: Structure, k: int = 3) -> list[Structure]:
    span = float(np.ptp(stage.x[: stage.n_fit]))
    S_grid = np.geomspace(0.3, max(0.8 * span, 0.4), 14)
    valves = [{"S_up_pct": su, "S_dn_pct": su * r, "J_up_pct": su * jr, "J_dn_pct": su * r * jr}
              for su in S_grid for r in (0.35, 0.55, 0.8, 1.25, 1.8, 2.8) for jr in (0.3, 0.75)]
    return valve_dynamics_starts(stage, reference, valves, k)


def read_starts(stage: Stage, reference: Structure) -> list[Structure]:
    """Asymmetric valves read off the recorded stem's slips (`diagnose.valve_fit.slip_reading`, OP
    shifted by the reference's dead time), from the reference's and from the recorded start state.
    Valve stage only (the target is the stem)."""
    if stage.name != "valve":
        return []
    n = stage.n_fit
    reading = slip_reading(delayed(stage.x[:n], int(round(reference.process.delay_s / stage.ts_s))), stage.y[:n])
    if reading is None:
        return []
    return [reference.replace(S_up_pct=su, J_up_pct=ju, S_dn_pct=sd, J_dn_pct=jd, **kw)
            for su, ju, sd, jd in reading.valves() for kw in y0_options(stage, reference)]


def fine_asym(stage: Stage, struct: Structure) -> Structure:
    """Fine polish of an asymmetric valve (on the loop stage with the dynamics held), as
    `fine_valve` for a symmetric one: both S scaled together in 0.5 % steps over +-6 %, then each
    side's S in 0.5 % steps over +-6 % with its J/S over the whole range, then 0.1 % and 1 % steps,
    then the initial state; twice. The one-direction scans step S by 1-2 %, and 1 % off in S moves
    every slip."""
    def one_round(best: Structure) -> Structure:
        m, mj, f = mesh(1.0 + np.linspace(-0.06, 0.06, 25), (0.9, 1.0, 1.1), (1, -1))
        grid = Candidates(best, S_up_pct=best.S_up_pct * m, S_dn_pct=best.S_dn_pct * m,
                          J_up_pct=best.J_up_pct * m * mj, J_dn_pct=best.J_dn_pct * m * mj, f0=f)
        b, _ = best_of(stage, [grid, best])
        for side in ("up", "dn"):
            S0 = max(getattr(b, f"S_{side}_pct"), 0.05)
            m, r = mesh(1.0 + np.linspace(-0.06, 0.06, 25), np.linspace(0.0, 1.45, 30))
            b, _ = best_of(stage, [Candidates(b, **{f"S_{side}_pct": S0 * m, f"J_{side}_pct": S0 * m * r}), b])
            S1, J1 = getattr(b, f"S_{side}_pct"), max(getattr(b, f"J_{side}_pct"), 0.02)
            m, mj = mesh(1.0 + np.linspace(-0.01, 0.01, 21), 1.0 + np.linspace(-0.08, 0.08, 17))
            b, _ = best_of(stage, [Candidates(b, **{f"S_{side}_pct": S1 * m, f"J_{side}_pct": J1 * mj}), b])
        return b

    return polish(stage, struct, one_round)
