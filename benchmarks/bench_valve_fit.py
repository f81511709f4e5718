"""Speed and exactness of the direct OP/MV valve fit (`diagnose.valve_fit.fit_valve`).

Records: PI loops around Kano's valve (tests/kano.py) with the stem exactly Kano's model of OP,
in the four classes (deadband, undershoot, no offset, overshoot, with the issue's S 2 / J 4 and
S 3 / J 5) and three start states (at rest, moving, stuck away from OP), plus the project's own
sticky loops (FOPTD / SOPTD / integrating) and three loops as `stiction simulate` writes them. Every
record is fitted in this process; a fit is exact
when S and J are within 2 % (J: of max(S, J)), the class is right and both intervals hold the truth.

Target (issue 24): <= 0.3 s per 10 000-sample record in process. ``--baseline-src DIR`` fits the
same records with another source tree's `fit_valve` (e.g. an earlier commit checked out with
``git worktree add``) in a subprocess of the same run, for a before/after ratio.

    python benchmarks/bench_valve_fit.py [--n 10000] [--baseline-src DIR] [--json FILE]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from benchmarks.machine import cpu_model  # noqa: E402


def records(n: int) -> list[tuple[str, float, float, np.ndarray, np.ndarray]]:
    sys.path.insert(0, str(ROOT / "tests"))
    from kano import KanoValve, kano_valve

    from diagnose.simulate import make_process, random_walk, simc_pi, simulate_loop, sticky_loop

    out = []
    starts = {"rest": dict(d0=1), "moving": dict(d0=-1, moving=True), "stuck": dict(d0=-1, y0=52.0, us0=50.0)}
    for S, J in ((2.0, 4.0), (3.0, 5.0), (4.0, 0.0), (4.0, 2.0), (3.0, 3.0)):
        for name, st in starts.items():
            seed = int(10 * S + J) + len(out)
            rng = np.random.default_rng(seed)
            rec = simulate_loop(n=n, ts_s=1.0, process=make_process("foptd", gain=1.5, tau_s=20.0, delay_s=3.0),
                                controller=simc_pi(1.5, 20.0, 3.0, 1.0), valve=KanoValve(S, J, 1),
                                load=random_walk(n, 0.02, rng, leak=0.002), noise_std=0.2, seed=seed, warmup=500)
            out.append((f"kano S{S:g} J{J:g} {name}", S, J, rec.op, kano_valve(rec.op, S, J, **st)))
    for S, J, kind in ((3.0, 1.0, "soptd"), (6.0, 9.0, "foptd"), (4.0, 2.0, "integrating")):
        rec = sticky_loop(S, J, n=n, noise_std=0.3, kind=kind, seed=43, load_walk_std=0.03,
                          gain=0.02 if kind == "integrating" else 1.0)
        out.append((f"own S{S:g} J{J:g} {kind}", S, J, rec.op, rec.mv))
    # `stiction simulate`'s loops as its CSV holds them (4 decimals): their valve starts so that the
    # first slip moves the stem against OP's side, a state the record does not show
    for S, J, seed in ((3.6, 0.5, 7), (5.0, 0.5, 8), (2.0, 0.5, 8)):
        rec = sticky_loop(S, J, n=n, noise_std=0.02, load_walk_std=0.01, seed=seed)
        out.append((f"simulate S{S:g} J{J:g} seed {seed}", S, J, np.round(rec.op, 4), np.round(rec.mv, 4)))
    return out


WORKER = """
import json, sys, time
import numpy as np
sys.path.insert(0, sys.argv[1])
try:
    from diagnose.valve_fit import fit_valve
except ImportError:
    from diagnose.fit import fit_valve
data = np.load(sys.argv[2])
out = []
fit_valve(data["op0"], data["mv0"], 1.0)
for i in range(int(data["count"])):
    t0, c0 = time.perf_counter(), time.process_time()
    vf = fit_valve(data[f"op{i}"], data[f"mv{i}"], 1.0)
    out.append([time.perf_counter() - t0, time.process_time() - c0, vf.S_pct, vf.J_pct,
                list(vf.S_interval_pct), list(vf.J_interval_pct)])
print(json.dumps(out))
"""


def exact(S, J, fS, fJ, Sint, Jint) -> bool:
    from diagnose.stiction_model import stiction_class
    return (abs(fS - S) <= 0.02 * S and abs(fJ - J) <= 0.02 * max(S, J)
            and stiction_class(fS, fJ) == stiction_class(S, J) and Sint[0] <= S <= Sint[1] and Jint[0] <= J <= Jint[1])


def run_tree(src: Path, recs) -> list:
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "recs.npz"
        arrays = {"count": len(recs)}
        for i, (_, _, _, op, mv) in enumerate(recs):
            arrays[f"op{i}"], arrays[f"mv{i}"] = op, mv
        np.savez(path, **arrays)
        proc = subprocess.run([sys.executable, "-c", WORKER, str(src), str(path)], capture_output=True, text=True,
                              check=True)
    return json.loads(proc.stdout.strip().splitlines()[-1])


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=10000)
    ap.add_argument("--baseline-src", metavar="DIR")
    ap.add_argument("--json")
    args = ap.parse_args(argv)
    recs = records(args.n)
    load0 = os.getloadavg()
    trees = {"this tree": ROOT}
    if args.baseline_src:
        trees[args.baseline_src] = Path(args.baseline_src).resolve()
    results = {name: run_tree(src, recs) for name, src in trees.items()}
    load1 = os.getloadavg()
    cpu = cpu_model()
    print(f"fit_valve on {len(recs)} records of {args.n} samples; {os.cpu_count()} CPUs ({cpu}); "
          f"load average {load0[0]:.2f} before, {load1[0]:.2f} after")
    summary = {}
    for name, rows in results.items():
        ok = [exact(S, J, *r[2:]) for (_, S, J, _, _), r in zip(recs, rows)]
        wall = [r[0] for r in rows]
        cpu_s = [r[1] for r in rows]
        summary[name] = {"exact": int(sum(ok)), "records": len(rows), "wall_s_median": statistics.median(wall),
                         "wall_s_max": max(wall), "cpu_s_median": statistics.median(cpu_s)}
        print(f"{name}: exact {sum(ok)}/{len(rows)}, wall median {statistics.median(wall):.3f} s "
              f"(max {max(wall):.3f}), CPU median {statistics.median(cpu_s):.3f} s")
        for (label, S, J, _, _), r, good in zip(recs, rows, ok):
            if not good:
                print(f"   not exact: {label}: S {r[2]:.3f} J {r[3]:.3f} S_int {r[4]} J_int {r[5]}")
    if args.json:
        Path(args.json).write_text(json.dumps({"summary": summary, "rows": results}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
