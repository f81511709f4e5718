"""Identify stiction in one loop record: verdict, S, J, class, process model and context.

`identify(record)` runs, in order:

1. data checks (too short, constant OP: `DataError`) and data quality (`diagnose.quality`); a
   record whose PV is unusable (flat, dead) is judged from OP's shape alone (`method="op_only"`);
2. S, J and the process from the Hammerstein fit on the whole record
   (`diagnose.fit.fit_hammerstein`); when the stem position MV is recorded, S, J and the class
   come from the direct OP -> MV fit (`diagnose.valve_fit.fit_valve`) and ``method`` says so;
3. the class test (`diagnose.search.class_test`): the valve's starting stuck point as a nuisance parameter, and
   the special shapes J = 0 (deadband) and J = S (no offset) accepted when the data do not reject
   them against the free fit; then the class from `diagnose.stiction_model.stiction_class`
   (tolerance max(0.1 %, 15 % of S));
4. the evidence (`diagnose.evidence`: the established non-invasive tests) and the fit's own
   evidence rows (`_fit_evidence`), combined into a calibrated probability of stiction and the
   verdict (`diagnose.verdict`); S, J and the class are reported where the verdict is stiction;
5. the oscillation context (`diagnose.oscillation`) and the confidence (the probability of the
   reported verdict, capped where the data are weak).

The combiner, its training corpus and its threshold are described in docs/verdict.md.
"""

from __future__ import annotations

import html
import math
import re
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Mapping, Sequence

import numpy as np

from . import quality, search
from .activity import ValveActivity, valve_activity
from .controller import ControllerAction, controller_action
from .errors import DataError
from .evidence import Evidence, pv_usable, run_all
from .fit import HammersteinFit, fit_hammerstein
from .notes import Note
from .objective import MIN_SAMPLES
from .oscillation import Oscillation, oscillation_context
from .plain import finite_or_none, op_amount, pct_per_op_unit, sj_decimals, units_in_words
from .process_model import ProcessModel
from .record import Finding, LoopRecord
from .stiction_model import stiction_class
from .valve_fit import ValveFit, fit_valve
from .verdict import Verdict, combine

if TYPE_CHECKING:  # the bank is imported only where a selection is made
    from matplotlib.figure import Figure

    from .narx.bank import Selection


#: Smallest S (% of span) at which the fit's own evidence counts: below this a valve is within the
#: resolution a positioner and a control valve specification normally allow (about 0.5 % of span).
#: The combined verdict may still find stiction below it from other evidence.
S_MIN_PCT = 0.5
#: Smallest fitted S (% of span) reported as a size when the verdict is stiction; below it the
#: class is ``unknown`` and S, J are not given (the fit found no band the evidence could be sized by).
S_SIZE_MIN_PCT = 0.1
#: Fewest slips of the fitted valve (times its modelled stem starts moving after standing still in
#: the record) from which S, J and the class are reported: one or two slips fit many (S, J) pairs
#: about equally well, and the intervals taken on the fit's error surface do not show it (they
#: measure the noise around the chosen valley, not which valley). The verdict itself does not use it.
SIZE_MIN_SLIPS = 3
#: In-sample relative reduction of the prediction-error cost (valve model against the linear model,
#: whole record, same noise model) at which the fit's row says stiction (set above what healthy
#: valves reach in the simulated calibration set; docs/fitting.md).
INSAMPLE_THRESHOLD = 0.05
#: The fitted band S at which the ``valve_band`` row says stiction, in multiples of OP's own
#: sample-to-sample noise (a band within OP's noise is moved through by the noise itself).
BAND_NOISE_RATIO = 3.0
#: Extra search windows of the Hammerstein fit (`diagnose.fit.fit_hammerstein`, ``windows``): the
#: record's first, middle and last third (at most 2000 samples each) are searched too, and the
#: cheapest whole-record refinement wins (docs/fitting.md, "Search").
FIT_WINDOWS = 3
#: A sharply determined S: the 95 % interval of S no wider than this fraction of S (a spurious S
#: fitted to a healthy valve sits on a flat error surface; a real one in a narrow valley).
SHARP_REL_WIDTH = 0.3
SHARP_MIN_S_PCT = 1.0
#: A backlash-shaped fit (J = 0 after the class test, S >= SHARP_MIN_S_PCT) says stiction when its
#: likelihood ratio over the linear model, ``n_eff ln(c_linear / c_deadband)``, exceeds the 0.1 %
#: quantile of chi-square with one degree of freedom (docs/fitting.md).
BACKLASH_LR = 10.83
#: Largest magnitude a signal may reach: beyond it no plant measurement lies, and squares overflow.
MAX_MAGNITUDE = 1e100
#: Upper bound on the confidence of a verdict judged from OP's shape alone (PV unusable).
OP_ONLY_CONFIDENCE_CAP = 0.75
#: A level tag (ISA letters L..C: LIC, LC, LRC) says the process is integrating.
_LEVEL_TAG = re.compile(r"(?<![A-Z])L[IR]?C(?=[0-9_.\-]|$)")
#: A flow tag (FIC, FC, FRC) says the process is self-regulating: a flow answers its valve within
#: seconds and settles; where the fit prefers an integrator it is following slow drift, not the
#: plant, and the evidence tests are those for self-regulating loops.
_FLOW_TAG = re.compile(r"(?<![A-Z])F[IR]?C(?=[0-9_.\-]|$)")


#: A regular cycle this slow (seconds) is a daily, shift or weather pattern of the plant (ambient
#: temperature, production schedule), not a loop oscillation: a valve's stick-slip cycle is set by
#: the loop's own dynamics (seconds to an hour). Reports call it a slow cycle and do not rank it.
SLOW_CYCLE_S = 4 * 3600.0


def _pair(v: tuple[float, float] | None) -> list[float | None] | None:
    return None if v is None else [finite_or_none(v[0]), finite_or_none(v[1])]


