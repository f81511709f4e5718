"""How much of a sticky valve PV shows: the ceiling of any OP/PV stiction verdict on a corpus.

A stiction verdict from OP and PV can only see the valve through PV. For each sticky record of a
`benchmarks.plantsim` corpus this script asks whether PV carries the valve's motion at all: it fits
the best linear loop from OP to PV and the best linear loop from the *true stem position* to PV
(the simulator's MV, which no OP/PV method has), each under its own best noise prefilter (as
the verdict's likelihood ratio compares its fits), and takes the deviance of the stem over OP,

    D = n_eff * ln(cost_OP / cost_stem)

(`diagnose.fit.fit_hammerstein` with ``stiction=False`` for both; ``n_eff`` from the OP fit's
residuals). D is what a perfect friction model, of any law, could gain over a linear loop. A record
whose D is small holds stiction in its stem but hides it in PV: noise, load and the process's
filtering swamp the few percent the stem lags OP. No OP/PV method can call such a record sticky
except by chance, so the share of records with D above a bound is a ceiling on OP/PV sensitivity.

The bound on D is a choice; the healthy records of the same seeds give its noise floor (their stem
differs from OP only by a positioner's lag or a play under its resolution), printed first.

Beside it, the command's verdict (`identify` on OP/PV, as `stiction identify` runs it), so each
law's sensitivity is given on the records PV shows and on those it hides.

Run:  python benchmarks/visibility.py --seed 3 [--n-per-kind 30] [--bound 10 --bound 50]
          [--workers 2] [--json out.json]
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

from benchmarks.plantsim import make_loop  # noqa: E402
from diagnose.fit import fit_hammerstein  # noqa: E402
from diagnose.identification import identify  # noqa: E402
from diagnose.record import LoopRecord  # noqa: E402

STICKY_KINDS = ("two_parameter", "kano", "force_balance")


def stem_deviance(op, mv, pv, ts_s: float) -> tuple[float, float]:
    """(D, n_eff): the deviance of the best linear stem -> PV loop over the best linear OP -> PV loop,
    each under its own best noise model (as the verdict's likelihood ratio compares its fits)."""
    by_op = fit_hammerstein(op, pv, ts_s, stiction=False, surface=False)
    by_stem = fit_hammerstein(mv, pv, ts_s, stiction=False, surface=False)
    ne = by_op.n_eff
    return ne * math.log(by_op.own_noise_cost / by_stem.own_noise_cost), ne


def _job(args: tuple[str, int, int, str]) -> dict:
    kind, seed, index, definition = args
    loop = make_loop(kind, seed, index, definition=definition)
    rec = LoopRecord(name=loop.name, ts_s=loop.ts_s, op=loop.op, pv=loop.pv, sp=loop.sp)
    d, ne = stem_deviance(loop.op, loop.mv, loop.pv, loop.ts_s)
    m = loop.meta
    row = {"kind": kind, "seed": seed, "index": index, "n": loop.n, "class": m.get("class"),
           "S_pct": m.get("S_pct"), "J_pct": m.get("J_pct"), "integrating": bool(m.get("integrating")),
           "deviance": d, "n_eff": ne}
    if loop.sticky:     # the healthy records only give D's noise floor
        res = identify(rec)
        row.update(called=bool(res.stiction), probability=res.stiction_probability)
    return row


def _sensitivity(group: list[dict]) -> str:
    return f"{sum(r['called'] for r in group) / len(group):.3f}" if group else "-"


def summarise(rows: list[dict], bounds: list[float]) -> list[str]:
    out = []
    by_kind: dict[str, list[dict]] = defaultdict(list)
    for r in rows:
        by_kind[r["kind"]].append(r)
    by_kind["all"] = rows
    for b in bounds:
        out.append(f"bound D >= {b:g}:")
        out.append(f"  {'law':14s} {'records':>7s} {'PV shows':>9s} {'sens (all)':>10s} "
                   f"{'sens (shown)':>12s} {'sens (hidden)':>13s}")
        for kind, rs in by_kind.items():
            shown = [r for r in rs if r["deviance"] >= b]
            hidden = [r for r in rs if r["deviance"] < b]
            out.append(f"  {kind:14s} {len(rs):7d} {len(shown) / len(rs):9.3f} {_sensitivity(rs):>10s} "
                       f"{_sensitivity(shown):>12s} {_sensitivity(hidden):>13s}")
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seed", type=int, action="append", required=True)
    ap.add_argument("--n-per-kind", type=int, default=30)
    ap.add_argument("--definition", default="identifiable", choices=("identifiable", "original"))
    ap.add_argument("--bound", type=float, action="append", help="deviance bounds (default 10 and 50)")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--json")
    a = ap.parse_args(argv)
    bounds = a.bound or [10.0, 50.0]
    kinds = STICKY_KINDS + ("healthy",)
    jobs = [(k, s, i, a.definition) for s in a.seed for k in kinds for i in range(a.n_per_kind)]
    t0 = time.perf_counter()
    with ProcessPoolExecutor(a.workers) as pool:
        every = list(pool.map(_job, jobs, chunksize=1))
    rows = [r for r in every if "called" in r]
    floor = np.array([r["deviance"] for r in every if r["kind"] == "healthy"])
    lines = [f"plantsim seeds {a.seed}, {a.definition} definition, {len(rows)} sticky and {floor.size} healthy "
             f"records, {time.perf_counter() - t0:.0f} s",
             f"healthy records' D: median {np.median(floor):.1f}, 90th percentile {np.percentile(floor, 90):.1f}, "
             f"95th {np.percentile(floor, 95):.1f}, max {floor.max():.1f}"]
    lines += summarise(rows, bounds)
    print("\n".join(lines))
    if a.json:
        Path(a.json).write_text(json.dumps({"seeds": a.seed, "definition": a.definition, "rows": every}, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
