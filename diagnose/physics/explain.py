"""`explain`: locate where the baseline model and the recording disagree, name the missing physics,
fit a model that has it, and show the held-out error fall.

Procedure (per stage: ``loop`` OP -> PV always, ``valve`` OP -> MV when the record has the stem
position):

1. baseline: the fitting stage's model (`diagnose.fit.fit_hammerstein`, or `fit_valve` on the
   valve stage) fitted on the first ``train_fraction`` of the record, or the identification the
   caller passes; the whole record is simulated from OP, only the rest is judged;
2. reference: the plain model refit by the shared searches (`diagnose.physics.search`) with the
   valve's initial state;
3. locate the mismatch on the residual of the better-trained plain model (`locate.locate`);
4. every registered hypothesis that applies to the stage is fitted on the training part from the
   reference (`PhysicsHypothesis.fit`); valve-side hypotheses go to the valve stage when MV is
   there (else to the loop stage), process-side ones to the loop stage;
5. every fitted model projected back onto the plain one and refit may improve the reference; the
   hypotheses are then polished from it (`PhysicsHypothesis.refit`);
6. every model is judged on the held-out part by its posterior-predictive mean
   (`posterior.predictive_mean`); a hypothesis is *accepted* when it passes the rules of `_judge`
   (held-out RMSE at least ``min_reduction`` below the reference's and half that below the
   baseline's, a third of both where held-out and training BIC are both at most `DECISIVE_BIC`;
   held-out BIC at most `STRONG_BIC`, training BIC negative, a material effect); a friction step
   inside a stage's training part, after which the valve is the plain valve the held-out part
   confirms, is judged on the training part (`_completed_step`). The
   accepted one with the lowest held-out BIC (one ``n_eff`` per stage, the reference's) is named,
   or, on a stage where an accepted friction step lies inside the training part, the lowest
   training BIC (`_StageRun.best_accepted`);
   none accepted -> ``missing_physics = None``.
"""

from __future__ import annotations

import dataclasses
import math
import warnings
from dataclasses import dataclass, field
from typing import Any, Iterable, Mapping, Sequence

import numpy as np

from .. import quality
from ..controller import controller_action
from ..errors import DataError, StictionWarning
from ..parallel import thread_count, thread_map
from ..plain import percent_change
from ..record import LoopRecord
from ..valve_fit import stem_slips
from .baseline import Baseline, from_hammerstein, from_valve_fit, make_baseline
from .hypotheses import PROCESS_SIDE, VALVE_SIDE, ExternalDisturbance, Fitted, PhysicsHypothesis, PlainModel, get
from .locate import Mismatch, limit_cycle_period, locate, slips_and_reversals
from .model import Stage, Structure, effective_n, predict, rmse
from .posterior import predictive_mean
from .result import (TARGETS, ExplainWarning, Explanation, FigureData, HypothesisResult, OtherStage, StageMismatch,
                     StageModels)
from .search import best_of, fine_valve, fit_initial_state, global_sj, grid_baseline, refine_plain

MIN_SAMPLES = 300
#: held-out BIC difference an augmented model must reach: "strong" evidence on the usual BIC scale
#: (Kass and Raftery 1995: 6-10 strong, > 10 very strong); a difference of a few units is what a
#: better plain fit that the reference search missed can give on a clean record
STRONG_BIC = -6.0
#: held-out and training BIC differences both at or below this are overwhelming evidence (odds of
#: e^30): the held-out RMSE then needs to fall by a third of ``min_reduction`` only
DECISIVE_BIC = -60.0
#: A friction step inside the training part: its valve after the step is the refit plain valve when
#: S agrees within this fraction and J within this fraction of S.
STEP_AFTER_TOLERANCE = 0.03
#: fewer slips of the identified valve than this in the training / held-out part -> warning
#: ``physics.valve_idle``: a valve that stays stuck carries no trace of its friction
MIN_SLIPS_TRAIN, MIN_SLIPS_HELDOUT = 5, 3


def _stage_for(record: LoopRecord, name: str, train: np.ndarray) -> Stage:
    x = np.asarray(record.op, float)
    lo, hi = float(x.min()), float(x.max())
    if lo < 0.0 or hi > 100.0:
        if hi - lo >= 100.0:
            raise DataError(f"OP of {record.name} spans {lo:g}..{hi:g}, more than a valve's 0..100 %; "
                            "scale it to % of span")
        x = x + (50.0 - 0.5 * (lo + hi))
    y = np.asarray(record.pv if name == "loop" else record.mv, float)
    sign = 0
    if name == "loop":
        # the controller's action (from the training part) fixes the process gain's sign: a fit
        # with the other sign explains PV through the controller, not the plant
        tr = np.flatnonzero(train)
        sp = None if record.sp is None else np.asarray(record.sp, float)[tr]
        sign = int(controller_action(np.asarray(record.op, float)[tr], y[tr], record.ts_s, sp=sp).sign)
    return Stage(name=name, x=x, y=y, ts_s=record.ts_s, train=train, gain_sign=sign)


def _burn_in(base: Baseline, stage: Stage) -> int:
    """Samples at the start whose simulation depends on the unknown initial valve and process state:
    through the simulated valve's first reversal plus the process response (5 % .. 40 % of the
    training part)."""
    n_tr = int(stage.train.sum())
    _, revs = slips_and_reversals(base.stem_hat)
    first = int(revs[0]) if revs.size else 0
    resp = 0 if stage.name == "valve" else _response_samples(base.structure, stage.ts_s)
    return int(min(max(first + resp, 0.05 * stage.n), 0.5 * n_tr))