@dataclass(frozen=True)
class ClassTest:
    """The class test's numbers (`diagnose.search.class_test`): the valve's starting stuck point free,
    and the special shapes J = 0 (deadband) and J = S (no offset) against the free (S, J) fit.

    Costs are the fit's output-error cost (PV units squared per scored sample).

    Attributes
    ----------
    cls : str or None
        The restricted shape accepted (``"deadband"`` or ``"no_offset"``), None for the free fit.
    S_pct, J_pct : float
        The chosen (S, J), % of span.
    f0 : float
        The chosen starting direction (+1 or -1).
    delta_pct : float
        The chosen starting stuck point, relative to OP's first sample, % of span.
    cost, cost_fit, cost_free, cost_deadband, cost_no_offset : float
        The chosen shape's cost; the fit as it was; the best free, deadband and no-offset shapes.
    bound : float
        The chi-square bound a restricted shape's cost must stay within.
    free_S_pct, free_J_pct : float
        The best free shape.
    plausible : tuple of str
        Every class shape within the bound, best first.
    """

    cls: str | None
    S_pct: float
    J_pct: float
    f0: float
    delta_pct: float
    cost: float
    cost_fit: float
    cost_free: float
    cost_deadband: float
    cost_no_offset: float
    bound: float
    free_S_pct: float
    free_J_pct: float
    plausible: tuple[str, ...] = ()

    @classmethod
    def from_search(cls, d: Mapping[str, Any]) -> "ClassTest":
        """From the mapping `diagnose.search.class_test` returns."""
        return cls(cls=d["cls"], S_pct=float(d["S_pct"]), J_pct=float(d["J_pct"]), f0=float(d["f0"]),
                   delta_pct=float(d["delta_pct"]), cost=float(d["cost"]), cost_fit=float(d["cost_fit"]),
                   cost_free=float(d["cost_free"]), cost_deadband=float(d["cost_deadband"]),
                   cost_no_offset=float(d["cost_no_offset"]), bound=float(d["bound"]),
                   free_S_pct=float(d["free_S_pct"]), free_J_pct=float(d["free_J_pct"]),
                   plausible=tuple(str(k) for k in d["plausible"]))

    def to_dict(self) -> dict[str, Any]:
        return {"cost_fit": finite_or_none(self.cost_fit), "cost_free": finite_or_none(self.cost_free),
                "bound": finite_or_none(self.bound), "cost_deadband": finite_or_none(self.cost_deadband),
                "cost_no_offset": finite_or_none(self.cost_no_offset), "free_S_pct": finite_or_none(self.free_S_pct),
                "free_J_pct": finite_or_none(self.free_J_pct), "plausible": list(self.plausible), "cls": self.cls,
                "S_pct": finite_or_none(self.S_pct), "J_pct": finite_or_none(self.J_pct), "f0": finite_or_none(self.f0),
                "delta_pct": finite_or_none(self.delta_pct), "cost": finite_or_none(self.cost)}


@dataclass(frozen=True)
class Detection:
    """The numbers behind the fit's own evidence rows.

    Attributes
    ----------
    insample_improvement : float or None
        Relative reduction of the prediction-error cost by the valve model over a linear loop
        (whole record); None when the stem never moved.
    op_noise_pct : float or None
        OP's sample-to-sample noise, % of span.
    S_min_pct : float or None
        `S_MIN_PCT`: the smallest S at which the fit's evidence counts.
    fitted_S_pct, fitted_J_pct : float or None
        The fit's (S, J) before the verdict (reported S and J are 0 on a no-stiction verdict).
    integrating : bool or None
        Whether the process was judged integrating (None: not known).
    backlash_lr : float or None
        Likelihood ratio of a deadband-shaped valve over a linear loop, where the fit is one.
    class_test : ClassTest or None
    op_only : bool
        PV was unusable: the verdict came from OP's shape alone (the other numbers are None).
    pv_unusable : str or None
        Why PV was unusable (with ``op_only`` False: the valve was fitted on OP -> MV alone).
    """

    insample_improvement: float | None = None
    op_noise_pct: float | None = None
    S_min_pct: float | None = None
    fitted_S_pct: float | None = None
    fitted_J_pct: float | None = None
    integrating: bool | None = None
    backlash_lr: float | None = None
    class_test: ClassTest | None = None
    op_only: bool = False
    pv_unusable: str | None = None

    def to_dict(self) -> dict[str, Any]:
        if self.op_only:
            return {"op_only": True, "pv_unusable": self.pv_unusable}
        d: dict[str, Any] = {"insample_improvement": finite_or_none(self.insample_improvement),
                             "op_noise_pct": finite_or_none(self.op_noise_pct),
                             "S_min_pct": finite_or_none(self.S_min_pct),
                             "fitted_S_pct": finite_or_none(self.fitted_S_pct),
                             "fitted_J_pct": finite_or_none(self.fitted_J_pct), "integrating": self.integrating}
        if self.pv_unusable is not None:      # the valve was fitted on the stem position alone
            d["pv_unusable"] = self.pv_unusable
        if self.backlash_lr is not None:
            d["backlash_lr"] = finite_or_none(self.backlash_lr)
        if self.class_test is not None:
            d["class_test"] = self.class_test.to_dict()
        return d


