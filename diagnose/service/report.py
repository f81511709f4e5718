"""Report content as blocks, rendered to Markdown here and to PDF by `diagnose.service.pdf`.

One content builder per report (`loop_blocks`, `summary_blocks`) turns results into a list of
blocks: a loop's report is built from its `diagnose.service.pipeline.Diagnosis` (the typed
objects), the plant summary from the summary rows (`diagnose.service.batch.loop_row`). The
Markdown and PDF renderers only lay blocks out, so both formats always say the same thing. Blocks
are tuples:

``("title", text)``, ``("h2", text)``, ``("p", text)``, ``("strong", text)``, ``("bullets", [text])``,
``("table", header, rows)``, ``("figure", name, caption)`` where ``name`` is a PNG file name beside
the report, ``("page",)``: a new page (the PDF starts one; Markdown draws a rule), and
``("landscape",)``: the PDF's pages are landscape, for a table too wide for a portrait page
(Markdown has no pages: nothing).

A loop's report opens with one page a maintenance planner can act on (the verdict, S and J with
what they mean, why we believe it, what to do); the figures and the details follow.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any, Mapping, Sequence

import numpy as np

from ..activity import BAND_SIGMAS, kept_digits
from ..plain import count, duration, number, percent, percent_change, sj_decimals
from .history import end_of_record, persistence, run_units, shown_run, verdict_of

if TYPE_CHECKING:
    from ..controller import ControllerAction
    from ..identification import Identification
    from ..verdict import Verdict
    from .pipeline import Diagnosis


Block = tuple

FIGURE_CAPTIONS = {
    "trends": "SP, PV and OP (and MV) over the whole record, with the fitted model's PV (and, when "
              "the valve sticks, its valve path) beneath them.",
    "phase": "OP-PV phase plot (and OP-MV where the stem position is recorded) over the last part "
             "of the record, with the fitted model's path dashed beneath it.",
    "surface": "Error surface over (S, J) of the fit that gave S and J (named in the figure's title); "
               "the dot is the estimate with its intervals, the dashed line J = S separates "
               "undershoot from overshoot.",
    "narx": "Free run of the NARX-SP model selected for the identified (S, J), against the record.",
    "spectrum": "PV power spectrum against period; the dashed line marks the oscillation when the "
                "loop oscillates.",
    "explanation": "Missing physics: where the fitted model and the plant disagree, and the "
                   "hypothesis that explains it.",
    "history": "S and J from earlier runs (history database), by the end of each record.",
}

#: The class of a valve whose recorded stem never moved (warning ``valve_not_moving``): "unknown"
#: because it is not judged, not because the fit could not size the band.
NOT_MOVING_MEANING = ("not judged: the stem never moved in this record, so how the valve breaks free and "
                      "where it lands (deadband, undershoot, no offset, overshoot) cannot be seen")

#: What each stiction class means for the valve, in a maintenance planner's words (docs/model.md).
CLASS_MEANING = {
    "none": "no stiction: the valve follows the controller output",
    "unknown": "the evidence says the valve sticks, but its size could not be measured from these data",
    "deadband": "J = 0 (within 15 % of S): the valve moves only after the controller output has travelled "
                "S back, then follows it smoothly (pure deadband or backlash)",
    "undershoot": "0 < J < S: after sticking the valve jumps, but by less than the band, so it stops "
                  "short of where the controller output asks it to be",
    "no_offset": "J = S (within 15 % of S): after sticking the valve jumps to where the controller output "
                 "asks",
    "overshoot": "J > S: after sticking the valve jumps past where the controller output asks it "
                 "to be",
}

S_MEANING = "S: deadband + stickband, how far OP must travel back before the valve moves"
J_MEANING = "J: slip jump, how far the valve jumps when it breaks free"

# ----------------------------------------------------------------------------------------------
# formatting helpers


def fmt(value: Any, spec: str = ".2f", none: str = "-") -> str:
    if value is None:
        return none
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, (int, float)):
        if isinstance(value, float) and not math.isfinite(value):
            return none
        return format(value, spec)
    return str(value)


def fmt_interval(value: tuple[float, float] | None, spec: str = ".2f") -> str:
    if value is None:
        return "-"
    lo, hi = value
    if not (math.isfinite(lo) and math.isfinite(hi)):
        return "-"
    return f"[{lo:{spec}}, {hi:{spec}}]"


def _controller_text(ctl: ControllerAction | None) -> str:
    if ctl is None or ctl.sign == 0:
        return "no PI law found in the records (manual, cascade slave or another algorithm)"
    bits = [f"{'reverse' if ctl.sign > 0 else 'direct'} acting"]
    if math.isfinite(ctl.Kc):
        bits.append(f"gain Kc {number(ctl.Kc)} % per PV unit")
    if math.isfinite(ctl.Ti_s):
        bits.append(f"integral time {duration(ctl.Ti_s)}")
    if math.isfinite(ctl.r2):
        bits.append(f"R2 {ctl.r2:.2f}")
    return ", ".join(bits)


def _params_text(params: Mapping[str, float | None]) -> str:
    return ", ".join(f"{k} {duration(v) if k.endswith('_s') else number(v)}"
                     for k, v in params.items() if isinstance(v, (int, float)))


def _oscillation_text(ident: Identification) -> str:
    osc = ident.oscillation
    reg = f", regularity {osc.regularity:.2f}" if osc.regularity > 0 else ""
    if ident.slow_cycle:
        return (f"slow cycle with a period of {duration(osc.period_s)}{reg}: a daily or shift "
                "pattern of the plant, not a loop oscillation")
    if ident.loop_oscillates:
        return f"oscillating with a period of {duration(osc.period_s)}{reg}"
    return "none detected"


# ----------------------------------------------------------------------------------------------
# content


#: How identify obtained S and J (its ``method``), in words for the report.
_METHOD_TEXT = {
    "op_mv": "OP and the recorded stem position (valve model fitted directly)",
    "op_pv": "OP and PV (Hammerstein fit: valve model + linear process, by simulation error)",
    "op_only": "OP alone (PV unusable): S and J cannot be given",
}

#: What each evidence test looks at, in a few words (docs/evidence.md has the detail).
EVIDENCE_LABELS = {
    "horch_xcorr": "OP-PV cross-correlation (Horch)",
    "horch_integrating": "PV curvature distribution, level loops (Horch)",
    "he_curve_fit": "Triangle vs sine half-cycles (He et al.)",
    "choudhury_bicoherence": "Bicoherence non-linearity (Choudhury et al.)",
    "kano_stuck": "Stuck then slip in the PV-OP path (Kano et al.)",
    "yamashita_qsa": "PV steady while OP moves (Yamashita)",
    "singhal_area": "Area before vs after each peak (Singhal & Salsbury)",
    "op_shape": "OP shape alone (He et al. on OP)",
    "model_fit": "Valve model's gain over a linear loop",
    "valve_band": "Fitted band S against OP's noise",
    "band_sharpness": "How sharply the fit pins S",
    "deadband_fit": "Deadband-shaped valve against a linear loop",
    "oscillation_regularity": "Oscillation regularity (context)",
}
_DECISION_TEXT = {"stiction": "stiction", "no_stiction": "no stiction", "undetermined": "undecided",
                  "cannot_judge": "cannot judge"}


def _label(test: str) -> str:
    return EVIDENCE_LABELS.get(test, test)


def evidence_rows(ident: Identification, *, numbers: bool = False) -> list[list[str]]:
    """The evidence table: each test, what it says (and its weight in the verdict), why.

    ``numbers``: the test's index and its threshold instead of the why.
    """
    contrib = dict(ident.verdict.contributions) if ident.verdict is not None else {}
    rows = []
    for ev in ident.evidence:
        says = _DECISION_TEXT.get(ev.decision, ev.decision)
        # a test can feed the verdict through more than its own row (``model_fit.lr`` beside
        # ``model_fit``): its weight is what all of them moved it by together
        weight = sum(v for k, v in contrib.items() if k == ev.test or k.startswith(ev.test + "."))
        if abs(weight) >= 0.005:
            says += f", weighs {weight:+.2f}"
        row = [_label(ev.test), says]
        if numbers:
            low = ev.extras.get("threshold_low")
            thr = number(ev.threshold) + ("" if low is None else f" (no stiction at {number(low)} or below)")
            gate = ev.extras.get("NGI_threshold")
            if gate is not None and ev.extras.get("NGI") is not None:
                # the index (NLI) counts only for a non-Gaussian signal: without this, an NLI above
                # its threshold beside "no stiction" reads as a contradiction
                thr += f", once NGI > {number(gate)} (NGI here {number(ev.extras['NGI'])})"
            row += [number(ev.value), thr]
        else:
            row.append(ev.note)
        rows.append(row)
    return rows


#: Why a test cannot judge (its ``reason``), in a few words (docs/evidence.md).
REASON_TEXT = {
    "too_short": "the record is too short", "op_flat": "OP hardly moves", "op_still": "OP hardly moves",
    "pv_unusable": "PV is unusable", "no_oscillation": "the loop does not oscillate",
    "too_few_cycles": "too few oscillation cycles", "irregular_oscillation": "the oscillation is irregular",
    "process_type_unknown": "the process type is unknown",
    "wrong_process_type": "not for this type of process", "irregular_ccf": "the cross-correlation is irregular",
    "non_finite": "the data have gaps", "bad_sample_period": "the sample period does not suit it",
}


def evidence_summary(ident: Identification) -> str:
    """Which tests agree, which disagree, which cannot judge this record and why, in a few lines
    (the table beside it names each test)."""
    by: dict[str, list[str]] = {k: [] for k in _DECISION_TEXT}
    for ev in ident.evidence:
        by.setdefault(ev.decision, []).append(ev.test)
    judged = len(ident.evidence) - len(by["cannot_judge"])
    def said(n: int, one: str, many: str) -> str:
        return f"{n} {one if n == 1 else many}"

    text = (f"Of the {count(judged, 'test')} that could judge this record, "
            f"{said(len(by['stiction']), 'says', 'say')} stiction, "
            f"{said(len(by['no_stiction']), 'says', 'say')} no stiction and "
            f"{said(len(by['undetermined']), 'is', 'are')} undecided.")
    reasons: dict[str, int] = {}
    for ev in ident.evidence:
        if ev.decision == "cannot_judge":
            why = REASON_TEXT.get(ev.reason, ev.reason.replace("_", " ") or "see the table")
            reasons[why] = reasons.get(why, 0) + 1
    if reasons:
        n = sum(reasons.values())
        text += f" {n} cannot judge it: " + "; ".join(f"{k} ({v})" for k, v in reasons.items()) + "."
    v = ident.verdict
    if v is not None:
        text += (f" Together they give a probability of stiction of {percent(v.stiction_probability)} "
                 f"({_threshold_text(v)}); each test's weight says how far it moved it.")
    return text


def _threshold_text(v: Verdict) -> str:
    """Where the verdict turns to stiction, and whether the fit's own evidence settled it."""
    text = f"stiction at {percent(v.threshold)} and above"
    if v.by_fit_rule:
        text += ("; between 50 % and that, the model fit's own evidence decides, and here it "
                 "does: a valve band clear of OP's noise with a clearly better fit than a linear loop")
    return text


