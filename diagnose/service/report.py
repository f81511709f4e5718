"""Report content as blocks, rendered to Markdown here and to PDF by `diagnose.service.pdf`.

One content builder per report (`loop_blocks`, `summary_blocks`) turns a result dict (the issue-3
JSON plus the service's keys, see `diagnose.service.pipeline`) into a list of blocks; the Markdown
and PDF renderers only lay blocks out, so both formats always say the same thing. Blocks are tuples:

``("title", text)``, ``("h2", text)``, ``("p", text)``, ``("strong", text)``, ``("bullets", [text])``,
``("table", header, rows)``, ``("figure", name, caption)`` where ``name`` is a PNG file name beside
the report.

The module also holds the atomic file writers every service output goes through.
"""

from __future__ import annotations

import math
from typing import Any, Iterable, Mapping, Sequence

from ..plain import duration, number, percent_change


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

#: What each stiction class means for the valve, in a maintenance planner's words (docs/model.md).
CLASS_MEANING = {
    "none": "no stiction: the valve follows the controller output",
    "deadband": "J = 0: the valve moves only after the controller output has travelled S back, "
                "then follows it smoothly (pure deadband or backlash)",
    "undershoot": "0 < J < S: after sticking the valve jumps, but by less than the band, so it stops "
                  "short of where the controller output asks it to be",
    "no_offset": "J = S: after sticking the valve jumps exactly to where the controller output asks",
    "overshoot": "J > S: after sticking the valve jumps past where the controller output asks it "
                 "to be",
}

#: The NARX-SP selection's keys, in words; keys not listed are internal and stay in the JSON.
NARX_LABELS = (("model", "Model"), ("S", "S of the model (%)"), ("J", "J of the model (%)"),
               ("distance", "Distance from the identified (S, J)"),
               ("robust", "Within its robustness margin"),
               ("free_run_rmse", "Free-run RMSE in training (% of span)"),
               ("free_run_rmse_record", "Free-run RMSE on this record"),
               ("free_run_against", "Compared with"))

#: The explanation's keys, in words.
EXPLAIN_LABELS = (("target", "Judged on"), ("baseline_rmse", "Held-out RMSE of the fitted model"),
                  ("improved_rmse", "Held-out RMSE with the missing physics"))


# ----------------------------------------------------------------------------------------------
# atomic writers




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


def fmt_interval(value: Any, spec: str = ".2f") -> str:
    from .pipeline import _interval

    lo, hi = _interval(value)
    if lo is None or hi is None:
        return "-"
    return f"[{lo:{spec}}, {hi:{spec}}]"


def _scalar_items(d: Mapping[str, Any], skip: Iterable[str] = ()) -> list[list[str]]:
    skip = set(skip)
    rows = []
    for k, v in d.items():
        if k in skip or isinstance(v, (Mapping, list, tuple)):
            continue
        rows.append([str(k), fmt(v, ".4g")])
    return rows


def _process_text(proc: Any) -> str:

    if not isinstance(proc, Mapping):
        return fmt(proc)
    kind = proc.get("kind", "?")
    bits = [str(kind)]
    for key, label in (("gain", "gain"), ("tau_s", "time constant"), ("tau2_s", "second time constant"),
                       ("delay_s", "dead time")):
        v = proc.get(key)
        if isinstance(v, (int, float)) and (key != "tau2_s" or v):
            bits.append(f"{label} {duration(v) if key.endswith('_s') else number(v)}")
    return ", ".join(bits)


def _controller_text(ctl: Any) -> str:

    if not isinstance(ctl, Mapping) or ctl.get("action") in (None, "unknown"):
        return "no PI law found in the records (manual, cascade slave or another algorithm)"
    bits = [f"{ctl['action']} acting"]
    if isinstance(ctl.get("Kc"), (int, float)):
        bits.append(f"gain Kc {number(ctl['Kc'])} % per PV unit")
    if isinstance(ctl.get("Ti_s"), (int, float)):
        bits.append(f"integral time {duration(ctl['Ti_s'])}")
    if isinstance(ctl.get("r2"), (int, float)):
        bits.append(f"R2 {ctl['r2']:.2f}")
    return ", ".join(bits)