@dataclass(frozen=True, eq=False)
class Identification:
    """The identification of one loop (`to_dict` gives the JSON object ``stiction identify`` prints).

    Attributes
    ----------
    loop : str
        The loop's name (tag).
    stiction : bool
        The combined verdict (`diagnose.verdict.combine`: the probability against its threshold,
        and the fit rule between 0.5 and the threshold).
    cls : str
        One of `diagnose.stiction_model.CLASSES` (``"none"`` when ``stiction`` is False), or
        ``"unknown"`` when the verdict is stiction but its size or shape cannot be given (OP-only
        judgement, a fit that finds no valve band, or a stem that never moved: `valve_not_moving`).
    S_pct, J_pct : float or None
        % of valve span (in OP's own units when `op_in_percent` is False), 0 when the class is
        ``none``, None when ``unknown`` or when the verdict came from OP alone (``op_only``: no
        model, so no size, whatever the verdict).
    S_interval_pct, J_interval_pct : (float, float) or None
        The 95 % intervals of S and J, same units; None where S and J are.
    process : ProcessModel or None
        The linear process of the Hammerstein fit (None for an OP-only judgement).
    rmse, r2 : float or None
        Free-run simulation fit of PV (or MV for the OP/MV method) over the record; None when no
        model was fitted (OP-only).
    oscillation : Oscillation
    warnings : tuple of Note
    confidence : float
        Probability of the reported verdict, 0..1, capped where the data are weak.
    method : str
        ``"op_pv"`` (Hammerstein fit), ``"op_mv"`` (valve fitted on the recorded stem position) or
        ``"op_only"`` (PV unusable: OP's shape alone).
    detection : Detection
        Numbers behind the fit's evidence (in-sample improvement, OP noise, class test).
    data_quality : tuple of Finding
    fit : HammersteinFit or None
    valve_fit : ValveFit or None
    linear_fit : HammersteinFit or None
    n : int
        Samples in the record.
    ts_s : float
        Sample period, seconds.
    fitted_S_pct, fitted_J_pct : float or None
        The fit's (S, J), whatever the verdict.
    controller : ControllerAction or None
        The controller's action and PI tuning read from OP, PV and SP; its sign constrains the
        process gain of the OP/PV fit.
    class_alternatives : tuple of str
        Other stiction classes the class test does not reject (their best cost lies within the
        same bound that accepts J = 0 or J = S); empty when the class is clear or ``none``.
    evidence : tuple of Evidence
        Every test's row: the non-invasive tests and the fit's own evidence.
    verdict : Verdict or None
        The combined verdict: probability, threshold, each row's contribution.
    narx : Selection or None
        The NARX-SP bank model nearest to the identified (S, J) (`diagnose.identify` and the service
        select it; `diagnose.identification.identify` alone leaves it None).
    source : str or None
        Where the record came from (file path), as `LoopRecord.source`.
    activity : ValveActivity or None
        Valve travel and reversals per day of record (OP, and MV where recorded; noise kept out by
        a hysteresis band) and the service factor where the record carries a mode signal
        (`diagnose.activity.valve_activity`, `record_activity`). Not part of the verdict.
    record : LoopRecord or None
        The record identified (for `plot`; not part of the JSON).
    """

    loop: str
    stiction: bool
    cls: str
    S_pct: float | None
    J_pct: float | None
    S_interval_pct: tuple[float, float] | None
    J_interval_pct: tuple[float, float] | None
    process: ProcessModel | None
    rmse: float | None
    r2: float | None
    oscillation: Oscillation
    warnings: tuple[Note, ...] = ()
    confidence: float = 0.0
    method: str = "op_pv"
    detection: Detection = field(default_factory=Detection)
    data_quality: tuple[Finding, ...] = ()
    fit: HammersteinFit | None = None
    valve_fit: ValveFit | None = None
    linear_fit: HammersteinFit | None = None
    n: int = 0
    ts_s: float = 1.0
    fitted_S_pct: float | None = None
    fitted_J_pct: float | None = None
    controller: ControllerAction | None = None
    class_alternatives: tuple[str, ...] = ()
    evidence: tuple[Evidence, ...] = ()
    verdict: Verdict | None = None
    narx: Selection | None = None
    source: str | None = None
    activity: ValveActivity | None = field(default=None, repr=False)
    record: LoopRecord | None = field(default=None, repr=False)

    @property
    def klass(self) -> str:
        return self.cls

    @property
    def stiction_probability(self) -> float | None:
        """The combined verdict's probability of stiction, 0..1 (None without a verdict)."""
        return None if self.verdict is None else self.verdict.stiction_probability

    @property
    def valve_not_moving(self) -> bool:
        """The recorded stem never moved: the class is ``unknown`` (not judged) and S is at least
        `fitted_S_pct`, OP's travel over the record."""
        return any(w.code == "valve_not_moving" for w in self.warnings)

    @property
    def op_in_percent(self) -> bool:
        """False when OP is not in % of span (`op_units`): it lay outside 0..100 % (mean-centred or
        in engineering units), or stayed within 0..1 with no stem position to scale it (a fraction
        of span). S and J are then in OP's own units, and every text says so."""
        return self.op_units == "% of span"

    @property
    def op_units(self) -> str:
        """The units of OP, and so of S, J and OP's travel: ``"% of span"``; ``"OP units"`` where OP
        lay outside 0..100 % (`op_in_percent` False); ``"fraction of span"`` where OP stayed
        within 0..1 and no stem position scaled it (warning ``data_quality.op_fraction``)."""
        return _op_units({w.code for w in self.warnings})

    @property
    def pct_per_op_unit(self) -> float:
        """% of span per unit of S and J (`diagnose.plain.pct_per_op_unit`): 100 where OP was
        logged as a fraction of span, else 1."""
        return pct_per_op_unit(self.op_units)

    @property
    def sj_digits(self) -> int:
        """Decimals S and J are written with (`diagnose.plain.sj_decimals`)."""
        return sj_decimals(self.op_units)

    @property
    def sj_units_text(self) -> str:
        """The units of S, J and OP's travel in words, as every text gives them
        (`diagnose.plain.units_in_words`)."""
        return units_in_words(self.op_units)

    @property
    def loop_oscillates(self) -> bool:
        """The loop oscillates regularly at a loop's own period (a slow cycle does not count)."""
        return bool(self.oscillation.oscillating) and not self.slow_cycle

    @property
    def slow_cycle(self) -> bool:
        """The regular cycle found is a daily or shift pattern (period >= `SLOW_CYCLE_S`)."""
        p = self.oscillation.period_s
        return bool(self.oscillation.oscillating) and p is not None and p >= SLOW_CYCLE_S

    def model_path(self, op_pct: np.ndarray | None = None) -> tuple[np.ndarray | None, np.ndarray | None]:
        """The fitted model's (valve path, PV) driven by ``op_pct`` (default: the record's OP).

        The valve path is the sticky valve that S and J describe (the valve fit on the stem position
        when S and J came from it, else the Hammerstein fit's valve); on a no-stiction verdict it is
        None and PV comes from the linear (no-stiction) fit. ``(None, None)`` when no model was
        fitted (OP-only judgement); PV None where PV was unusable and the valve was fitted on the
        stem position alone.
        """
        if op_pct is None:
            if self.record is None:
                raise DataError("this identification carries no record: pass op_pct")
            op_pct = self.record.op
        op = np.asarray(op_pct, dtype=float)
        fit = self.fit if self.stiction or self.linear_fit is None else self.linear_fit
        if fit is None:
            if self.stiction and self.valve_fit is not None:     # PV unusable: the valve alone
                return np.asarray(self.valve_fit.simulate(op), dtype=float), None
            return None, None
        mv_hat, pv_hat = (np.asarray(a, dtype=float) for a in fit.simulate(op))
        if not self.stiction:
            return None, pv_hat
        if self.method == "op_mv" and self.valve_fit is not None:
            mv_hat = np.asarray(self.valve_fit.simulate(op), dtype=float)
        return mv_hat, pv_hat

    def to_dict(self) -> dict[str, Any]:
        """The JSON object ``stiction identify --json`` prints."""
        return {
            "loop": self.loop,
            "stiction": bool(self.stiction),
            "stiction_probability": finite_or_none(self.stiction_probability),
            "class": self.cls,
            "class_alternatives": list(self.class_alternatives),
            "S": finite_or_none(self.S_pct),
            "J": finite_or_none(self.J_pct),
            "sj_units": self.op_units,
            "S_interval": _pair(self.S_interval_pct),
            "J_interval": _pair(self.J_interval_pct),
            "process": self.process.to_dict() if self.process is not None else {},
            "fit": {"rmse": finite_or_none(self.rmse), "r2": finite_or_none(self.r2)},
            "oscillation": self.oscillation.to_dict(),
            "evidence": [ev.to_dict() for ev in self.evidence],
            "combination": None if self.verdict is None else {
                "threshold": self.verdict.threshold, "op_only": self.verdict.op_only,
                "by_fit_rule": self.verdict.by_fit_rule,
                "contributions": {k: finite_or_none(v) for k, v in self.verdict.contributions.items()}},
            "warnings": [w.to_dict() for w in self.warnings],
            "confidence": float(self.confidence),
            "method": self.method,
            "detection": self.detection.to_dict(),
            "data_quality": [f.to_dict() for f in self.data_quality],
            "n_samples": int(self.n),
            "ts_s": float(self.ts_s),
            "controller": self.controller.to_dict() if self.controller is not None else None,
            "narx": None if self.narx is None else self.narx.to_dict(),
            "source": self.source,
            "activity": None if self.activity is None else self.activity.to_dict(),
        }

    # ------------------------------------------------------------------ notebooks
    def __repr__(self) -> str:
        p = self.stiction_probability
        size = ""
        if self.S_pct is not None and self.J_pct is not None and self.stiction:
            size = f", S_pct={self.S_pct:.3g}, J_pct={self.J_pct:.3g}"
        prob = "" if p is None else f", stiction_probability={p:.3f}"
        return (f"Identification(loop={self.loop!r}, stiction={self.stiction}, cls={self.cls!r}{size}{prob}, "
                f"confidence={self.confidence:.3f}, method={self.method!r}, n={self.n}, ts_s={self.ts_s:g}, "
                f"warnings={len(self.warnings)})")

    @property
    def nothing_judged(self) -> bool:
        """No test could judge the record: its "no stiction" is the combiner's prior, not a finding
        (warning ``nothing_judged``)."""
        return not self.stiction and self.verdict is not None and not self.verdict.judged

    @property
    def evidence_text(self) -> str:
        """The tests by what they said: ``"stiction: a, b; no stiction: c; undetermined: d;
        cannot judge: e"`` (a decision no test gave is left out)."""
        said = {k: [ev.test for ev in self.evidence if ev.decision == k]
                for k in ("stiction", "no_stiction", "undetermined", "cannot_judge")}
        return "; ".join(f"{k.replace('_', ' ')}: {', '.join(v)}" for k, v in said.items() if v)

    def _repr_html_(self) -> str:
        from .plain import duration, number

        e = html.escape
        unit = self.sj_units_text

        def iv(v: tuple[float, float] | None) -> str:
            return "" if v is None else f" [{number(v[0])}, {number(v[1])}]"

        rows = [("Verdict", ("stiction" if self.stiction else "no stiction") + f", class {self.cls}"),
                ("Probability of stiction", "-" if self.stiction_probability is None
                 else f"{self.stiction_probability:.0%}"),
                ("Confidence", f"{self.confidence:.0%}")]
        if self.S_pct is not None and self.J_pct is not None:
            rows += [("S", f"{number(self.S_pct)} {unit}{iv(self.S_interval_pct)}"),
                     ("J", f"{number(self.J_pct)} {unit}{iv(self.J_interval_pct)}")]
        rows.append(("Method", self.method))
        if self.process is not None:
            rows.append(("Process", self.process.describe()))
        if self.slow_cycle:
            rows.append(("Oscillation", f"slow cycle, period {duration(self.oscillation.period_s)}"))
        elif self.oscillation.oscillating:
            rows.append(("Oscillation", f"period {duration(self.oscillation.period_s)}, regularity "
                                        f"{self.oscillation.regularity:.2f}"))
        else:
            rows.append(("Oscillation", "none"))
        if self.evidence:
            rows.append(("Evidence", self.evidence_text))
        body = "".join(f"<tr><th style='text-align:left'>{e(k)}</th><td style='text-align:left'>{e(v)}</td></tr>"
                       for k, v in rows)
        warn = "".join(f"<li><code>{e(w.code)}</code> {e(w.message)}</li>" for w in self.warnings)
        return (f"<div><strong>Identification of {e(self.loop)}</strong> ({self.n} samples every "
                f"{e(duration(self.ts_s))})<table>{body}</table>"
                + (f"<p>Warnings:</p><ul>{warn}</ul>" if warn else "") + "</div>")

    def plot(self, kind: str = "trends") -> "Figure":
        """The report's figure of this identification as a new matplotlib `Figure`.

        Parameters
        ----------
        kind : {"trends", "phase", "surface", "spectrum"}
            ``trends``: SP, PV, OP (and MV) over the whole record with the fitted model beneath;
            ``phase``: OP-PV (and OP-MV) over the last 1000 samples; ``surface``: the (S, J) error
            surface of the fit that gave S and J; ``spectrum``: PV's power against period.
        """
        from . import figures

        if self.record is None:
            raise DataError("this identification carries no record to plot")
        return figures.plot_identification(self, kind)