def _source_line(diag: Diagnosis) -> str:
    rec = diag.record
    src = []
    if rec.source:
        src.append(f"source {rec.source}")
    src.append(f"{rec.n} samples every {duration(rec.ts_s)} ({duration(rec.duration_s)})")
    if rec.start:
        src.append(f"from {rec.start}")
    src.append("signals " + ", ".join(r.upper() for r in sorted(rec.roles())))
    nseg = rec.meta.get("n_segments")
    if nseg and nseg > 1:
        src.append(f"segment {int(rec.meta.get('segment', 0)) + 1} of {nseg}")
    return "; ".join(src) + "."


def _found_rows(diag: Diagnosis) -> list[list[str]]:
    ident = diag.identification
    unit = "% of span" if ident.op_in_percent else ident.sj_units_text
    meaning = NOT_MOVING_MEANING if ident.valve_not_moving else CLASS_MEANING.get(ident.cls)
    if ident.nothing_judged:
        meaning = "not judged: no test could judge this record, so the valve may or may not stick (see the warnings)"
    alt = (f" (the data also allow: {', '.join(ident.class_alternatives)})" if ident.class_alternatives else "")
    rows = [["Class", ident.cls + (f": {meaning}" if meaning else "") + alt]]
    if not ident.stiction and ident.S_interval_pct is not None and ident.J_interval_pct is not None:
        # a healthy valve: what the data would have shown (the upper ends of the intervals)
        rows += [[S_MEANING, f"0 (no stiction); the data allow at most {fmt(ident.S_interval_pct[1])} {unit}"],
                 [J_MEANING, f"0 (no stiction); the data allow at most {fmt(ident.J_interval_pct[1])} {unit}"]]
    elif ident.S_pct is not None and ident.J_pct is not None:
        sp = f".{ident.sj_digits}f"
        rows += [[S_MEANING, f"{fmt(ident.S_pct, sp)} {unit}, interval {fmt_interval(ident.S_interval_pct, sp)}"],
                 [J_MEANING, f"{fmt(ident.J_pct, sp)} {unit}, interval {fmt_interval(ident.J_interval_pct, sp)}"]]
    elif ident.valve_not_moving and ident.fitted_S_pct is not None:
        rows += [[S_MEANING, f"at least {fmt(ident.fitted_S_pct)} {unit} (OP travelled that far and the stem "
                             "never moved)"],
                 [J_MEANING, "not measurable: the valve never broke free in this record"]]
    else:
        rows += [[S_MEANING, "not measurable from these data"], [J_MEANING, "not measurable from these data"]]
    v = ident.verdict
    prob = "-" if v is None else f"{percent(v.stiction_probability)} ({_threshold_text(v)})"
    rows.append(["Probability of stiction", prob])
    return rows