def _labelled(d: Mapping[str, Any], labels: Sequence[tuple[str, str]]) -> list[list[str]]:
    """Rows of ``(label, value)`` for the keys in ``labels`` that ``d`` holds, numbers plain."""

    rows = []
    for key, label in labels:
        v = d.get(key)
        if v is None or isinstance(v, (Mapping, list, tuple)):
            continue
        if isinstance(v, str):
            text = {"mv": "the recorded stem position (MV)", "pv": "PV"}.get(v, v)
        else:
            text = fmt(v) if isinstance(v, bool) else number(v)
        rows.append([label, text])
    return rows


def _params_text(params: Any) -> str:

    if not isinstance(params, Mapping):
        return ""
    return ", ".join(f"{k} {duration(v) if k.endswith('_s') else number(v)}"
                     for k, v in params.items() if isinstance(v, (int, float)))


def _oscillation_text(osc: Mapping[str, Any]) -> str:

    reg = f", regularity {osc['strength']:.2f}" if osc.get("strength") is not None else ""
    if osc.get("slow_cycle"):
        return (f"slow cycle with a period of {duration(osc['period_s'])}{reg}: a daily or shift "
                "pattern of the plant, not a loop oscillation")
    if osc.get("present"):
        return f"oscillating with a period of {duration(osc['period_s'])}{reg}"
    return "none detected"


# ----------------------------------------------------------------------------------------------
# content


#: How identify obtained S and J (its ``method`` key), in words for the report.
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


def evidence_rows(result: Mapping[str, Any]) -> list[list[str]]:
    """The evidence table: each test, what it says, its index against its threshold, why."""
    rows = []
    contrib = ((result.get("combination") or {}).get("contributions") or {})
    for ev in result.get("evidence") or ():
        test = str(ev.get("test", "?"))
        idx = "-" if ev.get("value") is None else number(ev.get("value"))
        if ev.get("threshold") is not None and ev.get("value") is not None:
            idx += f" (threshold {number(ev.get('threshold'))})"
        weight = contrib.get(test)
        says = _DECISION_TEXT.get(str(ev.get("decision")), str(ev.get("decision")))
        if weight is not None and abs(weight) >= 0.005:
            says += f", weighs {weight:+.2f}"
        rows.append([EVIDENCE_LABELS.get(test, test), says, idx, str(ev.get("note", ""))])
    return rows


