"""`stiction history [LOOP]`: the S/J/class trend of a loop (or the loops known) from the database."""

from __future__ import annotations

import argparse
import json

from ._args import whole_number


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("loop", nargs="?", default=None, help="loop name (omit to list the loops)")
    p.add_argument("--db", default=None, help="history database (default $STICTION_HOME/history.sqlite "
                                              "or ~/.local/share/stiction/history.sqlite)")
    p.add_argument("--limit", type=whole_number(1, "1 or more"), default=None, metavar="N", help="show only the last N runs (N >= 1); the verdict's persistence and the degradation "
                        "still count the earlier ones")
    p.add_argument("--json", action="store_true", help="print the runs as JSON")


def run(args: argparse.Namespace) -> int:
    from ..history import History, degradation, format_trend, persistence, shown_run

    with History(args.db, readonly=True) as h:
        if args.loop is None:
            loops = h.loops()
            if args.json:
                print(json.dumps(loops))
            else:
                print(f"{len(loops)} loop(s) in {h.path}:")
                for name in loops:
                    last = h.runs(name, limit=1)
                    print(f"  {name:<30} {_last_verdict(last[0]) if last else ''}".rstrip())
            return 0
        # every run: the persistence (last 7) and the degradation (last 3) do not depend on --limit
        rows = h.runs(args.loop)
        if not rows:  # runs are filed under the file-safe tag ("FIC 101/A" -> "FIC_101_A")
            from ..batch import safe_name

            if safe_name(args.loop) != args.loop:
                args.loop = safe_name(args.loop)
                rows = h.runs(args.loop)
        if not rows and args.loop not in h.loops():
            from ...errors import StictionError

            known = ", ".join(h.loops()[:10]) or "none"
            raise StictionError(f"no runs of loop {args.loop!r} in {h.path} (loops: {known})")
    if args.json:
        # S and J as the trend shows them (only for runs that said stiction); the database keeps all
        shown = [shown_run(r) for r in (rows[-args.limit:] if args.limit else rows)]
        print(json.dumps({"loop": args.loop, "n_runs": len(rows), "runs": shown, "degradation": degradation(rows),
                          "persistence": persistence(rows)}, indent=1))
    else:
        print(format_trend(args.loop, rows, limit=args.limit), end="")
    return 0


def _last_verdict(row: dict) -> str:
    """The last run in a few words: "S 2.24 %" when it said stiction, "no stiction" when it did
    not (an S of 0.00 % read as a size), S alone for rows of releases that stored no verdict."""
    from ...plain import sj_decimals
    from ..history import run_units, said_no_stiction

    if said_no_stiction(row):
        return "no stiction"
    if row.get("S_pct") is None:
        return ""
    units = run_units(row)
    S = f"S {row['S_pct']:.{sj_decimals(units)}f}"
    return f"{S} %" if units == "% of span" else f"{S} ({units})"