def _response_samples(struct: Structure, ts_s: float) -> int:
    """Samples the process of ``struct`` takes to respond: its dead time and twice its lags."""
    p = struct.process
    return int(round((p.delay_s + 2.0 * (p.tau_s + p.tau2_s)) / ts_s))


#: oscillation periods of the loop after which its valve's and process's initial state no longer
#: show in PV
FORGET_PERIODS = 3


def _state_forgotten(stage: Stage, stem: np.ndarray, struct: Structure) -> int:
    """Samples after which the loop stage's unknown initial state no longer matters: `FORGET_PERIODS`
    periods of the loop's oscillation (from the reversals of ``stem``, the plain model's simulated
    valve) plus the process response; the whole stage where that valve reverses fewer than five
    times. A loop that cycles from the start moves its valve every half-cycle, so where a plain
    valve stays stuck through the first cycles (its friction too large for the small cycles before
    a friction step) the misfit is the valve, not the start."""
    n_fit = stage.n_fit
    _, revs = slips_and_reversals(stem[:n_fit])
    period = limit_cycle_period(stem[:n_fit], stage.x[:n_fit], stage.ts_s) if revs.size >= 5 else None
    if period is None or not math.isfinite(period) or period <= 0:
        return stage.n
    return int(FORGET_PERIODS * period / stage.ts_s + _response_samples(struct, stage.ts_s))


def _response_burn(base: Baseline, stage: Stage) -> int:
    """Samples at the start that depend on the process's unknown initial state (its response time;
    on the valve stage 1 % of the record)."""
    if stage.name == "valve":
        return int(max(0.01 * stage.n, 1))
    resp = _response_samples(base.structure, stage.ts_s)
    return int(min(max(resp, 0.02 * stage.n), 0.5 * int(stage.train.sum())))