def loop_blocks(result: Mapping[str, Any], figures: Sequence[str] = (),
                history_rows: Sequence[Mapping[str, Any]] | None = None,
                degradation: str | None = None) -> list[Block]:
    """The content of one loop's report.

    Parameters
    ----------
    result : mapping
        The loop's result (`diagnose.service.pipeline.diagnose_record`).
    figures : sequence of str
        Names of the figures that exist (``"trends"``, ``"phase"``...); files are ``NAME.png``.
    history_rows : sequence of mapping, optional
        Earlier runs of this loop from `diagnose.service.history` (oldest first).
    degradation : str, optional
        The degradation warning for this loop, if any.
    """
    from .pipeline import oscillation_info, op_in_percent, stiction_present

    figs = set(figures)
    rec = result.get("record") or {}
    loop = result.get("loop_id") or result.get("loop") or "loop"
    blocks: list[Block] = [("title", f"Stiction report: {loop}")]
    src = []
    if rec.get("source"):
        src.append(f"source {rec['source']}")
    if rec.get("n"):
        src.append(f"{rec['n']} samples every {duration(rec.get('ts_s'))} ({duration(rec.get('duration_s'))})")
    if rec.get("start"):
        src.append(f"from {rec['start']}")
    if rec.get("roles"):
        src.append("signals " + ", ".join(r.upper() for r in rec["roles"]))
    if rec.get("n_segments") and rec.get("n_segments", 1) > 1:
        src.append(f"segment {rec.get('segment', 0) + 1} of {rec['n_segments']}")
    if src:
        blocks.append(("p", "; ".join(src) + "."))
    blocks.append(("h2", "Verdict"))
    blocks.append(("strong", str(result.get("verdict", ""))))
    fitd = result.get("fit") or {}
    osc = oscillation_info(result)
    sev = result.get("severity") or {}
    unit = "% of span" if op_in_percent(result) else "in OP's own units (OP is not in % of span)"
    cls = str(result.get("class") or "")
    meaning = CLASS_MEANING.get(cls)
    rows = [
        ["Class", fmt(result.get("class")) + (f": {meaning}" if meaning else "") + (
            f" (the data also allow: {', '.join(result['class_alternatives'])})"
            if result.get("class_alternatives") else "")],
        ["S: deadband + stickband, how far OP must travel back before the valve moves",
         f"{fmt(result.get('S'))} {unit}, interval {fmt_interval(result.get('S_interval'))}"],
        ["J: slip jump, how far the valve jumps when it breaks free",
         f"{fmt(result.get('J'))} {unit}, interval {fmt_interval(result.get('J_interval'))}"],
        ["Probability of stiction", fmt(result.get("stiction_probability"), ".0%") + (
            f" (stiction at {fmt((result.get('combination') or {}).get('threshold'), '.0%')} and above)"
            if (result.get("combination") or {}).get("threshold") is not None else "")],
        ["Confidence", fmt(result.get("confidence"), ".0%")],
        ["S and J from", _METHOD_TEXT.get(result.get("method"), fmt(result.get("method")))],
        ["Process model", _process_text(result.get("process"))],
        ["Controller (from OP/PV/SP)", _controller_text(result.get("controller"))],
        ["Fit", f"RMSE {number(fitd.get('rmse'))}, R2 {fmt(fitd.get('r2'), '.3f')}"],
        ["Oscillation", _oscillation_text(osc)],
        ["Severity (0-100)", fmt(sev.get("score"), ".0f")],
    ]
    blocks.append(("table", ["Quantity", "Value"], rows))
    ev_rows = evidence_rows(result)
    if ev_rows:
        n_st = sum(1 for e in result["evidence"] if e.get("decision") == "stiction")
        n_no = sum(1 for e in result["evidence"] if e.get("decision") == "no_stiction")
        n_cj = sum(1 for e in result["evidence"] if e.get("decision") == "cannot_judge")
        blocks.append(("h2", "Why we believe it"))
        blocks.append(("p", f"{n_st} tests say stiction, {n_no} say no stiction, {n_cj} cannot judge this "
                            "record (the reason is given). Each test that judges moves the probability by its "
                            "weight (log-odds; positive towards stiction); docs/evidence.md and "
                            "docs/verdict.md describe the tests and how they are combined."))
        blocks.append(("table", ["Test", "Says", "Index", "Why"], ev_rows))
    blocks.append(("h2", "Recommended action"))
    blocks.append(("p", str(result.get("action", ""))))
    warns = list(result.get("warnings") or [])
    if degradation:
        warns.insert(0, {"code": "history.degradation", "message": degradation})
    blocks.append(("h2", "Warnings"))
    if warns:
        blocks.append(("bullets", [f"[{w.get('code', '?')}] {w.get('message', '')}" for w in warns]))
    else:
        narx_ok = isinstance(result.get("narx"), Mapping) and result["narx"].get("robust") is True
        blocks.append(("p", "None: the data passed every quality check" +
                       (" and the NARX-SP model is within its robustness margin." if narx_ok else ".")))
    drawn = bool(figs)  # a report without any figure (e.g. a monitor window) leaves their sections out
    for name, title in (("trends", "Trends"), ("phase", "Phase plots")):
        if name in figs:
            blocks += [("h2", title), ("figure", name, FIGURE_CAPTIONS[name])]
    if "surface" in figs:
        blocks += [("h2", "Error surface"), ("figure", "surface", FIGURE_CAPTIONS["surface"])]
    elif drawn:
        blocks += [("h2", "Error surface"), ("p", "No error surface (no Hammerstein fit for this loop).")]
    blocks.append(("h2", "NARX-SP free run"))
    narx = result.get("narx")
    codes = {str(w.get("code", "")) for w in warns}
    if isinstance(narx, Mapping) and narx:
        blocks.append(("table", ["NARX-SP", "Value"], _labelled(narx, NARX_LABELS)))
        if "narx" in figs:
            blocks.append(("figure", "narx", FIGURE_CAPTIONS["narx"]))
    elif codes & {"service.narx_unavailable", "service.narx_failed"}:
        blocks.append(("p", "No NARX-SP model: the bank could not be used (see the warnings above)."))
    elif stiction_present(result) is False:
        blocks.append(("p", "No NARX-SP model: the valve shows no stiction, and the bank's models "
                            "describe sticky valves."))
    else:
        blocks.append(("p", "No NARX-SP model: the NARX-SP stage was not run for this loop."))
    if "spectrum" in figs:
        blocks += [("h2", "Spectrum"), ("figure", "spectrum", FIGURE_CAPTIONS["spectrum"])]
    expl = result.get("explanation")
    if isinstance(expl, Mapping) and expl:
        blocks.append(("h2", "Missing physics"))
        text_keys = ("summary", "explanation", "verdict", "message", "conclusion")
        for key in text_keys:
            if isinstance(expl.get(key), str):
                blocks.append(("p", expl[key]))
                break
        if "missing_physics" in expl:
            blocks.append(("strong", f"Missing physics named: {expl.get('missing_physics') or 'none'}."))
        items = _labelled(expl, EXPLAIN_LABELS)
        if items:
            blocks.append(("table", ["Explanation", "Value"], items))
        hyps = expl.get("hypotheses") or expl.get("ranking")
        if isinstance(hyps, list) and hyps and isinstance(hyps[0], Mapping):

            # the change is signed, negative for a fall, as in the explanation's own text
            blocks.append(("table", ["Hypothesis", "Named", "Held-out RMSE", "Change", "Parameters"],
                           [[fmt(h.get("name")), fmt(bool(h.get("accepted"))), number(h.get("heldout_rmse"), 4),
                             percent_change(-h["heldout_reduction"]) if h.get("heldout_reduction") is not None
                             else "-", _params_text(h.get("params"))] for h in hyps]))
        if "explanation" in figs:
            blocks.append(("figure", "explanation", FIGURE_CAPTIONS["explanation"]))
    elif result.get("explain_auto"):
        blocks.append(("h2", "Missing physics"))
        blocks.append(("p", f"Not run: {result['explain_auto']} (run with --explain on to force it)."))
    if history_rows:
        blocks.append(("h2", "History"))
        if degradation:
            blocks.append(("strong", degradation))
        blocks.append(("table", ["Record end", "S %", "J %", "Class", "Confidence", "Run"],
                       [[str(r.get("data_end") or "-")[:19], fmt(r.get("S_pct")), fmt(r.get("J_pct")),
                         fmt(r.get("class")), fmt(r.get("confidence"), ".0%"), str(r.get("run_at", ""))[:19]]
                        for r in history_rows]))
        if "history" in figs:
            blocks.append(("figure", "history", FIGURE_CAPTIONS["history"]))
    dq = result.get("data_quality")
    if isinstance(dq, list) and dq and isinstance(dq[0], Mapping):
        blocks.append(("h2", "Data quality"))
        blocks.append(("table", ["Check", "Severity", "Finding"],
                       [[fmt(f.get("code")), fmt(f.get("severity")), fmt(f.get("message"))] for f in dq]))
    elif isinstance(dq, Mapping) and dq:
        blocks.append(("h2", "Data quality"))
        blocks.append(("table", ["Check", "Value"], _scalar_items(dq)))
    blocks.append(("p", f"Tool version {result.get('tool_version', '?')}."))
    return blocks