def _op_units(codes: set[str]) -> str:
    """OP's units from a record's warning codes (`Identification.op_units`)."""
    if "op_not_percent" in codes:
        return "OP units"
    return "fraction of span" if "data_quality.op_fraction" in codes else "% of span"


def _warn(code: str, message: str) -> Note:
    return Note(code, message)


def record_activity(record: LoopRecord) -> ValveActivity:
    """`valve_activity` of a record: OP, the stem position where recorded, and the service factor
    where a connector read a mode column (``meta["has_mode"]``; ``meta["manual_intervals"]`` and
    ``meta["mode_unknown_intervals"]``, ``[start, stop)`` sample ranges in manual and of unknown
    mode); without one the service factor is None."""
    meta = record.meta or {}
    auto = None
    iv = meta.get("manual_intervals")
    if meta.get("has_mode") or iv is not None:
        auto = np.ones(record.n)
        for value, intervals in ((0.0, iv), (np.nan, meta.get("mode_unknown_intervals"))):
            for a, b in intervals or ():
                auto[max(int(a), 0):max(min(int(b), record.n), 0)] = value
    mv = record.mv if record.mv is not None and np.all(np.isfinite(record.mv)) else None
    return valve_activity(record.op, record.ts_s, mv_pct=mv, mode_auto=auto)


def _check(record: LoopRecord) -> None:
    if record.n < MIN_SAMPLES:
        # a record cut short by max_samples is not a short export: name the option to raise
        cut = next((f for f in record.findings if f.code == "window"), None)
        fix = (f"max_samples (--max-samples) kept only the newest of its {cut.data['samples']}; give "
               f"{MIN_SAMPLES} or more, or 0 to keep every sample" if cut else "give a longer record")
        raise DataError(f"loop {record.name!r} has {record.n} samples; identification needs at least "
                        f"{MIN_SAMPLES} ({fix})")
    for role in ("op", "pv", "sp", "mv"):
        x = getattr(record, role)
        big = 0.0 if x is None else float(np.max(np.abs(x), where=np.isfinite(x), initial=0.0))
        if big > MAX_MAGNITUDE:
            # squares of such values overflow in every variance and spectrum the tests take
            raise DataError(f"loop {record.name!r}: {role.upper()} reaches {big:.3g} in "
                            "magnitude, which no plant measurement does (an overflow or a unit error in the "
                            "export): check the column's values")
    if np.ptp(record.op) <= 0:
        raise DataError(f"loop {record.name!r}: OP is constant ({record.op[0]:g}) over the whole record; "
                        "the controller never moved the valve, so stiction cannot be identified "
                        "(pick a period in automatic with some control action)")


