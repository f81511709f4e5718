"""Why the simulated benchmark's misses are missed: the search, a tie, or the data themselves.

Runs `identify` on the loops of `validate_simulated.py` (same seeds, same loops) and, for every
healthy loop and every loop whose class came out wrong, scores three models on the whole record,
on the fit's own noise prefilter and scored samples:

* the free fit (`Identification.fit`, before the class test);
* the truth: the simulator's S, J and process structure (gain and load by least squares, as in the
  fit), its first stuck point the best of 21 around OP's first sample and both directions (the
  valve's state when the record starts is unknown to everyone);
* the best linear model (the linear fit's structure or the free fit's, whichever is cheaper).

Healthy loops give the noise floor: the in-sample improvement of the free fit over the linear model
that noise alone produces. Each miss then falls in one class (docs/validation.md, "What limits the
3000-sample figure"):

* ``false_alarm``: a healthy loop flagged;
* ``below_floor``: a sticky loop reported ``none`` whose *truth* improves on the linear model by
  less than the healthy loops' 95th percentile (no detector working from PV can flag it without
  flagging more than 5 % of healthy loops);
* ``detectable``: a sticky loop reported ``none`` whose truth is above that floor;
* ``search``: a wrong class where the truth costs less than the free fit (the search missed it);
* ``tie``: a wrong class where the free fit costs less, by ``n_eff ln(cost ratio) < 2``;
* ``data_prefer_wrong``: a wrong class where the free fit costs less by ``n_eff ln(cost ratio) >= 2``
  (a Gaussian likelihood ratio of e or more in favour of the wrong shape).

Run:  python benchmarks/miss_anatomy.py --seed 101 --seed 202 [--n 3000]
          [--definition identifiable] [--loops 120] [--json out.json]
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from collections import Counter
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from diagnose.identification import identify  # noqa: E402
from diagnose.objective import Objective, ProcessGrid, burn_in, legendre_basis, op_offset, score_weights  # noqa: E402
from validate_simulated import cases  # noqa: E402

#: Stuck points tried for the truth's unknown starting state, in units of max(S, J) around OP[0].
TRUTH_STARTS = np.linspace(-1.0, 1.0, 21)
FLOOR_PERCENTILE = 95.0
TIE_DEVIANCE = 2.0


def _config(kind: str, tau_s: float, tau2_s: float, delay_s: float, ts_s: float):
    return ProcessGrid.of([(kind, tau_s, tau2_s, int(round(delay_s / ts_s)))], ts_s)


def costs(case, res) -> dict:
    """Whole-record costs (the fit's scaled SSE) of the linear model, the free fit and the truth."""
    fit, lin = res.fit, res.linear_fit
    rec = case.record
    op, pv, ts = np.asarray(rec.op, float), np.asarray(rec.pv, float), rec.ts_s
    x = op + fit.op_offset_pct
    w = score_weights(x.shape[0], None, burn_in(x, 0.05))
    sign = res.controller.sign or None
    prob = Objective(x.copy(), pv, ts, w, fit.load_order, fit.hp_tau_s, None, sign)

    def cost(p, S, J, F):
        return float(prob.score([S], [J], [F], _config(p.kind, p.tau_s, p.tau2_s, p.delay_s, ts))[0][0, 0])

    c_lin = min(cost(lin.process, 0.0, 0.0, 1.0), cost(fit.process, 0.0, 0.0, 1.0))
    prob = prob.with_start(fit.start_op_pct)
    c_fit = cost(fit.process, fit.S_pct, fit.J_pct, float(fit.f0))
    info = case.info
    tau2 = info["tau_s"] / 4 if info["kind"] == "soptd" else 0.0
    cfg = _config(info["kind"], info["tau_s"], tau2, info["delay_s"], ts)
    truth = Objective(op.copy(), pv, ts, w, fit.load_order, fit.hp_tau_s, None, sign)
    S, J = case.S_pct, case.J_pct
    c_truth = math.inf
    for dl in TRUTH_STARTS:
        t0 = truth.with_start(min(max(op[0] + dl * max(S, J, 0.01), 0.0), 100.0))
        c_truth = min(c_truth, float(t0.score([S, S], [J, J], [1.0, -1.0], cfg)[0][:, 0].min()))
    return {"c_lin": c_lin, "c_fit": c_fit, "c_truth": c_truth, "n_eff": float(fit.n_eff)}


def collect(seeds, n: int, definition: str, n_loops: int) -> list[dict]:
    rows = []
    for seed in seeds:
        for case in cases(n_loops, seed, n, definition):
            res = identify(case.record)
            if case.cls != "none" and res.cls == case.cls:
                continue
            row = {"seed": seed, "loop": case.record.name, "true_class": case.cls, "class": res.cls,
                   "S_true": case.S_pct, "J_true": case.J_pct, "S_fit": res.fit.S_pct, "J_fit": res.fit.J_pct,
                   "free_class": res.fit.stiction_class, **costs(case, res)}
            rows.append(row)
            print(json.dumps({k: (round(v, 5) if isinstance(v, float) else v) for k, v in row.items()}),
                  flush=True)
    return rows


def classify(rows: list[dict]) -> dict:
    healthy = [r for r in rows if r["true_class"] == "none"]
    floor = float(np.percentile([1.0 - r["c_fit"] / r["c_lin"] for r in healthy], FLOOR_PERCENTILE)) \
        if healthy else 0.0
    for r in rows:
        r["ins_truth"] = 1.0 - r["c_truth"] / r["c_lin"]
        r["deviance_fit_over_truth"] = r["n_eff"] * math.log(r["c_truth"] / r["c_fit"])
        if r["class"] == r["true_class"]:
            r["why"] = None
        elif r["true_class"] == "none":
            r["why"] = "false_alarm"
        elif r["class"] == "none":
            r["why"] = "below_floor" if r["ins_truth"] < floor else "detectable"
        elif r["c_truth"] < r["c_fit"]:
            r["why"] = "search"
        else:
            r["why"] = "tie" if r["deviance_fit_over_truth"] < TIE_DEVIANCE else "data_prefer_wrong"
    misses = [r for r in rows if r["why"]]
    ins_h = [1.0 - r["c_fit"] / r["c_lin"] for r in healthy]
    return {"healthy_loops": len(healthy),
            "healthy_insample_improvement_pct": {p: round(float(np.percentile(ins_h, p)) * 100, 3)
                                                 for p in (50, 90, 95)} if ins_h else {},
            "floor_pct": round(floor * 100, 3), "misses": len(misses),
            "by_cause": dict(Counter(r["why"] for r in misses)),
            "by_cause_and_confusion": {w: dict(Counter(f"{r['true_class']}->{r['class']}" for r in misses
                                                       if r["why"] == w))
                                       for w in sorted({r["why"] for r in misses})}}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, action="append", required=True, help="repeat for several seeds")
    ap.add_argument("--n", type=int, default=3000, help="samples per loop")
    ap.add_argument("--definition", choices=["original", "identifiable"], default="identifiable")
    ap.add_argument("--loops", type=int, default=120)
    ap.add_argument("--json")
    args = ap.parse_args(argv)
    rows = collect(args.seed, args.n, args.definition, args.loops)
    summary = classify(rows)
    print(json.dumps(summary, indent=2))
    if args.json:
        Path(args.json).write_text(json.dumps({"summary": summary, "rows": rows}, indent=1, default=float))
    return 0


if __name__ == "__main__":
    sys.exit(main())
