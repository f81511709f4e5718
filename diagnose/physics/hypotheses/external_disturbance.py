"""External disturbance: an oscillating load not caused by the valve (an additive sinusoid)."""

from __future__ import annotations

import math
import warnings

import numpy as np

from ...errors import StictionError, StictionWarning
from ..model import Stage, Structure, predict
from ..search import (best_of, coarse_starts, fit_initial_state, global_sj, grid_baseline, joint_process_polish,
                      refine_sj, refit_dynamics)
from .base import MIN_LOAD_SHARE, PROCESS_SIDE, PhysicsHypothesis, PlainModel


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

    def candidate_periods(self, stage: Stage, baseline: PlainModel) -> list[float]:
        """Periods of the largest spectral peaks away from the limit cycle's harmonics: of the plain
        model's residual, and of OP (a well-rejected load shows in OP more than in the residual,
        because the plain fit bends to follow it)."""
        reference = baseline.structure
        if baseline.residual is not None:
            r = np.asarray(baseline.residual, float)
        else:
            y_hat, _, _ = predict(stage, reference)
            r = stage.y - y_hat
        n = stage.n_fit
        tr = stage.train[:n]
        T = tr.sum() * stage.ts_s
        plc = baseline.limit_cycle_period_s
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
        follow the load through OP, and a load added to it alone barely helps at any period (the
        true period can rank low on the plain fit and first on the grid)."""
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

    def _search(self, stage, baseline):
        reference = baseline.structure
        periods = self.candidate_periods(stage, baseline)
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
            # can hold a load estimate that leads it nowhere, while a worse start's load leads the
            # fitting stage to the basin
            best = best_of(stage, [best] + [self._backfit(stage, st, rounds=2) for st in top])[0]
        best = self._polish(stage, best)
        if best.period_s is not None:
            if not stage.fixed_dynamics:
                # the polished load is a better estimate to take out: backfit once more (one round:
                # from a polished start later rounds find little more)
                bf = self._backfit(stage, best, rounds=1)
                if best_of(stage, [bf])[1] < best_of(stage, [best])[1]:
                    best = joint_process_polish(stage, bf, "period_s")
        return best

    def _polish(self, stage, best, again=False):
        best, _ = refine_sj(stage, best, s_span=0.04, n_s=9, j_span=0.15, n_j=5)
        if best.period_s is not None:
            best = joint_process_polish(stage, best, "period_s")
        return best

    @staticmethod
    def _backfit(stage: Stage, start: Structure, rounds: int = 2) -> Structure:
        """Backfitting: take the fitted load out of PV, fit the plain valve and process on what is
        left with the fitting stage, put the load back; repeat (``rounds`` times at most, fewer
        when the fitting stage returns the same plain fit again). A strong load bends a joint
        search of valve, process and load far off; the fitting stage's own global search on the
        cleaned PV does not see it. The first round gains the most: once the load is roughly out,
        the plain fit lands in its basin and later rounds only refine it."""
        from ...fit import fit_hammerstein

        n = stage.n_fit   # the samples after the training part are not scored: not simulated either
        t = np.arange(n) * stage.ts_s
        w = 2.0 * np.pi / start.period_s
        best, best_c = start, best_of(stage, [start])[1]
        cur = start
        last = None
        for _ in range(rounds):
            _, _, coef = predict(stage, cur)
            y = stage.y[:n] - coef[-2] * np.sin(w * t) - coef[-1] * np.cos(w * t)
            try:
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore", StictionWarning)
                    res = fit_hammerstein(stage.x[:n], y, stage.ts_s, train=stage.train[:n],
                                          gain_sign=stage.gain_sign or None, surface=False)
            except (StictionError, ValueError, np.linalg.LinAlgError):
                break
            if last is not None and _same_plain(res, last):
                break   # the plain fit of the last round again: further rounds change little
            last = res
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
        # sinusoid far below the noise cannot be what the plain model misses (on a record without
        # the effect a small sinusoid fits the slow random-walk load and would otherwise be named)
        return 0.5 * params["amplitude"] ** 2 >= MIN_LOAD_SHARE * residual_rms ** 2

    @staticmethod
    def at_limit_cycle(period_s: float | None, limit_cycle_period_s: float | None) -> bool:
        """Whether a load period sits on the loop's own oscillation period (within 8 %)."""
        if not period_s or not limit_cycle_period_s or not math.isfinite(period_s):
            return False
        return abs(period_s / limit_cycle_period_s - 1.0) < 0.08


def _same_plain(a, b) -> bool:
    """Two fits of the fitting stage agree: S and J within 1 % of S, the same direction, lags
    within 2 %, the same dead time and kind."""
    tol = 0.01 * max(a.S_pct, b.S_pct, 1e-9)
    pa, pb = a.process, b.process
    return (abs(a.S_pct - b.S_pct) <= tol and abs(a.J_pct - b.J_pct) <= tol and a.f0 == b.f0
            and pa.kind == pb.kind and pa.delay_s == pb.delay_s
            and abs(pa.tau_s - pb.tau_s) <= 0.02 * max(pa.tau_s, pb.tau_s, 1e-9)
            and abs(pa.tau2_s - pb.tau2_s) <= 0.02 * max(pa.tau2_s, pb.tau2_s, 1e-9))
