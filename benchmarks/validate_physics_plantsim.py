"""Proof on concealed data from the independent simulator: hide one piece of physics in loops made by
`benchmarks.plantsim` (not the project's own simulator: other friction laws, process structures,
controllers and noise), run `explain`, and count how often it names the right effect and leaves
clean loops alone.

Records: `benchmarks.plantsim.concealed_set(seed, n_per_effect, laws=..., process_kinds=...)`,
8000 samples at 1 s, first 65 % for fitting. Sets, as in `validate_physics.py`:

* OP/PV only (``target="pv"``): every effect; actuator_lag reported apart (from OP/PV alone a lag
  after the friction is the same input-output model as a second process lag);
* with the stem position (valve-side effects judged on OP -> MV): none, actuator_lag,
  asymmetric_stiction, time_varying_friction. plantsim's MV is the true stem; the record gets the
  stem as a positioner reports it, with white measurement noise of ``--mv-noise`` % of span
  (seeded per record), as the project's concealed generator has.

How strongly each effect shows is plantsim's ``meta["effect_pv_change"]`` (RMS change of PV over the
twin's control error); the score is also given for the records where it is at least 0.5 and 1.

    python benchmarks/validate_physics_plantsim.py --seed 41 --per-effect 5 [--restricted] [--jobs 2]

``--restricted``: draw only the laws and processes the baseline can model (two-parameter and Kano
valves on FOPTD and SOPTD processes). ``--baseline TREE`` runs the same records with the explain of
another checkout (its own process per record, PYTHONPATH=TREE) and scores both. ``--records
EFFECT:SET:INDEX ...`` runs those records instead of a set; ``--list-steps FIRST-LAST`` prints every
friction-step record of sets FIRST..LAST in that form (e.g. to compare two trees on steps alone);
``--stem-only`` runs only the records with the stem recorded (a change to the valve-stage fits),
``--pv-only`` only those from OP/PV alone (a change to the loop-stage fits).
"""

from __future__ import annotations

import argparse
import functools
import json
import os
import subprocess
import sys
import time
from collections import Counter, defaultdict
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))
EFFECTS = ["none", "actuator_lag", "asymmetric_stiction", "valve_characteristic", "external_disturbance",
           "time_varying_friction"]
MV_SETS = ["none", "actuator_lag", "asymmetric_stiction", "time_varying_friction"]
RESTRICTED = {"laws": ("two_parameter", "kano"), "process_kinds": ("foptd", "soptd")}


def record(effect: str, seed: int, index: int, n: int, with_mv: bool, restricted: bool, mv_noise: float):
    """The ``index``-th record of ``effect`` in the set of ``seed`` (as `concealed_set` draws it), as a
    `LoopRecord`, and its truth (plantsim's meta)."""
    from benchmarks.plantsim import concealed
    from diagnose.record import LoopRecord

    kw = RESTRICTED if restricted else {}
    loop = concealed(effect, seed * 1000 + index, n=n, **kw)
    mv = None
    if with_mv:
        rng = np.random.default_rng([seed, index, EFFECTS.index(effect), 7])
        mv = loop.mv + rng.normal(0.0, mv_noise, loop.n)
    rec = LoopRecord(name=loop.name, ts_s=loop.ts_s, op=loop.op, pv=loop.pv, sp=loop.sp, mv=mv)
    return rec, loop.meta


def _record_spec(spec: str) -> tuple[str, int, int]:
    try:
        e, seed, i = spec.split(":")
        if e not in EFFECTS:
            raise ValueError(f"unknown effect {e!r}")
        return e, int(seed), int(i)
    except ValueError as exc:
        raise SystemExit(f"--records {spec}: expected EFFECT:SET:INDEX with EFFECT one of "
                         f"{', '.join(EFFECTS)} ({exc})")


def step_records(first: int, last: int, per_effect: int, n: int, restricted: bool) -> list[str]:
    """Every time_varying_friction record of sets ``first``..``last`` (indices below ``per_effect``)
    whose friction changes in one step (plantsim draws a step for 30 % of them), as --records specs."""
    from benchmarks.plantsim import concealed

    kw = RESTRICTED if restricted else {}
    return [f"time_varying_friction:{s}:{i}" for s in range(first, last + 1) for i in range(per_effect)
            if concealed("time_varying_friction", s * 1000 + i, n=n, **kw).meta.get("tvf_shape") == "step"]


