"""`stiction demo`: the nightly batch on the bundled sample logs; says where the reports are."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from ._args import whole_number


def sample_logs() -> Path:
    """The repository's sample_logs/ (beside the package), else ./sample_logs."""
    here = Path(__file__).resolve().parents[3] / "sample_logs"
    if here.is_dir():
        return here
    cwd = Path.cwd() / "sample_logs"
    if cwd.is_dir():
        return cwd
    from ...errors import DataError

    raise DataError("sample_logs/ not found (run from the repository root, or use `stiction batch`)")


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", default="stiction-demo-out", help="output folder (default ./stiction-demo-out)")
    p.add_argument("--workers", type=whole_number(1, "1 or more"), default=None,
                   help="worker processes (default: CPU count)")
    p.add_argument("--db", default=None, help="history database (default: the one `stiction history` reads, "
                                              "$STICTION_HOME/history.sqlite or ~/.local/share/stiction/history.sqlite)")
    from .batch import add_explain_argument

    add_explain_argument(p, "off", "it takes 3-40 s per loop")
    p.add_argument("--quiet", action="store_true", help="no progress bar")


def run(args: argparse.Namespace) -> int:
    from ..batch import run_batch
    from ..history import default_db_path
    from .batch import explain_mode, report

    out = Path(args.out)
    src = sample_logs()
    db = Path(args.db) if args.db else default_db_path()
    print(f"diagnosing the loops in {src} ...", file=sys.stderr)
    res = run_batch([src], out, workers=args.workers, db=db, explain=explain_mode(args.explain),
                    progress=not args.quiet)
    report(res)
    top = [r for r in res.rows if r["status"] == "ok"][:3]
    if top:
        print("worst loops: " + ", ".join(f"{r['loop']} (severity {r['severity']:.1f}, {r['class']})"
                                          for r in top))
    reads = "`stiction history LOOP` reads it" if not args.db else f"`stiction history LOOP --db {db}` reads it"
    print(f"history: {db} ({reads})")
    if args.explain == "off":
        print("missing physics was not run (it takes 3-40 s per loop): `stiction demo --explain on`, "
              f"or one loop: `stiction explain {src / 'FIC103.csv'}`")
    print(f"open {out / 'summary.md'} (or summary.pdf) to start.")
    return 1 if res.n_failed else 0