def _detail_rows(diag: Diagnosis) -> list[list[str]]:
    ident = diag.identification
    sev = diag.severity
    if ident.rmse is None:
        fit = "-"
    elif ident.valve_fit is not None:  # not method: a stem that never moved leaves the OP -> PV fit
        fit = f"stem position (MV): RMSE {number(ident.rmse)} % of span, R2 {fmt(ident.r2, '.3f')}"
    else:
        unit = diag.record.units.get("pv") or "PV units"
        fit = f"PV: RMSE {number(ident.rmse)} {unit}, R2 {fmt(ident.r2, '.3f')}"
    return [["Confidence in the verdict", percent(ident.confidence)],
            ["S and J from", _METHOD_TEXT.get(ident.method, ident.method)],
            ["Process model", "-" if ident.process is None else ident.process.describe()],
            ["Controller (from OP/PV/SP)", _controller_text(ident.controller)],
            ["Fit of the model (free-run simulation)", fit],
            ["Oscillation", _oscillation_text(ident)],
            ["Severity (0-100)", f"{sev.score:.1f}: stiction {sev.size:.1f}, oscillation {sev.oscillation:.1f}, "
                                 f"data quality {sev.data_quality:.0f}"]]


def _rate(value: float | None, unit: str) -> str:
    """A per-day rate as the report shows it: never an exponent, and no more digits than the JSON
    and the summary keep (`ValveActivity.to_dict`: 4 significant), so all three give one number."""
    text = number(kept_digits(value))
    return text if text == "-" else f"{text} {unit}"


