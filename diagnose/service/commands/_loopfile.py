"""What every command that reads historian exports shares: the reading options (the same names and
meanings in every command and in the Python front door, `diagnose.api`), turning them into
options, choosing the loop (and segment), and printing a result."""

from __future__ import annotations

import argparse
import json
import os
import sys
from contextlib import contextmanager
from typing import Any, Callable, Iterator

from ...errors import StictionError
from ._args import whole_number

#: The layouts ``--format`` takes (`connectors.layouts`).
FORMATS = ("auto", "wide", "long", "ragged", "influx", "dcs")


def add_read_arguments(p: argparse.ArgumentParser, verb: str, *, tags: bool = True) -> None:
    """The reading options: columns, time, time zone, layout, tag map, loop, length.

    ``verb`` says what is done to the chosen loop (``--loop`` help); ``tags=False`` leaves out
    ``--tags`` for a command that declares its own.
    """
    g = p.add_argument_group("reading the data (the same options in every command; docs/api.md)")
    g.add_argument("--op", metavar="COL", help="controller output column (OP, %% of span)")
    g.add_argument("--pv", metavar="COL", help="process variable column")
    g.add_argument("--sp", metavar="COL", help="setpoint column")
    g.add_argument("--mv", metavar="COL", help="valve stem position column (%% of span), if recorded")
    g.add_argument("--time", metavar="COL", help="time column (default: found by its name or content)")
    g.add_argument("--ts-s", dest="ts_s", type=float, metavar="SECONDS",
                   help="sample period in seconds (default: the median spacing of the times)")
    g.add_argument("--ts", dest="ts_legacy", metavar="SECONDS|COL", help=argparse.SUPPRESS)
    g.add_argument("--tz", metavar="ZONE", help="time zone of times without one (IANA name such as "
                                                "Europe/Berlin, or +hh:mm; default UTC)")
    g.add_argument("--dst", choices=("infer", "earliest", "latest", "raise"), default=None,
                   help="local times at clock changes (default infer)")
    order = g.add_mutually_exclusive_group()
    order.add_argument("--dayfirst", dest="dayfirst", action="store_const", const=True, default=None,
                       help="dates such as 05/03/2026 are day first (5 March; default: the dates decide, "
                            "and a date_order warning says when they cannot)")
    order.add_argument("--monthfirst", dest="dayfirst", action="store_const", const=False,
                       help="dates such as 05/03/2026 are month first (3 May)")
    g.add_argument("--format", dest="fmt", metavar="LAYOUT", choices=FORMATS,
                   help="file layout: " + ", ".join(FORMATS) + " (default auto)")
    if tags:
        g.add_argument("--tags", metavar="TOML", help="tag map (TOML) naming each loop's columns")
    g.add_argument("--loop", metavar="NAME", help=f"the loop to {verb} when a file holds several")
    g.add_argument("--max-samples", dest="max_samples", type=whole_number(0, "0 or more"), metavar="N",
                   help="samples kept per loop, the newest (default 100000; 0 keeps all)")


def add_file_arguments(p: argparse.ArgumentParser, verb: str) -> None:
    """FILE and the reading options (``verb``: what is done to the loop)."""
    p.add_argument("file", metavar="FILE", help="historian export (CSV or another supported layout), or a "
                                                "folder of them read as one source (files it cannot read are "
                                                "skipped with a note)")
    add_read_arguments(p, verb)


def read_options(args: argparse.Namespace) -> dict[str, Any]:
    """The reading options given on the command line, by their Python names (`diagnose.api`
    functions and `connectors.read_records` take them as they are)."""
    opts: dict[str, Any] = {}
    for key in ("op", "pv", "sp", "mv", "time", "tz", "dst", "dayfirst", "tags", "loop", "max_samples"):
        v = getattr(args, key, None)
        if v is not None:
            opts[key] = v
    if getattr(args, "fmt", None) is not None:
        opts["format"] = args.fmt
    ts_s = getattr(args, "ts_s", None)
    legacy = getattr(args, "ts_legacy", None)
    if legacy is not None:  # the older --ts: a number is the period, anything else the time column
        try:
            ts_s = float(legacy)
        except ValueError:
            opts.setdefault("time", legacy)
    if ts_s is not None:
        opts["ts_s"] = ts_s
    from ...api import check_read_options

    return check_read_options(opts, diagnosis=True)     # every command that reads a file diagnoses it


@contextmanager
def naming_file(path: str | os.PathLike) -> Iterator[None]:
    """Make every error raised inside name FILE first, as the reader's errors do: identification
    and explain work on a record and know its loop, not the file the user gave."""
    label = os.fspath(path)
    try:
        yield
    except StictionError as exc:
        text = str(exc)
        if not text.startswith((f"{label}:", f"{label} ")):
            exc.args = (f"{label}: {text}",)
        raise


def say_skipped(findings) -> None:
    """One line on stderr per file of a folder that could not be read and was skipped (the reader's
    ``file_skipped`` findings): the result holds the loops of the other files, and a file left out
    must not pass in silence."""
    for f in findings:
        if f.code == "file_skipped":
            print(f"note: {f.message}", file=sys.stderr)


def select_record(records: list, loop: str | None, source: str, verb: str = "identified"):
    """The record to work on and notes to report (as ``{"code", "message"}``); see
    `diagnose.api.choose_record`."""
    from ...api import choose_record

    rec, notes = choose_record(records, loop, source, verb)
    return rec, [n.to_dict() for n in notes]


def emit(d: dict[str, Any], *, as_json: bool, summary: Callable[[dict[str, Any]], str]) -> None:
    """Print a result: one JSON object on stdout (warnings repeated on stderr), or the summary."""
    if as_json:
        sys.stdout.write(json.dumps(d, allow_nan=False) + "\n")
        for w in d["warnings"]:
            print(f"warning [{w['code']}]: {w['message']}", file=sys.stderr)
    else:
        print(summary(d))
