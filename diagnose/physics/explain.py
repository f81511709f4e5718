"""`explain`: locate where the baseline model and the recording disagree, name the missing physics,
fit a model that has it, and show the held-out error fall.

Procedure (per stage: ``loop`` OP -> PV always, ``valve`` OP -> MV when the record has the stem
position):

1. baseline: the fitting stage's model (`diagnose.fit.fit_hammerstein`) fitted on the first
   ``train_fraction`` of the record; the whole record is simulated from OP, only the rest is judged;
2. locate the mismatch on the baseline's residual (`locate.locate`);
3. reference: the plain model refit by the same local searches the hypotheses use;
4. every registered hypothesis that applies to the stage is fitted on the training part;
   valve-side hypotheses go to the valve stage when MV is there (else to the loop stage),
   process-side ones to the loop stage;
5. a hypothesis is *accepted* when, on the held-out part, (a) its RMSE is at least
   ``min_reduction`` below the reference's, (b) also below the baseline's by half that, and (c) its
   held-out BIC, ``n_eff ln(SSE_h / SSE_ref) + k ln(n_eff)`` with ``n_eff`` the effective number of
   independent held-out residuals and ``k`` the added parameters, is below ``STRONG_BIC`` (-6). The accepted one
   with the lowest held-out BIC (ranked with one ``n_eff`` per stage, the reference's) is named; none
   accepted -> ``missing_physics = None``.
"""

from __future__ import annotations

import dataclasses
import math
import warnings
from dataclasses import dataclass, field
from typing import Any, Mapping, Sequence

import numpy as np

from ..controller import controller_action
from ..errors import DataError, StictionWarning
from ..record import LoopRecord
from .baseline import Baseline, make_baseline
from .hypotheses import PROCESS_SIDE, VALVE_SIDE, ExternalDisturbance, PlainModel, get
from .locate import Mismatch, locate, slips_and_reversals
from .model import Stage, Structure, effective_n, predict, rmse
from .search import best_of, fine_valve, fit_initial_state, global_sj, grid_baseline, refine_plain
from .posterior import predictive_mean

MIN_SAMPLES = 300
#: held-out BIC difference an augmented model must reach: "strong" evidence on the usual BIC scale
#: (Kass and Raftery 1995: 6-10 strong, > 10 very strong); a difference of a few units is what a
#: better plain fit that the reference search missed can give on a clean record
STRONG_BIC = -6.0
#: fewer slips of the identified valve than this in the training / held-out part -> warning
#: ``physics.valve_idle``: a valve that stays stuck carries no trace of its friction
MIN_SLIPS_TRAIN, MIN_SLIPS_HELDOUT = 5, 3


@dataclass(frozen=True)
class HypothesisResult:
    """One tested hypothesis."""

    name: str
    params: Mapping[str, float]
    heldout_rmse: float
    accepted: bool
    stage: str
    train_rmse: float
    reduction: float
    delta_bic: float
    n_extra: int
    train_delta_bic: float = float("nan")
    #: why it was not accepted (the first rule it failed, in words); empty when accepted
    refused: str = ""

    def to_dict(self) -> dict[str, Any]:
        return {"name": self.name, "params": {k: _num(v) for k, v in self.params.items()},
                "heldout_rmse": _num(self.heldout_rmse), "accepted": bool(self.accepted),
                "stage": self.stage, "target": _TARGET[self.stage], "train_rmse": _num(self.train_rmse),
                "heldout_reduction": _num(self.reduction), "delta_bic": _num(self.delta_bic),
                "train_delta_bic": _num(self.train_delta_bic),
                "n_extra_params": int(self.n_extra), "refused": self.refused}


_TARGET = {"loop": "pv", "valve": "mv"}


def _num(v: Any) -> Any:
    if isinstance(v, (float, np.floating)):
        v = float(v)
        return v if math.isfinite(v) else None
    return v


