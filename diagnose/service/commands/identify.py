"""`stiction identify`: identify stiction (S, J, class) in one loop's record.

The command is `diagnose.identify` (the Python front door) on FILE with the reading options, and
prints its result: ``--json`` the result's ``to_dict()``, else a short summary.
"""

from __future__ import annotations

import argparse
import json
import sys
from typing import TYPE_CHECKING

from ._loopfile import add_file_arguments, naming_file, read_options, say_skipped

if TYPE_CHECKING:
    from ...identification import Identification


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_file_arguments(p, "identify")
    p.add_argument("--json", action="store_true",
                   help="print exactly one JSON object on stdout (messages go to stderr)")


def summary(ident: Identification) -> str:
    """A short human summary of an identification."""
    from ...plain import duration, number

    lines = []
    verdict = "STICTION" if ident.stiction else "no stiction"
    if ident.nothing_judged:
        verdict = "no evidence either way"      # the combiner's prior, not a healthy valve
    prob = ident.stiction_probability
    head = f"{ident.loop}: {verdict} (class {ident.cls}"
    if prob is not None:
        head += f", probability {prob:.2f}"
    lines.append(head + f", confidence {ident.confidence:.2f})")
    if ident.stiction and ident.S_pct is not None and ident.J_pct is not None:
        si = ident.S_interval_pct or (float("nan"), float("nan"))
        ji = ident.J_interval_pct or (float("nan"), float("nan"))
        src = " from OP/MV" if ident.method == "op_mv" else ""
        unit = ident.sj_units_text
        pct = " %" if ident.op_in_percent else ""
        d = ident.sj_digits
        lines.append(f"  S = {ident.S_pct:.{d}f}{pct} [{si[0]:.{d}f}, {si[1]:.{d}f}]   J = {ident.J_pct:.{d}f}{pct} "
                     f"[{ji[0]:.{d}f}, {ji[1]:.{d}f}]  ({unit}{src})")
        if ident.class_alternatives:
            lines.append(f"  the data also allow class {' or '.join(ident.class_alternatives)}")
    elif ident.stiction and ident.valve_not_moving and ident.fitted_S_pct is not None:
        pct = " %" if ident.op_in_percent else f" ({ident.sj_units_text})"
        lines.append(f"  S >= {ident.fitted_S_pct:.2f}{pct} (OP's travel; the stem never moved, so J and the class "
                     "are not judged)")
    if ident.evidence:
        lines.append(f"  evidence: {ident.evidence_text}")
    if ident.process is not None:
        lines.append(f"  process: {ident.process.describe(short=True)}")
    if ident.rmse is not None and ident.r2 is not None:
        # a recorded stem that moved is fitted OP -> MV: that rmse is in % of span, not PV units
        of = "MV from OP, % of span" if ident.valve_fit is not None else "PV from OP"
        lines.append(f"  fit: rmse {number(ident.rmse)}, r2 {ident.r2:.3f} (free-run simulation of {of})")
    osc = ident.oscillation
    if ident.slow_cycle:
        lines.append(f"  slow cycle: period {duration(osc.period_s)} (a daily or shift pattern, not a loop "
                     "oscillation)")
    elif osc.oscillating:
        lines.append(f"  oscillating: period {duration(osc.period_s)}, regularity {osc.regularity:.2f}")
    else:
        lines.append("  not oscillating regularly")
    if ident.narx is not None:
        lines.append(f"  NARX-SP model: {ident.narx.model} ({'within' if ident.narx.robust else 'outside'} "
                     "its robustness margin)")
    for w in ident.warnings:
        lines.append(f"  warning [{w.code}]: {w.message}")
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    from ...api import identify

    opts = read_options(args)
    with naming_file(args.file):
        ident = identify(args.file, **opts)
    say_skipped(ident.data_quality)
    if args.json:
        d = ident.to_dict()
        sys.stdout.write(json.dumps(d, allow_nan=False) + "\n")
        for w in ident.warnings:
            print(f"warning [{w.code}]: {w.message}", file=sys.stderr)
    else:
        print(summary(ident))
    return 0
