"""Batch throughput: 1 vs 2 workers, peak memory, and the 1000-loop time.

Simulates ``--loops`` closed loops of ``--samples`` samples (seeded mix of classes, S 0..6 %, J
0..6 %, FOPTD/SOPTD/integrating), writes them as wide CSV (not timed), then runs
``stiction batch`` on them with full reports (figures, Markdown, PDF, JSON, summary; the
missing-physics stage as ``--explain``, default off like the batch) once with 1 worker and once with 2, each in a fresh
subprocess (so imports and pool start-up are counted and the peak RSS of every process is
measured). Prints a Markdown fragment for docs/_bench_service.md; the 1000-loop time is measured
when ``--loops 1000`` is given, else extrapolated from the 2-worker throughput (and says so).

    python benchmarks/bench_batch.py --loops 16 --samples 10000
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from benchmarks.machine import cpu_model  # noqa: E402


def make_loops(folder: Path, n_loops: int, n_samples: int, seed: int = 0) -> None:
    from connectors.historian import write_wide
    from diagnose.simulate import sticky_loop

    rng = np.random.default_rng(seed)
    folder.mkdir(parents=True, exist_ok=True)
    kinds = ["foptd", "foptd", "soptd", "integrating"]
    for i in range(n_loops):
        healthy = rng.random() < 0.2
        S = 0.0 if healthy else float(rng.uniform(0.5, 6.0))
        J = 0.0 if healthy else float(rng.uniform(0.0, 6.0))
        kind = kinds[i % len(kinds)]
        gain = 0.02 if kind == "integrating" else float(rng.uniform(0.5, 2.0))
        rec = sticky_loop(S, J, n=n_samples, ts_s=1.0, gain=gain, tau_s=float(rng.uniform(10, 60)),
                          delay_s=float(rng.integers(1, 8)), kind=kind, noise_std=0.03, load_walk_std=0.02,
                          f0=1 if rng.random() < 0.5 else -1, seed=seed * 100003 + i, name=f"L{i:04d}")
        write_wide(rec.replace(mv=None) if i % 2 else rec, folder / f"L{i:04d}.csv")


def run_batch(logs: Path, out: Path, workers: int, explain: str) -> dict:
    """One `stiction batch` in a subprocess; wall time and the largest RSS of any process."""
    code = ("import resource, sys, time\n"
            "from diagnose.service.cli import main\n"
            "t = time.perf_counter(); rc = main(sys.argv[1:]); el = time.perf_counter() - t\n"
            "ru_s = resource.getrusage(resource.RUSAGE_SELF); ru_c = resource.getrusage(resource.RUSAGE_CHILDREN)\n"
            "print('BENCH', rc, el, ru_s.ru_maxrss, ru_c.ru_maxrss, ru_s.ru_utime + ru_s.ru_stime, "
            "ru_c.ru_utime + ru_c.ru_stime)\n")
    args = ["batch", str(logs), "--out", str(out), "--workers", str(workers), "--quiet",
            "--db", str(out.parent / f"{out.name}.sqlite"), "--explain", explain]
    proc = subprocess.run([sys.executable, "-c", code, *args], capture_output=True, text=True)
    line = [ln for ln in proc.stdout.splitlines() if ln.startswith("BENCH")]
    if not line:
        raise SystemExit(f"batch failed:\n{proc.stdout}\n{proc.stderr}")
    _, rc, el, rss_self, rss_child, cpu_self, cpu_child = line[-1].split()
    summary = json.loads((out / "summary.json").read_text())
    per_loop = [r.get("seconds") for r in summary["loops"] if r.get("seconds")]
    stages: dict[str, list[float]] = {}
    for f in out.glob("loops/*/*.json"):
        for k, v in json.loads(f.read_text()).get("timings_s", {}).items():
            stages.setdefault(k, []).append(float(v))
    worker_rss = max([r.get("worker_peak_rss_mib") or 0 for r in summary["loops"]] + [0])
    return {"workers": workers, "rc": int(rc), "wall_s": float(el), "loops": summary["n_loops"],
            "failed": summary["n_failed"],
            "peak_rss_mib": max(int(rss_self) / 1024, int(rss_child) / 1024, worker_rss),
            # a pool's workers are children of multiprocessing's fork server, which the batch's
            # RUSAGE_CHILDREN does not see: with workers their own CPU per loop (``cpu_s``) is added
            "cpu_s": float(cpu_self) + float(cpu_child)
            + (sum(float(r.get("cpu_s") or 0.0) for r in summary["loops"]) if workers > 1 else 0.0),
            "median_loop_s": float(np.median(per_loop)) if per_loop else float("nan"),
            "stages": {k: {"median_s": round(float(np.median(v)), 3), "max_s": round(max(v), 3), "n": len(v)}
                       for k, v in stages.items()}}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--loops", type=int, default=16)
    ap.add_argument("--samples", type=int, default=10_000)
    ap.add_argument("--explain", choices=["auto", "on", "off"], default="off",
                    help="missing-physics stage, as `stiction batch --explain` (default off)")
    ap.add_argument("--workers", default="1,2", help="worker counts to compare (default 1,2)")
    ap.add_argument("--keep", default=None, help="keep the data and outputs in this folder")
    args = ap.parse_args()
    root = Path(args.keep) if args.keep else Path(tempfile.mkdtemp(prefix="bench_batch_"))
    logs = root / "logs"
    t0 = time.perf_counter()
    if not logs.exists():
        make_loops(logs, args.loops, args.samples)
    gen_s = time.perf_counter() - t0
    explain = args.explain
    results = []
    for w in [int(x) for x in args.workers.split(",")]:
        out = root / f"out_w{w}"
        shutil.rmtree(out, ignore_errors=True)
        results.append(run_batch(logs, out, w, explain))
        print(json.dumps(results[-1]), file=sys.stderr)
    base = results[0]
    load = os.getloadavg()
    print(f"### Batch throughput ({time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())})\n")
    print(f"Data: {args.loops} simulated loops x {args.samples} samples at 1 s (seeded mix of classes and "
          f"processes, half with MV), wide CSV, generated in {gen_s:.0f} s (not timed). Full reports: "
          f"figures, Markdown, PDF, JSON, summary; NARX-SP free run; missing-physics stage `--explain {explain}`. "
          f"Machine: {len(os.sched_getaffinity(0))} CPUs usable of {os.cpu_count()} "
          f"({cpu_model()}), "
          f"load average before the last run {load[0]:.1f}.\n")
    print("| workers | wall s | loops/s | speed-up | CPU s | median s/loop (in worker) | peak RSS MiB | failed |")
    print("|---|---|---|---|---|---|---|---|")
    for r in results:
        print(f"| {r['workers']} | {r['wall_s']:.1f} | {r['loops'] / r['wall_s']:.3f} | "
              f"{base['wall_s'] / r['wall_s']:.2f}x | {r['cpu_s']:.0f} | {r['median_loop_s']:.2f} | "
              f"{r['peak_rss_mib']:.0f} | {r['failed']} |")
    print("\nPer-loop stage times in the workers (median / max seconds, loops that ran the stage), "
          f"{results[-1]['workers']} workers:\n")
    for k, v in results[-1]["stages"].items():
        print(f"- {k}: {v['median_s']:.2f} / {v['max_s']:.2f} s ({v['n']} loops)")
    best = results[-1]
    t1000 = best["wall_s"] / best["loops"] * 1000
    how = "measured" if args.loops >= 1000 else f"extrapolated from {args.loops} loops"
    print(f"\n1000 loops with {best['workers']} workers: {t1000 / 60:.1f} min ({how}); target <= 20 min.")


if __name__ == "__main__":
    main()
