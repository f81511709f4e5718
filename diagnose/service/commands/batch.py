"""`stiction batch`: diagnose every loop in files/folders; per-loop reports and a plant summary."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path


def add_explain_argument(p: argparse.ArgumentParser, default: str, cost: str) -> None:
    """``--explain [off|auto|on]`` (bare ``--explain`` is ``on``), the same in batch, demo and monitor."""
    p.add_argument("--explain", nargs="?", const="on", choices=["off", "auto", "on"], default=default,
                   help=f"run the missing-physics stage: off ({cost}), auto only where the fitted model "
                        "leaves a mismatch (free-run r2 on PV < 0.5), on (or a bare --explain) for every "
                        f"loop (default {default})")
    p.add_argument("--no-explain", dest="explain", action="store_const", const="off", help=argparse.SUPPRESS)


def add_arguments(p: argparse.ArgumentParser) -> None:
    from ._loopfile import add_read_arguments

    p.add_argument("inputs", nargs="+", metavar="INPUT", help="historian export files and/or folders")
    p.add_argument("--out", required=True, help="output folder (reports, figures, summary)")
    p.add_argument("--workers", type=int, default=None,
                   help="worker processes (default: CPU count; 1 runs in this process)")
    p.add_argument("--scheduler", default=None,
                   help="run on Dask distributed: 'local' for a LocalCluster of --workers processes, "
                        "or a scheduler address such as tcp://10.0.0.5:8786")
    p.add_argument("--db", default=None, help="history database (default $STICTION_HOME/history.sqlite "
                                              "or ~/.local/share/stiction/history.sqlite)")
    p.add_argument("--no-history", action="store_true", help="do not store results in the history database")
    add_explain_argument(p, "off", "it takes 3-40 s per loop")
    p.add_argument("--narx", action=argparse.BooleanOptionalAction, default=True,
                   help="select and free-run the NARX-SP model (default on)")
    p.add_argument("--pdf", action=argparse.BooleanOptionalAction, default=True,
                   help="write PDF reports beside the Markdown (default on)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    add_read_arguments(p, "diagnose (the others in each file are left out)")


def read_options(args: argparse.Namespace) -> dict:
    """The reading options of the command line, without the tag map (the batch applies it file
    by file)."""
    from ._loopfile import read_options as options

    opts = options(args)
    opts.pop("tags", None)
    return opts


def explain_mode(value: str) -> bool | str:
    return {"on": True, "off": False}.get(value, "auto")


def report(res, stream=None) -> None:
    """What the batch did, on stdout; failures on stderr."""
    from ...plain import count
    from ..report import not_read

    stream = stream or sys.stdout
    t = res.counts
    # loops are what the files read held: a file that could not be read is said apart, not a loop
    said = [f"{count(t['loops'], 'loop')} from {count(res.n_files - t['files_failed'], 'file')}: "
            f"{t['diagnosed']} diagnosed ({res.n_skipped} unchanged since the last run), "
            f"{t['loops_failed']} failed"] + not_read(t)
    print("; ".join(said) + f", {res.elapsed_s:.1f} s", file=stream)
    pdf = getattr(res, "pdf", True)
    print(f"summary: {res.out_dir / 'summary.md'} (also {'.pdf, ' if pdf else ''}.csv, .json)", file=stream)
    print(f"per-loop reports: {res.out_dir / 'loops'}/LOOP/LOOP.md ({'.pdf, ' if pdf else ''}.json, figures)",
          file=stream)
    groups: dict[str, list[str]] = {}
    for f in getattr(res, "skipped_files", None) or []:
        # files are left alone for different reasons (not an export, no loop of that --loop); the
        # tail in brackets is per file (a file's loops) and stays in the summary
        why = str(f.get("reason") or "left alone").split(" (")[0]
        groups.setdefault(why, []).append(Path(f["path"]).name)
    for why, names in groups.items():
        names.sort()  # workers report in the order they finish
        shown = ", ".join(names[:5]) + (", ..." if len(names) > 5 else "")
        print(f"left alone: {len(names)} file(s), {why}: {shown}; listed in the summary", file=stream)
    for r in res.rows:
        if r["status"] != "ok":
            print(f"failed: {r['loop']} ({r.get('source')}): {r.get('error')}", file=sys.stderr)


def run(args: argparse.Namespace) -> int:
    from ..batch import run_batch

    if args.workers is not None and args.workers < 1:
        from ...errors import DataError

        raise DataError("--workers must be at least 1")
    res = run_batch(args.inputs, args.out, workers=args.workers, scheduler=args.scheduler, tags=args.tags,
                    read_options=read_options(args), explain=explain_mode(args.explain), narx=args.narx, pdf=args.pdf,
                    db=args.db, history=not args.no_history, progress=not args.quiet)
    report(res)
    if args.loop and res.counts["loops"] == 0:
        # a --loop that no file holds is a typo or the wrong folder, not a night with nothing to do
        print(f"error: no file read holds a loop named {args.loop!r}; the loops each file holds are listed "
              f"in {res.summary_md}", file=sys.stderr)
        return 1
    return 1 if res.n_failed else 0
