"""Throughput of the batched stiction kernel against a straightforward pure-Python loop.

Targets (issue 2): >= 50 million candidate-samples per second on one core, and >= 50x the
pure-Python reference (Kano's model as written for the tests, tests/kano.py) measured in the same
run. Every vector variant of the compiled kernels the CPU supports is timed (baseline, AVX2,
AVX-512); all must give the same numbers.

    python benchmarks/bench_stiction_model.py [--candidates 2000] [--samples 10000]
"""

from __future__ import annotations

import argparse
import sys
import time

from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from diagnose import kernels  # noqa: E402
from diagnose.stiction_model import stiction_batch  # noqa: E402
from kano import kano_valve  # noqa: E402


def best_of(fn, repeats: int) -> float:
    best = float("inf")
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--candidates", type=int, default=2000)
    ap.add_argument("--samples", type=int, default=10000)
    ap.add_argument("--ref-candidates", type=int, default=5, help="candidates for the pure-Python baseline")
    args = ap.parse_args(argv)

    rng = np.random.default_rng(0)
    n, m = args.samples, args.candidates
    x = 50 + 8 * np.sin(2 * np.pi * np.arange(n) / 200) + np.cumsum(rng.normal(0, 0.05, n)) + rng.normal(0, 0.2, n)
    S = rng.uniform(0, 10, m)
    J = rng.uniform(0, 10, m)
    f0 = rng.choice([-1.0, 1.0], m)
    out = np.empty((m, n))
    k = args.ref_candidates
    t_ref = best_of(lambda: [kano_valve(x, S[i], J[i], int(f0[i])) for i in range(k)], 1)
    ref_rate = k * n / t_ref
    print(f"pure Python (Kano's model, tests/kano.py): {k} candidates x {n} samples in {t_ref * 1e3:.1f} ms "
          f"= {ref_rate / 1e6:.3f} M candidate-samples/s")
    ok = True
    first = None
    try:
        for level in range(kernels.max_isa_level() + 1):
            name = kernels.set_isa(level)
            t_batch = best_of(lambda: stiction_batch(x, S, J, f0, out=out), 3)
            batch_rate = m * n / t_batch
            ok_rate = batch_rate >= 50e6
            ok_speedup = batch_rate / ref_rate >= 50
            same = all(np.allclose(out[i], kano_valve(x, S[i], J[i], int(f0[i])), rtol=0, atol=1e-12)
                       for i in range(k))
            first = out.copy() if first is None else first
            same_variants = bool(np.array_equal(out, first))
            print(f"{name}: {m} candidates x {n} samples in {t_batch * 1e3:.1f} ms "
                  f"= {batch_rate / 1e6:.1f} M candidate-samples/s (target >= 50) {'OK' if ok_rate else 'MISSED'}; "
                  f"{batch_rate / ref_rate:.0f}x the pure Python (target >= 50x) {'OK' if ok_speedup else 'MISSED'}; "
                  f"equal to Kano's model: {same}; to the first variant: {same_variants}")
            ok = ok and ok_rate and ok_speedup and same and same_variants
    finally:
        kernels.set_isa(None)
    return 0 if ok else 1

if __name__ == "__main__":
    sys.exit(main())
