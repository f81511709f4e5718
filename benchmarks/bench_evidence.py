"""Speed of diagnose.evidence.run_all against baselines measured in the same process.

On seeded simulated records of 10 000 samples (a sticky flow loop, a healthy loop with a
sinusoidal load, a sticky level loop), each run several times; the figures are medians. The
baselines are one `diagnose.oscillation.oscillation_context` call (the core's oscillation test) and,
with --identify, one `diagnose.identification.identify` call on the same record (what `stiction
identify` does now). Timings on a shared machine are noisy: read the ratios.
Run:  python benchmarks/bench_evidence.py [--n 10000] [--repeat 15] [--identify]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from diagnose.evidence import run_all  # noqa: E402
from diagnose.oscillation import oscillation_context  # noqa: E402
from diagnose.simulate import PIDController, make_process, simulate_loop, sinusoid, sticky_loop  # noqa: E402


def records(n: int):
    yield "sticky flow", False, sticky_loop(3.0, 1.0, n=n, tau_s=2.0, delay_s=1.0, Kc=0.2, Ti_s=2.0,
                                            noise_std=0.05, load_walk_std=0.01, seed=0)
    yield "healthy, sine load", False, simulate_loop(
        n=n, ts_s=0.25, process=make_process("foptd", gain=1.0, tau_s=10.0, delay_s=1.0), controller=PIDController(Kc=2.0, Ti_s=10.0),
        load=sinusoid(n, 0.25, 20.0, 2.0), noise_std=0.05, seed=0, warmup=400)
    yield "sticky level", True, sticky_loop(3.0, 1.0, n=n, kind="integrating", gain=0.02, tau_s=0.0, delay_s=2.0,
                                             noise_std=0.02, load_walk_std=0.002, seed=0)


def median_time(f, repeat: int) -> float:
    f()     # warm caches (filter designs, imports)
    ts = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        f()
        ts.append(time.perf_counter() - t0)
    return float(np.median(ts))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=10_000, help="samples per record")
    ap.add_argument("--repeat", type=int, default=15)
    ap.add_argument("--identify", action="store_true", help="also time diagnose.identification.identify once per record")
    args = ap.parse_args(argv)
    print(f"{'record':20} {'run_all ms':>10} {'osc ms':>8} {'ratio':>7}" + (f" {'identify s':>10} {'share':>7}"
                                                                            if args.identify else ""))
    for name, integ, r in records(args.n):
        t_ev = median_time(lambda: run_all(r.op, r.pv, r.ts_s, sp=r.sp, integrating=integ), args.repeat)
        t_osc = median_time(lambda: oscillation_context(r.pv, r.ts_s, sp=r.sp, op=r.op), args.repeat)
        line = f"{name:20} {1000 * t_ev:10.1f} {1000 * t_osc:8.2f} {t_ev / t_osc:7.1f}"
        if args.identify:
            from diagnose.identification import identify
            t0 = time.perf_counter()
            identify(r)
            t_id = time.perf_counter() - t0
            line += f" {t_id:10.2f} {t_ev / t_id:7.3f}"
        print(line, flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
