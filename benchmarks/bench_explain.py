"""Speed of `stiction explain` on 8000-sample records, against a baseline tree in the same run.

Each record is a concealed-effect loop of the independent simulator (`benchmarks.plantsim.concealed`,
8000 samples at 1 s), explained OP/PV only and with the stem position. Every explain runs in a
fresh subprocess (one record at a time, so the trees never share a process and the machine's other
jobs load both alike): the current tree, and with ``--baseline PATH`` a checkout of another
revision with its compiled kernels built (e.g. ``git worktree add /tmp/old <rev>`` and
``pip install -e /tmp/old`` into another venv, or copy the built ``diagnose/_kernels*.so`` into
it), alternating record by record. Prints wall and CPU seconds (the child's user + system time)
per record and the medians, and with ``--md FILE`` writes them as markdown.

    python benchmarks/bench_explain.py [--records 6] [--threads N] [--baseline /tmp/old]

The CPU model and the load average are printed with the figures: the machine is shared, so only
ratios measured in the same run compare.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from benchmarks.machine import cpu_model  # noqa: E402

CHILD = r"""
import json, sys, time, resource
import numpy as np
from diagnose.record import LoopRecord
from diagnose.physics import explain
# the record is drawn by this checkout's plantsim (it imports nothing from diagnose): a baseline
# tree may predate it
sys.path.insert(0, sys.argv[6])
from benchmarks.plantsim import concealed
effect, seed, mv, n, threads = sys.argv[1], int(sys.argv[2]), sys.argv[3] == "1", int(sys.argv[4]), sys.argv[5]
loop = concealed(effect, seed, n=n)
rec = LoopRecord(name=loop.name, ts_s=loop.ts_s, op=loop.op, pv=loop.pv, sp=loop.sp, mv=loop.mv if mv else None)
kw = {} if threads == "default" else {"threads": int(threads)}
r0 = resource.getrusage(resource.RUSAGE_SELF)
t0 = time.perf_counter()
try:
    ex = explain(rec, target="auto" if mv else "pv", **kw)
except TypeError:          # a tree whose explain has no threads option
    ex = explain(rec, target="auto" if mv else "pv")
wall = time.perf_counter() - t0
r1 = resource.getrusage(resource.RUSAGE_SELF)
cpu = (r1.ru_utime - r0.ru_utime) + (r1.ru_stime - r0.ru_stime)
print(json.dumps({"named": ex.missing_physics, "wall_s": wall, "cpu_s": cpu}))
"""

#: (effect, seed): one record per effect of plantsim's concealed set (seed 24 of the benchmark,
#: records 24000-24005), so the speed is measured over every kind of search
RECORDS = [("none", 24000), ("actuator_lag", 24001), ("asymmetric_stiction", 24002),
           ("valve_characteristic", 24003), ("external_disturbance", 24004), ("time_varying_friction", 24005)]


def run_one(tree: Path, effect: str, seed: int, mv: bool, n: int, threads: str) -> dict:
    env = dict(os.environ, PYTHONPATH=str(tree))
    out = subprocess.run([sys.executable, "-c", CHILD, effect, str(seed), "1" if mv else "0", str(n), threads,
                          str(ROOT)],
                         cwd=tree, env=env, capture_output=True, text=True)
    if out.returncode != 0:
        tail = (out.stderr.strip().splitlines() or ["(no message)"])[-1]
        raise SystemExit(f"explain of {effect} {seed} in {tree} failed: {tail}")
    return json.loads(out.stdout.strip().splitlines()[-1])


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--records", type=int, default=len(RECORDS), help="records of RECORDS to run (each OP/PV and with MV)")
    ap.add_argument("--n", type=int, default=8000)
    ap.add_argument("--threads", default="default", help="explain's threads (default: its own default)")
    ap.add_argument("--baseline", default="", help="a tree of another revision to time in the same run")
    ap.add_argument("--md", default="")
    args = ap.parse_args(argv)
    trees = [("this tree", ROOT)] + ([("baseline", Path(args.baseline).resolve())] if args.baseline else [])
    rows = []
    for effect, seed in RECORDS[: args.records]:
        for mv in (False, True):
            row = {"effect": effect, "seed": seed, "mv": mv}
            for name, tree in trees:
                r = run_one(tree, effect, seed, mv, args.n, args.threads)
                row[name] = r
                print(f"{effect:22s} {seed} {'OP/MV' if mv else 'OP/PV'} {name:9s} named {str(r['named']):22s} "
                      f"wall {r['wall_s']:6.1f} s  cpu {r['cpu_s']:6.1f} s", flush=True)
            rows.append(row)
    load = os.getloadavg()
    lines = [f"`python benchmarks/bench_explain.py --records {args.records} --threads {args.threads}"
             + (" --baseline TREE" if args.baseline else "") + f"`: {len(rows)} explains of {args.n}-sample records, "
             f"{cpu_model()}, {os.cpu_count()} cores, load average after the run {load[0]:.1f} / {load[1]:.1f} / "
             f"{load[2]:.1f}.", "",
             "| record | set | " + " | ".join(f"{nm} named | wall s | CPU s" for nm, _ in trees) + " |",
             "|---|---|" + "---|---|---|" * len(trees)]
    for r in rows:
        lines.append(f"| {r['effect']} {r['seed']} | {'with MV' if r['mv'] else 'OP/PV'} | " + " | ".join(
            f"{r[nm]['named'] or 'none'} | {r[nm]['wall_s']:.1f} | {r[nm]['cpu_s']:.1f}" for nm, _ in trees) + " |")
    for nm, _ in trees:
        w = [r[nm]["wall_s"] for r in rows]
        c = [r[nm]["cpu_s"] for r in rows]
        lines.append("")
        lines.append(f"{nm}: wall median {statistics.median(w):.1f} s, max {max(w):.1f} s; CPU median "
                     f"{statistics.median(c):.1f} s, max {max(c):.1f} s")
    if args.baseline:
        ratio = [r["baseline"]["cpu_s"] / r["this tree"]["cpu_s"] for r in rows]
        lines.append(f"CPU time of the baseline over this tree: median {statistics.median(ratio):.1f}x "
                     f"(range {min(ratio):.1f}-{max(ratio):.1f}x)")
    text = "\n".join(lines)
    print(text)
    if args.md:
        Path(args.md).write_text(text + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
