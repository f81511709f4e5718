"""Identify stiction in one loop record: S, J, class, verdict, process model and context.

`identify(record)` runs, in order:

1. data checks (too short, constant OP or PV: `DataError`) and data quality (`diagnose.quality`);
2. S, J and the verdict: the valve + process model against the linear-only model (S = J = 0),
   with four kinds of evidence: a held-out test (even/odd interleaved blocks), the in-sample
   reduction of the prediction-error cost, a sharply determined S, and the likelihood ratio of a
   backlash-shaped (J = 0) valve; always S >= 0.5 %;
3. S, J and the process from the fit on the whole record (`diagnose.fit.fit_hammerstein`); when the
   stem position MV is recorded, S, J and the class come from the direct OP -> MV fit
   (`diagnose.valve_fit.fit_valve`) and ``method`` says so;
4. the class test (`diagnose.search.class_test`): the valve's starting stuck point as a nuisance parameter, and
   the special shapes J = 0 (deadband) and J = S (no offset) accepted when the data do not reject
   them against the free fit; then the class from `diagnose.stiction_model.stiction_class`
   (tolerance max(0.1 %, 15 % of S));
5. the oscillation context (`diagnose.oscillation`) and a confidence in [0, 1].

The threshold and its justification are in docs/fitting.md.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from . import search
from .errors import DataError
from .controller import ControllerAction, controller_action
from .fit import HammersteinFit, fit_hammerstein
from .objective import MIN_SAMPLES
from .oscillation import Oscillation, oscillation_context
from .record import Finding, LoopRecord
from .stiction_model import stiction_class
from .valve_fit import ValveFit, fit_valve

#: Relative reduction of the held-out output error the valve model must achieve over the
#: linear-only model to call stiction (see docs/fitting.md for how it was chosen).
DETECTION_THRESHOLD = 0.02
#: Smallest S (% of span) reported as stiction: below this a valve is within the resolution a
#: positioner and a control valve specification normally allow (about 0.5 % of span).
S_MIN_PCT = 0.5
#: In-sample relative reduction of the prediction-error cost (valve model against the linear model,
#: whole record, same noise model) that also counts as evidence, together with S >= S_MIN_PCT.
#: Set from the simulated calibration runs: healthy valves stayed below 0.03 (docs/fitting.md).
INSAMPLE_THRESHOLD = 0.05
#: Records longer than this are block-averaged for the held-out test (the verdict), not for S and J.
DETECT_MAX_SAMPLES = 4000
DETECT_COARSE_SAMPLES = 2000
#: Extra search windows of the Hammerstein fit (`diagnose.fit.fit_hammerstein`, ``windows``): the
#: record's first, middle and last third (at most 2000 samples each) are searched too, and the
#: cheapest whole-record refinement wins (docs/fitting.md, "Search windows").
FIT_WINDOWS = 3
#: Number of interleaved blocks for the held-out test.
N_BLOCKS = 6
#: Batches of the held-out losses for the paired t statistic.
N_BATCHES = 24
#: A sharply determined S also counts as evidence: the 95 % interval of S no wider than this
#: fraction of S, with an in-sample improvement above SHARP_MIN_INSAMPLE (a spurious S fitted to a
#: healthy valve sits on a flat error surface; a real one on a narrow valley). 0.5 % was tried
#: (deadband valves on slow processes improve the in-sample cost by only 0.7-0.9 %): +3 loops of
#: 480 on the calibration seeds, but two healthy false positives on a blind seed (docs/fitting.md).
SHARP_REL_WIDTH = 0.3
SHARP_MIN_INSAMPLE = 0.01
SHARP_MIN_S_PCT = 1.0
#: A backlash-shaped fit (J = 0 after the class test, S >= SHARP_MIN_S_PCT) also counts as evidence
#: when its likelihood ratio over the linear model, ``n_eff ln(c_linear / c_deadband)``, exceeds
#: the 0.1 % quantile of chi-square with one degree of freedom (docs/fitting.md).
BACKLASH_LR = 10.83
#: One-sided critical value of the paired t statistic (about 1 % for 20+ batches).
T_CRIT = 2.0
def _finite(v: float | None) -> float | None:
    if v is None:
        return None
    v = float(v)
    return v if math.isfinite(v) else None


@dataclass(frozen=True, eq=False)
class Identification:
    """The identification of one loop (`to_dict` gives the issue-3 JSON object).

    Attributes
    ----------
    loop : str
    stiction : bool
    cls : str
        One of `diagnose.stiction_model.CLASSES` (``"none"`` when ``stiction`` is False).
    S_pct, J_pct : float
        % of valve span, 0 when the class is ``none``.
    S_interval_pct, J_interval_pct : (float, float)
    process : ProcessModel or None
    rmse, r2 : float
        Free-run simulation fit of PV (or MV for the OP/MV method) over the record.
    oscillation : Oscillation
    warnings : tuple of dict
        ``{"code": str, "message": str}``.
    confidence : float
        Confidence in the verdict, 0..1.
    method : str
        ``"op_pv"`` (Hammerstein fit) or ``"op_mv"`` (valve fitted on the recorded stem position).
    detection : dict
        Numbers behind the verdict (held-out errors, improvement, threshold).
    data_quality : tuple of Finding
    fit : HammersteinFit or None
    valve_fit : ValveFit or None
    linear_fit : HammersteinFit or None
    controller : ControllerAction or None
        The controller's action and PI tuning read from OP, PV and SP; its sign constrains the
        process gain of the OP/PV fit.
    class_alternatives : tuple of str
        Other stiction classes the class test does not reject (their best cost lies within the
        same bound that accepts J = 0 or J = S); empty when the class is clear or ``none``.
    """

    loop: str
    stiction: bool
    cls: str
    S_pct: float
    J_pct: float
    S_interval_pct: tuple[float, float]
    J_interval_pct: tuple[float, float]
    process: Any
    rmse: float
    r2: float
    oscillation: Oscillation
    warnings: tuple = ()
    confidence: float = 0.0
    method: str = "op_pv"
    detection: dict = field(default_factory=dict)
    data_quality: tuple = ()
    fit: HammersteinFit | None = None
    valve_fit: ValveFit | None = None
    linear_fit: HammersteinFit | None = None
    n: int = 0
    ts_s: float = 1.0
    fitted_S_pct: float = 0.0
    fitted_J_pct: float = 0.0
    controller: ControllerAction | None = None
    class_alternatives: tuple = ()

    @property
    def klass(self) -> str:
        return self.cls

    def to_dict(self) -> dict[str, Any]:
        """The issue-3 JSON object (plus confidence, method, detection, data_quality)."""
        return {
            "loop": self.loop,
            "stiction": bool(self.stiction),
            "class": self.cls,
            "class_alternatives": list(self.class_alternatives),
            "S": float(self.S_pct),
            "J": float(self.J_pct),
            "S_interval": [float(self.S_interval_pct[0]), float(self.S_interval_pct[1])],
            "J_interval": [float(self.J_interval_pct[0]), float(self.J_interval_pct[1])],
            "process": self.process.to_dict() if self.process is not None else {},
            "fit": {"rmse": _finite(self.rmse), "r2": _finite(self.r2)},
            "oscillation": self.oscillation.to_dict(),
            "warnings": [dict(w) for w in self.warnings],
            "confidence": float(self.confidence),
            "method": self.method,
            "detection": {k: (_finite(v) if isinstance(v, float) else v) for k, v in self.detection.items()},
            "data_quality": [f.to_dict() for f in self.data_quality],
            "n_samples": int(self.n),
            "ts_s": float(self.ts_s),
            "controller": self.controller.to_dict() if self.controller is not None else None,
        }


def _blocks(n: int, n_blocks: int) -> tuple[np.ndarray, np.ndarray]:
    edges = np.linspace(0, n, n_blocks + 1).astype(int)
    train = np.zeros(n, bool)
    for b in range(0, n_blocks, 2):
        train[edges[b]:edges[b + 1]] = True
    return train, ~train


def _quality(record: LoopRecord) -> tuple[Finding, ...]:
    findings = tuple(record.findings)
    if not (record.meta or {}).get("quality_checked"):
        try:
            from . import quality
        except ImportError:  # pragma: no cover - quality module not installed
            return findings
        known = {(f.code, f.message) for f in findings}
        findings = findings + tuple(f for f in quality.assess(record) if (f.code, f.message) not in known)
    return findings


def _warn(code: str, message: str) -> dict[str, str]:
    return {"code": code, "message": message}


def _check(record: LoopRecord) -> None:
    if record.n < MIN_SAMPLES:
        raise DataError(f"loop {record.name!r} has {record.n} samples; identification needs at least "
                        f"{MIN_SAMPLES} (give a longer record)")
    if np.ptp(record.op) <= 0:
        raise DataError(f"loop {record.name!r}: OP is constant ({record.op[0]:g}) over the whole record; "
                        "the controller never moved the valve, so stiction cannot be identified "
                        "(pick a period in automatic with some control action)")
    if np.ptp(record.pv) <= 0:
        raise DataError(f"loop {record.name!r}: PV is constant ({record.pv[0]:g}) over the whole record; "
                        "check the PV column (--pv) or the instrument")


def _paired_t(loss_a: np.ndarray, loss_b: np.ndarray, block_id: np.ndarray, n_batches: int) -> float:
    """t statistic of the batch-wise log ratio ``log(mean loss_a / mean loss_b)``.

    The held-out losses are cut into contiguous batches inside each held-out block; batch means
    are close to independent when batches are long against the residuals' correlation time, and
    the log ratio makes the statistic scale-free (a loop whose disturbance level changes over the
    record does not dominate it).
    """
    ratios = []
    blocks = np.unique(block_id)
    for b in blocks:
        idx = np.flatnonzero(block_id == b)
        for part in np.array_split(idx, max(1, n_batches // max(1, blocks.size))):
            if part.size:
                la, lb = float(loss_a[part].mean()), float(loss_b[part].mean())
                if la > 0 and lb > 0:
                    ratios.append(math.log(la / lb))
    r = np.asarray(ratios)
    if r.size < 3:
        return 0.0
    se = float(r.std(ddof=1)) / math.sqrt(r.size)
    if se <= 0:
        return 100.0 if r.mean() > 0 else 0.0
    return float(min(r.mean() / se, 100.0))


def _decimate(op: np.ndarray, y: np.ndarray, ts_s: float, max_samples: int):
    """Block means of OP and y (about ``max_samples`` left) for the held-out test of long records."""
    n = op.shape[0]
    if n <= max_samples:
        return op, y, ts_s
    q = int(math.ceil(n / max_samples))
    nd = n // q
    return (op[: nd * q].reshape(nd, q).mean(axis=1), y[: nd * q].reshape(nd, q).mean(axis=1), ts_s * q)


def _detect(op: np.ndarray, y: np.ndarray, ts_s: float, fitter, n_blocks: int, **opts) -> dict[str, Any]:
    if op.shape[0] > DETECT_MAX_SAMPLES:
        op, y, ts_s = _decimate(op, y, ts_s, DETECT_COARSE_SAMPLES)
    opts = dict(opts, surface=False)
    train, test = _blocks(op.shape[0], n_blocks)
    f_v = fitter(op, y, ts_s, train=train, **opts)
    f_l = fitter(op, y, ts_s, train=train, stiction=False, **opts)
    h_v = f_v.hammerstein if isinstance(f_v, ValveFit) else f_v
    h_l = f_l.hammerstein if isinstance(f_l, ValveFit) else f_l
    r_v = h_v.heldout_residuals(op, y, test)
    r_l = h_l.heldout_residuals(op, y, test)
    e_v = float(r_v @ r_v) / r_v.size
    e_l = float(r_l @ r_l) / r_l.size
    imp = 1.0 - e_v / e_l if e_l > 0 else 0.0
    edges = np.linspace(0, op.shape[0], n_blocks + 1).astype(int)
    block_id = np.searchsorted(edges, np.flatnonzero(test), side="right")
    t = _paired_t(r_l ** 2, r_v ** 2, block_id, N_BATCHES)
    return {"heldout_mse_valve": e_v, "heldout_mse_linear": e_l, "improvement": imp, "t_stat": t,
            "train_S_pct": f_v.S_pct, "train_J_pct": f_v.J_pct}


def _backlash_lr(fit: HammersteinFit, linear: HammersteinFit, ctest: dict[str, Any]) -> float | None:
    """Likelihood ratio of the class test's deadband-shaped valve (J = 0) over the linear model,
    ``n_eff ln(c_linear / c_deadband)``, on the fit's cost scale (None when a cost is not positive).

    One extra parameter (S): a deadband cannot mimic a load step the way a slip jump can, so this
    shape's in-sample gain is not inflated like the free fit's (docs/fitting.md, "Detection")."""
    if not (linear.cost > 0 and ctest["cost_fit"] > 0):
        return None
    ratio = (fit.cost / linear.cost) * ctest["cost_deadband"] / ctest["cost_fit"]
    n_eff = fit.n_eff if math.isfinite(fit.n_eff) else float(fit.n_fit)
    return n_eff * math.log(1.0 / ratio) if ratio > 0 else math.inf


def identify(record: LoopRecord, *, threshold: float = DETECTION_THRESHOLD, n_blocks: int = N_BLOCKS,
             use_mv: bool = True, class_test: bool = True, **fit_opts) -> Identification:
    """Identify stiction (verdict, S, J, class) in one loop.

    Parameters
    ----------
    record : LoopRecord
    threshold : float
        Relative held-out error reduction required to call stiction.
    n_blocks : int
        Interleaved blocks of the held-out test (even blocks train, odd blocks test).
    use_mv : bool
        Fit the valve directly on OP -> MV when the record has a stem position.
    class_test : bool
        Test the special shapes J = 0 (deadband) and J = S (no offset) against the free (S, J)
        fit and report the restricted fit when the data do not reject it (`diagnose.search.class_test`).
    **fit_opts
        Passed to `diagnose.fit.fit_hammerstein` (e.g. ``n_S``, ``load_order``, ``hp_tau_s``;
        ``windows`` defaults to `FIT_WINDOWS`).

    Raises
    ------
    DataError
        The record cannot be identified (too short, constant OP or PV).
    """
    _check(record)
    findings = _quality(record)
    alternatives: tuple = ()
    warnings: list[dict[str, str]] = []
    compression = False
    for f in findings:
        if f.severity in ("warning", "error"):
            warnings.append(_warn(f"data_quality.{f.code}", f.message))
        if f.code == "compression" and f.severity != "info":
            compression = True
    op, pv, ts = record.op, record.pv, record.ts_s
    if float(np.min(op)) < 0.0 or float(np.max(op)) > 100.0:
        warnings.append(_warn("op_not_percent",
                              f"OP spans {float(np.min(op)):g}..{float(np.max(op)):g}, outside 0..100 % of "
                              "span (mean-centred or in engineering units?); it was shifted into the span, "
                              "so S and J are in OP's own units"))
    osc = oscillation_context(pv, ts, sp=record.sp, op=op)

    method = "op_pv"
    valve_fit = None
    mv_still = False
    if use_mv and record.mv is not None:
        method = "op_mv"
        mv = record.mv
        if np.ptp(mv) <= 1e-9 * max(1.0, abs(float(mv[0]))):
            mv_still = True
        else:
            valve_fit = fit_valve(op, mv, ts)

    # the controller's sign rules out the controller path (a linear block explaining PV through
    # OP = f(PV) always has the gain sign opposite to the plant's)
    ctl = controller_action(op, pv, ts, sp=record.sp)
    fit_opts = dict(fit_opts)
    fit_opts.setdefault("windows", FIT_WINDOWS)
    if ctl.sign and "gain_sign" not in fit_opts:
        fit_opts["gain_sign"] = ctl.sign
    # the Hammerstein fit on the whole record (process model, PV fit; S and J for op_pv)
    fit = fit_hammerstein(op, pv, ts, **fit_opts)
    linear = fit_hammerstein(op, pv, ts, stiction=False,
                             **dict(fit_opts, surface=False, hp_tau_s=fit.hp_tau_s))

    if mv_still:
        S_lo = float(np.percentile(op, 99.5) - np.percentile(op, 0.5))
        warnings.append(_warn("valve_not_moving",
                              f"the stem position (MV) never moves while OP travels {S_lo:.3g} % of span: "
                              "the valve is stuck (or MV is not the stem position); S is at least that, "
                              "J cannot be identified"))
        det = {"improvement": None, "threshold": threshold}
        stiction, S, J = True, S_lo, 0.0
        S_int, J_int = (S_lo, 100.0), (0.0, 100.0)
        cls = "deadband"
        confidence = 0.7
        rmse, r2 = fit.rmse, fit.r2
    else:
        if valve_fit is not None:
            S, J = valve_fit.S_pct, valve_fit.J_pct
            S_int, J_int = valve_fit.S_interval_pct, valve_fit.J_interval_pct
            rmse, r2 = valve_fit.rmse, valve_fit.r2
            ins = 0.0           # the direct OP/MV fit is judged by the held-out test alone
        else:
            S, J = fit.S_pct, fit.J_pct
            S_int, J_int = fit.S_interval_pct, fit.J_interval_pct
            rmse, r2 = fit.rmse, fit.r2
            ins = (1.0 - fit.cost / linear.cost) if linear.cost > 0 else 0.0
        ctest = None
        if class_test and valve_fit is None and S >= S_MIN_PCT:
            ctest = search.class_test(op, pv, ts, fit, float(fit_opts.get("burn_frac", 0.05)),
                                      fit_opts.get("gain_sign"))
            if ctest["cls"] is not None or ctest["cost"] < ctest["cost_fit"]:
                # the verdict's evidence stays that of the fit (no credit for the extra freedom)
                S, J = ctest["S_pct"], ctest["J_pct"]
                S_int = (min(S_int[0], S), max(S_int[1], S))
                J_int = (min(J_int[0], J), max(J_int[1], J))
        det = {"threshold": threshold, "S_min_pct": S_MIN_PCT, "t_crit": T_CRIT,
               "insample_threshold": INSAMPLE_THRESHOLD, "insample_improvement": ins}
        # The held-out test is positive evidence only: a valve fitted on half the record and
        # simulated with a slightly wrong S can stay out of step with the plant for long stretches
        # of the other half, so a bad held-out score does not veto clear in-sample evidence.
        insample_ok = ins > INSAMPLE_THRESHOLD
        rel_width = (S_int[1] - S_int[0]) / S if S > 0 else float("inf")
        det["S_rel_width"] = rel_width
        sharp_ok = (valve_fit is None and rel_width <= SHARP_REL_WIDTH and ins > SHARP_MIN_INSAMPLE
                    and S >= SHARP_MIN_S_PCT)
        backlash_ok = False
        if ctest is not None and S >= SHARP_MIN_S_PCT and stiction_class(S, J) == "deadband":
            lr = _backlash_lr(fit, linear, ctest)
            if lr is not None:
                det["backlash_lr"] = lr
                backlash_ok = lr > BACKLASH_LR
        # The held-out test is run only where it can change the verdict.
        if S >= S_MIN_PCT and not (insample_ok or sharp_ok or backlash_ok):
            if valve_fit is not None:
                det.update(_detect(op, record.mv, ts, fit_valve, n_blocks))
            else:
                det.update(_detect(op, pv, ts, fit_hammerstein, n_blocks, **fit_opts))
        else:
            det.update({"improvement": None, "t_stat": None})
        imp = det["improvement"]
        heldout_ok = imp is not None and imp > threshold and det["t_stat"] > T_CRIT
        det["rule"] = ("heldout" if heldout_ok else "insample" if insample_ok else "sharp" if sharp_ok
                       else "backlash" if backlash_ok else "none")
        if ctest is not None:
            det["class_test"] = {k: (float(v) if isinstance(v, (int, float)) else v) for k, v in ctest.items()}
        stiction = bool((heldout_ok or insample_ok or sharp_ok or backlash_ok) and S >= S_MIN_PCT)
        cls = stiction_class(S, J) if stiction else "none"
        if stiction and cls == "none":
            stiction = False
        if stiction and ctest is not None:
            alternatives = tuple(k for k in ctest["plausible"] if k != cls)
        # confidence: how far the evidence is from the decision boundary
        t = det["t_stat"]
        t_margin = (abs(t - T_CRIT) / T_CRIT if math.isfinite(t) else 3.0) if t is not None else 3.0
        if stiction and det["rule"] == "heldout":
            margin = min(t_margin, abs(imp - threshold) / 0.05)
        elif stiction:
            margin = ins / 0.1             # in-sample / sharp / backlash evidence: the size of the improvement
        elif S < S_MIN_PCT:
            margin = 3.0 * (S_MIN_PCT - S) / S_MIN_PCT      # no valve band worth reporting
        else:
            # no stiction: distance below the held-out and in-sample thresholds
            margin = max(0.0, min(t_margin if (t is not None and t < T_CRIT) else 0.0,
                                  (INSAMPLE_THRESHOLD - ins) / INSAMPLE_THRESHOLD * 3.0, 3.0))
        confidence = 0.5 + 0.5 * math.tanh(margin)
        if r2 < 0.2 and method == "op_pv":
            confidence *= 0.8
            warnings.append(_warn("poor_fit", f"the model explains little of PV (free-run r2 = {r2:.2f}); "
                                  "unmeasured disturbances dominate, the verdict is less certain"))
        if record.n < 5 * MIN_SAMPLES:
            confidence *= 0.8
            warnings.append(_warn("short_record", f"only {record.n} samples; longer records identify S and J "
                                  "more reliably"))
    fitted_S, fitted_J = S, J
    det["fitted_S_pct"] = float(fitted_S)
    det["fitted_J_pct"] = float(fitted_J)
    if compression:
        confidence = min(confidence, 0.5)
        if stiction:
            warnings.append(_warn("data_quality.compression",
                                  "historian compression can fake stiction shapes: the stiction verdict is "
                                  "hedged; confirm on uncompressed data"))
    if not stiction:
        S = J = 0.0
        S_int, J_int = (0.0, float(S_int[1])), (0.0, float(J_int[1]))
    seen = set()
    uniq = []
    for w in warnings:
        key = (w["code"], w["message"])
        if key not in seen:
            seen.add(key)
            uniq.append(w)
    return Identification(
        loop=record.name, stiction=stiction, cls=cls, S_pct=float(S), J_pct=float(J),
        S_interval_pct=(float(S_int[0]), float(S_int[1])), J_interval_pct=(float(J_int[0]), float(J_int[1])),
        process=fit.process, rmse=float(rmse), r2=float(r2), oscillation=osc, warnings=tuple(uniq),
        confidence=float(min(max(confidence, 0.0), 1.0)), method=method, detection=det,
        data_quality=findings, fit=fit, valve_fit=valve_fit, linear_fit=linear, n=record.n, ts_s=ts,
        fitted_S_pct=float(fitted_S), fitted_J_pct=float(fitted_J), controller=ctl,
        class_alternatives=alternatives)
