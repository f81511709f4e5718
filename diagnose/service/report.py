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


Block = tuple

FIGURE_CAPTIONS = {
    "trends": "SP, PV and OP (and MV) over the record, with the fitted model's PV and valve path.",
    "phase": "OP-PV phase plot (and OP-MV where the stem position is recorded) over the last part "
             "of the record, with the fitted model's path over it.",
    "surface": "Error surface of the Hammerstein fit over (S, J); the dot is the estimate with its "
               "intervals, the dashed line J = S separates undershoot from overshoot.",
    "narx": "Free run of the NARX-SP model selected for the identified (S, J), against the record.",
    "spectrum": "PV power spectrum against period, with the detected oscillation period.",
    "explanation": "Missing physics: where the fitted model and the plant disagree, and the "
                   "hypothesis that explains it.",
    "history": "S and J from earlier runs (history database).",
}


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


def _duration(seconds: Any) -> str:
    s = float(seconds or 0.0)
    if s >= 7200:
        return f"{s / 3600:.1f} h"
    if s >= 120:
        return f"{s / 60:.0f} min"
    return f"{s:.0f} s"


def _process_text(proc: Any) -> str:
    if not isinstance(proc, Mapping):
        return fmt(proc)
    kind = proc.get("kind", "?")
    bits = [str(kind)]
    for key, label, spec in (("gain", "K", ".3g"), ("tau_s", "tau", ".3g"), ("tau2_s", "tau2", ".3g"),
                             ("delay_s", "delay", ".3g")):
        v = proc.get(key)
        if isinstance(v, (int, float)) and (key != "tau2_s" or v):
            bits.append(f"{label} = {v:{spec}}{' s' if key.endswith('_s') else ''}")
    return ", ".join(bits)


def _controller_text(ctl: Any) -> str:
    if not isinstance(ctl, Mapping) or ctl.get("action") in (None, "unknown"):
        return "no PI law found in the records (manual, cascade slave or another algorithm)"
    bits = [f"{ctl['action']} acting"]
    if isinstance(ctl.get("Kc"), (int, float)):
        bits.append(f"Kc = {ctl['Kc']:.3g} % per PV unit")
    if isinstance(ctl.get("Ti_s"), (int, float)):
        bits.append(f"Ti = {ctl['Ti_s']:.3g} s")
    if isinstance(ctl.get("r2"), (int, float)):
        bits.append(f"R2 {ctl['r2']:.2f}")
    return ", ".join(bits)


# ----------------------------------------------------------------------------------------------
# content


