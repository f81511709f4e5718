"""Proof on concealed data: hide one piece of physics in simulated closed loops, run `explain`, and
count how often it names the right one (and leaves clean loops alone).

Each record draws its plant, controller and effect parameters from its seed
(`diagnose.physics.concealed.concealed_loop`). Sets:

* OP/PV only (``--target pv``): clean, asymmetric_stiction, valve_characteristic,
  external_disturbance, time_varying_friction, and actuator_lag (reported apart: from OP/PV alone a
  lag after the friction is the same as a second process lag);
* with the measured stem position MV (valve-side effects judged on OP -> MV): clean,
  actuator_lag, asymmetric_stiction, time_varying_friction.

Prints the confusion table, the held-out RMSE change and timings, writes one JSON line per record
to ``--jsonl`` and, with ``--md FILE``, the markdown to FILE.

    python benchmarks/validate_physics.py [--per-effect 12] [--n 3000] [--seed0 1000] [--jobs N]

``--jobs N`` runs N records side by side (one process each; results identical, per-record times
then measured under that load). ``--only EFFECT[:SEED[:mv]],...`` re-runs just those records (e.g.
the misses while iterating); ``--sets mv`` or ``--sets pv`` one half.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from collections import Counter, defaultdict
from pathlib import Path

import numpy as np

from diagnose.physics import explain
from diagnose.physics.concealed import concealed_loop

PV_SETS = ["none", "asymmetric_stiction", "valve_characteristic", "external_disturbance",
           "time_varying_friction", "actuator_lag"]
MV_SETS = ["none", "actuator_lag", "asymmetric_stiction", "time_varying_friction"]
NAMES = ["none", "actuator_lag", "asymmetric_stiction", "valve_characteristic", "external_disturbance",
         "time_varying_friction"]


def hypothesis_numbers(ex) -> dict[str, list[float]]:
    """Each hypothesis's held-out BIC change, training BIC change and held-out RMSE fall, as the
    rows keep them (``delta_bic_heldout_train_reduction``)."""
    return {h.name: [round(float(h.delta_bic), 2), round(float(h.train_delta_bic), 2), round(float(h.reduction), 3)]
            for h in ex.hypotheses}


# the benchmark's valves move: at least 10 times in the 65 % training part, 5 in the held-out part
MIN_MOVES = (0.65, 10, 5)


def run_one(effect: str, seed: int, with_mv: bool, n: int, raw: bool = False, threads: int | None = None) -> dict:
    moves = None if raw else MIN_MOVES
    rec, truth = concealed_loop(effect, seed, n=n, with_mv=with_mv, min_moves=moves)
    t0 = time.perf_counter()
    ex = explain(rec, target="auto" if with_mv else "pv", threads=threads)
    dt = time.perf_counter() - t0
    named = ex.missing_physics or "none"
    acc = {h.name: h.accepted for h in ex.hypotheses}
    dbic = hypothesis_numbers(ex)
    # how much the hidden effect changes what is recorded: RMS difference from the record's
    # effect-free twin (same plant, controller, setpoints, loads and noise), in units of the noise
    exposure = 0.0
    if effect != "none":
        twin, _ = concealed_loop(effect, seed, n=n, with_mv=with_mv, apply_effect=False, min_moves=moves)
        exposure = float(np.sqrt(np.mean((rec.pv - twin.pv) ** 2)) / truth["noise_std"])
        if with_mv:
            exposure = max(exposure, float(np.sqrt(np.mean((rec.mv - twin.mv) ** 2)) / 0.1))
    return {"effect": effect, "seed": seed, "with_mv": with_mv, "named": named, "target": ex.target,
            "baseline_rmse": ex.baseline_rmse, "improved_rmse": ex.improved_rmse,
            "reference_rmse": ex.mismatch.reference_rmse,
            "reduction": 1.0 - ex.improved_rmse / ex.baseline_rmse if ex.baseline_rmse > 0 else 0.0,
            "accepted": acc, "delta_bic_heldout_train_reduction": dbic, "exposure": exposure, "warnings": [w.code for w in ex.warnings], "seconds": dt,
            "truth": {k: (float(v) if isinstance(v, (int, float, np.floating)) else v) for k, v in truth.items()}}


def _run_packed(job: tuple) -> dict:
    return run_one(*job)


def table(rows: list[dict], sets: list[str], title: str) -> tuple[str, dict]:
    by = defaultdict(Counter)
    for r in rows:
        by[r["effect"]][r["named"]] += 1
    lines = [f"**{title}** (rows: hidden effect, columns: named; last column: records where the effect "
             "is exercised, i.e. changes the recording by more than the noise RMS)", "",
             "| hidden \\ named | " + " | ".join(NAMES) + " | right | right where exercised |",
             "|---" * (len(NAMES) + 3) + "|"]
    stats = {}
    for e in sets:
        c = by[e]
        tot = sum(c.values())
        right = c[e] / tot if tot else float("nan")
        stats[e] = (c[e], tot)
        ex = [r for r in rows if r["effect"] == e and (e == "none" or r.get("exposure", 1e9) >= 1.0)]
        n_ex = sum(r["named"] == e for r in ex)
        lines.append(f"| {e} | " + " | ".join(str(c[nm]) for nm in NAMES) + f" | {c[e]}/{tot} ({100 * right:.0f} %) "
                     f"| {n_ex}/{len(ex)} |")
    return "\n".join(lines), stats


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--per-effect", type=int, default=12)
    ap.add_argument("--n", type=int, default=3000, help="samples per record (1 s sampling)")
    ap.add_argument("--seed0", type=int, default=1000)
    ap.add_argument("--jsonl", default="benchmarks/_physics_results.jsonl")
    ap.add_argument("--md", default="",
                    help="also write the markdown to this file (docs/_bench_physics.md holds several "
                         "sets and the real recordings: write elsewhere and merge by hand)")
    ap.add_argument("--sets", default="pv,mv", help="pv, mv or both")
    ap.add_argument("--resume", action="store_true", help="reuse records already in --jsonl")
    ap.add_argument("--raw-draws", action="store_true",
                    help="keep every seed's first draw, also when its valve stays stuck through the "
                         "training or the held-out part (the sets before 2026-11-23 05 UTC); by default "
                         "such a draw is drawn again (concealed_loop(min_moves=...))")
    ap.add_argument("--only", default="",
                    help="run only these records: comma-separated EFFECT, EFFECT:SEED or EFFECT:SEED:mv "
                         "(e.g. time_varying_friction:2000,actuator_lag:2003:mv); the table then covers "
                         "those records only")
    ap.add_argument("--jobs", type=int, default=1,
                    help="worker processes (records are independent; timings per record are then "
                         "measured side by side)")
    ap.add_argument("--threads", type=int, default=None,
                    help="threads of each explain (default: explain's own, 1 with --jobs > 1)")
    ap.add_argument("--real", action="store_true",
                    help="run on the real recordings in --data instead (prints a table, draws figures)")
    ap.add_argument("--examples", action="store_true",
                    help="draw one concealed example per effect to docs/figures/physics_concealed_*.png")
    ap.add_argument("--data", default=str(Path(__file__).resolve().parents[2] / "shared" / "data"),
                    help="folder of the shared real data (default: ../shared/data beside the repository)")
    ap.add_argument("--figdir", default="docs/figures")
    args = ap.parse_args(argv)
    if args.real:
        return real_data(args)
    if args.examples:
        return examples(args)

    done = {}
    if args.resume and os.path.exists(args.jsonl):
        with open(args.jsonl) as fh:
            for line in fh:
                r = json.loads(line)
                done[(r["effect"], r["seed"], r["with_mv"])] = r
    jobs = []
    for kind in args.sets.split(","):
        sets, mv = (PV_SETS, False) if kind == "pv" else (MV_SETS, True)
        for e in sets:
            for i in range(args.per_effect):
                jobs.append((e, args.seed0 + i, mv))
    if args.only:
        keep = [tuple(tok.split(":")) for tok in args.only.split(",") if tok]

        def wanted(e: str, seed: int, mv: bool) -> bool:
            for k in keep:
                if k[0] != e or (len(k) > 1 and int(k[1]) != seed) or (len(k) > 2 and (k[2] == "mv") != mv):
                    continue
                return True
            return False

        jobs = [j for j in jobs if wanted(*j)]
    rows = []
    t_all = time.perf_counter()
    threads = args.threads if args.threads is not None else (1 if args.jobs > 1 else None)
    todo = [(e, seed, mv, args.n, args.raw_draws, threads) for e, seed, mv in jobs if (e, seed, mv) not in done]
    if args.jobs > 1:
        import multiprocessing as mp

        pool = mp.get_context("spawn").Pool(args.jobs)
        results = pool.imap(_run_packed, todo)
    else:
        pool = None
        results = map(_run_packed, todo)
    with open(args.jsonl, "a" if args.resume else "w") as out:
        for k, (e, seed, mv) in enumerate(jobs):
            if (e, seed, mv) in done:
                rows.append(done[(e, seed, mv)])
                continue
            r = next(results)
            rows.append(r)
            out.write(json.dumps(r) + "\n")
            out.flush()
            print(f"[{k + 1}/{len(jobs)}] {e:22s} seed {seed} mv={mv!s:5s} -> {r['named']:22s} "
                  f"rmse {r['baseline_rmse']:.3g} -> {r['improved_rmse']:.3g} ({r['seconds']:.1f} s)",
                  file=sys.stderr)
    if pool is not None:
        pool.close()
        pool.join()
    wall = time.perf_counter() - t_all
    md = render(rows, args, wall)
    print(md)
    if args.md:
        tmp = args.md + ".tmp"
        with open(tmp, "w") as fh:
            fh.write(md + "\n")
        os.replace(tmp, args.md)
    return 0


def _machine() -> str:
    """The CPU model, core count and load average after the run, as bench_explain.py prints them
    (the figure used to say "under load from other jobs" whatever the load)."""
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    from benchmarks.machine import cpu_model

    load = os.getloadavg()
    return (f"{cpu_model()}, {os.cpu_count()} cores, load average after the run {load[0]:.1f} / "
            f"{load[1]:.1f} / {load[2]:.1f}")


def render(rows: list[dict], args, wall: float) -> str:
    parts = ["## Missing physics: proof on concealed data", "",
             f"`python benchmarks/validate_physics.py --per-effect {args.per_effect} --n {args.n} "
             f"--seed0 {args.seed0}`: {len(rows)} simulated closed loops (PI on FOPTD with a sticky valve, "
             "S 2.5-6 %, J 0.2-1.0 S, tau 10-35 s, dead time 1-5 s, 1 s sampling, "
             f"{args.n} samples, first 65 % for fitting, last 35 % held out; effect parameters random per "
             "seed, see diagnose/physics/concealed.py).", ""]
    pv = [r for r in rows if not r["with_mv"]]
    mv = [r for r in rows if r["with_mv"]]
    summary = {}
    if pv:
        t, st = table(pv, [e for e in PV_SETS if any(r["effect"] == e for r in pv)], "OP/PV only")
        parts += [t, ""]
        summary["pv"] = st
    if mv:
        t, st = table(mv, [e for e in MV_SETS if any(r["effect"] == e for r in mv)],
                      "with the stem position MV (valve-side effects judged on OP -> MV)")
        parts += [t, ""]
        summary["mv"] = st
    # headline numbers
    scored = [r for r in rows if r["effect"] != "none" and not (r["effect"] == "actuator_lag" and not r["with_mv"])]
    clean = [r for r in rows if r["effect"] == "none"]
    right = sum(r["named"] == r["effect"] for r in scored)
    left = sum(r["named"] == "none" for r in clean)
    named_right = [r for r in scored if r["named"] == r["effect"]]
    red = [r["reduction"] for r in named_right]
    lag_pv = [r for r in rows if r["effect"] == "actuator_lag" and not r["with_mv"]]
    parts += ["| measure | value | target |", "|---|---|---|",
              f"| right effect named (all sets except actuator_lag from OP/PV) | {right}/{len(scored)} "
              f"({100 * right / max(len(scored), 1):.0f} %) | >= 90 % |",
              f"| clean records left alone | {left}/{len(clean)} ({100 * left / max(len(clean), 1):.0f} %) | >= 95 % |",
              f"| median held-out RMSE reduction where the right effect is named | "
              f"{100 * float(np.median(red)) if red else float('nan'):.0f} % (IQR "
              f"{100 * float(np.percentile(red, 25)) if red else float('nan'):.0f}-"
              f"{100 * float(np.percentile(red, 75)) if red else float('nan'):.0f} %) | >= 30 % |"]
    if lag_pv:
        n_lag = sum(r["named"] == "actuator_lag" for r in lag_pv)
        n_none = sum(r["named"] == "none" for r in lag_pv)
        parts.append(f"| actuator_lag from OP/PV alone (not scored: indistinguishable from process lag) | "
                     f"named {n_lag}/{len(lag_pv)}, none {n_none}/{len(lag_pv)} | - |")
    exercised = [r for r in scored if r.get("exposure", 1e9) >= 1.0]
    if len(exercised) < len(scored):
        n_ex = sum(r["named"] == r["effect"] for r in exercised)
        parts.append(f"| right effect named where the hidden effect is exercised (changes the recording by "
                     f"more than the noise RMS; {len(scored) - len(exercised)} record(s) where it does not) | "
                     f"{n_ex}/{len(exercised)} ({100 * n_ex / max(len(exercised), 1):.0f} %) | - |")
    secs = [r["seconds"] for r in rows]
    parts += ["", f"Time per record: median {np.median(secs):.1f} s, max {np.max(secs):.1f} s "
              f"({_machine()}; whole run {wall / 60:.1f} min).", ""]
    # per-effect RMSE change
    parts += ["| set | effect | n named right | median baseline RMSE | median improved RMSE | median reduction |",
              "|---|---|---|---|---|---|"]
    for label, rs in (("OP/PV", pv), ("with MV", mv)):
        for e in NAMES[1:]:
            sel = [r for r in rs if r["effect"] == e and r["named"] == e]
            if not sel:
                continue
            parts.append(f"| {label} | {e} | {len(sel)} | {np.median([r['baseline_rmse'] for r in sel]):.3g} | "
                         f"{np.median([r['improved_rmse'] for r in sel]):.3g} | "
                         f"{100 * np.median([r['reduction'] for r in sel]):.0f} % |")
    return "\n".join(parts)


REAL = [
    # (label, file under --data, read options, explain options)
    ("DAMADICS actuator, OP -> MV", "damadics-lublin/lublin_actuator3_2001-10-11_1h.csv",
     {"pv": "PV_flow_F_t_per_h"}, {"target": "mv"}),
    ("DAMADICS actuator, OP/MV/flow (auto)", "damadics-lublin/lublin_actuator3_2001-10-11_1h.csv",
     {"pv": "PV_flow_F_t_per_h"}, {"target": "auto"}),
    ("DAMADICS actuator, OP -> flow only", "damadics-lublin/lublin_actuator3_2001-10-11_1h.csv",
     {"pv": "PV_flow_F_t_per_h", "mv": None}, {"target": "pv"}),
    ("ISDB CHEM1 (flow, stiction)", "isdb-subset/CHEM1.csv", {}, {}),
    ("ISDB PAP2 (flow, stiction)", "isdb-subset/PAP2.csv", {}, {}),
    ("ISDB CHEM10 (pressure, stiction)", "isdb-subset/CHEM10.csv", {}, {}),
    ("ISDB PAP9 (temperature, no stiction)", "isdb-subset/PAP9.csv", {}, {}),
    ("ISDB PAP4 (concentration, dead zone)", "isdb-subset/PAP4.csv", {}, {}),
]


def _slug(label: str) -> str:
    return "".join(c if c.isalnum() else "_" for c in label.split(",")[0].split("(")[0].strip().lower()).strip("_")


def real_data(args) -> int:
    import connectors

    from connectors.historian import atomic_write
    from diagnose.service.figures import explanation_png

    rows = ["| record | samples | target | baseline RMSE | plain refit RMSE | named | improved RMSE | "
            "fall vs baseline | fall vs refit | notes |", "|---|---|---|---|---|---|---|---|---|---|"]
    for label, rel, ropts, eopts in REAL:
        path = os.path.join(args.data, rel)
        opts = {k: v for k, v in ropts.items() if v is not None}
        recs = connectors.read_records(path, **opts)
        rec = max(recs, key=lambda r: r.n)
        if "mv" in ropts and ropts["mv"] is None:
            rec = rec.replace(mv=None)
        t0 = time.perf_counter()
        ex = explain(rec, **eopts)
        dt = time.perf_counter() - t0
        ref = ex.mismatch.reference_rmse
        named = ex.missing_physics or "none"
        params = ""
        if ex.missing_physics:
            h = next(h for h in ex.hypotheses if h.name == ex.missing_physics)
            params = ", ".join(f"{k} {v:.3g}" for k, v in h.params.items())
        warn = "; ".join(w.code for w in ex.warnings)
        fall_b = 1 - ex.improved_rmse / ex.baseline_rmse if ex.baseline_rmse else 0.0
        fall_r = 1 - ex.improved_rmse / ref if ref else 0.0
        rows.append(f"| {label} | {rec.n} | {ex.target} | {ex.baseline_rmse:.4g} | {ref:.4g} | {named} | "
                    f"{ex.improved_rmse:.4g} | {100 * fall_b:.0f} % | {100 * fall_r:.0f} % | {params} {warn} |")
        fig = os.path.join(args.figdir, f"physics_real_{_slug(label)}_{ex.target}.png")
        atomic_write(fig, explanation_png(ex, rec.name, dpi=110))
        print(f"{label}: {named} ({dt:.1f} s) -> {fig}", file=sys.stderr)
        print(f"   {ex.explanation}", file=sys.stderr)
    print("\n".join(rows))
    return 0


def examples(args) -> int:
    from connectors.historian import atomic_write
    from diagnose.service.figures import explanation_png

    for effect, mv in (("none", False), ("actuator_lag", True), ("asymmetric_stiction", False),
                       ("valve_characteristic", False), ("external_disturbance", False),
                       ("time_varying_friction", False)):
        rec, truth = concealed_loop(effect, 100, n=args.n, with_mv=mv)
        ex = explain(rec, target="auto" if mv else "pv")
        fig = os.path.join(args.figdir, f"physics_concealed_{effect}.png")
        atomic_write(fig, explanation_png(ex, rec.name, dpi=110))
        print(f"{effect}: named {ex.missing_physics}, held-out {ex.baseline_rmse:.3g} -> "
              f"{ex.improved_rmse:.3g}; truth {truth} -> {fig}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
