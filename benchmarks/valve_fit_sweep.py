"""Exactness of the OP/MV valve fit on loops as `stiction simulate` writes them.

Each loop is simulated with the command's defaults (`diagnose.simulate.sticky_loop` as
``stiction simulate --S S --J J --seed SEED`` calls it), written to a CSV and read back, so OP and
the stem carry the file's rounding; the fit (`diagnose.valve_fit.fit_valve`) is exact when S and J
are within 2 % (J: of max(S, J)), and the truth lies in both 95 % intervals. The default grid is S
2, 3.6 and 5 x J 0.5, 2, 4 and 7 x seeds 1-8 (96 loops, about a minute on two cores).

    python benchmarks/valve_fit_sweep.py [--S 2 3.6 5] [--J 0.5 2 4 7] [--seeds 8] [--src DIR]

``--src DIR`` fits with another source tree's `fit_valve` (e.g. an earlier commit checked out with
``git worktree add``).
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--S", type=float, nargs="+", default=[2.0, 3.6, 5.0])
    ap.add_argument("--J", type=float, nargs="+", default=[0.5, 2.0, 4.0, 7.0])
    ap.add_argument("--seeds", type=int, default=8, help="seeds 1..N per (S, J)")
    ap.add_argument("--src", default=str(ROOT), help="source tree whose fit_valve is timed")
    args = ap.parse_args(argv)
    sys.path.insert(0, str(Path(args.src).resolve()))
    import diagnose
    from connectors.historian import write_wide
    from diagnose.simulate import sticky_loop
    from diagnose.valve_fit import fit_valve

    exact = inside = total = 0
    misses = []
    with tempfile.TemporaryDirectory() as tmp:
        for S in args.S:
            for J in args.J:
                for seed in range(1, args.seeds + 1):
                    # the command's defaults (diagnose/service/commands/simulate.py)
                    rec = sticky_loop(S, J, n=3000, noise_std=0.02, load_walk_std=0.01, seed=seed)
                    path = Path(tmp) / f"s{S:g}_j{J:g}_{seed}.csv"
                    write_wide(rec, path)
                    (back,) = diagnose.read_loops(path)
                    fit = fit_valve(back.op, back.mv, back.ts_s)
                    ok = abs(fit.S_pct - S) <= 0.02 * S and abs(fit.J_pct - J) <= 0.02 * max(S, J)
                    holds = (fit.S_interval_pct[0] <= S <= fit.S_interval_pct[1]
                             and fit.J_interval_pct[0] <= J <= fit.J_interval_pct[1])
                    exact += ok
                    inside += holds
                    total += 1
                    if not (ok and holds):
                        misses.append(f"S {S:g} J {J:g} seed {seed}: fitted S {fit.S_pct:.3f} J {fit.J_pct:.3f}, "
                                      f"r2 {fit.r2:.4f}")
    print(f"{args.src}: exact {exact}/{total}, truth inside both intervals {inside}/{total}")
    for m in misses:
        print("   " + m)
    return 0


if __name__ == "__main__":
    sys.exit(main())