def activity_blocks(diag: Diagnosis) -> list[Block]:
    """Valve travel and reversals per day (and the service factor where the record has a mode
    signal): what loop-monitoring tools rank valve wear by. Nothing for a result without them."""
    act = diag.identification.activity
    if act is None:
        return []
    unit = diag.identification.op_units
    rows = [["OP travel", _rate(act.travel_pct_per_day, f"{unit} per day")],
            ["OP reversals", _rate(act.reversals_per_day, "per day")]]
    if act.mv_travel_pct_per_day is not None:
        rows += [["Stem (MV) travel", _rate(act.mv_travel_pct_per_day, "% of span per day")],
                 ["Stem (MV) reversals", _rate(act.mv_reversals_per_day, "per day")]]
    sf = act.service_factor
    meta = getattr(diag.record, "meta", None) or {}
    unknown = ("-: the mode column has no known value over this record (none before it, or bad ones)"
               if meta.get("has_mode") else "-: no mode signal recorded")
    rows.append(["Service factor (time in automatic)", unknown if sf is None
                 else "100 %" if sf >= 1.0 else percent(sf)])
    def width(v: float) -> str:  # a noiseless signal's band is a rounding-level floor: 0
        return "0" if v < 1e-6 else number(v)

    band = f"{width(act.noise_band_pct)} {unit}"
    if act.mv_noise_band_pct is not None:
        band += f" (MV: {width(act.mv_noise_band_pct)} % of span)"
    rows.append(["Noise band (movement within it not counted)", band])
    rows.append(["Record length the rates are per", duration(act.days * 86_400.0)])
    return [("h2", "Valve activity"),
            ("p", "How far the valve was asked to travel (OP) and how often it reversed, per day of this "
                  "record; a valve that travels far and reverses often wears its packing and seat. "
                  f"Movement within OP's noise band ({number(BAND_SIGMAS)} times its noise, estimated from "
                  "its second differences, which its ramps do not touch) is not counted. A short record's "
                  "rates extrapolate it to a day."),
            ("table", ["Quantity", "Value"], rows)]


def _narx_blocks(diag: Diagnosis, figs: set[str], codes: set[str]) -> list[Block]:
    sel = diag.selection
    blocks: list[Block] = [("h2", "NARX-SP free run")]
    if sel is not None:
        rows = [["Model", sel.model], ["S and J of the model", f"{number(sel.S)} %, {number(sel.J)} % of span"],
                ["Distance from the identified (S, J)", f"{number(sel.distance)} % of span"],
                ["Within its robustness margin", "yes" if sel.robust else "no"],
                ["Free-run RMSE at the identified (S, J)", f"{number(sel.free_run_rmse)} % of span"]]
        run = diag.narx_run
        if run is not None and run.rmse_record is not None:
            what = ("% of span, against the recorded stem position (MV)" if run.against == "mv"
                    else "PV units, against PV through the fitted process")
            rows.append(["Free-run RMSE on this record", f"{number(run.rmse_record)} {what}"])
        still = _narx_still(diag)
        blocks.append(("table", ["NARX-SP", "Value"], rows))
        if still is not None:
            blocks.append(("p", f"The model's valve does not move in its free run on this record (it stays at "
                                f"{number(still)} % of span, while OP travels {number(_op_travel(diag))} % of span): "
                                "the RMSE above measures the record's own swing, not a model that follows it off "
                                "by that much. The bank's model at this (S, J) stays stuck under this OP; S, J "
                                "and the class come from the fit, not from this model."))
        if "narx" in figs:
            blocks.append(("figure", "narx", FIGURE_CAPTIONS["narx"]))
    elif codes & {"service.narx_unavailable", "service.narx_failed"}:
        blocks.append(("p", "No NARX-SP model: the bank could not be used (see the warnings above)."))
    elif diag.identification.nothing_judged:
        blocks.append(("p", "No NARX-SP model: no test could judge whether the valve sticks."))
    elif not diag.identification.stiction:
        blocks.append(("p", "No NARX-SP model: the valve shows no stiction, and the bank's models "
                            "describe sticky valves."))
    elif diag.identification.S_pct is None:
        blocks.append(("p", "No NARX-SP model: the size of the stiction (S and J) is not known."))
    else:
        blocks.append(("p", "No NARX-SP model: the NARX-SP stage was not run for this loop."))
    return blocks


