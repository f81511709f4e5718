"""`stiction identify`: identify stiction (S, J, class) in one loop's record."""

from __future__ import annotations

import argparse
import math
from typing import Any

from ._loopfile import add_file_arguments, emit, read_options, select_record


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_file_arguments(p, "identify")
    p.add_argument("--json", action="store_true",
                   help="print exactly one JSON object on stdout (messages go to stderr)")


def _clean(obj: Any) -> Any:
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, dict):
        return {k: _clean(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_clean(v) for v in obj]
    if hasattr(obj, "item") and not isinstance(obj, (str, bytes)):
        try:
            return _clean(obj.item())
        except (TypeError, ValueError):
            return obj
    return obj


def summary(d: dict[str, Any]) -> str:
    """A short human summary of an identification dict."""
    lines = []
    verdict = "STICTION" if d["stiction"] else "no stiction"
    prob = d.get("stiction_probability")
    head = f"{d['loop']}: {verdict} (class {d['class']}"
    if prob is not None:
        head += f", probability {prob:.2f}"
    lines.append(head + f", confidence {d.get('confidence', 0):.2f})")
    if d["stiction"] and d.get("S") is not None:
        si, ji = d["S_interval"], d["J_interval"]
        src = " from OP/MV" if d.get("method") == "op_mv" else ""
        lines.append(f"  S = {d['S']:.2f} % [{si[0]:.2f}, {si[1]:.2f}]   J = {d['J']:.2f} % "
                     f"[{ji[0]:.2f}, {ji[1]:.2f}]  (% of valve span{src})")
        if d.get("class_alternatives"):
            lines.append(f"  the data also allow class {' or '.join(d['class_alternatives'])}")
    ev = d.get("evidence") or []
    if ev:
        said = {k: [e["test"] for e in ev if e["decision"] == k]
                for k in ("stiction", "no_stiction", "undetermined", "cannot_judge")}
        lines.append("  evidence: " + "; ".join(f"{k.replace('_', ' ')}: {', '.join(v)}"
                                               for k, v in said.items() if v))
    from ...plain import duration, number
    from ..pipeline import oscillation_info

    p = d.get("process") or {}
    if p:
        extra = f", tau2 {duration(p['tau2_s'])}" if "tau2_s" in p else ""
        lines.append(f"  process: {p['kind']}, gain {number(p['gain'])}, tau {duration(p['tau_s'])}{extra}, "
                     f"dead time {duration(p['delay_s'])}")
    fit = d.get("fit") or {}
    if fit.get("rmse") is not None:
        lines.append(f"  fit: rmse {number(fit['rmse'])}, r2 {fit['r2']:.3f} (free-run simulation)")
    o = d.get("oscillation") or {}
    osc = oscillation_info(d)
    if osc["slow_cycle"]:
        lines.append(f"  slow cycle: period {duration(o['period_s'])} (a daily or shift pattern, not a loop "
                     "oscillation)")
    elif o.get("oscillating"):
        lines.append(f"  oscillating: period {duration(o['period_s'])}, regularity {o['regularity']:.2f}")
    else:
        lines.append("  not oscillating regularly")
    for w in d.get("warnings", []):
        lines.append(f"  warning [{w['code']}]: {w['message']}")
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    import connectors

    from ...identify import identify
    from ..pipeline import select_narx

    opts = read_options(args)
    records = connectors.read_records(args.file, **opts)
    rec, notes = select_record(records, args.loop, str(args.file))
    result = identify(rec)
    d = result.to_dict()
    d["warnings"] = notes + d["warnings"]
    sel, warning = select_narx(d)
    d["narx"] = None if sel is None else sel.to_dict()
    if warning:
        d["warnings"].append(warning)
    if rec.source is None:
        d["source"] = str(args.file)
    d = _clean(d)
    emit(d, as_json=args.json, summary=summary)
    return 0
