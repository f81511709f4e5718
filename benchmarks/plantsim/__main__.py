"""Command line: write a labelled corpus (or a concealed-effect set) as wide CSV files.

    python -m benchmarks.plantsim --out DIR --seed S [--n-per-kind N] [--kinds a,b] [--n SAMPLES]
                                  [--ts SECONDS] [--mv] [--definition original|identifiable]
    python -m benchmarks.plantsim --out DIR --seed S --concealed N [--effects a,b] [--n SAMPLES] [--mv]
"""

from __future__ import annotations

import argparse
import sys
import time

from .export import write_loops
from .concealed import EFFECTS, concealed_set
from .scenarios import DEFINITIONS, SCENARIOS, corpus


def _names(text: str, allowed, what: str) -> list[str]:
    names = [t.strip() for t in text.split(",") if t.strip()]
    bad = [t for t in names if t not in allowed]
    if bad:
        raise ValueError(f"unknown {what} {', '.join(bad)}; choose from {', '.join(allowed)}")
    return names


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m benchmarks.plantsim",
                                 description="Write simulated closed-loop records (wide CSV) and labels.csv.")
    ap.add_argument("--out", required=True, help="output folder (created if missing)")
    ap.add_argument("--seed", type=int, default=0, help="seed: the same seed writes the same files")
    ap.add_argument("--n-per-kind", type=int, default=8, help="records per scenario (default 8)")
    ap.add_argument("--kinds", help=f"comma-separated scenarios (default all: {', '.join(SCENARIOS)})")
    ap.add_argument("--n", type=int, help="samples per record (default drawn; 8000 for --concealed)")
    ap.add_argument("--ts", type=float, help="sample period in seconds (default drawn; 1 for --concealed)")
    ap.add_argument("--mv", action="store_true", help="also write the true stem position (TAG.POS)")
    ap.add_argument("--definition", choices=DEFINITIONS, default="original",
                    help="corpus definition: original (default, reproduces earlier seeds) or identifiable "
                         "(every record a running loop, every sticky record able to show its stiction)")
    ap.add_argument("--concealed", type=int, metavar="N",
                    help="write N concealed-effect records per effect instead of the corpus")
    ap.add_argument("--effects", help=f"comma-separated effects for --concealed (default all: {', '.join(EFFECTS)})")
    args = ap.parse_args(argv)
    try:
        if args.n is not None and args.n < 50:
            raise ValueError(f"--n must be at least 50 samples, got {args.n}")
        if args.ts is not None and not args.ts > 0:
            raise ValueError(f"--ts must be > 0 seconds, got {args.ts}")
        t0 = time.perf_counter()
        if args.concealed is not None:
            if args.concealed < 1:
                raise ValueError(f"--concealed must be at least 1, got {args.concealed}")
            effects = _names(args.effects, EFFECTS, "effect") if args.effects else EFFECTS
            loops = concealed_set(args.seed, args.concealed, effects=effects, n=args.n or 8000,
                                  ts_s=args.ts or 1.0)
        else:
            if args.n_per_kind < 1:
                raise ValueError(f"--n-per-kind must be at least 1, got {args.n_per_kind}")
            kinds = _names(args.kinds, SCENARIOS, "scenario") if args.kinds else None
            loops = list(corpus(args.seed, args.n_per_kind, kinds=kinds, n=args.n, ts_s=args.ts,
                                definition=args.definition))
        paths = write_loops(loops, args.out, with_mv=args.mv)
    except (ValueError, OSError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    sticky = sum(1 for lp in loops if lp.sticky)
    print(f"wrote {len(paths)} records ({sticky} sticky) and labels.csv to {args.out} "
          f"in {time.perf_counter() - t0:.1f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