def _op_travel(diag: Diagnosis) -> float:
    op = np.asarray(diag.record.op, dtype=float) * diag.identification.pct_per_op_unit
    return float(np.percentile(op, 99) - np.percentile(op, 1))


def _narx_still(diag: Diagnosis) -> float | None:
    """Where the NARX-SP model's valve stays when its free run does not move on this record
    (moves less than a twentieth of OP's travel), else None."""
    run = diag.narx_run
    if run is None or run.mv_hat_pct is None or diag.record is None:
        return None
    mv = np.asarray(run.mv_hat_pct, dtype=float) * diag.identification.pct_per_op_unit
    if mv.size == 0 or not np.all(np.isfinite(mv)):
        return None
    return float(np.median(mv)) if np.ptp(mv) < 0.05 * _op_travel(diag) else None


def _explanation_blocks(diag: Diagnosis, figs: set[str]) -> list[Block]:
    expl = diag.explanation
    if expl is None:
        if diag.explain_auto:
            return [("h2", "Missing physics"),
                    ("p", f"Not run: {diag.explain_auto} (run with --explain on to force it).")]
        return []
    unit = "% of span" if expl.target == "mv" else "PV units"
    judged = {"mv": "the stem position (MV)", "pv": "PV"}.get(expl.target, expl.target)
    blocks: list[Block] = [("h2", "Missing physics"), ("p", expl.explanation),
                           ("strong", f"Missing physics named: {expl.missing_physics or 'none'}."),
                           ("table", ["Explanation", "Value"],
                            [["Judged on", judged],
                             ["Held-out RMSE of the fitted model", f"{number(expl.baseline_rmse)} {unit}"],
                             ["Held-out RMSE with the missing physics", f"{number(expl.improved_rmse)} {unit}"]])]
    if expl.hypotheses:
        from ..physics.hypotheses import shown_params

        # the change is signed, negative for a fall, as in the explanation's own text
        # hypotheses of the valve stage are judged on MV (% of span), the others on PV: each row
        # carries its own unit
        blocks.append(("table", ["Hypothesis", "Named", "Judged on", "Held-out RMSE", "Change", "Parameters"],
                       [[h.name, _named_text(h), h.target.upper(),
                         f"{number(h.heldout_rmse, 4)} {'% of span' if h.target == 'mv' else 'PV units'}",
                         percent_change(-h.reduction),
                         _params_text(shown_params(h.name, h.params))]
                        for h in expl.hypotheses]))
    if "explanation" in figs:
        blocks.append(("figure", "explanation", FIGURE_CAPTIONS["explanation"]))
    return blocks


def _named_text(h: Any) -> str:
    """Whether a hypothesis passed, and on which part a friction step inside the training part did."""
    if not h.accepted:
        return "no"
    return "yes, on the training part" if h.evidence == "training" else "yes"


def _runs_note(runs: Any) -> str:
    """" (5/7 runs)" beside the probability: how many of the loop's last runs said stiction."""
    if isinstance(runs, (list, tuple)) and len(runs) == 2:
        return f" ({runs[0]}/{runs[1]} runs)"
    return ""