def _backlash_lr(fit: HammersteinFit, linear: HammersteinFit, ctest: dict[str, Any]) -> float | None:
    """Likelihood ratio of the class test's deadband-shaped valve (J = 0) over the linear model,
    ``n_eff ln(c_linear / c_deadband)``, on the fit's cost scale (None when a cost is not positive).

    One extra parameter (S): a deadband cannot mimic a load step the way a slip jump can, so this
    shape's in-sample gain is not inflated like the free fit's (docs/fitting.md, "The fit's evidence")."""
    if not (linear.cost > 0 and ctest["cost_fit"] > 0):
        return None
    ratio = (fit.cost / linear.cost) * ctest["cost_deadband"] / ctest["cost_fit"]
    n_eff = fit.n_eff if math.isfinite(fit.n_eff) else float(fit.n_fit)
    return n_eff * math.log(1.0 / ratio) if ratio > 0 else math.inf


def _op_noise_pct(op: np.ndarray) -> float:
    """OP's sample-to-sample noise, % of span: a robust sd of its first differences over sqrt(2).

    The floor S is judged against: a valve band smaller than a few times this is within what OP's
    own noise moves the valve by anyway."""
    d = np.diff(np.asarray(op, dtype=float))
    if d.size < 2:
        return 0.0
    mad = float(np.median(np.abs(d - np.median(d))))
    return 1.4826 * mad / math.sqrt(2.0)


def _tag_process(name: str | None) -> bool | None:
    """What the loop's tag says of its process: True (integrating) for a level tag, False
    (self-regulating) for a flow tag that is not also a level tag, None where it says neither."""
    name = name or ""
    if _LEVEL_TAG.search(name):
        return True
    if _FLOW_TAG.search(name):
        return False
    return None


def _integrating_hint(record: LoopRecord, fit: HammersteinFit | None) -> bool | None:
    """Is the process integrating? A flow tag (``FIC``/``FC``) says no; otherwise the fit's chosen
    structure, or a level tag (``LIC``/``LC``)."""
    tag = _tag_process(record.name)
    if tag is False:
        return False
    if fit is not None and fit.process is not None and fit.process.kind == "integrating":
        return True
    if tag:
        return True
    return False if fit is not None else None


def _slips(mv_pct: np.ndarray) -> int:
    """How many times a modelled stem path starts moving after standing still (its slips)."""
    moving = np.abs(np.diff(np.asarray(mv_pct, dtype=float))) > 1e-9
    return int(np.count_nonzero(moving[1:] & ~moving[:-1]))


def _fit_evidence(*, S_pct: float, S_int: tuple[float, float], ins: float | None, n_eff: float | None,
                  ins_own_noise: float | None, backlash_lr: float | None, op_noise_pct: float,
                  op_range_pct: float, slips: int, osc: Oscillation, method: str,
                  op_units: str = "% of span") -> tuple[Evidence, ...]:
    """The Hammerstein (or OP/MV valve) fit's own evidence as rows of the evidence table.

    ``model_fit`` carries the improvement itself and, as ``lr``, the likelihood ratio
    ``n_eff ln(c_linear / c_valve)``: an improvement weighed by how many independent samples back
    it (a 5 % gain over 10 000 samples is stronger evidence than over 500). For ``lr`` each model
    is scored under its own best noise model (``ins_own_noise``, from the fits' ``noise_costs``):
    the shared noise model is the linear loop's choice, and where the valve explains slow error
    the linear loop leaves, that choice filters out the very error the valve explains."""
    rows = []
    pct = pct_per_op_unit(op_units)    # the floors below are in % of span
    src = "the valve fitted on the stem position" if method == "op_mv" else "the valve + process model"
    if ins is not None:
        dec = "stiction" if ins > INSAMPLE_THRESHOLD else "no_stiction"
        extras = {}
        if n_eff is not None and math.isfinite(n_eff) and ins < 1.0:
            gain = ins if ins_own_noise is None else min(ins_own_noise, 1.0 - 1e-12)
            extras["lr"] = min(n_eff * -math.log1p(-max(gain, 0.0)), 1e4)
        note = (f"{src} explains {100 * ins:.1f} % of the error a linear loop leaves "
                f"(threshold {100 * INSAMPLE_THRESHOLD:.0f} %)")
        if ins_own_noise is not None and ins_own_noise > ins + 0.01:
            # the likelihood ratio reads this larger figure: say where it comes from
            note += (f"; {100 * ins_own_noise:.1f} % with each model under its own noise model, as the "
                     "likelihood ratio compares them")
        rows.append(Evidence("model_fit", ins, INSAMPLE_THRESHOLD, dec, note, extras=extras))
    ratio = S_pct / op_noise_pct if op_noise_pct > 0 else (100.0 if S_pct > 0 else 0.0)
    ratio = min(ratio, 100.0)
    dec = "stiction" if ratio >= BAND_NOISE_RATIO and S_pct * pct >= S_MIN_PCT else "no_stiction"
    # a band that OP hardly ever crosses is a valve that hardly moves: little for the fit to go by
    if op_units == "% of span":
        noise, travel = f"{op_noise_pct:.3g} %", f"{op_range_pct:.3g} % of span"
    else:   # the same numbers in OP's own units (a fraction of span, or engineering units)
        noise, travel = f"{op_noise_pct:.3g}", f"{op_range_pct:.3g} (the same units)"
    rows.append(Evidence("valve_band", ratio, BAND_NOISE_RATIO, dec,
                         f"fitted valve band S = {op_amount(S_pct, op_units)} is {ratio:.1f} times OP's own "
                         f"sample-to-sample noise ({noise}); the fitted valve slips "
                         f"{'once' if slips == 1 else f'{slips} times'} as OP travels over {travel}",
                         extras={"S_pct": S_pct, "slips": float(slips),
                                 "S_over_range": S_pct / op_range_pct if op_range_pct > 0 else 1.0}))
    if S_pct > 0 and math.isfinite(S_int[1] - S_int[0]):
        width = (S_int[1] - S_int[0]) / S_pct
        dec = "stiction" if width <= SHARP_REL_WIDTH and S_pct * pct >= SHARP_MIN_S_PCT else "undetermined"
        rows.append(Evidence("band_sharpness", min(width, 10.0), SHARP_REL_WIDTH, dec,
                             f"the 95 % interval of S is {100 * width:.0f} % of S wide (a real band sits in a "
                             "narrow valley of the fit's error; a spurious one on a flat surface)"))
    if backlash_lr is not None:
        lr = min(float(backlash_lr), 1000.0)
        dec = "stiction" if lr > BACKLASH_LR else "no_stiction"
        rows.append(Evidence("deadband_fit", lr, BACKLASH_LR, dec,
                             f"likelihood ratio {lr:.1f} of a deadband-shaped valve over a linear loop "
                             f"(threshold {BACKLASH_LR}: chi-square, 1 degree of freedom, 0.1 %)"))
    if osc.regularity > 0:
        if osc.oscillating:
            note = (f"PV oscillates regularly (regularity {osc.regularity:.2f}, period "
                    f"{osc.period_s:.0f} s); regularity alone does not say what causes it")
        elif osc.regularity > 1.0:
            # a few long cycles can look regular by chance: the record is too short to say
            note = (f"too few cycles to call the oscillation regular ({osc.cycles:.1f} periods of "
                    f"{osc.period_s:.0f} s in the record, regularity {osc.regularity:.2f}; needs at "
                    "least 2 periods and 4 half-periods in PV's autocorrelation)")
        else:
            note = f"no regular oscillation (regularity {osc.regularity:.2f}, threshold 1)"
        rows.append(Evidence("oscillation_regularity", min(osc.regularity, 20.0), 1.0, "undetermined", note))
    return tuple(rows)


