"""`stiction explain`: locate where the identified model and the recording disagree, name the missing
physics, fit a model that has it, and show the held-out error fall."""

from __future__ import annotations

import argparse
import json
import math
import sys
from typing import Any

from ...errors import DataError


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("file", metavar="FILE", help="historian export (CSV or another supported layout)")
    p.add_argument("--op", metavar="COL", help="controller output column (OP, %% of span)")
    p.add_argument("--pv", metavar="COL", help="process variable column")
    p.add_argument("--sp", metavar="COL", help="setpoint column")
    p.add_argument("--mv", metavar="COL", help="valve stem position column (%% of span), if recorded")
    p.add_argument("--ts", metavar="SECONDS|COL",
                   help="sample period in seconds (a number), or the name of the timestamp column")
    p.add_argument("--format", dest="fmt", metavar="LAYOUT", help="file layout override")
    p.add_argument("--tags", metavar="TOML", help="tag map (TOML) naming each loop's columns")
    p.add_argument("--loop", metavar="NAME", help="loop to explain when the file holds several")
    p.add_argument("--target", choices=["auto", "pv", "mv"], default="auto",
                   help="auto: OP->PV, plus OP->MV for valve-side effects when MV is recorded; "
                        "pv: OP/PV only; mv: the valve alone (needs MV)")
    p.add_argument("--train-fraction", type=float, default=0.65, metavar="F",
                   help="leading fraction of the record the fits may use; the rest is held out (default 0.65)")
    p.add_argument("--hypotheses", metavar="NAMES",
                   help="comma-separated hypotheses to test (default: all registered)")
    p.add_argument("--min-reduction", type=float, default=0.10, metavar="F",
                   help="smallest relative held-out RMSE reduction that names an effect (default 0.10)")
    p.add_argument("--figure", metavar="PNG", help="also draw the residual, conditioned residuals and fits")
    p.add_argument("--json", action="store_true",
                   help="print exactly one JSON object on stdout (messages go to stderr)")


def _read_options(args: argparse.Namespace) -> dict[str, Any]:
    opts: dict[str, Any] = {}
    for role in ("op", "pv", "sp", "mv"):
        v = getattr(args, role)
        if v is not None:
            opts[role] = v
    if args.ts is not None:
        try:
            ts_s = float(args.ts)
        except ValueError:
            opts["ts"] = args.ts
        else:
            if not (math.isfinite(ts_s) and ts_s > 0):
                raise DataError(f"--ts {args.ts}: the sample period must be a positive number of seconds")
            opts["ts_s"] = ts_s
    for key in ("fmt", "tags", "loop"):
        v = getattr(args, key)
        if v is not None:
            opts[key] = v
    return opts


def _select(records: list, loop: str | None, source: str):
    notes: list[dict[str, str]] = []
    if not records:
        raise DataError(f"{source}: no loop found in the file")
    names = list(dict.fromkeys(r.name for r in records))
    if loop is not None:
        chosen = [r for r in records if r.name == loop]
        if not chosen:
            raise DataError(f"{source}: no loop named {loop!r} (loops: {', '.join(names)})")
    elif len(names) > 1:
        raise DataError(f"{source} holds {len(names)} loops ({', '.join(names)}); choose one with --loop NAME")
    else:
        chosen = records
    rec = max(chosen, key=lambda r: r.n)
    if len(chosen) > 1:
        notes.append({"code": "segments",
                      "message": f"the record is split into {len(chosen)} segments (gaps or mode changes); "
                                 f"explained the longest ({rec.n} samples)"})
    return rec, notes


def summary(d: dict[str, Any]) -> str:
    """A short human summary of an explanation dict."""
    unit = "% of span" if d.get("target") == "mv" else "PV units"
    lines = [f"{d.get('loop', '')}: missing physics: {d['missing_physics'] or 'none named'}",
             f"  held-out RMSE ({d.get('target', 'pv').upper()}, {unit}): baseline {d['baseline_rmse']:.4g}"
             f" -> {d['improved_rmse']:.4g}"]
    for h in d["hypotheses"]:
        params = ", ".join(f"{k} {v:.3g}" for k, v in h["params"].items() if v is not None)
        mark = "*" if h["accepted"] else " "
        red = h.get("heldout_reduction")
        lines.append(f"  {mark} {h['name']:<22} [{h.get('target', '')}] held-out {h['heldout_rmse']:.4g}"
                     f" ({'' if red is None else f'{100 * red:+.0f} %'})  {params}")
    m = d.get("mismatch") or {}
    for w in (m.get("windows") or [])[:3]:
        lines.append(f"  mismatch window {w['start_s']:.0f}-{w['end_s']:.0f} s: RMS {w['rms']:.3g} "
                     f"({w['ratio_to_median']:.1f}x median)")
    for hint in m.get("hints") or []:
        lines.append(f"  residual: {hint}")
    lines.append("  " + d["explanation"])
    for w in d.get("warnings", []):
        lines.append(f"  warning [{w['code']}]: {w['message']}")
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    import connectors

    from ...physics import explain

    if not 0.3 <= args.train_fraction <= 0.9:
        raise DataError(f"--train-fraction {args.train_fraction}: use a value between 0.3 and 0.9")
    if not 0.0 < args.min_reduction < 1.0:
        raise DataError(f"--min-reduction {args.min_reduction}: use a value between 0 and 1")
    hyps = None
    if args.hypotheses:
        hyps = [h.strip() for h in args.hypotheses.split(",") if h.strip()]
    records = connectors.read_records(args.file, **_read_options(args))
    rec, notes = _select(records, args.loop, str(args.file))
    result = explain(rec, target=args.target, train_fraction=args.train_fraction, hypotheses=hyps,
                     min_reduction=args.min_reduction)
    d = result.to_dict()
    d["warnings"] = notes + d["warnings"]
    if args.figure:
        from ...physics.figures import plot_explanation
        plot_explanation(result, rec, args.figure)
        print(f"wrote {args.figure}", file=sys.stderr)
    if args.json:
        sys.stdout.write(json.dumps(d, allow_nan=False) + "\n")
        for w in d["warnings"]:
            print(f"warning [{w['code']}]: {w['message']}", file=sys.stderr)
    else:
        print(summary(d))
    return 0
