"""The stiction verdict on short windows of level loops (integrating processes), OP and PV only.

A historian window of a level loop is often short (two hours at 10 s is 751 samples) and holds a
few slow cycles at most. This script asks how often the verdict (`identify` on OP/PV, as
``stiction identify`` runs it) calls a sticky level valve in such windows, and how often it leaves
a healthy one alone.

The records come from the project's own simulator (`diagnose.simulate.sticky_loop`, ``kind=
"integrating"``): a two-parameter valve on an integrator with a lag and a dead time under a PI,
with white PV noise, at 10 s. Every record draws its own parameters from ``(seed, family,
index)``; one record in three is healthy; per record: lag 10-60 s, dead time 10, 20 or 30 s,
integrating rate 0.001-0.004 PV units per second per % of span. Two families:

- ``load``: the PI the simulator tunes for an integrator, a slow random-walk inflow load (step
  size 0, 0.02 or 0.05) the loop has to reject; S from 0.3, 0.5, 1 and 2 % of span, J from 0, S/2
  and S; noise 0.005-0.03; 751, 1500 or 3000 samples.
- ``detuned``: the PI detuned as level loops often are for averaging control (gain x 0.3, 0.5 or
  1, integral time x 1, 2 or 4) and a small random-walk inflow load (step size 0.002 or 0.005):
  the sticky valve drives slow stick-slip cycles, a few per window; S from 0.2, 0.3, 0.4, 0.6 and
  1 %, J from 0, S/2 and S; noise 0.003-0.02; 751 or 1500 samples.

A sticky record whose stem moved fewer than 6 times after the simulator's warm-up (three cycles'
slips) is left out: nothing in it can show the valve.

Beside the verdict it prints the fit's likelihood ratio over a linear loop (``model_fit.lr``) on
its own, as an AUC of sticky against healthy records: how far the fit alone separates them.

The combiner is trained on seeds 1 and 2 of both families (``benchmarks/train_verdict.py
features --level-loops``); seed 3 is the test seed of that training, and seeds 4 and above were
never used in it.

With ``--visibility`` it also asks, per sticky record, how much better the true stem position
explains PV than OP does (the deviance D of `benchmarks.visibility`): where D is small PV hides
the valve, and no OP/PV verdict can call the record but by chance.

Run:  python benchmarks/level_loops.py --seed 4 [--seed ...] [--family load --family detuned]
          [--per-seed 60] [--workers 2] [--visibility] [--json out.json]
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from collections import defaultdict
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks.machine import cpu_model  # noqa: E402
from benchmarks.visibility import stem_deviance  # noqa: E402
from diagnose.identification import identify  # noqa: E402
from diagnose.record import LoopRecord  # noqa: E402
from diagnose.simulate import sticky_loop  # noqa: E402

#: A sticky record whose stem moved fewer times than this is left out (it cannot show the valve).
MIN_MOVES = 6
#: The simulator's warm-up (samples simulated before the record starts).
WARMUP = 500
#: The record families (module docstring): the choices each record draws from, its random stream,
#: the offset of its simulation seed and the simulator's warm-up (a detuned loop settles into its
#: cycle slowly).
FAMILIES = {
    "load": {"stream": 7, "seed_offset": 0, "warmup": WARMUP, "S": (0.3, 0.5, 1.0, 2.0),
             "noise": (0.005, 0.03), "load": (0.0, 0.02, 0.05), "n": (751, 1500, 3000),
             "Kc_x": (1.0,), "Ti_x": (1.0,)},
    "detuned": {"stream": 11, "seed_offset": 500, "warmup": 800, "S": (0.2, 0.3, 0.4, 0.6, 1.0),
                "noise": (0.003, 0.02), "load": (0.002, 0.005), "n": (751, 1500),
                "Kc_x": (0.3, 0.5, 1.0), "Ti_x": (1.0, 2.0, 4.0)},
}


def stem_moves(mv_pct: np.ndarray) -> int:
    """How many separate times the stem starts moving (runs of motion, not moving samples)."""
    moving = np.flatnonzero(np.abs(np.diff(np.asarray(mv_pct, dtype=float))) > 1e-9)
    return int(moving.size and 1 + np.count_nonzero(np.diff(moving) > 1))


def level_loop(seed: int, index: int, family: str = "load") -> tuple[LoopRecord, dict]:
    """Record ``index`` of ``seed`` in ``family``: the simulated loop (with its stem position) and
    its truth."""
    if family not in FAMILIES:
        raise ValueError(f"unknown level-loop family {family!r} (have {', '.join(FAMILIES)})")
    fam = FAMILIES[family]
    rng = np.random.default_rng([seed, fam["stream"], index])
    sticky = index % 3 != 0
    S = float(rng.choice(fam["S"])) if sticky else 0.0
    J = float(rng.choice([0.0, S / 2, S])) if sticky else 0.0
    tau = float(rng.uniform(10.0, 60.0))
    delay = float(rng.choice([10.0, 20.0, 30.0]))
    rate = float(rng.uniform(0.001, 0.004))
    noise = float(rng.uniform(*fam["noise"]))
    load = float(rng.choice(fam["load"]))
    n = int(rng.choice(fam["n"]))
    kc_x = float(rng.choice(fam["Kc_x"]))
    ti_x = float(rng.choice(fam["Ti_x"]))
    # the simulator's own PI for an integrator, scaled
    theta = delay + tau + 10.0
    rec = sticky_loop(S, J, n=n, ts_s=10.0, kind="integrating", gain=rate, tau_s=tau, delay_s=delay,
                      noise_std=noise, load_walk_std=load, seed=seed * 1000 + index + fam["seed_offset"],
                      name="LIC1", warmup=fam["warmup"], Kc=kc_x / (rate * 2 * theta), Ti_s=ti_x * 8 * theta)
    truth = {"seed": seed, "index": index, "family": family, "sticky": sticky, "S_pct": S, "J_pct": J, "n": n,
             "load_step": load, "noise": noise, "Kc_x": kc_x, "Ti_x": ti_x,
             "moves": stem_moves(rec.mv) if rec.mv is not None else 0}
    return rec, truth


def _job(args: tuple[int, int, str, bool]) -> dict:
    seed, index, family, visibility = args
    rec, row = level_loop(seed, index, family)
    if row["sticky"] and row["moves"] < MIN_MOVES:
        return row
    if visibility and row["sticky"]:
        row["deviance"] = stem_deviance(rec.op, rec.mv, rec.pv, rec.ts_s)[0]
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
    if any("deviance" in r for r in sticky):
        # how much of the valve PV shows (benchmarks/visibility.py): the calls where it does
        bands = [(-math.inf, 10.0, "D < 10"), (10.0, 50.0, "10 <= D < 50"), (50.0, math.inf, "D >= 50")]
        parts = []
        for lo, hi, label in bands:
            g = [r["called"] for r in sticky if lo <= r.get("deviance", math.nan) < hi]
            parts.append(f"{label}: {sum(g)}/{len(g)}")
        out.append("  called by what PV shows of the stem (deviance D): " + ", ".join(parts))
    for key, label in (("S_pct", "S %"), ("load_step", "load step"), ("n", "samples")):
        groups: dict = defaultdict(list)
        for r in sticky:
            groups[r[key]].append(r["called"])
        if len(groups) > 1:
            out.append(f"  called by {label}: " + ", ".join(f"{k:g}: {sum(v)}/{len(v)}" for k, v in sorted(groups.items())))
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seed", type=int, action="append", required=True)
    ap.add_argument("--family", action="append", choices=FAMILIES, help="default: both")
    ap.add_argument("--per-seed", type=int, default=60, help="records per seed and family")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--visibility", action="store_true",
                    help="also the deviance of the true stem over OP per sticky record (benchmarks/visibility.py)")
    ap.add_argument("--json")
    a = ap.parse_args(argv)
    families = a.family or list(FAMILIES)
    jobs = [(s, i, f, a.visibility) for f in families for s in a.seed for i in range(a.per_seed)]
    t0 = time.perf_counter()
    with ProcessPoolExecutor(a.workers) as pool:
        rows = list(pool.map(_job, jobs, chunksize=2))
    lines = [f"level loops, own simulator, seeds {a.seed}, {a.per_seed} records per seed and family, "
             f"{time.perf_counter() - t0:.0f} s on {cpu_model()} ({a.workers} workers)"]
    for f in families:
        lines.append(f"family {f}:")
        lines += ["  " + line for line in summarise([r for r in rows if r["family"] == f])]
    print("\n".join(lines))
    if a.json:
        Path(a.json).write_text(json.dumps({"seeds": a.seed, "rows": rows}, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