def _confidence_caps(findings: Sequence[Finding], n: int, r2: float | None, method: str,
                     warnings: list[Note]) -> float:
    """Upper bound on the confidence from what weakens the data, with a warning for each."""
    cap = 1.0
    codes = {f.code for f in findings if f.severity != "info"}
    if "compression" in codes:
        cap = min(cap, 0.5)
        # one finding, one warning: the finding's own warning (what was seen) also says what it
        # does to the verdict, rather than a second warning of the same code counting twice
        hedge = "the verdict is hedged; confirm on uncompressed data"
        seen = next((i for i, w in enumerate(warnings) if w.code == "data_quality.compression"), None)
        if seen is None:
            warnings.append(_warn("data_quality.compression",
                                  f"historian compression can fake (and hide) stiction shapes: {hedge}"))
        else:
            warnings[seen] = _warn("data_quality.compression", f"{warnings[seen].message}; {hedge}")
    if "op_fraction" in codes:
        cap = min(cap, 0.5)
    if "duplicates" in codes:
        # a warning only where many rows share a time stamp (a spreadsheet dropped the seconds):
        # the rows kept are one per stamp, so the record's period and its dynamics are not the plant's
        cap = min(cap, 0.5)
    if r2 is not None and r2 < 0.2 and method == "op_pv":
        cap = min(cap, 0.8)
        warnings.append(_warn("poor_fit", f"the model explains little of PV (free-run r2 = {r2:.2f}); "
                              "unmeasured disturbances dominate, the verdict is less certain"))
    if n < 5 * MIN_SAMPLES:
        cap = min(cap, 0.8)
        warnings.append(_warn("short_record", f"only {n} samples; longer records identify S and J "
                              "more reliably"))
    return cap


def _unique(warnings: list[Note]) -> tuple[Note, ...]:
    return tuple(dict.fromkeys(warnings))


def _reported_size(stiction: bool, S: float, J: float, S_int: tuple[float, float], J_int: tuple[float, float],
                   pct: float, units: str, no_band: str, warnings: list[Note], slips: int):
    """The class, S, J and their intervals a verdict reports from a fit's (S, J) (in OP's units;
    ``pct`` % of span per unit): 0 with the intervals' upper ends on a no-stiction verdict, and
    class ``unknown`` without a size where other evidence found stiction the fit could not size
    (``no_band`` says which fit, in the ``size_unknown`` warning) or where the fitted valve slips
    fewer than `SIZE_MIN_SLIPS` times."""
    if not stiction:
        return "none", 0.0, 0.0, (0.0, float(S_int[1])), (0.0, float(J_int[1]))
    cls = stiction_class(S * pct, J * pct)
    if cls == "none" or S * pct < S_SIZE_MIN_PCT:
        warnings.append(_warn("size_unknown", f"the evidence says the valve sticks but {no_band} "
                              f"(S = {op_amount(S, units)}): S, J and the class cannot be given"))
        return "unknown", None, None, S_int, J_int
    if slips < SIZE_MIN_SLIPS:
        times = {0: "never slips", 1: "slips only once", 2: "slips only twice"}.get(slips, f"slips only {slips} times")
        warnings.append(_warn("size_unknown",
                              f"the evidence says the valve sticks, but the fitted valve {times} in this "
                              f"record (its fit: S = {op_amount(S, units)}, J = {op_amount(J, units)}): "
                              f"too few slips to size S and J or tell the class (needs "
                              f"{SIZE_MIN_SLIPS}); a longer record, or one with setpoint moves, shows more"))
        return "unknown", None, None, S_int, J_int
    return cls, S, J, S_int, J_int


def _valve_improvement(valve_fit, op: np.ndarray, mv: np.ndarray, ts: float) -> float:
    """Relative fall of the OP -> MV cost from a linear valve to the fitted sticky one."""
    lin_v = fit_valve(op, mv, ts, stiction=False).hammerstein.cost
    # a stem that follows OP exactly leaves the linear valve a cost at rounding level: the ratio of
    # two such costs means nothing, and there is nothing to improve on
    if lin_v <= 1e-12 * max(float(np.var(mv)), 1e-300):
        return 0.0
    return max(1.0 - valve_fit.hammerstein.cost / lin_v, -1.0)


