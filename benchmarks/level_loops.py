"""The stiction verdict on short windows of level loops (integrating processes), OP and PV only.

A historian window of a level loop is often short (two hours at 10 s is 751 samples), holds a few
slow cycles at most, and its level is pushed about by inflow changes the loop has to reject. This
script asks how often the verdict (`identify` on OP/PV, as ``stiction identify`` runs it) calls a
sticky level valve in such windows, and how often it leaves a healthy one alone.

The records come from the project's own simulator (`diagnose.simulate.sticky_loop`, ``kind=
"integrating"``): a two-parameter valve on an integrator with a lag and a dead time, under the PI
that simulator tunes for an integrator, with white PV noise and a slow random-walk inflow load.
Every record draws its own parameters from ``(seed, index)``: one record in three is healthy; the
others draw S from 0.3, 0.5, 1 and 2 % of span and J from 0, S/2 and S. Per record: lag 10-60 s,
dead time 10, 20 or 30 s, integrating rate 0.001-0.004 PV units per second per % of span, noise
0.005-0.03, load step size 0, 0.02 or 0.05, and 751, 1500 or 3000 samples at 10 s. A sticky
record whose stem moved fewer than 10 times after the simulator's warm-up is left out (nothing in
it can show the valve: the same rule as the simulated benchmark's identifiable definition).

Beside the verdict it prints the fit's likelihood ratio over a linear loop (``model_fit.lr``) on
its own, as an AUC of sticky against healthy records: how far the fit alone separates them.

Run:  python benchmarks/level_loops.py --seed 1 --seed 2 --seed 3 [--per-seed 60] [--workers 2]
          [--json out.json]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections import defaultdict
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks.machine import cpu_model  # noqa: E402
from diagnose.identification import identify  # noqa: E402
from diagnose.record import LoopRecord  # noqa: E402
from diagnose.simulate import sticky_loop  # noqa: E402

#: A sticky record whose stem moved fewer times than this is left out (it cannot show the valve).
MIN_MOVES = 10
#: The simulator's warm-up (samples simulated before the record starts).
WARMUP = 500


def stem_moves(mv_pct: np.ndarray) -> int:
    """How many separate times the stem starts moving (runs of motion, not moving samples)."""
    moving = np.flatnonzero(np.abs(np.diff(np.asarray(mv_pct, dtype=float))) > 1e-9)
    return int(moving.size and 1 + np.count_nonzero(np.diff(moving) > 1))


def level_loop(seed: int, index: int) -> tuple[LoopRecord, dict]:
    """Record ``index`` of ``seed``: the simulated loop (with its stem position) and its truth."""
    rng = np.random.default_rng([seed, 7, index])
    sticky = index % 3 != 0
    S = float(rng.choice([0.3, 0.5, 1.0, 2.0])) if sticky else 0.0
    J = float(rng.choice([0.0, S / 2, S])) if sticky else 0.0
    tau = float(rng.uniform(10.0, 60.0))
    delay = float(rng.choice([10.0, 20.0, 30.0]))
    rate = float(rng.uniform(0.001, 0.004))
    noise = float(rng.uniform(0.005, 0.03))
    load = float(rng.choice([0.0, 0.02, 0.05]))
    n = int(rng.choice([751, 1500, 3000]))
    rec = sticky_loop(S, J, n=n, ts_s=10.0, kind="integrating", gain=rate, tau_s=tau, delay_s=delay,
                      noise_std=noise, load_walk_std=load, seed=seed * 1000 + index, name="LIC1",
                      warmup=WARMUP)
    truth = {"seed": seed, "index": index, "sticky": sticky, "S_pct": S, "J_pct": J, "n": n,
             "load_step": load, "noise": noise, "moves": stem_moves(rec.mv) if rec.mv is not None else 0}
    return rec, truth


def _job(args: tuple[int, int]) -> dict:
    rec, row = level_loop(*args)
    if row["sticky"] and row["moves"] < MIN_MOVES:
        return row
    res = identify(rec.replace(mv=None))
    lr = next((ev.extras.get("lr") for ev in res.evidence if ev.test == "model_fit"), None)
    row.update(called=bool(res.stiction), probability=res.stiction_probability, lr=lr,
               S_fit_pct=res.fit.S_pct if res.fit is not None else None)
    return row


def auc(pos, neg) -> float:
    """Probability that a random positive scores above a random negative (ties count half)."""
    p = np.asarray([v for v in pos if v is not None], float)
    q = np.asarray([v for v in neg if v is not None], float)
    if p.size == 0 or q.size == 0:
        return float("nan")
    return float((p[:, None] > q[None, :]).mean() + 0.5 * (p[:, None] == q[None, :]).mean())


def summarise(rows: list[dict]) -> list[str]:
    """Sensitivity by S, load and length; specificity; the fit's likelihood ratio as an AUC."""
    judged = [r for r in rows if "called" in r]
    sticky = [r for r in judged if r["sticky"]]
    healthy = [r for r in judged if not r["sticky"]]
    sens = sum(r["called"] for r in sticky) / len(sticky) if sticky else float("nan")
    spec = sum(not r["called"] for r in healthy) / len(healthy) if healthy else float("nan")
    out = [f"{len(sticky)} sticky records (valve moved >= {MIN_MOVES} times), {len(healthy)} healthy; "
           f"{len(rows) - len(judged)} sticky records left out (valve never free)",
           f"called sticky: {sens:.3f} of sticky records; left alone: {spec:.3f} of healthy records; "
           f"balanced accuracy {(sens + spec) / 2:.3f}",
           f"fit's likelihood ratio alone, AUC sticky vs healthy: {auc([r['lr'] for r in sticky], [r['lr'] for r in healthy]):.3f}"]
    for key, label in (("S_pct", "S %"), ("load_step", "load step"), ("n", "samples")):
        groups: dict = defaultdict(list)
        for r in sticky:
            groups[r[key]].append(r["called"])
        out.append(f"  called by {label}: " + ", ".join(f"{k:g}: {sum(v)}/{len(v)}" for k, v in sorted(groups.items())))
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seed", type=int, action="append", required=True)
    ap.add_argument("--per-seed", type=int, default=60)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--json")
    a = ap.parse_args(argv)
    jobs = [(s, i) for s in a.seed for i in range(a.per_seed)]
    t0 = time.perf_counter()
    with ProcessPoolExecutor(a.workers) as pool:
        rows = list(pool.map(_job, jobs, chunksize=2))
    lines = [f"level loops, own simulator, seeds {a.seed}, {a.per_seed} records each, "
             f"{time.perf_counter() - t0:.0f} s on {cpu_model()} ({a.workers} workers)"]
    lines += summarise(rows)
    print("\n".join(lines))
    if a.json:
        Path(a.json).write_text(json.dumps({"seeds": a.seed, "rows": rows}, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