def loop_blocks(diag: Diagnosis, figures: Sequence[str] = (),
                history_rows: Sequence[Mapping[str, Any]] | None = None,
                degradation: str | None = None) -> list[Block]:
    """The content of one loop's report: one page to act on, then the figures and details.

    Parameters
    ----------
    diag : Diagnosis
    figures : sequence of str
        Names of the figures that exist (``"trends"``, ``"phase"``...); files are ``NAME.png``.
    history_rows : sequence of mapping, optional
        Earlier runs of this loop from the history database (oldest first).
    degradation : str, optional
        The degradation warning for this loop (default: the diagnosis's own).
    """
    ident = diag.identification
    figs = set(figures)
    degradation = degradation or diag.degradation
    loop = diag.loop_id or ident.loop
    blocks: list[Block] = [("title", f"Stiction report: {loop}"), ("p", _source_line(diag)),
                           ("h2", "Verdict"), ("strong", diag.verdict_text),
                           ("table", ["Quantity", "Value"], _found_rows(diag))]
    if ident.evidence:
        blocks += [("h2", "Why we believe it"), ("p", evidence_summary(ident)),
                   ("table", ["Test", "Says", "Why"], evidence_rows(ident))]
    blocks += [("h2", "Recommended action"), ("p", diag.action)]
    warns = [f"[{w.code}] {w.message}" for w in diag.warnings]
    if degradation:
        warns.insert(0, f"[history.degradation] {degradation}")
    if warns:
        blocks.append(("p", f"Read it with the {len(warns)} warning{'s' if len(warns) > 1 else ''} under "
                            "Warnings below: they say what limits this result."))
    # the details
    if figs:
        blocks.append(("page",))
    blocks.append(("h2", "Warnings"))
    if warns:
        blocks.append(("bullets", warns))
    else:
        narx_ok = diag.selection is not None and diag.selection.robust
        blocks.append(("p", "None: the data passed every quality check" +
                       (" and the NARX-SP model is within its robustness margin." if narx_ok else ".")))
    blocks += [("h2", "Loop model"), ("table", ["Quantity", "Value"], _detail_rows(diag))]
    blocks += activity_blocks(diag)
    for name, title in (("trends", "Trends"), ("phase", "Phase plots")):
        if name in figs:
            blocks += [("h2", title), ("figure", name, FIGURE_CAPTIONS[name])]
    if "surface" in figs:
        blocks += [("h2", "Error surface"), ("figure", "surface", FIGURE_CAPTIONS["surface"])]
    elif figs:  # a report without any figure (e.g. a monitor window) leaves the figure sections out
        blocks += [("h2", "Error surface"), ("p", "No error surface (no model was fitted for this loop).")]
    codes = {w.code for w in diag.warnings}
    blocks += _narx_blocks(diag, figs, codes)
    if "spectrum" in figs:
        blocks += [("h2", "Spectrum"), ("figure", "spectrum", FIGURE_CAPTIONS["spectrum"])]
    blocks += _explanation_blocks(diag, figs)
    if ident.evidence:
        blocks += [("h2", "Evidence in numbers"),
                   ("p", "Each test's index against the threshold at which it says stiction "
                         "(docs/evidence.md describes the tests, docs/verdict.md how they are combined)."),
                   ("table", ["Test", "Says", "Index", "Threshold"], evidence_rows(ident, numbers=True))]
    if history_rows:
        blocks.append(("h2", "History"))
        if degradation:
            blocks.append(("strong", degradation))
        held = persistence(list(history_rows) + [verdict_of(ident)])
        if held:
            blocks.append(("p", f"Verdict over this loop's runs: {held} (this run included). One window "
                                "can hold too little stick-slip to tell; a valve called sticky on most "
                                "of its windows is the firmer finding."))
        # the table holds the runs the sentence above counts and the figure draws: this one too
        rec = diag.record
        this_run = {"data_end": end_of_record(rec.start, rec.n, rec.ts_s) if rec is not None else None,
                    "stiction": int(bool(ident.stiction)), "stiction_probability": ident.stiction_probability,
                    "S_pct": ident.S_pct, "J_pct": ident.J_pct, "class": ident.cls,
                    "confidence": ident.confidence, "run_at": "this run", "sj_units": ident.op_units}
        runs = list(history_rows) + [this_run]
        # S and J in each run's own units (`history.run_units`), as the trend of `stiction history`
        plain_pct = all(run_units(r) == "% of span" for r in runs)

        def size(r: Mapping[str, Any], key: str) -> str:
            units = run_units(r)
            text = fmt(r.get(key), _sj_spec(units))
            if plain_pct or text == "-":
                return text
            return f"{text} %" if units == "% of span" else _in_units(text, units)

        table = [[str(r.get("data_end") or "-")[:19], percent(r.get("stiction_probability")), size(r, "S_pct"),
                  size(r, "J_pct"), fmt(r.get("class")), percent(r.get("confidence")), str(r.get("run_at", ""))[:19]]
                 for r in map(shown_run, runs)]
        blocks.append(("table", ["Record end", "P(stiction)", "S %" if plain_pct else "S", "J %" if plain_pct else "J",
                                 "Class", "Confidence", "Run"], table))
        if "history" in figs:
            blocks.append(("figure", "history", FIGURE_CAPTIONS["history"]))
    if ident.data_quality:
        blocks.append(("h2", "Data quality"))
        blocks.append(("table", ["Check", "Severity", "Finding"],
                       [[f.code, f.severity, f.message] for f in ident.data_quality]))
    blocks.append(("p", f"Tool version {diag.tool_version}."))
    return blocks


