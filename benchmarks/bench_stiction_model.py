"""Throughput of the batched stiction kernel against a straightforward pure-Python loop.

Targets (issue 2): >= 50 million candidate-samples per second on one core, and >= 50x the
pure-Python reference measured in the same run. The kernel runs on the native (C) path when it
builds, else on numba; ``STICTION_NATIVE=0`` forces numba. The path used is printed.

    python benchmarks/bench_stiction_model.py [--candidates 2000] [--samples 10000]
    STICTION_NATIVE=0 python benchmarks/bench_stiction_model.py
"""

from __future__ import annotations

import argparse
import os
import sys
import time

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import numpy as np

from diagnose.stiction_model import stiction_batch, stiction_reference


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
    stiction_batch(x, S[:2], J[:2], f0[:2])          # compile or load the cache outside the timing

    t_batch = best_of(lambda: stiction_batch(x, S, J, f0, out=out), 3)
    k = args.ref_candidates
    t_ref = best_of(lambda: [stiction_reference(x, S[i], J[i], int(f0[i])) for i in range(k)], 1)

    batch_rate = m * n / t_batch
    ref_rate = k * n / t_ref
    ok_rate = batch_rate >= 50e6
    ok_speedup = batch_rate / ref_rate >= 50
    from diagnose import native

    path = native.status()["kernels"].get("diagnose.stiction_model._batch_kernel", "?")
    print(f"kernel path    : {path}")
    print(f"batched kernel : {m} candidates x {n} samples in {t_batch * 1e3:.1f} ms "
          f"= {batch_rate / 1e6:.1f} M candidate-samples/s  (target >= 50)  {'OK' if ok_rate else 'MISSED'}")
    print(f"pure Python    : {k} candidates x {n} samples in {t_ref * 1e3:.1f} ms "
          f"= {ref_rate / 1e6:.3f} M candidate-samples/s")
    print(f"speed-up       : {batch_rate / ref_rate:.0f}x  (target >= 50x)  {'OK' if ok_speedup else 'MISSED'}")
    # exactness on the timed data
    same = all(np.array_equal(out[i], stiction_reference(x, S[i], J[i], int(f0[i]))) for i in range(k))
    print(f"batch == reference on the first {k} candidates: {same}")
    return 0 if (ok_rate and ok_speedup and same) else 1


if __name__ == "__main__":
    sys.exit(main())