def run_one(job: tuple) -> dict:
    effect, seed, index, n, with_mv, restricted, mv_noise, threads = job
    from benchmarks.validate_physics import hypothesis_numbers
    from diagnose.physics import explain

    rec, meta = record(effect, seed, index, n, with_mv, restricted, mv_noise)
    t0 = time.perf_counter()
    kw = {} if threads is None else {"threads": threads}
    ex = explain(rec, target="auto" if with_mv else "pv", **kw)
    row = _row(effect, seed, index, with_mv, meta, ex.missing_physics, time.perf_counter() - t0,
               [h.name for h in ex.hypotheses if h.accepted], ex.baseline_rmse, ex.improved_rmse)
    # each hypothesis's numbers as `validate_physics.py` keeps them (acceptance rules can be studied
    # on the rows without running explain again), and why it was refused
    row["delta_bic_heldout_train_reduction"] = hypothesis_numbers(ex)
    row["refused"] = {h.name: h.refused for h in ex.hypotheses if h.refused}
    return row


def _row(effect, seed, index, with_mv, meta, named, seconds, accepted, base, improved) -> dict:
    keep = ("law", "process", "class", "S_pct", "J_pct", "effect_size", "effect_size_unit", "effect_pv_change",
            "draw", "guard_passed")
    return {"effect": effect, "seed": seed * 1000 + index, "with_mv": with_mv, "named": named or "none",
            "accepted": accepted, "baseline_rmse": base, "improved_rmse": improved, "seconds": seconds,
            "truth": {k: meta.get(k) for k in keep}}


BASELINE_CHILD = r"""
import json, sys, time
sys.path.insert(0, sys.argv[1])
from diagnose.physics import explain
sys.path.insert(0, sys.argv[2])
from benchmarks.validate_physics_plantsim import record, _row
effect, seed, index, n, with_mv, restricted, mv_noise = (sys.argv[3], int(sys.argv[4]), int(sys.argv[5]),
    int(sys.argv[6]), sys.argv[7] == "1", sys.argv[8] == "1", float(sys.argv[9]))
kw = {} if sys.argv[10] == "default" else {"threads": int(sys.argv[10])}
rec, meta = record(effect, seed, index, n, with_mv, restricted, mv_noise)
t0 = time.perf_counter()
ex = explain(rec, target="auto" if with_mv else "pv", **kw)
print(json.dumps(_row(effect, seed, index, with_mv, meta, ex.missing_physics, time.perf_counter() - t0,
                      [h.name for h in ex.hypotheses if h.accepted], ex.baseline_rmse, ex.improved_rmse)))
"""