def _identify_valve_only(record: LoopRecord, findings: tuple[Finding, ...], warnings: list[Note],
                         reason: str, integrating: bool | None, units: str) -> Identification:
    """The verdict, S, J and class from the valve fit on OP -> MV, for a record whose PV is unusable
    but whose stem moved: the valve is seen directly, so no process model is needed to size it.
    The PV-based tests cannot judge; the verdict is the OP/MV combiner's on what remains."""
    op, mv, ts = record.op, record.mv, record.ts_s
    osc = oscillation_context(op, ts)
    warnings.append(_warn("pv_unusable",
                          f"PV is unusable ({reason}): the valve is sized from the stem position (MV) alone; "
                          "no process model, and the PV-based tests cannot judge"))
    if integrating is None:
        integrating = _tag_process(record.name)
    pct = pct_per_op_unit(units)
    vf = fit_valve(op, mv, ts)
    S_seen, J_seen = float(vf.S_pct), float(vf.J_pct)
    # the band the stem shows bounds S from above even where it is read as none
    S_int, J_int = vf.S_interval_pct, vf.J_interval_pct
    if S_seen * pct < S_MIN_PCT:
        # the stem is seen directly and no PV test can weigh in: a band within what a positioner
        # allows is read as none, or a precisely fitted 0.2 % backlash (or a band fitted to a stem
        # that follows a noiseless OP ramp) would be called stiction on the fit's rows alone
        warnings.append(_warn("band_below_resolution",
                              f"the stem position shows a band of {op_amount(S_seen, units)}, under the "
                              f"{S_MIN_PCT:g} % of span a positioner normally allows: read as a valve without "
                              "a band"))
        vf, ins = fit_valve(op, mv, ts, stiction=False), 0.0
    else:
        ins = _valve_improvement(vf, op, mv, ts)
    op_noise = _op_noise_pct(op)
    slips = _slips(vf.hammerstein.simulate(op)[0])
    fit_rows = _fit_evidence(S_pct=float(vf.S_pct), S_int=vf.S_interval_pct, ins=ins, n_eff=vf.hammerstein.n_eff,
                             ins_own_noise=None, backlash_lr=None, op_noise_pct=op_noise,
                             op_range_pct=float(np.percentile(op, 99) - np.percentile(op, 1)),
                             slips=slips, osc=osc, method="op_mv", op_units=units)
    evidence = tuple(run_all(op, record.pv, ts, sp=record.sp, integrating=integrating, op_units=units)) + fit_rows
    cap = _confidence_caps(findings, record.n, vf.r2, "op_mv", warnings)
    verdict = combine(evidence, kind="op_mv", confidence_cap=cap)
    S, J = float(vf.S_pct), float(vf.J_pct)
    cls, S_out, J_out, S_int, J_int = _reported_size(verdict.stiction, S, J, S_int, J_int,
                                                     pct, units, "the valve fit finds no band", warnings, slips)
    det = Detection(insample_improvement=ins, op_noise_pct=op_noise, S_min_pct=S_MIN_PCT, fitted_S_pct=S_seen,
                    fitted_J_pct=J_seen, integrating=integrating, pv_unusable=reason)
    return Identification(
        loop=record.name, stiction=verdict.stiction, cls=cls, S_pct=S_out, J_pct=J_out,
        S_interval_pct=None if S_out is None else (float(S_int[0]), float(S_int[1])),
        J_interval_pct=None if J_out is None else (float(J_int[0]), float(J_int[1])),
        process=None, rmse=float(vf.rmse), r2=float(vf.r2), oscillation=osc, warnings=_unique(warnings),
        confidence=float(min(max(verdict.confidence, 0.0), 1.0)), method="op_mv", detection=det,
        data_quality=findings, valve_fit=vf, n=record.n, ts_s=ts, fitted_S_pct=S_seen, fitted_J_pct=J_seen,
        evidence=evidence, verdict=verdict, source=record.source, activity=record_activity(record),
        record=record)


def _identify_op_only(record: LoopRecord, findings: tuple[Finding, ...], warnings: list[Note],
                      reason: str, integrating: bool | None) -> Identification:
    """The verdict from OP's shape alone, for a record whose PV is unusable."""
    op, ts = record.op, record.ts_s
    osc = oscillation_context(op, ts)
    warnings.append(_warn("pv_unusable",
                          f"PV is unusable ({reason}): the verdict is judged from OP's shape alone and is "
                          "less certain; S and J need a usable PV or a recorded stem position that moves"))
    if integrating is None:
        integrating = _tag_process(record.name)
    evidence = run_all(op, record.pv, ts, sp=record.sp, integrating=integrating,
                       op_units=_op_units({w.code for w in warnings}))
    cap = min(OP_ONLY_CONFIDENCE_CAP, _confidence_caps(findings, record.n, None, "op_only", warnings))
    verdict = combine(evidence, kind="op_only", confidence_cap=cap)
    if not verdict.judged:
        warnings.append(_warn("nothing_judged", "no test could judge this record: the verdict is the combiner's "
                              "prior, and 'no stiction' here means no evidence either way, not a healthy valve"))
    det = Detection(op_only=True, pv_unusable=reason)
    return Identification(
        loop=record.name, stiction=verdict.stiction, cls="unknown" if verdict.stiction else "none",
        S_pct=None, J_pct=None, S_interval_pct=None, J_interval_pct=None, process=None,
        rmse=None, r2=None, oscillation=osc, warnings=_unique(warnings), confidence=verdict.confidence,
        method="op_only", detection=det, data_quality=findings, n=record.n, ts_s=ts,
        evidence=tuple(evidence), verdict=verdict, source=record.source, activity=record_activity(record),
        record=record)


