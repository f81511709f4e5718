"""How long the independent plant simulator takes to write a corpus, against the project's simulator.

    python benchmarks/bench_plantsim.py [--loops-per-kind 9] [--n 3000] [--seed 0] [--runs 3]

Generates ``loops-per-kind`` records of every scenario at ``n`` samples and 1 s (99 records by
default), per scenario and in total, and in the same run the same number of records of the same
length from `diagnose.simulate.sticky_loop` (the project's own simulator: two-parameter valve,
FOPTD, SIMC PI, 500-sample warm-up) as the baseline. Prints the median wall time of ``runs`` runs
and the ratio; timings on a shared machine are noisy, the ratio less so.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from benchmarks.plantsim import SCENARIOS, corpus  # noqa: E402


def _plantsim(per_kind: int, n: int, seed: int) -> tuple[float, dict[str, float], int]:
    per = {}
    total_samples = 0
    t0 = time.perf_counter()
    for k in SCENARIOS:
        t1 = time.perf_counter()
        for loop in corpus(seed, per_kind, kinds=[k], n=n, ts_s=1.0):
            total_samples += loop.n
        per[k] = time.perf_counter() - t1
    return time.perf_counter() - t0, per, total_samples


def _project(count: int, n: int, seed: int) -> float:
    from diagnose.simulate import sticky_loop
    t0 = time.perf_counter()
    for i in range(count):
        sticky_loop(3.0, 1.0, n=n, noise_std=0.05, load_walk_std=0.01, seed=seed + i)
    return time.perf_counter() - t0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--loops-per-kind", type=int, default=9)
    ap.add_argument("--n", type=int, default=3000)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--runs", type=int, default=3)
    args = ap.parse_args(argv)
    count = args.loops_per_kind * len(SCENARIOS)
    ours, base, pers = [], [], []
    for r in range(args.runs):
        t, per, samples = _plantsim(args.loops_per_kind, args.n, args.seed)
        ours.append(t)
        pers.append(per)
        base.append(_project(count, args.n, args.seed))
    print(f"{count} records x {args.n} samples at 1 s ({samples} samples after warm-up), {args.runs} runs")
    print(f"plantsim:            median {statistics.median(ours):6.2f} s  (runs: "
          f"{', '.join(f'{t:.2f}' for t in ours)})")
    print(f"diagnose.simulate:   median {statistics.median(base):6.2f} s  (runs: "
          f"{', '.join(f'{t:.2f}' for t in base)})")
    print(f"ratio plantsim / diagnose.simulate: {statistics.median(ours) / statistics.median(base):.2f}")
    print("per scenario (median s for", args.loops_per_kind, "records):")
    for k in SCENARIOS:
        print(f"  {k:18s} {statistics.median(p[k] for p in pers):6.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