SUMMARY_COLUMNS = ["rank", "loop", "status", "severity", "verdict", "class", "S_pct", "S_lo", "S_hi",
                   "J_pct", "J_lo", "J_hi", "sj_units", "sj_in_op_units", "stiction_probability", "sticky_runs",
                   "confidence", "oscillation_period_s",
                   "slow_cycle_period_s", "travel_pct_per_day", "reversals_per_day", "warnings",
                   "data_quality_warnings", "degradation", "action", "report", "file", "source", "error"]


#: What a failed summary row stands for (its ``scope``): an input path that could not be opened
#: (no such file or folder, a folder that cannot be listed), a file found but not read (or its
#: worker died), or one loop of a file that was read. Rows without a scope are loops.
FAILED_SCOPES = ("input", "file", "loop")


def tally(rows: Sequence[Mapping[str, Any]]) -> dict[str, int]:
    """What a batch's rows count: ``loops`` (found in the files read: ``diagnosed`` and
    ``loops_failed``), ``files_failed`` and ``inputs_failed``. A file that could not be read is
    not a loop, so it is counted apart."""
    scope = [r.get("scope") or "loop" for r in rows if r.get("status") != "ok"]
    ok = sum(1 for r in rows if r.get("status") == "ok")
    return {"diagnosed": ok, "loops_failed": scope.count("loop"), "loops": ok + scope.count("loop"),
            "files_failed": scope.count("file"), "inputs_failed": scope.count("input")}


def not_read(t: Mapping[str, int]) -> list[str]:
    """The inputs a batch could not read, in words (nothing when it read them all)."""
    out = []
    if t["files_failed"]:
        out.append(f"{count(t['files_failed'], 'file')} could not be read")
    if t["inputs_failed"]:
        out.append(f"{count(t['inputs_failed'], 'input')} not found or not readable")
    return out


def _row_units(row: Mapping[str, Any]) -> str:
    """The units of a summary row's S, J and travel (``sj_units``, `Identification.op_units`); a
    row stored without it has only ``sj_in_op_units``."""
    return row.get("sj_units") or ("OP units" if row.get("sj_in_op_units") else "% of span")


def _sj_spec(units: str) -> str:
    """The format of S and J in a summary row's units (`diagnose.plain.sj_decimals`)."""
    return f".{sj_decimals(units)}f"


def _in_units(text: str, units: str) -> str:
    """A summary cell of S, J or travel: a value not in % of span says what it is in."""
    return text if text == "-" or units == "% of span" else f"{text} ({units})"


def _loop_and_file(row: Mapping[str, Any]) -> str:
    """A loop as a bullet of the summary names it: with the file it came from, as the table's
    ``File`` column does (two exports of one tag are otherwise two bullets of one name)."""
    where = row.get("file") or row.get("source")
    return f"{row['loop']} ({where})" if where else str(row["loop"])