SUMMARY_COLUMNS = ["rank", "loop", "status", "severity", "verdict", "class", "S_pct", "S_lo", "S_hi",
                   "J_pct", "J_lo", "J_hi", "sj_in_op_units", "confidence", "oscillation_period_s",
                   "slow_cycle_period_s", "warnings",
                   "data_quality_warnings", "degradation", "action", "report", "source", "error"]


def summary_blocks(rows: Sequence[Mapping[str, Any]], *, title: str = "Plant stiction summary",
                   generated_at: str | None = None, tool_version: str | None = None,
                   links: bool = True, skipped_files: Sequence[Mapping[str, Any]] = ()) -> list[Block]:
    """The plant summary: loops ranked by severity, then the failures."""

    ok = [r for r in rows if r.get("status") == "ok"]
    bad = [r for r in rows if r.get("status") != "ok"]
    sticky = [r for r in ok if r.get("sticky")]
    blocks: list[Block] = [("title", title)]
    line = (f"{len(rows)} loops: {len(ok)} diagnosed, {len(bad)} failed; "
            f"{len(sticky)} with stiction.")
    if generated_at:
        line += f" Generated {generated_at}"
        if tool_version:
            line += f" by stiction {tool_version}"
        line += "."
    blocks.append(("p", line))
    blocks.append(("p", "Severity (0-100) adds stiction size scaled by confidence (up to 50), "
                        "oscillation (25), data-quality warnings (15) and NARX-SP robustness (10). "
                        "Slow cycles (periods of hours: daily or shift patterns of the plant) are "
                        "not loop oscillations and add nothing."))
    blocks.append(("h2", "Loops ranked by severity"))
    table = []
    for r in ok:
        name = str(r.get("loop"))
        if links and r.get("report"):
            name = f"[{name}]({r['report']})"
        op_units = " (OP units)" if r.get("sj_in_op_units") else ""
        osc = duration(r.get("oscillation_period_s"))
        if r.get("slow_cycle_period_s"):
            osc = f"slow cycle {duration(r['slow_cycle_period_s'])}"
        table.append([fmt(r.get("rank"), "d"), name, fmt(r.get("severity"), ".0f"), fmt(r.get("class")),
                      fmt(r.get("S_pct")) + op_units, fmt(r.get("J_pct")) + op_units, fmt(r.get("confidence"), ".0%"),
                      osc,
                      fmt(r.get("data_quality_warnings"), "d") + (" (degrading)" if r.get("degradation") else "")])
    blocks.append(("table", ["#", "Loop", "Severity", "Class", "S %", "J %", "Conf.", "Oscillation",
                             "DQ warn."], table))
    if any(r.get("degradation") for r in ok):
        blocks.append(("h2", "Degrading valves"))
        blocks.append(("bullets", [f"{r['loop']}: {r['degradation']}" for r in ok if r.get("degradation")]))
    actions = [r for r in ok if r.get("sticky")]
    if actions:
        blocks.append(("h2", "Recommended actions"))
        blocks.append(("bullets", [f"{r['loop']}: {r.get('action', '')}" for r in actions]))
    if bad:
        blocks.append(("h2", "Failed loops and files"))
        blocks.append(("table", ["Loop", "Source", "Error"],
                       [[fmt(r.get("loop")), fmt(r.get("source")), fmt(r.get("error"))] for r in bad]))
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
        else:  # pragma: no cover - programming error
            raise ValueError(f"unknown block kind {kind!r}")
    return "\n".join(out)


def loop_markdown(result: Mapping[str, Any], figures: Sequence[str] = (), **kw: Any) -> str:
    return to_markdown(loop_blocks(result, figures, **kw))