def _clean(obj: Any) -> Any:
    if isinstance(obj, dict):
        return {str(k): _clean(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_clean(v) for v in obj]
    if isinstance(obj, (np.integer,)):
        return int(obj)
    if isinstance(obj, (np.bool_,)):
        return bool(obj)
    if isinstance(obj, np.ndarray):
        return [_clean(v) for v in obj.tolist()]
    return _num(obj)


@dataclass(frozen=True, eq=False)
class Explanation:
    """Result of `explain`.

    Attributes
    ----------
    missing_physics : str or None
        Name of the accepted hypothesis, None when the baseline is good enough or nothing helps.
    baseline_rmse, improved_rmse : float
        Held-out RMSE of the baseline and of the named model (equal when None), in the target's
        units (PV units on the loop stage, % of span on the valve stage).
    hypotheses : tuple of HypothesisResult
    mismatch : dict
        Localisation of the baseline's residual on the reported stage (JSON-ready).
    explanation : str
        A few sentences for an engineer.
    warnings : tuple of dict
        ``{"code", "message"}``.
    target : {"pv", "mv"}
        What the reported RMSEs measure.
    arrays : dict of ndarray
        Figure data (see `figure_data`).
    """

    missing_physics: str | None
    baseline_rmse: float
    improved_rmse: float
    hypotheses: tuple[HypothesisResult, ...]
    mismatch: Mapping[str, Any]
    explanation: str
    warnings: tuple[Mapping[str, str], ...]
    target: str = "pv"
    loop: str = ""
    baseline_source: str = ""
    arrays: Mapping[str, Any] = field(default_factory=dict, repr=False)
    stages: Mapping[str, Any] = field(default_factory=dict, repr=False)

    def to_dict(self) -> dict[str, Any]:
        """The issue-7 JSON object (plus ``loop``, ``target`` and ``baseline_source``)."""
        return _clean({
            "loop": self.loop,
            "missing_physics": self.missing_physics,
            "baseline_rmse": self.baseline_rmse,
            "improved_rmse": self.improved_rmse,
            "target": self.target,
            "baseline_source": self.baseline_source,
            "hypotheses": [h.to_dict() for h in self.hypotheses],
            "mismatch": dict(self.mismatch),
            "explanation": self.explanation,
            "warnings": [dict(w) for w in self.warnings],
        })

    def figure_data(self) -> dict[str, Any]:
        """Arrays for the report: residual over time with located windows, conditioned residuals,
        baseline and improved fits.

        Keys: ``t_s``, ``observed``, ``baseline``, ``improved``, ``residual_baseline``,
        ``residual_improved``, ``train_end_s``, ``windows`` (list of (start_s, end_s)),
        ``window_t_s``/``window_rms``, ``after_slip_profile``/``profile_lag_s``,
        ``op_bin_centres_pct``/``op_bin_rms``, ``direction_rms`` (opening, closing),
        ``freq_hz``/``residual_psd``, ``limit_cycle_period_s``, ``target``, ``missing_physics``.
        """
        a = dict(self.arrays)
        a["target"] = self.target
        a["missing_physics"] = self.missing_physics
        return a


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
    p = base.structure.process
    resp = 0 if stage.name == "valve" else int(round((p.delay_s + 2.0 * (p.tau_s + p.tau2_s)) / stage.ts_s))
    return int(min(max(first + resp, 0.05 * stage.n), 0.5 * n_tr))


def _response_burn(base: Baseline, stage: Stage) -> int:
    """Samples at the start that depend on the process's unknown initial state (its response time;
    on the valve stage 1 % of the record)."""
    if stage.name == "valve":
        return int(max(0.01 * stage.n, 1))
    p = base.structure.process
    resp = int(round((p.delay_s + 2.0 * (p.tau_s + p.tau2_s)) / stage.ts_s))
    return int(min(max(resp, 0.02 * stage.n), 0.5 * int(stage.train.sum())))


def _leading_misfit(stage: Stage, struct: Structure) -> int:
    """End of a leading run of windows the plain model cannot follow (unknown initial valve state).

    The linear coefficients are fitted on the second half of the training part only, so that the
    start cannot bend them; windows whose residual RMS exceeds 2.5 times the median of that half
    are counted from the start (at most half of the training part).
    """
    n_fit = stage.n_fit
    half = np.zeros(stage.n, bool)
    half[n_fit // 2:n_fit] = True
    y_hat, _, _ = predict(dataclasses.replace(stage, train=half), struct)
    e = stage.y - y_hat
    w = max(20, stage.n // 60)
    rms = np.array([float(np.sqrt(np.mean(e[a:a + w] ** 2))) for a in range(0, n_fit, w)])
    med = float(np.median(rms[len(rms) // 2:])) if rms.size else 0.0
    k = 0
    while k < len(rms) and rms[k] > 2.5 * med:
        k += 1
    return int(min(k * w, 0.5 * n_fit))


def _response_s(struct: Structure, stage: Stage) -> float:
    if stage.name == "valve":
        return 0.0
    p = struct.process
    return float(p.delay_s + 0.5 * (p.tau_s + p.tau2_s))


@dataclass
class _StageRun:
    stage: Stage
    baseline: Baseline
    base_rmse: float
    reference: Structure
    ref_hat: np.ndarray
    ref_rmse: float
    mismatch: Mismatch
    fitted: list = field(default_factory=list)   # (Fitted, y_hat, HypothesisResult)
    loc_hat: np.ndarray | None = None
    loc_stem: np.ndarray | None = None
    n_eff: float = 1.0   # effective number of independent held-out residuals of the reference

    def rank_bic(self, res: "HypothesisResult") -> float:
        """Held-out BIC difference of an accepted hypothesis for ranking: the same form as
        ``delta_bic`` but with one ``n_eff`` for the whole stage (the reference's), so that the
        ranking follows the held-out error and the parameter count rather than the colour of each
        model's own residual."""
        n = max(self.n_eff, 1.0)
        ratio = max(res.heldout_rmse, 1e-300) / max(self.ref_rmse, 1e-300)
        return 2.0 * n * math.log(ratio) + res.n_extra * math.log(n)


def _run_stage(stage: Stage, hyps, *, given: Structure | None, use_fit_module: bool,
               min_reduction: float) -> _StageRun:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", StictionWarning)
        base = make_baseline(stage, given, use_fit_module=use_fit_module)
        burn = _burn_in(base, stage)
        if burn > int(np.argmax(stage.train)):
            train = stage.train.copy()
            train[:burn] = False
            stage = dataclasses.replace(stage, train=train)
            if given is None:
                base = make_baseline(stage, given, use_fit_module=use_fit_module)
    ho = stage.heldout
    base_rmse = rmse((stage.y - base.y_hat)[ho])
    # reference: the plain model refit by the hypotheses' searches, from the baseline and (when the
    # baseline came from elsewhere) from the grid, whichever trains better
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
    ref_hat, ref_stem, _ = predict(stage, ref)
    # a leading stretch the plain model still cannot follow at all (far above the rest) is not
    # scored
    burn2 = _leading_misfit(stage, ref)
    if burn2 > int(np.argmax(stage.train)):
        train = stage.train.copy()
        train[:burn2] = False
        stage = dataclasses.replace(stage, train=train)
        ref, ref_sse = refine_plain(stage, ref)
        ref_hat, ref_stem, _ = predict(stage, ref)
        ho = stage.heldout
    # locate on the residual of the better-trained of the two plain models (the fitting stage's
    # baseline, or the same structure refit by the searches here)
    tr = stage.train
    base_tr = float(np.sum((stage.y - base.y_hat)[tr] ** 2))
    if ref_sse < base_tr:
        located_on, loc_hat, loc_stem, loc_struct = "reference", ref_hat, ref_stem, ref
    else:
        located_on, loc_hat, loc_stem, loc_struct = "baseline", base.y_hat, base.stem_hat, base.structure
    mism = locate(stage.y - loc_hat, loc_stem, stage.x, stage.ts_s, train=stage.train,
                  response_s=_response_s(loc_struct, stage))
    mism.summary["located_on"] = located_on
    plain = PlainModel(ref, identified=base.structure, limit_cycle_period_s=mism.limit_cycle_period_s,
                       residual=stage.y - ref_hat)
    fits = {h.name: h.fit(stage, plain) for h in hyps}
    # Searches over rough output-error surfaces: a hypothesis may win only because its search found
    # a better plain valve. Project every fitted model back onto the plain one, refit, and let the
    # reference take the best; then refit the hypotheses from it and keep each one's better fit.
    best_ref, best_sse = ref, ref_sse
    for f in fits.values():
        mid = int(np.mean(np.flatnonzero(stage.train))) if stage.train.any() else 0
        for p in _plain_projections(f.structure, mid, stage.ts_s):
            r, c = refine_plain(stage, p, rounds=1)
            if c < best_sse:
                best_ref, best_sse = r, c
    if stage.name == "valve" and best_ref is not ref:
        best_ref = fine_valve(stage, best_ref)
        best_sse = best_of(stage, [best_ref])[1]
    if best_sse < ref_sse * (1.0 - 1e-6):
        ref, ref_sse = best_ref, best_sse
        ref_hat, _, _ = predict(stage, ref)
        plain = PlainModel(ref, identified=base.structure, limit_cycle_period_s=mism.limit_cycle_period_s,
                           residual=stage.y - ref_hat)
        for h in hyps:
            again = h.fit(stage, plain)
            if again.train_sse < fits[h.name].train_sse:
                fits[h.name] = again
    # Every model is judged on the held-out part by its posterior-predictive mean (posterior.py):
    # one fitted parameter set of a stiction model extrapolates by luck as much as by physics.
    n_eff_tr = effective_n((stage.y - ref_hat)[stage.train])
    ref_hat = predictive_mean(stage, ref, n_eff_tr).y_hat
    ref_rmse = rmse((stage.y - ref_hat)[ho])
    run = _StageRun(stage, base, base_rmse, ref, ref_hat, ref_rmse, mism)
    run.loc_hat, run.loc_stem = loc_hat, loc_stem
    e_ref = (stage.y - ref_hat)[ho]
    sse_ref = float(e_ref @ e_ref)
    n_eff = effective_n(e_ref)
    run.n_eff = n_eff
    ref_tr_rms = math.sqrt(ref_sse / max(int(stage.train.sum()), 1))   # for the materiality rules
    for h in hyps:
        fitted = fits[h.name]
        y_point, _, _ = predict(stage, fitted.structure)
        y_hat = predictive_mean(stage, fitted.structure, n_eff_tr).y_hat
        e = (stage.y - y_hat)[ho]
        sse = float(e @ e)
        r_h = rmse(e)
        red = 1.0 - r_h / ref_rmse if ref_rmse > 0 else 0.0
        # independent samples: counted on the better model's residual (a missing effect leaves the
        # reference's residual slow and correlated; the right model's is closer to the noise)
        n_h = max(n_eff, effective_n(e)) if sse < sse_ref else n_eff
        dbic = n_h * math.log(max(sse, 1e-300) / max(sse_ref, 1e-300)) + fitted.n_extra * math.log(n_h)
        need = min_reduction
        on_lc = (fitted.name == "external_disturbance" and ExternalDisturbance.at_limit_cycle(
            fitted.params.get("period_s"), mism.limit_cycle_period_s))
        if on_lc:
            need = 2.0 * min_reduction   # a load on the loop's own period: stricter
        # the added physics must also explain the training data significantly better (a model that
        # trains no better but happens to extrapolate better is search luck, not physics)
        n_tr = n_eff_tr
        if fitted.train_sse < ref_sse:
            n_tr = max(n_eff_tr, effective_n((stage.y - y_point)[stage.train]))
        dbic_tr = (n_tr * math.log(max(fitted.train_sse, 1e-300) / max(ref_sse, 1e-300))
                   + fitted.n_extra * math.log(n_tr))
        checks = [
            # one sign convention in every line: a change is signed, negative = the error falls
            (red >= need, f"held-out RMSE change {-100 * red:+.0f} % against the refit plain model, "
                          f"{-100 * need:+.0f} % or less needed" + (" (a load at the loop's own oscillation period)"
                                                                    if on_lc else "")),
            (r_h <= base_rmse * (1.0 - 0.5 * min_reduction),
             f"held-out RMSE not {50 * min_reduction:.0f} % below the baseline's"),
            (dbic <= STRONG_BIC, f"held-out BIC change {dbic:+.1f}, {STRONG_BIC:+.0f} needed"),
            (dbic_tr < 0, f"trains no better than the plain model for its extra parameters "
                          f"(training BIC change {dbic_tr:+.1f})"),
            (all(math.isfinite(v) for v in fitted.params.values()), "parameters not finite"),
            (h.material(fitted.params, stage.n * stage.ts_s, ref_tr_rms), "too small to matter"),
        ]
        failed = [why for passed, why in checks if not passed]
        ok = not failed
        tr = stage.train
        tr_rmse = rmse((stage.y - y_point)[tr])
        res = HypothesisResult(name=fitted.name, params=dict(fitted.params), heldout_rmse=r_h,
                               accepted=ok, stage=stage.name, train_rmse=tr_rmse, reduction=red,
                               delta_bic=dbic, n_extra=fitted.n_extra, train_delta_bic=dbic_tr,
                               refused=failed[0] if failed else "")
        run.fitted.append((fitted, y_hat, res))
    return run


def _plain_projections(s: Structure, n_mid: int = 0, ts_s: float = 1.0) -> list[Structure]:
    """The plain models nearest to an augmented one (extra physics removed)."""
    base = s.replace(tau_lag_s=0.0, char_c=0.0, period_s=None, dS_pct_per_s=0.0, dJ_pct_per_s=0.0)
    out = []
    if s.S_up_pct != s.S_dn_pct or s.J_up_pct != s.J_dn_pct:
        for S, J in ((s.S_up_pct, s.J_up_pct), (s.S_dn_pct, s.J_dn_pct),
                     ((s.S_up_pct + s.S_dn_pct) / 2, (s.J_up_pct + s.J_dn_pct) / 2)):
            out.append(base.replace(S_up_pct=S, S_dn_pct=S, J_up_pct=J, J_dn_pct=J))
    elif s.dS_pct_per_s or s.dJ_pct_per_s:
        out.append(base)
        if n_mid:
            t = n_mid * ts_s
            S, J = max(s.S_up_pct + s.dS_pct_per_s * t, 0.0), max(s.J_up_pct + s.dJ_pct_per_s * t, 0.0)
            out.append(base.replace(S_up_pct=S, S_dn_pct=S, J_up_pct=J, J_dn_pct=J))
    else:
        out.append(base)
    return out


def explain(record: LoopRecord, *, target: str = "auto", train_fraction: float = 0.65,
            hypotheses: Sequence[str] | None = None, min_reduction: float = 0.10,
            baseline: Mapping[str, Structure] | None = None, use_fit_module: bool = True) -> Explanation:
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
    baseline : mapping stage -> Structure, optional
        Use these baselines instead of fitting (``{"loop": ..., "valve": ...}``), e.g. the true
        parameters of a simulation.
    use_fit_module : bool
        Fit the baseline with `diagnose.fit` (False: the built-in grid).

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
    warn: list[dict[str, str]] = []
    for f in record.findings:
        if f.severity in ("warning", "error"):
            warn.append({"code": f"data_quality.{f.code}", "message": f.message})

    runs: dict[str, _StageRun] = {}
    for sn in stage_names:
        stage = _stage_for(record, sn, train)
        if np.ptp(stage.y) <= 0 or np.ptp(stage.x) <= 0:
            raise DataError(f"{record.name}: {'PV' if sn == 'loop' else 'MV'} or OP is constant; "
                            "nothing to explain")
        if sn == "loop":
            mine = [h for h in hyps if h.side == PROCESS_SIDE or (h.side == VALVE_SIDE and not has_mv)]
        else:
            mine = [h for h in hyps if h.side == VALVE_SIDE]
        given = None if baseline is None else baseline.get(sn)
        runs[sn] = _run_stage(stage, mine, given=given, use_fit_module=use_fit_module,
                              min_reduction=min_reduction)

    all_results = [(sn, f, yh, res) for sn, r in runs.items() for f, yh, res in r.fitted]
    accepted = [t for t in all_results if t[3].accepted]
    # two accepted on one stage: the one that explains the held-out data best for its parameters
    winner = min(accepted, key=lambda t: runs[t[0]].rank_bic(t[3])) if accepted else None
    report_stage = winner[0] if winner else ("valve" if "valve" in runs and "loop" not in runs else
                                             ("loop" if "loop" in runs else "valve"))
    run = runs[report_stage]
    stage = run.stage
    base_rmse = run.base_rmse
    improved_hat = winner[2] if winner else run.baseline.y_hat
    improved_rmse = winner[3].heldout_rmse if winner else base_rmse

    # ambiguity and structural warnings
    if winner:
        w = winner[3]
        if w.name == "actuator_lag" and report_stage == "loop":
            warn.append({"code": "physics.indistinguishable",
                         "message": "from OP and PV alone a first-order lag after the friction cannot be told "
                                    "apart from a second lag in the process; the stem position (MV) would "
                                    "tell them apart"})
        close = [t[3] for t in accepted if t is not winner and t[3].heldout_rmse <= w.heldout_rmse * 1.05
                 and t[0] == winner[0]]
        for c in close:
            warn.append({"code": "physics.ambiguous",
                         "message": f"{c.name} explains the held-out data almost as well as {w.name} "
                                    f"(RMSE {c.heldout_rmse:.4g} vs {w.heldout_rmse:.4g}); the data cannot "
                                    "tell them apart"})
        if w.name == "external_disturbance" and ExternalDisturbance.at_limit_cycle(
                w.params.get("period_s"), runs[winner[0]].mismatch.limit_cycle_period_s):
            warn.append({"code": "physics.entrained",
                         "message": "the load's period is the loop's own oscillation period: an external "
                                    "oscillation entraining the loop, or a model error at the limit cycle, "
                                    "cannot be told apart from these data"})
        if w.params.get("tau_s") is not None and w.name == "actuator_lag" and w.params["tau_s"] < 0.75 * record.ts_s:
            warn.append({"code": "physics.sub_sample",
                         "message": "the fitted lag is shorter than one sample; the sampling is too coarse to "
                                    "resolve it"})
    else:
        ss = np.std(stage.y[stage.heldout]) or 1.0
        if min(base_rmse, run.ref_rmse) > 0.5 * ss:
            warn.append({"code": "physics.unexplained",
                         "message": "the baseline misses much of the held-out data but no hypothesis "
                                    "explains it significantly; see the located windows"})

    for sn, r in runs.items():
        idle = _idle_valve(r)
        if idle:
            warn.append({"code": "physics.valve_idle", "message": idle})
            break
    text = _text(record, winner, runs, report_stage, base_rmse, improved_rmse)
    summary = dict(run.mismatch.summary)
    summary["stage"] = report_stage
    summary["train_fraction"] = float(train_fraction)
    summary["heldout_start_s"] = float(n_tr * record.ts_s)
    summary["reference_rmse"] = float(run.ref_rmse)
    if len(runs) > 1:
        summary["other_stages"] = {sn: {"baseline_rmse": r.base_rmse, "reference_rmse": r.ref_rmse,
                                        "hints": r.mismatch.summary.get("hints", [])}
                                   for sn, r in runs.items() if sn != report_stage}
    arrays = _arrays(run, improved_hat, record, n_tr)
    order = {h.name: i for i, h in enumerate(hyps)}
    results = tuple(sorted((t[3] for t in all_results), key=lambda h: order.get(h.name, 99)))
    return Explanation(missing_physics=winner[3].name if winner else None,
                       baseline_rmse=float(base_rmse), improved_rmse=float(improved_rmse),
                       hypotheses=results, mismatch=summary, explanation=text, warnings=tuple(warn),
                       target=_TARGET[report_stage], loop=record.name,
                       baseline_source=run.baseline.source, arrays=arrays,
                       stages={sn: {"baseline": r.baseline.structure, "reference": r.reference}
                               for sn, r in runs.items()})


def _idle_valve(run: _StageRun) -> str | None:
    """Message when the identified valve hardly moves in the training or the held-out part."""
    if run.loc_stem is None or run.loc_hat is None:
        return None
    if run.stage.name == "valve":
        # the predicted MV: a fit to a stuck stem may slip with no gain (least-squares scale ~ 0)
        slips, _ = slips_and_reversals(np.asarray(run.loc_hat, float), eps=0.01)
    else:
        slips, _ = slips_and_reversals(np.asarray(run.loc_stem, float))
    tr = run.stage.train
    n_tr = int(np.sum(tr[slips]))
    n_ho = int(np.sum(run.stage.heldout[slips]))
    if n_tr >= MIN_SLIPS_TRAIN and n_ho >= MIN_SLIPS_HELDOUT:
        return None
    return (f"the identified valve moves only {n_tr} times in the training part and {n_ho} times in the "
            "held-out part: a valve that stays stuck carries no trace of its friction, so valve-side "
            "effects cannot be learned or judged from this record; a longer record, or one in which "
            "the loop cycles, is needed")


def _arrays(run: _StageRun, improved_hat: np.ndarray, record: LoopRecord, n_tr: int) -> dict[str, Any]:
    st = run.stage
    m = run.mismatch
    a = m.arrays
    t = np.arange(st.n) * st.ts_s
    s = m.summary
    return {
        "t_s": t, "observed": st.y, "baseline": run.baseline.y_hat, "reference": run.ref_hat,
        "improved": improved_hat, "residual_baseline": st.y - run.baseline.y_hat,
        "residual_located": st.y - run.loc_hat, "located_on": s.get("located_on", "baseline"),
        "residual_improved": st.y - improved_hat,
        "op_pct": st.x, "stem_hat_pct": run.loc_stem, "train_end_s": float(n_tr * st.ts_s),
        "train_start_s": float(int(np.argmax(st.train)) * st.ts_s),
        "windows": [(w["start_s"], w["end_s"]) for w in s["windows"]],
        "window_t_s": a["window_t_s"], "window_rms": a["window_rms"],
        "profile_lag_s": a["profile_lag_s"], "after_slip_profile": a["after_slip_profile"],
        "op_bin_centres_pct": a["op_bin_centres_pct"], "op_bin_rms": a["op_bin_rms"],
        "direction_rms": (s["direction"]["opening"]["rms"], s["direction"]["closing"]["rms"]),
        "freq_hz": a["freq_hz"], "residual_psd": a["residual_psd"],
        "limit_cycle_period_s": m.limit_cycle_period_s, "slip_t_s": a["slips"] * st.ts_s,
        "units": "% of span" if st.name == "valve" else (record.units.get("pv") or "PV units"),
    }


def _fmt_params(params: Mapping[str, float]) -> str:
    from ..plain import duration, number

    return ", ".join(f"{k} = {duration(v) if k.endswith('_s') else number(v)}" for k, v in params.items())


def _text(record, winner, runs, report_stage, base_rmse, improved_rmse) -> str:
    run = runs[report_stage]
    what = "MV (stem position) from OP" if report_stage == "valve" else "PV from OP"
    hints = run.mismatch.summary.get("hints", [])
    parts = [f"Baseline ({run.baseline.source}) simulating {what}: held-out RMSE {base_rmse:.4g}; "
             f"the same structure refit here: {run.ref_rmse:.4g}."]
    if hints:
        parts.append("Residual: " + "; ".join(hints) + ".")
    if winner:
        h = winner[3]
        from .hypotheses import REGISTRY

        desc = REGISTRY[h.name].description if h.name in REGISTRY else h.name
        parts.append(f"Missing physics: {h.name} ({desc}; {_fmt_params(h.params)}). "
                     f"With it the held-out RMSE falls to {improved_rmse:.4g} "
                     f"({-100 * (1 - improved_rmse / base_rmse) if base_rmse > 0 else 0:+.0f} % against the baseline).")
    else:
        best = min((t[2] for r in runs.values() for t in r.fitted), key=lambda h: h.heldout_rmse,
                   default=None)
        if best is not None:
            parts.append(f"No missing physics named: the best hypothesis ({best.name}, "
                         f"{_TARGET[best.stage].upper()}) changes the held-out RMSE by "
                         f"{-100 * best.reduction:+.0f} % against the refit plain model"
                         + (f"; refused: {best.refused}." if best.refused else "."))
        else:
            parts.append("No hypothesis was tested.")
    return " ".join(parts)