def summary_blocks(rows: Sequence[Mapping[str, Any]], *, title: str = "Plant stiction summary",
                   generated_at: str | None = None, tool_version: str | None = None,
                   links: bool = True, skipped_files: Sequence[Mapping[str, Any]] = ()) -> list[Block]:
    """The plant summary: loops ranked by severity, then the failures."""

    ok = [r for r in rows if r.get("status") == "ok"]
    bad = [r for r in rows if r.get("status") != "ok"]
    sticky = [r for r in ok if r.get("sticky")]
    # thirteen columns: on a portrait page their words would not fit
    blocks: list[Block] = [("landscape",), ("title", title)]
    t = tally(rows)
    line = (f"{count(t['loops'], 'loop')}: {t['diagnosed']} diagnosed, {t['loops_failed']} failed; "
            f"{len(sticky)} with stiction." + "".join(f" {x[0].upper()}{x[1:]}." for x in not_read(t)))
    if generated_at:
        line += f" Generated {generated_at}"
        if tool_version:
            line += f" by stiction {tool_version}"
        line += "."
    blocks.append(("p", line))
    blocks.append(("p", "Severity (0-100) adds the probability of stiction weighted by its size (up to "
                        "50), oscillation (25) and data-quality warnings (15), so likely sticky valves "
                        "rank first; equal severities are ordered by S. Slow cycles (periods of hours: "
                        "daily or shift patterns of the plant) are not loop oscillations and add nothing."))
    blocks.append(("p", "Travel is how far OP moved in % of valve span per day of record, Reversals how often it "
                        "changed direction per day (movement within OP's noise band not counted): a valve that "
                        "travels far and reverses often wears its packing. S, J and travel of a loop whose OP is "
                        "not in % of span are in OP's own units, marked beside them. DQ warn.: data-quality "
                        "warnings."))
    if any(r.get("sticky_runs") for r in ok):
        blocks.append(("p", "Beside P(stiction), (k/m runs): of the loop's last m runs in the history, this one "
                            "included, k said stiction. One window can hold too little stick-slip to tell; "
                            "a valve called sticky run after run is the firmer finding."))
    blocks.append(("h2", "Loops ranked by severity"))
    table = []
    for r in ok:
        name = str(r.get("loop"))
        if links and r.get("report"):
            name = f"[{name}]({r['report']})"
        units = _row_units(r)
        osc = duration(r.get("oscillation_period_s"))
        if r.get("slow_cycle_period_s"):
            osc = f"slow cycle {duration(r['slow_cycle_period_s'])}"
        # the degradation is S's trend over the loop's records: beside S, not a data-quality warning
        rising = " (degrading)" if r.get("degradation") else ""
        table.append([fmt(r.get("rank"), "d"), name, fmt(r.get("severity"), ".1f"), fmt(r.get("class")),
                      _in_units(fmt(r.get("S_pct"), _sj_spec(units)), units) + rising,
                      _in_units(fmt(r.get("J_pct"), _sj_spec(units)), units),
                      # as the loop's own report words them: a rounded "100%" reads as a certainty
                      percent(r.get("stiction_probability")) + _runs_note(r.get("sticky_runs")),
                      percent(r.get("confidence")),
                      osc,
                      _in_units(number(r.get("travel_pct_per_day")), units), number(r.get("reversals_per_day")),
                      fmt(r.get("data_quality_warnings"), "d"),
                      # which file the loop came from: two copies of one export give FIC103 and
                      # FIC103__FIC103, told apart only by it (last: a path is the widest cell)
                      fmt(r.get("file") or r.get("source"))])
    blocks.append(("table", ["#", "Loop", "Severity", "Class", "S %", "J %", "P(stiction)", "Conf.", "Oscillation",
                             "Travel %/day", "Reversals/day", "DQ warn.", "File"], table))
    if any(r.get("degradation") for r in ok):
        blocks.append(("h2", "Degrading valves"))
        blocks.append(("bullets", [f"{_loop_and_file(r)}: {r['degradation']}" for r in ok if r.get("degradation")]))
    actions = [r for r in ok if r.get("sticky")]
    if actions:
        blocks.append(("h2", "Recommended actions"))
        blocks.append(("bullets", [f"{_loop_and_file(r)}: {r.get('action', '')}" for r in actions]))
    if bad:
        blocks.append(("h2", "Failed loops and files"))
        blocks.append(("table", ["Loop", "File", "Error"],
                       [[fmt(r.get("loop")), fmt(r.get("file") or r.get("source")), fmt(r.get("error"))]
                        for r in bad]))
    if skipped_files:
        blocks.append(("h2", "Files left alone"))
        blocks.append(("table", ["File", "Why"], [[fmt(f.get("path")), fmt(f.get("reason"))]
                                                  for f in skipped_files]))
    return blocks


# ----------------------------------------------------------------------------------------------
# Markdown


def _md_cell(text: str) -> str:
    return str(text).replace("|", "\\|").replace("\n", " ")


def to_markdown(blocks: Sequence[Block], *, figure_path: str = "{name}.png") -> str:
    """Blocks as Markdown; figures link to ``figure_path.format(name=...)`` beside the file."""
    out: list[str] = []
    for b in blocks:
        kind = b[0]
        if kind == "title":
            out.append(f"# {b[1]}\n")
        elif kind == "h2":
            out.append(f"## {b[1]}\n")
        elif kind == "p":
            out.append(f"{b[1]}\n")
        elif kind == "strong":
            out.append(f"**{b[1]}**\n")
        elif kind == "bullets":
            out.append("\n".join(f"- {item}" for item in b[1]) + "\n")
        elif kind == "table":
            header, rows = b[1], b[2]
            lines = ["| " + " | ".join(_md_cell(h) for h in header) + " |",
                     "|" + "|".join("---" for _ in header) + "|"]
            lines += ["| " + " | ".join(_md_cell(c) for c in row) + " |" for row in rows]
            out.append("\n".join(lines) + "\n")
        elif kind == "figure":
            out.append(f"![{b[2]}]({figure_path.format(name=b[1])})\n\n*{b[2]}*\n")
        elif kind == "page":
            out.append("---\n")
        elif kind == "landscape":
            continue
        else:  # pragma: no cover - programming error
            raise ValueError(f"unknown block kind {kind!r}")
    return "\n".join(out)


def loop_markdown(diag: Diagnosis, figures: Sequence[str] = (), **kw: Any) -> str:
    return to_markdown(loop_blocks(diag, figures, **kw))
