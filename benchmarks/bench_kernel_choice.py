"""The measurement behind the kernel choice: numba (cache=True) against the C extension built by pip.

For each path, in fresh interpreters of the same run:

* start-up: importing the path and the first call of a kernel (numba: ``import numba`` and loading
  a cached kernel, whose first call also builds numba's target context; C: loading the library);
* the scoring kernel's speed in ns per candidate-structure-sample (60 valve candidates x 24
  process structures x 4000 samples, the identification's main workload), best of 5.

The numba kernels are no longer in this tree: ``--numba-src DIR`` points at a tree that has them
(the commit before the single kernel, e.g. ``git worktree add /tmp/numba 771abd2``), run with
``STICTION_NATIVE=0`` so that its numba path is measured. The C extension is measured at each of
its vector variants (baseline, AVX2, AVX-512, as far as the CPU has them).

    python benchmarks/bench_kernel_choice.py [--numba-src DIR] [--md FILE]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from benchmarks.machine import cpu_model  # noqa: E402

C_PROBE = r"""
import json, sys, time
t0 = time.perf_counter()
import numpy as np
t1 = time.perf_counter()
from diagnose import kernels
t2 = time.perf_counter()
from diagnose.objective import Objective, ProcessGrid, burn_in, score_weights
from diagnose.simulate import sticky_loop
rec = sticky_loop(3.0, 1.0, n=4000, noise_std=0.2, load_walk_std=0.02, seed=1)
x = rec.op.copy()
obj = Objective(x, rec.pv, 1.0, score_weights(x.size, None, burn_in(x, 0.05)), 2, 10.0)
grid = ProcessGrid.of([(k, t, t / 3 if k == "soptd" else 0.0, d) for k in ("foptd", "soptd")
                       for t in (5.0, 10.0, 20.0, 40.0) for d in (1, 3, 5)], 1.0)
rng = np.random.default_rng(0)
S = rng.uniform(0.5, 6, 60); J = S * rng.uniform(0, 2, 60); F = rng.choice([-1.0, 1.0], 60)
out = {"import_numpy_s": t1 - t0, "load_s": t2 - t1, "variants": {}}
for level in range(kernels.max_isa_level() + 1):
    name = kernels.set_isa(level)
    best = 1e9
    for _ in range(5):
        t = time.perf_counter(); sse = obj.score(S, J, F, grid)[0]; best = min(best, time.perf_counter() - t)
    out["variants"][name] = best / (60 * len(grid) * x.size) * 1e9
    out["checksum"] = float(sse.sum())
print(json.dumps(out))
"""

NUMBA_PROBE = r"""
import json, sys, time
sys.path.insert(0, sys.argv[1])
t0 = time.perf_counter()
import numpy as np
t1 = time.perf_counter()
import numba
t2 = time.perf_counter()
from diagnose import output_error as oe, stiction_model as sm
x0 = np.linspace(0, 10, 100)
t3 = time.perf_counter()
sm._batch_kernel.numba(x0, np.array([1.0]), np.array([0.5]), np.array([1.0]), np.empty((1, 100)))
t4 = time.perf_counter()
from diagnose.simulate import sticky_loop
rec = sticky_loop(3.0, 1.0, n=4000, noise_std=0.2, load_walk_std=0.02, seed=1)
x = rec.op.copy()
w = oe._score_weights(x.size, None, oe._burn_in(x, 0.05))
prob = oe._Problem(x, rec.pv, 1.0, w, 2, 10.0)
cfg = oe._make_configs([(k, t, t / 3 if k == "soptd" else 0.0, d) for k in ("foptd", "soptd")
                        for t in (5.0, 10.0, 20.0, 40.0) for d in (1, 3, 5)], 1.0)
rng = np.random.default_rng(0)
S = rng.uniform(0.5, 6, 60); J = S * rng.uniform(0, 2, 60); F = rng.choice([-1.0, 1.0], 60)
sse = np.empty((60, len(cfg))); gain = np.empty((60, len(cfg)))
args = (prob.x, S, J, F, cfg.a1, cfg.a2, cfg.d, cfg.integ, 1.0, prob.ahp, prob.w, prob.yw, prob.Qw, prob.Qty,
        prob.yyp, sse, gain, False, np.nan)
k = oe._ham_sse.numba
k(*args)
best = 1e9
for _ in range(5):
    t = time.perf_counter(); k(*args); best = min(best, time.perf_counter() - t)
print(json.dumps({"import_numpy_s": t1 - t0, "import_numba_s": t2 - t1, "first_call_s": t4 - t3,
                  "ns": best / (60 * len(cfg) * x.size) * 1e9, "checksum": float(sse.sum())}))
"""


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--numba-src", metavar="DIR")
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--md", metavar="FILE")
    args = ap.parse_args(argv)
    load0 = os.getloadavg()[0]
    c_runs = [json.loads(subprocess.run([sys.executable, "-c", C_PROBE], capture_output=True, text=True,
                                        check=True, cwd=ROOT).stdout) for _ in range(args.runs)]
    n_runs = []
    if args.numba_src:
        env = dict(os.environ, STICTION_NATIVE="0")
        for _ in range(args.runs):
            p = subprocess.run([sys.executable, "-c", NUMBA_PROBE, str(Path(args.numba_src).resolve())],
                               capture_output=True, text=True, env=env)
            if p.returncode != 0:
                raise SystemExit(p.stderr)
            n_runs.append(json.loads(p.stdout.strip().splitlines()[-1]))
    load1 = os.getloadavg()[0]
    lines = [f"Machine: {os.cpu_count()} CPUs ({cpu_model()}), Python {platform.python_version()}; load average "
             f"{load0:.2f} before, {load1:.2f} after; best of {args.runs} fresh interpreters.", "",
             "| path | start-up (s) | scoring kernel, ns per candidate-structure-sample |", "|---|---|---|"]
    if n_runs:
        imp = min(r["import_numba_s"] for r in n_runs)
        first = min(r["first_call_s"] for r in n_runs)
        lines.append(f"| numba, cache=True (`--numba-src`) | {imp + first:.3f} (import {imp:.3f} + first call of a "
                     f"cached kernel {first:.3f}) | {min(r['ns'] for r in n_runs):.2f} |")
    load = min(r["load_s"] for r in c_runs)
    for name in c_runs[0]["variants"]:
        ns = min(r["variants"][name] for r in c_runs)
        lines.append(f"| C extension, {name} | {load:.3f} (loading the library) | {ns:.2f} |")
    if n_runs:
        same = abs(n_runs[0]["checksum"] - c_runs[0]["checksum"]) <= 1e-9 * abs(c_runs[0]["checksum"])
        lines.append("")
        lines.append(f"Same costs from both paths on this workload: {'yes' if same else 'NO'}.")
    text = "\n".join(lines) + "\n"
    sys.stdout.write(text)
    if args.md:
        Path(args.md).write_text(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