#: How identify obtained S and J (its ``method`` key), in words for the report.
_METHOD_TEXT = {
    "op_mv": "OP and the recorded stem position (valve model fitted directly)",
    "op_pv": "OP and PV (Hammerstein fit: valve model + linear process, by simulation error)",
}


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
    from .pipeline import oscillation_info

    figs = set(figures)
    rec = result.get("record") or {}
    loop = result.get("loop_id") or result.get("loop") or "loop"
    blocks: list[Block] = [("title", f"Stiction report: {loop}")]
    src = []
    if rec.get("source"):
        src.append(f"source {rec['source']}")
    if rec.get("n"):
        src.append(f"{rec['n']} samples at {fmt(rec.get('ts_s'), 'g')} s ({_duration(rec.get('duration_s'))})")
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
    rows = [
        ["Class", fmt(result.get("class")) + (
            f" (the data also allow: {', '.join(result['class_alternatives'])})"
            if result.get("class_alternatives") else "")],
        ["S (deadband + stickband)", f"{fmt(result.get('S'))} % of span, interval {fmt_interval(result.get('S_interval'))}"],
        ["J (slip jump)", f"{fmt(result.get('J'))} % of span, interval {fmt_interval(result.get('J_interval'))}"],
        ["Confidence", fmt(result.get("confidence"), ".0%")],
        ["S and J from", _METHOD_TEXT.get(result.get("method"), fmt(result.get("method")))],
        ["Process model", _process_text(result.get("process"))],
        ["Controller (from OP/PV/SP)", _controller_text(result.get("controller"))],
        ["Fit", f"RMSE {fmt(fitd.get('rmse'), '.3g')}, R2 {fmt(fitd.get('r2'), '.3f')}"],
        ["Oscillation", ("none detected" if osc["present"] is False else
                         f"period {fmt(osc['period_s'], '.0f')} s" +
                         (f", regularity {osc['strength']:.2f}" if osc["strength"] is not None else ""))],
        ["Severity (0-100)", fmt(sev.get("score"), ".0f")],
    ]
    blocks.append(("table", ["Quantity", "Value"], rows))
    blocks.append(("h2", "Recommended action"))
    blocks.append(("p", str(result.get("action", ""))))
    warns = list(result.get("warnings") or [])
    if degradation:
        warns.insert(0, {"code": "history.degradation", "message": degradation})
    blocks.append(("h2", "Warnings"))
    if warns:
        blocks.append(("bullets", [f"[{w.get('code', '?')}] {w.get('message', '')}" for w in warns]))
    else:
        blocks.append(("p", "None: the data passed every quality check and the model is within its "
                            "robustness margin."))
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
    if isinstance(narx, Mapping) and narx:
        blocks.append(("table", ["NARX-SP", "Value"], _scalar_items(narx)))
        if "narx" in figs:
            blocks.append(("figure", "narx", FIGURE_CAPTIONS["narx"]))
    else:
        blocks.append(("p", "No NARX-SP model was selected for this loop (see warnings)."))
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
        items = _scalar_items(expl, skip=text_keys + ("missing_physics", "loop"))
        if items:
            blocks.append(("table", ["Explanation", "Value"], items))
        hyps = expl.get("hypotheses") or expl.get("ranking")
        if isinstance(hyps, list) and hyps and isinstance(hyps[0], Mapping):
            keys = [k for k in hyps[0] if not isinstance(hyps[0][k], (Mapping, list, tuple))][:6]
            blocks.append(("table", keys, [[fmt(h.get(k), ".4g") for k in keys] for h in hyps]))
        if "explanation" in figs:
            blocks.append(("figure", "explanation", FIGURE_CAPTIONS["explanation"]))
    elif result.get("explain_auto"):
        blocks.append(("h2", "Missing physics"))
        blocks.append(("p", f"Not run: {result['explain_auto']} (run with --explain on to force it)."))
    if history_rows:
        blocks.append(("h2", "History"))
        if degradation:
            blocks.append(("strong", degradation))
        blocks.append(("table", ["Run", "S %", "J %", "Class", "Confidence"],
                       [[str(r.get("run_at", ""))[:19], fmt(r.get("S_pct")), fmt(r.get("J_pct")),
                         fmt(r.get("class")), fmt(r.get("confidence"), ".0%")] for r in history_rows]))
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
                   "J_pct", "J_lo", "J_hi", "confidence", "oscillation_period_s", "warnings",
                   "data_quality_warnings", "degradation", "action", "report", "source", "error"]


def summary_blocks(rows: Sequence[Mapping[str, Any]], *, title: str = "Plant stiction summary",
                   generated_at: str | None = None, tool_version: str | None = None,
                   links: bool = True) -> list[Block]:
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
                        "oscillation (25), data-quality warnings (15) and NARX-SP robustness (10)."))
    blocks.append(("h2", "Loops ranked by severity"))
    table = []
    for r in ok:
        name = str(r.get("loop"))
        if links and r.get("report"):
            name = f"[{name}]({r['report']})"
        table.append([fmt(r.get("rank"), "d"), name, fmt(r.get("severity"), ".0f"), fmt(r.get("class")),
                      fmt(r.get("S_pct")), fmt(r.get("J_pct")), fmt(r.get("confidence"), ".0%"),
                      fmt(r.get("oscillation_period_s"), ".0f"),
                      fmt(r.get("data_quality_warnings"), "d") + (" (degrading)" if r.get("degradation") else "")])
    blocks.append(("table", ["#", "Loop", "Severity", "Class", "S %", "J %", "Conf.", "Period s",
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