def identify(record: LoopRecord, *, use_mv: bool = True, class_test: bool = True,
             integrating: bool | None = None, **fit_opts) -> Identification:
    """Identify stiction (verdict, S, J, class) in one loop.

    Parameters
    ----------
    record : LoopRecord
    use_mv : bool
        Fit the valve directly on OP -> MV when the record has a stem position.
    class_test : bool
        Test the special shapes J = 0 (deadband) and J = S (no offset) against the free (S, J)
        fit and report the restricted fit when the data do not reject it (`diagnose.search.class_test`).
    integrating : bool, optional
        Whether the process is integrating (a level loop); by default the fitted structure, or a
        level tag (``LIC``), decides. Some evidence tests read different signals for each kind.
    **fit_opts
        Passed to `diagnose.fit.fit_hammerstein` (e.g. ``n_S``, ``load_order``, ``hp_tau_s``;
        ``windows`` defaults to `FIT_WINDOWS`).

    Raises
    ------
    DataError
        The record cannot be judged at all (too short, OP constant).
    """
    _check(record)
    findings = quality.findings_of(record)
    warnings: list[Note] = []
    if use_mv:
        record, findings, note = quality.op_in_percent(record, findings)
        if note:
            warnings.append(_warn("op_rescaled", note))
    for f in findings:
        if f.severity in ("warning", "error"):
            warnings.append(_warn(f"data_quality.{f.code}", f.message))
    op, pv, ts = record.op, record.pv, record.ts_s
    if float(np.min(op)) < 0.0 or float(np.max(op)) > 100.0:
        warnings.append(_warn("op_not_percent",
                              f"OP spans {float(np.min(op)):g}..{float(np.max(op)):g}, outside 0..100 % of "
                              "span (mean-centred or in engineering units?); it was shifted into the span, "
                              "so S and J are in OP's own units"))
    # what S and J come out in: the floors and the class tolerances below are in % of span
    units = _op_units({w.code for w in warnings})
    pct = pct_per_op_unit(units)
    if any(f.code == "pv_missing" for f in findings):
        pv_ok, pv_reason = False, "the file holds no usable PV value"
    else:
        pv_ok, pv_reason = pv_usable(pv)
    if not pv_ok:
        # the loop fit needs PV even where the stem position is recorded (process model, controller
        # action, the PV-based tests), so the verdict falls back to OP's shape
        if use_mv and record.mv is not None and np.ptp(record.mv) > 1e-9 * max(1.0, abs(float(record.mv[0]))):
            return _identify_valve_only(record, findings, warnings, pv_reason, integrating, units)
        if use_mv and record.mv is not None:
            warnings.append(_warn("mv_unused", "the stem position (MV) is recorded but never moves, and PV is "
                                  "unusable: a still stem without PV says nothing of the valve, so the verdict "
                                  "is judged from OP's shape"))
        return _identify_op_only(record, findings, warnings, pv_reason, integrating)
    osc = oscillation_context(pv, ts, sp=record.sp, op=op)

    method = "op_pv"
    valve_fit = None
    mv_still = False
    if use_mv and record.mv is not None:
        method = "op_mv"
        mv = record.mv
        travel = float(np.percentile(op, 99.5) - np.percentile(op, 0.5))
        still = np.ptp(mv) <= 1e-9 * max(1.0, abs(float(mv[0])))
        if still and travel < S_MIN_PCT:
            # OP never asked for more than a band the verdict would not call stiction: a still
            # stem says nothing of the valve, so the verdict is OP/PV's
            method = "op_pv"
            warnings.append(_warn("mv_uninformative",
                                  f"the stem position (MV) never moves, but OP travels only {travel:.2g} % of "
                                  f"span, less than the {S_MIN_PCT:g} % band the verdict calls stiction: a "
                                  "healthy valve need not move either, so the stem says nothing and the "
                                  "verdict is judged from OP and PV"))
        elif still:
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
    if integrating is None:
        integrating = _integrating_hint(record, fit)

    alternatives: tuple[str, ...] = ()
    ctest = None
    backlash_lr = None
    if mv_still:
        S_lo = travel
        warnings.append(_warn("valve_not_moving",
                              f"the stem position (MV) never moves while OP travels {S_lo:.3g} % of span: "
                              "the valve is stuck (or MV is not the stem position); S is at least that, "
                              "but J and the class (the shape of the friction) cannot be judged from a "
                              "valve that never moved"))
        S, J = S_lo, 0.0
        S_int, J_int = (S_lo, 100.0), (0.0, 100.0)
        rmse, r2 = fit.rmse, fit.r2
        ins = None
    else:
        if valve_fit is not None:
            S, J = valve_fit.S_pct, valve_fit.J_pct
            S_int, J_int = valve_fit.S_interval_pct, valve_fit.J_interval_pct
            rmse, r2 = valve_fit.rmse, valve_fit.r2
            ins = _valve_improvement(valve_fit, op, record.mv, ts)
        else:
            S, J = fit.S_pct, fit.J_pct
            S_int, J_int = fit.S_interval_pct, fit.J_interval_pct
            rmse, r2 = fit.rmse, fit.r2
            ins = (1.0 - fit.cost / linear.cost) if linear.cost > 0 else 0.0
        if class_test and valve_fit is None and S * pct >= S_MIN_PCT:
            ctest = search.class_test(op, pv, ts, fit, float(fit_opts.get("burn_frac", 0.05)),
                                      fit_opts.get("gain_sign"), threads=fit_opts.get("threads"),
                                      pct_per_unit=pct)
            if ctest["cls"] is not None or ctest["cost"] < ctest["cost_fit"]:
                # the verdict's evidence stays that of the fit (no credit for the extra freedom)
                S, J = ctest["S_pct"], ctest["J_pct"]
                S_int = (min(S_int[0], S), max(S_int[1], S))
                J_int = (min(J_int[0], J), max(J_int[1], J))
            if S * pct >= SHARP_MIN_S_PCT and stiction_class(S * pct, J * pct) == "deadband":
                backlash_lr = _backlash_lr(fit, linear, ctest)
    op_noise = _op_noise_pct(op)
    source = valve_fit.hammerstein if valve_fit is not None else fit
    slips = 0 if mv_still else _slips(source.simulate(op)[0])
    op_range = float(np.percentile(op, 99) - np.percentile(op, 1))
    ins_own = None
    if valve_fit is None and not mv_still and linear.own_noise_cost > 0:
        ins_own = 1.0 - fit.own_noise_cost / linear.own_noise_cost
    fit_rows = _fit_evidence(S_pct=float(S), S_int=S_int, ins=ins, n_eff=source.n_eff, ins_own_noise=ins_own,
                             backlash_lr=backlash_lr,
                             op_noise_pct=op_noise, op_range_pct=op_range, slips=slips, osc=osc, method=method,
                             op_units=units)
    tests = run_all(op, pv, ts, sp=record.sp, integrating=integrating, op_units=units)
    evidence = tuple(tests) + fit_rows
    cap = _confidence_caps(findings, record.n, r2, method, warnings)
    if mv_still:
        verdict = Verdict(stiction_probability=1.0, stiction=True, threshold=0.5, confidence=min(0.7, cap))
    else:
        verdict = combine(evidence, kind="op_mv" if method == "op_mv" else "full", confidence_cap=cap)
    stiction = verdict.stiction
    det = Detection(insample_improvement=ins, op_noise_pct=op_noise, S_min_pct=S_MIN_PCT, fitted_S_pct=float(S),
                    fitted_J_pct=float(J), integrating=integrating, backlash_lr=backlash_lr,
                    class_test=None if ctest is None else ClassTest.from_search(ctest))
    S_out: float | None
    J_out: float | None
    if stiction and mv_still:
        # the class is read off how the valve breaks free and where it lands: a stem that never
        # moved shows neither, and S = OP's travel, J = 0 is a lower bound, not a deadband
        cls = "unknown"
        S_out = J_out = None
    else:
        cls, S_out, J_out, S_int, J_int = _reported_size(stiction, float(S), float(J), S_int, J_int, pct, units,
                                                         "the model fit finds no valve band", warnings, slips)
        if cls not in ("none", "unknown") and ctest is not None:
            alternatives = tuple(k for k in ctest["plausible"] if k != cls)
    return Identification(
        loop=record.name, stiction=stiction, cls=cls, S_pct=S_out, J_pct=J_out,
        S_interval_pct=None if S_out is None else (float(S_int[0]), float(S_int[1])),
        J_interval_pct=None if J_out is None else (float(J_int[0]), float(J_int[1])),
        process=fit.process, rmse=float(rmse), r2=float(r2), oscillation=osc, warnings=_unique(warnings),
        confidence=float(min(max(verdict.confidence, 0.0), 1.0)), method=method, detection=det,
        data_quality=findings, fit=fit, valve_fit=valve_fit, linear_fit=linear, n=record.n, ts_s=ts,
        fitted_S_pct=float(S), fitted_J_pct=float(J), controller=ctl,
        class_alternatives=alternatives, evidence=evidence, verdict=verdict, source=record.source,
        activity=record_activity(record), record=record)