def run_baseline(job: tuple, tree: str) -> dict:
    """The same record explained by the tree at ``tree`` (its own interpreter process: the two
    packages share a name). The record itself is drawn by this tree's plantsim, passed in by
    seed: plantsim is the same in both. It gets this tree's ``--threads`` too, or the two trees' times
    would compare one thread with all of them."""
    effect, seed, index, n, with_mv, restricted, mv_noise, threads = job
    env = dict(os.environ, PYTHONPATH=tree)
    out = subprocess.run([sys.executable, "-c", BASELINE_CHILD, tree, str(ROOT), effect, str(seed), str(index), str(n),
                          "1" if with_mv else "0", "1" if restricted else "0", str(mv_noise),
                          "default" if threads is None else str(threads)],
                         cwd=tree, env=env, capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def run_pair(job: tuple, baseline: str = "") -> tuple[dict, dict | None]:
    """`run_one`, then (``baseline``: a tree) `run_baseline` on the same record, in the same worker:
    each worker runs one explain at a time, so the two trees' seconds are measured under the same
    load (a baseline run after the workers, while they run ahead, would share the cores with them)."""
    r = run_one(job)
    return r, (run_baseline(job, baseline) if baseline else None)


def score(rows: list[dict], title: str, min_change: float = 0.0) -> tuple[list[str], dict]:
    """Confusion tables (OP/PV, with MV) and the headline numbers of ``rows``."""
    def exercised(r):
        c = r["truth"].get("effect_pv_change")
        return r["effect"] == "none" or (c is not None and c >= min_change)

    rows = [r for r in rows if exercised(r)]
    out = [f"**{title}**" + (f" (records whose effect changes PV by at least {min_change:g} of the control "
                             "error's spread)" if min_change else ""), ""]
    for mv, sets, name in ((False, EFFECTS, "OP/PV"), (True, MV_SETS, "with MV")):
        sub = [r for r in rows if r["with_mv"] == mv]
        if not sub:
            continue
        by = defaultdict(Counter)
        for r in sub:
            by[r["effect"]][r["named"]] += 1
        out += [f"{name} (rows: hidden effect, columns: named)", "",
                "| hidden \\ named | " + " | ".join(EFFECTS) + " | right |", "|---" * (len(EFFECTS) + 2) + "|"]
        for e in sets:
            c = by[e]
            tot = sum(c.values())
            if tot:
                out.append(f"| {e} | " + " | ".join(str(c[k]) for k in EFFECTS) + f" | {c[e]}/{tot} |")
        out.append("")
    scored = [r for r in rows if r["effect"] != "none" and not (r["effect"] == "actuator_lag" and not r["with_mv"])]
    clean = [r for r in rows if r["effect"] == "none"]
    right = sum(r["named"] == r["effect"] for r in scored)
    left = sum(r["named"] == "none" for r in clean)
    wrong = sum(r["named"] not in ("none", r["effect"]) for r in scored)
    lag_pv = [r for r in rows if r["effect"] == "actuator_lag" and not r["with_mv"]]
    stats = {"right": right, "scored": len(scored), "clean_left": left, "clean": len(clean), "wrong_names": wrong}
    out += ["| measure | value | target |", "|---|---|---|",
            f"| right effect named (all but actuator_lag from OP/PV) | {right}/{len(scored)} "
            f"({100 * right / max(len(scored), 1):.0f} %) | >= 90 % |",
            f"| clean records left alone | {left}/{len(clean)} ({100 * left / max(len(clean), 1):.0f} %) | >= 95 % |",
            f"| a wrong effect named | {wrong}/{len(scored)} | - |"]
    if lag_pv:
        out.append(f"| actuator_lag from OP/PV (not scored) | named {sum(r['named'] == 'actuator_lag' for r in lag_pv)}"
                   f"/{len(lag_pv)}, none {sum(r['named'] == 'none' for r in lag_pv)}/{len(lag_pv)} | - |")
    return out, stats


def make_jobs(args: argparse.Namespace, threads) -> list[tuple]:
    """The explains to run: each record of ``--records`` (or of the set) from OP/PV and, where its
    effect is judged on the stem, with MV; with ``--stem-only`` only the latter, with ``--pv-only``
    only the former."""
    if args.records:
        jobs = []
        for spec in args.records:
            e, seed, i = _record_spec(spec)
            jobs += [(e, seed, i, args.n, mv, args.restricted, args.mv_noise, threads)
                     for mv in (False, True) if not mv or e in MV_SETS]
    else:
        jobs = [(e, args.seed, i, args.n, False, args.restricted, args.mv_noise, threads)
                for e in EFFECTS for i in range(args.per_effect)]
        jobs += [(e, args.seed, i, args.n, True, args.restricted, args.mv_noise, threads)
                 for e in MV_SETS for i in range(args.per_effect)]
    if args.stem_only:
        return [j for j in jobs if j[4]]
    return [j for j in jobs if not j[4]] if args.pv_only else jobs


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=41, help="plantsim set seed (records seed*1000 + i)")
    ap.add_argument("--per-effect", type=int, default=5)
    ap.add_argument("--n", type=int, default=8000)
    ap.add_argument("--restricted", action="store_true", help="two-parameter/Kano valves on FOPTD/SOPTD only")
    ap.add_argument("--mv-noise", type=float, default=0.1, help="stem measurement noise, %% of span (RMS)")
    ap.add_argument("--jobs", type=int, default=1)
    ap.add_argument("--threads", type=int, default=None)
    ap.add_argument("--baseline", default="", help="also run each record with this tree's explain")
    ap.add_argument("--records", nargs="+", default=None, metavar="EFFECT:SET:INDEX",
                    help="run these records instead of a set (each from OP/PV, and with MV where the effect is "
                         "judged on the stem), e.g. time_varying_friction:60:0")
    ap.add_argument("--list-steps", default="", metavar="FIRST-LAST",
                    help="print, as --records arguments, every friction-step record of sets FIRST..LAST "
                         "(indices below --per-effect) and exit")
    ap.add_argument("--stem-only", action="store_true",
                    help="only the records with the stem position recorded (for a change to the valve-stage fits)")
    ap.add_argument("--pv-only", action="store_true",
                    help="only the records from OP/PV alone (for a change to the loop-stage fits)")
    ap.add_argument("--jsonl", default="")
    ap.add_argument("--md", default="")
    args = ap.parse_args(argv)
    if args.list_steps:
        first, _, last = args.list_steps.partition("-")
        if not (first.isdigit() and last.isdigit()):
            raise SystemExit(f"--list-steps {args.list_steps}: expected FIRST-LAST, two set numbers, e.g. 60-89")
        print(" ".join(step_records(int(first), int(last), args.per_effect, args.n, args.restricted)))
        return 0
    run_label = "records" if args.records else str(args.seed)
    jsonl = args.jsonl or f"benchmarks/_physics_plantsim_{run_label}{'_restricted' if args.restricted else ''}.jsonl"
    threads = args.threads if args.threads is not None else (1 if args.jobs > 1 else None)
    jobs = make_jobs(args, threads)
    t_all = time.perf_counter()
    run = functools.partial(run_pair, baseline=args.baseline)
    if args.jobs > 1:
        import multiprocessing as mp

        pool = mp.get_context("spawn").Pool(args.jobs)
        results = pool.imap(run, jobs)
    else:
        pool = None
        results = map(run, jobs)
    rows, base_rows = [], []
    with open(jsonl, "w") as fh:
        for k, job in enumerate(jobs):
            r, b = next(results)
            if b is not None:
                r["baseline_tree"] = {"named": b["named"], "seconds": b["seconds"]}
                base_rows.append(b)
            rows.append(r)
            fh.write(json.dumps(r) + "\n")
            fh.flush()
            extra = f" | baseline tree: {r['baseline_tree']['named']} ({r['baseline_tree']['seconds']:.1f} s)" \
                if args.baseline else ""
            print(f"[{k + 1}/{len(jobs)}] {r['effect']:22s} {r['seed']} mv={r['with_mv']!s:5s} -> {r['named']:22s} "
                  f"({r['seconds']:.1f} s; {r['truth']['law']}, {r['truth']['process']}, change "
                  f"{r['truth'].get('effect_pv_change') or 0:.2f}){extra}", file=sys.stderr, flush=True)
    if pool is not None:
        pool.close()
        pool.join()
    wall = time.perf_counter() - t_all
    what = "two-parameter and Kano valves on FOPTD/SOPTD processes" if args.restricted else \
        "two-parameter, Kano and force-balance valves on FOPTD, SOPTD and third-order processes"
    what_run = f"--records ({len(args.records)} records)" if args.records else \
        f"--seed {args.seed} --per-effect {args.per_effect}"
    md = [f"`python benchmarks/validate_physics_plantsim.py {what_run}"
          + (" --restricted" if args.restricted else "") + (" --stem-only" if args.stem_only else "")
          + f"`: plantsim concealed {'records' if args.records else 'set ' + run_label} "
          f"({len(jobs)} explains of {args.n}-sample records at 1 s; {what}; MV with {args.mv_noise:g} % noise). "
          f"Per-record results in `{jsonl}`.", ""]
    for label, rs in [("this tree", rows)] + ([("baseline tree", base_rows)] if args.baseline else []):
        for thr in (0.0, 0.5, 1.0):
            part, _ = score(rs, label, thr)
            md += part + [""]
        secs = [r["seconds"] for r in rs]
        md.append(f"{label}: time per record median {np.median(secs):.1f} s, max {max(secs):.1f} s")
        md.append("")
    md.append(f"Whole run {wall / 60:.1f} min (--jobs {args.jobs}).")
    text = "\n".join(md)
    print(text)
    if args.md:
        Path(args.md).write_text(text + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
