"""`stiction explain`: locate where the identified model and the recording disagree, name the missing
physics, fit a model that has it, and show the held-out error fall."""

from __future__ import annotations

import argparse
import sys
from typing import Any

from ...errors import DataError
from ._loopfile import add_file_arguments, emit, naming_file, read_options, say_skipped, select_record


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_file_arguments(p, "explain")
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


def summary(d: dict[str, Any]) -> str:
    """A short human summary of an explanation dict.

    Every change of the held-out error is printed signed, negative for a fall (``-5 %``), as the
    explanation's own text prints it; times are plain durations.
    """
    from ...plain import duration, number, percent_change

    unit = "% of span" if d.get("target") == "mv" else "PV units"
    # the hypotheses' changes are against the plain model refit here, which can differ a lot from
    # the baseline (an integrating process's balance error grows over the held-out part): both shown
    ref = (d.get("mismatch") or {}).get("reference_rmse")
    head = f"  held-out RMSE ({d.get('target', 'pv').upper()}, {unit}): baseline {number(d['baseline_rmse'], 4)}"
    if ref is not None:
        head += f", plain model refit here {number(ref, 4)}"
    head += (f" -> with {d['missing_physics']} {number(d['improved_rmse'], 4)}" if d["missing_physics"]
             else "; nothing named")
    lines = [f"{d.get('loop', '')}: missing physics: {d['missing_physics'] or 'none named'}", head]
    # valve-side hypotheses judged on the stem (OP -> MV) are measured against that stage's own
    # baseline and reference, in % of span: without them their changes cannot be read
    for stage, other in ((d.get("mismatch") or {}).get("other_stages") or {}).items():
        if other.get("baseline_rmse") is None:
            continue
        line = (f"  held-out RMSE ({'MV' if stage == 'valve' else stage}, % of span): baseline "
                f"{number(other['baseline_rmse'], 4)}")
        if other.get("reference_rmse") is not None:
            line += f", plain model refit here {number(other['reference_rmse'], 4)}"
        lines.append(line)
    for h in d["hypotheses"]:
        params = ", ".join(f"{k} {duration(v) if k.endswith('_s') else number(v)}"
                           for k, v in h["params"].items() if v is not None)
        mark = "*" if h["accepted"] else " "
        red = h.get("heldout_reduction")
        change = "" if red is None else f"change {percent_change(-red)}"
        # each hypothesis in its own stage's units: MV rows in % of span, PV rows in PV units
        h_unit = "% of span" if h.get("target") == "mv" else "PV units"
        on_training = " judged on the training part;" if h.get("evidence") == "training" else ""
        lines.append(f"  {mark} {h['name']:<22} [{h.get('target', '')}] held-out {number(h['heldout_rmse'], 4)}"
                     f" {h_unit} ({change}){on_training}  {params}")
    m = d.get("mismatch") or {}
    for w in (m.get("windows") or [])[:3]:
        lines.append(f"  mismatch window {duration(w['start_s'])} to {duration(w['end_s'])}: RMS {number(w['rms'])} "
                     f"({w['ratio_to_median']:.1f}x median)")
    for hint in m.get("hints") or []:
        lines.append(f"  residual: {hint}")
    lines.append("  " + d["explanation"])
    for w in d.get("warnings", []):
        lines.append(f"  warning [{w['code']}]: {w['message']}")
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    import connectors

    from ...physics import ExplainWarning, explain

    if not 0.3 <= args.train_fraction <= 0.9:
        raise DataError(f"--train-fraction {args.train_fraction}: use a value between 0.3 and 0.9")
    if not 0.0 < args.min_reduction < 1.0:
        raise DataError(f"--min-reduction {args.min_reduction}: use a value between 0 and 1")
    hyps = None
    if args.hypotheses is not None:
        hyps = [h.strip() for h in args.hypotheses.split(",") if h.strip()]
        if not hyps:
            raise DataError(f"--hypotheses {args.hypotheses!r}: name at least one hypothesis (comma-separated), "
                            "or leave the option out to try them all")
    opts = read_options(args)
    with naming_file(args.file):
        records = connectors.read_records(args.file, **opts)
        rec, notes = select_record(records, args.loop, str(args.file), "explained")
        say_skipped(rec.findings)
        result = explain(rec, target=args.target, train_fraction=args.train_fraction, hypotheses=hyps,
                         min_reduction=args.min_reduction)
    result = result.with_warnings(tuple(ExplainWarning(w["code"], w["message"]) for w in notes))
    d = result.to_dict()
    if args.figure:
        from connectors.historian import atomic_write

        from ..figures import explanation_png
        atomic_write(args.figure, explanation_png(result, rec.name, dpi=110))
        print(f"wrote {args.figure}", file=sys.stderr)
    emit(d, as_json=args.json, summary=summary)
    return 0
