"""What every command that diagnoses one loop from one file shares: the file and column options,
turning them into `connectors.read_records` options, and choosing the loop (and segment)."""

from __future__ import annotations

import argparse
import json
import math
import sys
from typing import Any, Callable

from ...errors import DataError


def add_file_arguments(p: argparse.ArgumentParser, verb: str) -> None:
    """FILE and the column, layout, tag-map and loop options (``verb``: what is done to the loop)."""
    p.add_argument("file", metavar="FILE", help="historian export (CSV or another supported layout)")
    p.add_argument("--op", metavar="COL", help="controller output column (OP, %% of span)")
    p.add_argument("--pv", metavar="COL", help="process variable column")
    p.add_argument("--sp", metavar="COL", help="setpoint column")
    p.add_argument("--mv", metavar="COL", help="valve stem position column (%% of span), if recorded")
    p.add_argument("--ts", metavar="SECONDS|COL",
                   help="sample period in seconds (a number), or the name of the timestamp column")
    p.add_argument("--format", dest="fmt", metavar="LAYOUT", help="file layout override")
    p.add_argument("--tags", metavar="TOML", help="tag map (TOML) naming each loop's columns")
    p.add_argument("--loop", metavar="NAME", help=f"loop to {verb} when the file holds several")


def read_options(args: argparse.Namespace) -> dict[str, Any]:
    """The `connectors.read_records` options given on the command line."""
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


def select_record(records: list, loop: str | None, source: str, verb: str = "identified"):
    """The record to work on: the named (or only) loop's longest segment, and notes to report."""
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
                                 f"{verb} the longest ({rec.n} samples)"})
    return rec, notes


def emit(d: dict[str, Any], *, as_json: bool, summary: Callable[[dict[str, Any]], str]) -> None:
    """Print a result: one JSON object on stdout (warnings repeated on stderr), or the summary."""
    if as_json:
        sys.stdout.write(json.dumps(d, allow_nan=False) + "\n")
        for w in d["warnings"]:
            print(f"warning [{w['code']}]: {w['message']}", file=sys.stderr)
    else:
        print(summary(d))