def _leading_misfit(stage: Stage, struct: Structure) -> int:
    """End of a leading run of windows the plain model cannot follow (unknown initial valve state).

    The linear coefficients are fitted on the second half of the training part only, so that the
    start cannot bend them; windows whose residual RMS exceeds 2.5 times the median of that half
    are counted from the start (at most half of the training part). On the valve stage the run ends
    by the recorded stem's third slip: after a slip the valve's state follows from OP alone, so a
    plain valve that still cannot follow is another valve (friction that stepped or drifted), and
    its evidence stays in the training part. On the loop stage, where the stem is not recorded, the
    run ends by `_state_forgotten`: a few cycles of the loop's oscillation after the start.
    """
    n_fit = stage.n_fit
    half = np.zeros(stage.n, bool)
    half[n_fit // 2:n_fit] = True
    y_hat, stem_hat, _ = predict(dataclasses.replace(stage, train=half), struct)
    e = stage.y - y_hat
    w = max(20, stage.n // 60)
    rms = np.array([float(np.sqrt(np.mean(e[a:a + w] ** 2))) for a in range(0, n_fit, w)])
    med = float(np.median(rms[len(rms) // 2:])) if rms.size else 0.0
    k = 0
    while k < len(rms) and rms[k] > 2.5 * med:
        k += 1
    cut = int(min(k * w, 0.5 * n_fit))
    if stage.name == "valve" and cut:
        slips = stem_slips(stage.y[:n_fit])
        if np.count_nonzero(slips < cut) >= 3:
            cut = int(slips[2])
    elif cut:
        cut = min(cut, _state_forgotten(stage, stem_hat, struct))
    return cut


def _response_s(struct: Structure, stage: Stage) -> float:
    if stage.name == "valve":
        return 0.0
    p = struct.process
    return float(p.delay_s + 0.5 * (p.tau_s + p.tau2_s))


@dataclass
class _StageRun:
    """One stage's models and results while `explain` runs."""

    stage: Stage
    baseline: Baseline
    base_rmse: float
    reference: Structure
    ref_hat: np.ndarray
    ref_rmse: float
    mismatch: Mismatch
    located_on: str
    loc_hat: np.ndarray
    loc_stem: np.ndarray
    n_eff: float = 1.0   # effective number of independent held-out residuals of the reference
    n_eff_train: float = 1.0   # the same on the training part
    ref_train_rmse: float = float("nan")
    fitted: list = field(default_factory=list)   # (Fitted, y_hat, HypothesisResult)
    steps: set = field(default_factory=set)   # accepted friction steps completed in the training part

    def rank_bic(self, res: HypothesisResult) -> float:
        """Held-out BIC difference of an accepted hypothesis for ranking: the same form as
        ``delta_bic`` but with one ``n_eff`` for the whole stage (the reference's), so that the
        ranking follows the held-out error and the parameter count rather than the colour of each
        model's own residual."""
        n = max(self.n_eff, 1.0)
        ratio = max(res.heldout_rmse, 1e-300) / max(self.ref_rmse, 1e-300)
        return 2.0 * n * math.log(ratio) + res.n_extra * math.log(n)

    def rank_train_bic(self, res: HypothesisResult) -> float:
        """`rank_bic` on the training part (one ``n_eff`` for the stage, the reference's)."""
        n = max(self.n_eff_train, 1.0)
        ratio = max(res.train_rmse, 1e-300) / max(self.ref_train_rmse, 1e-300)
        return 2.0 * n * math.log(ratio) + res.n_extra * math.log(n)

    def best_accepted(self, accepted: list) -> tuple | None:
        """The stage's accepted hypothesis to name (``accepted``: its (stage, Fitted, y_hat,
        HypothesisResult) tuples): the one that explains the held-out part best for its parameters,
        or, where a friction step completed inside the training part is accepted, the training part:
        the held-out part then lies after the step, where any effect that mimics the valve after it
        (an asymmetry between the two friction levels) does as well as the step."""
        if not accepted:
            return None
        if any(t[3].name in self.steps for t in accepted):
            return min(accepted, key=lambda t: self.rank_train_bic(t[3]))
        return min(accepted, key=lambda t: self.rank_bic(t[3]))


def _without_start(stage: Stage, k: int) -> Stage:
    train = stage.train.copy()
    train[:k] = False
    return dataclasses.replace(stage, train=train)


def _baseline_stage(stage: Stage, given: Structure | None, source: str,
                    use_fit_module: bool) -> tuple[Stage, Baseline]:
    """The baseline, and the stage with the start it cannot simulate left out of the training part
    (the baseline refit on what is left when it was fitted here)."""
    base = make_baseline(stage, given, source=source, use_fit_module=use_fit_module)
    burn = _burn_in(base, stage)
    if burn > int(np.argmax(stage.train)):
        stage = _without_start(stage, burn)
        if given is None:
            base = make_baseline(stage, None, use_fit_module=use_fit_module)
    return stage, base


def _reference(stage: Stage, base: Baseline) -> tuple[Stage, Structure, float]:
    """The plain model refit by the shared searches, with the valve's initial state, and the stage
    it is scored on (the start scored again except the process's own response time, and any
    leading stretch the plain model still cannot follow left out)."""
    # from the baseline and (when the baseline came from elsewhere) from the grid, whichever trains
    # better
    ref, ref_sse = refine_plain(stage, base.structure)
    if base.source != "grid":
        alt = grid_baseline(stage, start=ref)
        alt_ref, alt_sse = refine_plain(stage, alt, rounds=1)
        if alt_sse < ref_sse:
            ref, ref_sse = alt_ref, alt_sse
    # the valve's state at the start is unknown (where it is stuck, which way it last moved): fit
    # it, then score the start again (all but the process's own response time)
    start = _response_burn(base, stage)
    if start < int(np.argmax(stage.train)):
        train = stage.train.copy()
        train[start:stage.n_fit] = True
        full = dataclasses.replace(stage, train=train)
        r0, _ = fit_initial_state(full, ref)
        r0, c0 = refine_plain(full, r0)
        if stage.name == "valve":
            # the target is the stem: start from its first samples and search the valve globally
            r1 = global_sj(full, ref.replace(y0_pct=float(np.median(full.y[:3]))))
            r1, _ = fit_initial_state(full, r1)
            r1, c1 = refine_plain(full, r1)
            if c1 < c0:
                r0 = r1
        stage, ref = full, r0
        ref, ref_sse = best_of(stage, [ref])
    if stage.name == "valve":
        # OP -> MV: the cost is sharp in S; every valve-stage hypothesis gets the same fine polish
        ref = fine_valve(stage, ref)
        ref, ref_sse = best_of(stage, [ref])
    # a leading stretch the plain model still cannot follow at all (far above the rest) is not
    # scored
    burn2 = _leading_misfit(stage, ref)
    if burn2 > int(np.argmax(stage.train)):
        stage = _without_start(stage, burn2)
        ref, ref_sse = refine_plain(stage, ref)
    return stage, ref, ref_sse


def _plain_projections(s: Structure, n_mid: int = 0, ts_s: float = 1.0) -> list[Structure]:
    """The plain models nearest to an augmented one (extra physics removed)."""
    # without the drift window too: a step's time carried into a reference would make a later
    # drift polished from it a step, and a reference that wins back reports that time
    base = s.plain_part()
    out = []
    if s.S_up_pct != s.S_dn_pct or s.J_up_pct != s.J_dn_pct:
        for S, J in ((s.S_up_pct, s.J_up_pct), (s.S_dn_pct, s.J_dn_pct),
                     ((s.S_up_pct + s.S_dn_pct) / 2, (s.J_up_pct + s.J_dn_pct) / 2)):
            out.append(base.replace(S_up_pct=S, S_dn_pct=S, J_up_pct=J, J_dn_pct=J))
    elif s.dS_pct_per_s or s.dJ_pct_per_s:
        out.append(base)
        # a step: the friction after it; a drift: at mid-training
        if math.isfinite(s.drift_for_s) or n_mid:
            S, J = s.friction_at(math.inf if math.isfinite(s.drift_for_s) else n_mid * ts_s)
            out.append(base.replace(S_up_pct=S, S_dn_pct=S, J_up_pct=J, J_dn_pct=J))
    else:
        out.append(base)
    return out


def _better_reference(stage: Stage, ref: Structure, ref_sse: float, fits: Iterable[Fitted],
                      threads: int) -> tuple[Structure, float]:
    """The reference, or a better plain model: every fitted hypothesis with its extra physics
    removed, refit. Searches over rough output-error surfaces: a hypothesis may win only because
    its search found a better plain valve."""
    mid = int(np.mean(np.flatnonzero(stage.train))) if stage.train.any() else 0
    proj = [p for f in fits for p in _plain_projections(f.structure, mid, stage.ts_s)]
    refits = thread_map(lambda p: refine_plain(stage, p, rounds=1), proj, threads)
    best_ref, best_sse = ref, ref_sse
    for r, c in refits:
        if c < best_sse:
            best_ref, best_sse = r, c
    if stage.name == "valve" and best_ref is not ref:
        best_ref = fine_valve(stage, best_ref)
        best_sse = best_of(stage, [best_ref])[1]
    # the searches' scores carry the compiled least squares' tiny ridge, a floor far below any noise
    # but far above the error of an exact fit (a noise-free stem): the swap is decided on the plain
    # least squares of `predict`
    if best_ref is not ref and best_sse < ref_sse * (1.0 - 1e-6) and \
            _exact_train_sse(stage, best_ref) < _exact_train_sse(stage, ref) * (1.0 - 1e-6):
        return best_ref, best_sse
    return ref, ref_sse


def _exact_train_sse(stage: Stage, struct: Structure) -> float:
    y_hat, _, _ = predict(stage, struct)
    return float(np.sum((stage.y - y_hat)[stage.train] ** 2))


def _run_stage(stage: Stage, hyps: Sequence[PhysicsHypothesis], *, given: Structure | None, source: str,
               use_fit_module: bool, min_reduction: float, threads: int) -> _StageRun:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", StictionWarning)
        stage, base = _baseline_stage(stage, given, source, use_fit_module)
    base_rmse = rmse((stage.y - base.y_hat)[stage.heldout])
    stage, ref, ref_sse = _reference(stage, base)
    ref_hat, ref_stem, _ = predict(stage, ref)
    # locate on the residual of the better-trained of the two plain models (the fitting stage's
    # baseline, or the plain model refit by the searches here)
    base_tr = float(np.sum((stage.y - base.y_hat)[stage.train] ** 2))
    if ref_sse < base_tr:
        located_on, loc_hat, loc_stem, loc_struct = "reference", ref_hat, ref_stem, ref
    else:
        located_on, loc_hat, loc_stem, loc_struct = "baseline", base.y_hat, base.stem_hat, base.structure
    mism = locate(stage.y - loc_hat, loc_stem, stage.x, stage.ts_s, train=stage.train,
                  response_s=_response_s(loc_struct, stage))
    plain = PlainModel(ref, identified=base.structure, limit_cycle_period_s=mism.limit_cycle_period_s,
                       residual=stage.y - ref_hat)
    # the longest searches first, so that threads finish together
    order = sorted(hyps, key=lambda h: -_COST_RANK.get(h.name, 0))
    fits = dict(zip([h.name for h in order], thread_map(lambda h: h.fit(stage, plain), order, threads)))
    better, better_sse = _better_reference(stage, ref, ref_sse, [fits[h.name] for h in hyps], threads)
    if better is not ref:
        ref, ref_sse = better, better_sse
        ref_hat, _, _ = predict(stage, ref)
        plain = PlainModel(ref, identified=base.structure, limit_cycle_period_s=mism.limit_cycle_period_s,
                           residual=stage.y - ref_hat)
        again = thread_map(lambda h: h.refit(stage, fits[h.name], plain), order, threads)
        for h, f in zip(order, again):
            if f.train_sse < fits[h.name].train_sse:
                fits[h.name] = f
    run = _StageRun(stage, base, base_rmse, ref, ref_hat, float("nan"), mism, located_on, loc_hat, loc_stem)
    _judge(run, [fits[h.name] for h in hyps], {h.name: h for h in hyps}, ref_sse, min_reduction, threads)
    return run


#: hypotheses whose searches take longest go to the threads first
_COST_RANK = {"external_disturbance": 4, "time_varying_friction": 3, "valve_characteristic": 2,
              "asymmetric_stiction": 1}


def _noise_like(e: np.ndarray) -> bool:
    """A residual no bigger than twice its own sample-to-sample noise (``std(diff e) / sqrt 2``,
    the RMS of white noise): what is left is measurement noise, not a miss. A regulated PV that is
    mostly noise otherwise reads as a baseline that misses half of it."""
    if e.size < 3:
        return True
    white = float(np.std(np.diff(e))) / math.sqrt(2.0)
    return float(np.sqrt(np.mean(e * e))) <= 2.0 * white


def _judge(run: _StageRun, fits: list[Fitted], by_name: Mapping[str, PhysicsHypothesis], ref_sse: float,
           min_reduction: float, threads: int) -> None:
    """Judge the reference and every fitted hypothesis on the held-out part by their
    posterior-predictive means (one fitted parameter set of a stiction model extrapolates by luck
    as much as by physics), and apply the acceptance rules (module docstring)."""
    stage, ho = run.stage, run.stage.heldout
    n_eff_tr = effective_n((stage.y - run.ref_hat)[stage.train])
    means = thread_map(lambda s: predictive_mean(stage, s, n_eff_tr).y_hat,
                       [run.reference] + [f.structure for f in fits], threads)
    run.ref_hat = means[0]
    run.ref_rmse = ref_rmse = rmse((stage.y - run.ref_hat)[ho])
    e_ref = (stage.y - run.ref_hat)[ho]
    sse_ref = float(e_ref @ e_ref)
    n_eff = effective_n(e_ref)
    run.n_eff = n_eff
    ref_tr_rms = math.sqrt(ref_sse / max(int(stage.train.sum()), 1))   # for the materiality rules
    run.n_eff_train, run.ref_train_rmse = n_eff_tr, ref_tr_rms
    # a reference that reproduces the held-out part to rounding (a noise-free stem) leaves nothing
    # to improve: changes are taken against at least a thousandth of the signal's spread, not
    # against the rounding error itself
    floor = 1e-3 * (float(np.std(stage.y[ho])) or 1.0)
    plc = run.mismatch.limit_cycle_period_s
    ref_point = None
    for fitted, y_hat in zip(fits, means[1:]):
        h = by_name[fitted.name]
        y_point, stem_point, _ = predict(stage, fitted.structure)
        e = (stage.y - y_hat)[ho]
        sse = float(e @ e)
        r_h = rmse(e)
        red = (ref_rmse - r_h) / max(ref_rmse, floor)
        # independent samples: counted on the better model's residual (a missing effect leaves the
        # reference's residual slow and correlated; the right model's is closer to the noise)
        n_h = max(n_eff, effective_n(e)) if sse < sse_ref else n_eff
        dbic = n_h * math.log(max(sse, 1e-300) / max(sse_ref, 1e-300)) + fitted.n_extra * math.log(n_h)
        need = min_reduction
        on_lc = (fitted.name == "external_disturbance"
                 and ExternalDisturbance.at_limit_cycle(fitted.params.get("period_s"), plc))
        if on_lc:
            need = 2.0 * min_reduction   # a load on the loop's own period: stricter
        # the added physics must also explain the training data significantly better (a model that
        # trains no better but happens to extrapolate better is search luck, not physics)
        n_tr = n_eff_tr
        if fitted.train_sse < ref_sse:
            n_tr = max(n_eff_tr, effective_n((stage.y - y_point)[stage.train]))
        dbic_tr = (n_tr * math.log(max(fitted.train_sse, 1e-300) / max(ref_sse, 1e-300))
                   + fitted.n_extra * math.log(n_tr))
        # an effect small against the noise (a short lag on a noisy stem) moves the RMSE by a few
        # per cent only; where both parts give overwhelming evidence for it, a third of the
        # reduction is enough
        decisive = dbic <= DECISIVE_BIC and dbic_tr <= DECISIVE_BIC
        if decisive:
            need = need / 3.0
        checks = [
            # one sign convention in every line: a change is signed, negative = the error falls
            (red >= need,
             f"held-out RMSE change {percent_change(-red)} against the refit plain model, "
             f"{percent_change(-need)} or less needed"
             + (" (a load at the loop's own oscillation period)" if on_lc else "")
             + (f" (held-out and training BIC both {DECISIVE_BIC:+.0f} or lower)" if decisive else "")),
            (r_h <= run.base_rmse * (1.0 - 0.5 * need),
             f"held-out RMSE not {50 * need:.0f} % below the baseline's"),
            (dbic <= STRONG_BIC, f"held-out BIC change {dbic:+.1f}, {STRONG_BIC:+.0f} needed"),
            (dbic_tr < 0, f"trains no better than the plain model for its extra parameters "
                          f"(training BIC change {dbic_tr:+.1f})"),
            (all(math.isfinite(v) for v in fitted.params.values()), "parameters not finite"),
            (h.material(fitted.params, stage.n * stage.ts_s, ref_tr_rms), "too small to matter"),
        ]
        failed = [why for passed, why in checks if not passed]
        evidence = "heldout"
        if failed and _completed_step(stage, fitted, stem_point):
            # friction that stepped inside the training part and held since: on the held-out part
            # the valve after the step is a plain valve, which no model predicts better than the
            # plain valve refit there, so the evidence is the training part's and the held-out part
            # may only not contradict it: the valve after the step is the refit plain valve, or
            # predicts the held-out part about as well. Point predictions on both sides: the side
            # after the step is fitted on part of the training samples, so its posterior is wider
            # than the reference's and its mean smears a sharp valve's slips, and hundredths of a
            # per cent in S that those samples cannot resolve misplace held-out slips
            S_after, J_after = fitted.structure.friction_at(math.inf)
            ref_s = max(run.reference.S_up_pct, 1e-9)
            same = (abs(S_after / ref_s - 1.0) <= STEP_AFTER_TOLERANCE
                    and abs(J_after - run.reference.J_up_pct) <= STEP_AFTER_TOLERANCE * ref_s)
            if ref_point is None:
                ref_point = predict(stage, run.reference)[0]
            change = rmse((stage.y - y_point)[ho]) / max(rmse((stage.y - ref_point)[ho]), floor) - 1.0
            step_checks = [
                (dbic_tr <= DECISIVE_BIC,
                 f"a step inside the training part needs a training BIC change of {DECISIVE_BIC:+.0f} or lower "
                 f"(got {dbic_tr:+.1f})"),
                (same or change <= min_reduction,
                 f"the valve after the step is not the refit plain valve, and its held-out RMSE is "
                 f"{percent_change(change)} against that valve's (point predictions), "
                 f"{percent_change(min_reduction)} or less allowed"),
            ] + checks[-2:]   # finite and material, as for every hypothesis
            step_failed = [why for passed, why in step_checks if not passed]
            if step_failed:
                failed = [f"{failed[0]}; as a step inside the training part: {step_failed[0]}"]
            else:
                failed, evidence = [], "training"
        res = HypothesisResult(name=fitted.name, params=fitted.params, heldout_rmse=r_h, accepted=not failed,
                               stage=stage.name, train_rmse=rmse((stage.y - y_point)[stage.train]), reduction=red,
                               delta_bic=dbic, n_extra=fitted.n_extra, train_delta_bic=dbic_tr,
                               refused=failed[0] if failed else "", evidence=evidence)
        run.fitted.append((fitted, y_hat, res))
        if res.accepted and _completed_step(stage, fitted, stem_point):
            run.steps.add(fitted.name)


def _completed_step(stage: Stage, fitted: Fitted, stem: np.ndarray) -> bool:
    """A friction step (a change one sample long) inside the scored training part, with the fitted
    valve slipping at least `MIN_SLIPS_TRAIN` times in the training part on each side of it: the
    target (the recorded stem, or PV through the process) shows the valve before and after the
    change."""
    s = fitted.structure
    if not (s.dS_pct_per_s or s.dJ_pct_per_s) or s.drift_for_s != stage.ts_s:
        return False
    k = int(round(s.drift_from_s / stage.ts_s))
    slips, _ = slips_and_reversals(np.asarray(stem, float), eps=0.01)
    tr = slips[stage.train[slips]]
    return int(np.sum(tr < k)) >= MIN_SLIPS_TRAIN and int(np.sum(tr > k)) >= MIN_SLIPS_TRAIN


def _given_structures(identification: Any, baseline: Mapping[str, Structure] | None
                      ) -> tuple[dict[str, Structure], str]:
    """The baselines passed in, per stage, and their source."""
    if baseline is not None:
        return dict(baseline), "given"
    out: dict[str, Structure] = {}
    if identification is not None:
        fit = getattr(identification, "fit", identification)
        if fit is not None and getattr(fit, "process", None) is not None:
            out["loop"] = from_hammerstein(fit)
        vfit = getattr(identification, "valve_fit", None)
        if vfit is not None:
            out["valve"] = from_valve_fit(vfit)
    return out, "identify"


def explain(record: LoopRecord, *, target: str = "auto", train_fraction: float = 0.65,
            hypotheses: Sequence[str] | None = None, min_reduction: float = 0.10,
            identification: Any = None, baseline: Mapping[str, Structure] | None = None,
            use_fit_module: bool = True, threads: int | None = None) -> Explanation:
    """Locate the baseline's mismatch, test the missing-physics hypotheses, name the best.

    Parameters
    ----------
    record : LoopRecord
        One loop (OP and PV; MV used when present).
    target : {"auto", "pv", "mv"}
        ``auto``: OP -> PV, and OP -> MV for valve-side effects when MV is present; ``pv``: OP/PV
        only; ``mv``: the valve alone (needs MV).
    train_fraction : float
        Leading fraction of the record the fits may score; the rest is held out.
    hypotheses : sequence of str, optional
        Names from `diagnose.physics.REGISTRY` (default: all).
    min_reduction : float
        Smallest relative held-out RMSE reduction that can name an effect.
    identification : diagnose.identify.Identification or diagnose.fit.HammersteinFit, optional
        The identification of this record the caller already has: its Hammerstein fit (valve,
        process and the valve's start state) is the loop stage's baseline and its valve fit the
        valve stage's, instead of fitting them again on the training part. Their gain and offset
        are refit on the training part, but their other parameters saw the whole record, so the
        baseline's held-out RMSE is then not strictly held out (the reference, refit here on the
        training part, is what every hypothesis is judged against).
    baseline : mapping stage -> Structure, optional
        Use these baselines (``{"loop": ..., "valve": ...}``), e.g. the true parameters of a
        simulation (wins over ``identification``).
    use_fit_module : bool
        Fit a baseline not given with `diagnose.fit` (False: the built-in grid).
    threads : int, optional
        Threads the independent searches run on (None: the cores the process may use, at most 4; 1
        when the caller runs records in parallel itself). The result does not depend on it.

    Returns
    -------
    Explanation
    """
    if target not in ("auto", "pv", "mv"):
        raise DataError(f"target must be auto, pv or mv, not {target!r}")
    if not 0.3 <= train_fraction <= 0.9:
        raise DataError(f"train_fraction must be between 0.3 and 0.9, got {train_fraction}")
    n = record.n
    if n < MIN_SAMPLES:
        raise DataError(f"{record.name}: record has {n} samples; explain needs at least {MIN_SAMPLES} "
                        "(a training part and a held-out part of several oscillation periods each)")
    if target == "mv" and record.mv is None:
        raise DataError(f"{record.name}: target mv needs the valve stem position (MV column); "
                        "name it with --mv or use --target pv")
    n_tr = int(round(train_fraction * n))
    train = np.zeros(n, bool)
    train[:n_tr] = True
    hyps = get(hypotheses)
    has_mv = record.mv is not None and target != "pv"
    stage_names = []
    if target in ("auto", "pv"):
        stage_names.append("loop")
    if has_mv:
        stage_names.append("valve")
    # a fraction-of-span OP beside a stem position in %: scaled as identify scales it, so that S and J
    # come out in % of span and the valve stage has the stem's scale
    record, findings, rescaled = quality.op_in_percent(record, quality.findings_of(record))
    frac = None if rescaled or record.mv is not None else next(
        (f for f in findings if f.code == "op_fraction" and f.severity != "info"), None)
    if frac is not None:
        # a fraction-of-span OP with no stem to confirm it, read as identify reads it: the valve's
        # travel, its characteristic and the searches' steps are in % of span, so OP is taken x 100
        # (the caller's identification is in OP's own units and is not reused)
        record = record.replace(op=np.asarray(record.op, dtype=float) * 100.0,
                                findings=tuple(f for f in record.findings if f.code != "op_fraction"))
        identification = None
        rescaled = (f"OP stays within 0..1 ({frac.data.get('min', 0):.3g} to {frac.data.get('max', 0):.3g}) and no "
                    "stem position scales it: read as a fraction of span, as identify reads it, and explained "
                    "with OP x 100, so the valve's parameters here are in % of span (identify gives S and J in "
                    "fractions); if OP really is in % (a valve all but shut), they do not apply")
    warn: list[ExplainWarning] = [ExplainWarning(f"data_quality.{f.code}", f.message) for f in record.findings
                                  if f.severity in ("warning", "error")]
    if rescaled:
        warn.append(ExplainWarning("op_rescaled", rescaled))
    given, source = _given_structures(identification, baseline)
    nthreads = thread_count(threads, cap=4)

    jobs = []
    for sn in stage_names:
        stage = _stage_for(record, sn, train)
        if np.ptp(stage.y) <= 0 or np.ptp(stage.x) <= 0:
            # OP's value as recorded: stage.x may be shifted into 0..100 %
            flat = [f"{role} ({float(shown[0]):g})"
                    for role, shown, seen in (("PV" if sn == "loop" else "MV", stage.y, stage.y),
                                              ("OP", record.op, stage.x))
                    if np.ptp(seen) <= 0]
            todo = ("use --target pv, or give a period in which the stem moved" if flat[0].startswith("MV")
                    and len(flat) == 1 else "give a period in which the loop moved")
            raise DataError(f"{record.name}: {' and '.join(flat)} {'is' if len(flat) == 1 else 'are'} constant "
                            f"over the whole record, so the {sn} stage has no mismatch to explain; {todo}")
        if sn == "loop":
            mine = [h for h in hyps if h.side == PROCESS_SIDE or (h.side == VALVE_SIDE and not has_mv)]
        else:
            mine = [h for h in hyps if h.side == VALVE_SIDE]
        jobs.append((sn, stage, mine))
    # the stages are independent: with two, each gets half the threads
    per = max(1, nthreads // len(jobs))
    done = thread_map(lambda j: _run_stage(j[1], j[2], given=given.get(j[0]), source=source,
                                           use_fit_module=use_fit_module, min_reduction=min_reduction, threads=per),
                      jobs, min(nthreads, len(jobs)))
    runs: dict[str, _StageRun] = {j[0]: r for j, r in zip(jobs, done)}
    return _assemble(record, runs, hyps, warn, train_fraction, n_tr)


def _assemble(record: LoopRecord, runs: dict[str, _StageRun], hyps: Sequence[PhysicsHypothesis],
              warn: list[ExplainWarning], train_fraction: float, n_tr: int) -> Explanation:
    all_results = [(sn, f, yh, res) for sn, r in runs.items() for f, yh, res in r.fitted]
    accepted = [t for t in all_results if t[3].accepted]
    # two accepted on one stage: the one that explains the held-out data best for its parameters
    # (the training data after a completed friction step, `_StageRun.best_accepted`); between the
    # stages, the held-out data
    best = [b for b in (r.best_accepted([t for t in accepted if t[0] == sn]) for sn, r in runs.items()) if b]
    winner = min(best, key=lambda t: runs[t[0]].rank_bic(t[3])) if best else None
    report_stage = winner[0] if winner else ("loop" if "loop" in runs else "valve")
    run = runs[report_stage]
    stage = run.stage
    base_rmse = run.base_rmse
    improved_hat = winner[2] if winner else run.baseline.y_hat
    improved_rmse = winner[3].heldout_rmse if winner else base_rmse
    if winner and winner[3].evidence == "training" and run.ref_rmse < improved_rmse:
        # a friction step inside the training part: after it the valve is the plain valve that
        # predicts the held-out part, so that is its prediction there
        improved_hat = np.where(stage.heldout, run.ref_hat, improved_hat)
        improved_rmse = run.ref_rmse

    # ambiguity and structural warnings
    if winner:
        w = winner[3]
        if w.name == "actuator_lag" and report_stage == "loop":
            warn.append(ExplainWarning(
                "physics.indistinguishable",
                "from OP and PV alone a first-order lag after the friction cannot be told apart from a second "
                "lag in the process; the stem position (MV) would tell them apart"))
        close = [t[3] for t in accepted if t is not winner and t[3].heldout_rmse <= w.heldout_rmse * 1.05
                 and t[0] == winner[0]]
        wrun = runs[winner[0]]
        for c in close:
            if w.name in wrun.steps:
                warn.append(ExplainWarning(
                    "physics.ambiguous",
                    f"{c.name} predicts the held-out part as well as or better than {w.name} (RMSE "
                    f"{c.heldout_rmse:.4g} vs {w.heldout_rmse:.4g}), but that part lies after the friction step, "
                    f"where an effect that imitates the valve after it does as well; on the training part the step "
                    f"explains more (training BIC {wrun.rank_train_bic(w):+.1f} vs {wrun.rank_train_bic(c):+.1f})"))
                continue
            warn.append(ExplainWarning(
                "physics.ambiguous",
                f"{c.name} explains the held-out data almost as well as {w.name} (RMSE {c.heldout_rmse:.4g} vs "
                f"{w.heldout_rmse:.4g}); the data cannot tell them apart"))
        if w.name == "external_disturbance" and ExternalDisturbance.at_limit_cycle(
                w.params.get("period_s"), runs[winner[0]].mismatch.limit_cycle_period_s):
            warn.append(ExplainWarning(
                "physics.entrained",
                "the load's period is the loop's own oscillation period: an external oscillation entraining the "
                "loop, or a model error at the limit cycle, cannot be told apart from these data"))
        if w.name == "actuator_lag" and w.params.get("tau_s", math.inf) < 0.75 * record.ts_s:
            warn.append(ExplainWarning(
                "physics.sub_sample",
                "the fitted lag is shorter than one sample; the sampling is too coarse to resolve it"))
    else:
        ss = np.std(stage.y[stage.heldout]) or 1.0
        if min(base_rmse, run.ref_rmse) > 0.5 * ss and not _noise_like((stage.y - run.ref_hat)[stage.heldout]):
            warn.append(ExplainWarning(
                "physics.unexplained",
                "the baseline misses much of the held-out data but no hypothesis explains it significantly; "
                "see the located windows"))
    for r in runs.values():
        idle = _idle_valve(r)
        if idle:
            warn.append(ExplainWarning("physics.valve_idle", idle))
            break
    text = _text(record, winner, runs, report_stage, base_rmse, improved_rmse)
    others = tuple(OtherStage(sn, r.base_rmse, r.ref_rmse, r.mismatch.hints)
                   for sn, r in runs.items() if sn != report_stage)
    mismatch = StageMismatch.of(run.mismatch, located_on=run.located_on, stage=report_stage,
                                train_fraction=float(train_fraction), heldout_start_s=float(n_tr * record.ts_s),
                                reference_rmse=float(run.ref_rmse), other_stages=others)
    order = {h.name: i for i, h in enumerate(hyps)}
    results = tuple(sorted((t[3] for t in all_results), key=lambda h: order.get(h.name, 99)))
    return Explanation(missing_physics=winner[3].name if winner else None,
                       baseline_rmse=float(base_rmse), improved_rmse=float(improved_rmse),
                       hypotheses=results, mismatch=mismatch, explanation=text, warnings=tuple(warn),
                       target=TARGETS[report_stage], loop=record.name, baseline_source=run.baseline.source,
                       arrays=_figure_data(run, improved_hat, record, n_tr),
                       stages=tuple(StageModels(sn, r.baseline.structure, r.reference, r.baseline.source)
                                    for sn, r in runs.items()))


def _idle_valve(run: _StageRun) -> str | None:
    """Message when the identified valve hardly moves in the training or the held-out part."""
    if run.stage.name == "valve":
        # the predicted MV: a fit to a stuck stem may slip with no gain (least-squares scale ~ 0)
        slips, _ = slips_and_reversals(np.asarray(run.loc_hat, float), eps=0.01)
    else:
        slips, _ = slips_and_reversals(np.asarray(run.loc_stem, float))
    n_tr = int(np.sum(run.stage.train[slips]))
    n_ho = int(np.sum(run.stage.heldout[slips]))
    if n_tr >= MIN_SLIPS_TRAIN and n_ho >= MIN_SLIPS_HELDOUT:
        return None
    return (f"the identified valve moves only {n_tr} times in the training part and {n_ho} times in the "
            "held-out part: a valve that stays stuck carries no trace of its friction, so valve-side "
            "effects cannot be learned or judged from this record; a longer record, or one in which "
            "the loop cycles, is needed")


def _figure_data(run: _StageRun, improved_hat: np.ndarray, record: LoopRecord, n_tr: int) -> FigureData:
    st, m = run.stage, run.mismatch
    a = m.arrays
    return FigureData(
        t_s=np.arange(st.n) * st.ts_s, observed=st.y, baseline=run.baseline.y_hat, reference=run.ref_hat,
        improved=improved_hat, residual_baseline=st.y - run.baseline.y_hat, residual_located=st.y - run.loc_hat,
        residual_improved=st.y - improved_hat, located_on=run.located_on, op_pct=st.x, stem_hat_pct=run.loc_stem,
        train_start_s=float(int(np.argmax(st.train)) * st.ts_s), train_end_s=float(n_tr * st.ts_s),
        windows=tuple((w.start_s, w.end_s) for w in m.windows), mismatch=a,
        direction_rms=(m.direction.opening.rms, m.direction.closing.rms),
        limit_cycle_period_s=m.limit_cycle_period_s, slip_t_s=a.slips * st.ts_s,
        units="% of span" if st.name == "valve" else (record.units.get("pv") or "PV units"))


def _fmt_params(params: Mapping[str, float]) -> str:
    from ..plain import duration, number

    return ", ".join(f"{k} = {duration(v) if k.endswith('_s') else number(v)}" for k, v in params.items())


def _refit_kind(run: _StageRun) -> str:
    """Says so when the refit's grid chose another process family than the baseline's: the
    hypotheses are judged against the refit, and an integrating level fitted as a slow
    self-regulating process is a different model, not the baseline's parameters polished."""
    old, new = run.baseline.structure.process, run.reference.process
    if run.stage.name != "loop" or old.kind == new.kind:
        return ""
    return f" (as {_KIND_WORDS[new.kind]} process, where the baseline has {_KIND_WORDS[old.kind]} one)"


_KIND_WORDS = {"foptd": "a first-order", "soptd": "a second-order", "integrating": "an integrating"}


def _text(record: LoopRecord, winner, runs: dict[str, _StageRun], report_stage: str, base_rmse: float,
          improved_rmse: float) -> str:
    from .hypotheses import REGISTRY, shown_params

    run = runs[report_stage]
    what = "MV (stem position) from OP" if report_stage == "valve" else "PV from OP"
    hints = run.mismatch.hints
    parts = [f"Baseline ({run.baseline.source}) simulating {what}: held-out RMSE {base_rmse:.4g}; "
             f"the plain model refit here{_refit_kind(run)}: {run.ref_rmse:.4g}."]
    if hints:
        parts.append("Residual: " + "; ".join(hints) + ".")
    if winner:
        h = winner[3]
        desc = REGISTRY[h.name].description if h.name in REGISTRY else h.name
        params = _fmt_params(shown_params(h.name, h.params))
        if h.evidence == "training":
            parts.append(f"Missing physics: {h.name} ({desc}; {params}). The friction changed inside the training "
                         f"part and held since: judged on the training part (training BIC change "
                         f"{h.train_delta_bic:+.1f}, RMSE {h.train_rmse:.4g}); the held-out part is predicted by the "
                         f"plain valve after the change (held-out RMSE {run.ref_rmse:.4g}).")
        else:
            parts.append(f"Missing physics: {h.name} ({desc}; {params}). "
                         f"With it the held-out RMSE falls to {improved_rmse:.4g} "
                         f"({percent_change(improved_rmse / base_rmse - 1.0 if base_rmse > 0 else 0.0)} "
                         "against the baseline).")
    else:
        # by the relative change: the stages' RMSEs are in different units (PV units, % of span)
        best = max((t[2] for r in runs.values() for t in r.fitted), key=lambda h: h.reduction,
                   default=None)
        if best is not None:
            on = "MV" if best.target == "mv" else "PV"
            parts.append(f"No missing physics named: the best hypothesis ({best.name}) changes the held-out "
                         f"RMSE of {on} by {percent_change(-best.reduction)} against the plain model refit on "
                         f"{on}" + (f"; refused: {best.refused}." if best.refused else "."))
        else:
            parts.append("No hypothesis was tested.")
    return " ".join(parts)
