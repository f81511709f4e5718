"""Speed and accuracy of `fit_hammerstein` against a plain scipy differential-evolution fit.

Both fits minimise the *same* cost: the prediction-error cost of `diagnose.fit` (valve model ->
first-order-plus-dead-time process, gain and load by least squares, the same noise prefilter),
evaluated by the same compiled kernel. Differential evolution searches (S, J, f0, log tau, dead
time) directly (scipy defaults: popsize 15, tol 0.01, no polishing), handed the FOPTD family, or
with ``--de-same-model`` also the structure our fit searches (FOPTD, SOPTD, integrating);
`fit_hammerstein` runs its grid + refinement over all three structures, once as a single search
(``windows=0``, the default of `fit_hammerstein`) and once with the extra search windows that
`identify` uses (``windows=FIT_WINDOWS``). All run in the same process on the same loops, so
machine load affects them alike.

Also times the whole ``stiction identify FILE --json`` command on a 10 000-sample loop
(interpreter start and imports included) against a bare ``python -c pass``.

Run:  python benchmarks/bench_fit.py [--loops 8] [--cli-runs 5] [--de-budgets [POP:TOL,...]]
          [--de-same-model]
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from diagnose.fit import fit_hammerstein  # noqa: E402
from diagnose.identification import FIT_WINDOWS  # noqa: E402
from diagnose.objective import Objective, ProcessGrid, burn_in, legendre_basis, op_offset, score_weights  # noqa: E402
from validate_simulated import make_case  # noqa: E402


#: Process structures of our model, as (kind, tau2 / tau): the fit's grid (`diagnose.fit`) holds
#: FOPTD, SOPTD with tau2 = tau / 3 and tau2 = tau, and the integrator with a lag.
SAME_STRUCTURES = (("foptd", 0.0), ("soptd", 1.0 / 3.0), ("soptd", 1.0), ("integrating", 0.0))


def de_fit(op, pv, ts_s, hp_tau_s, *, seed=0, maxiter=1000, engine="kernel", popsize=15, tol=0.01,
           structures=(("foptd", 0.0),)):
    """Plain differential evolution over (S, J, f0, log tau, delay) on the same cost (scipy's
    defaults: ``popsize`` 15, ``tol`` 0.01); with several ``structures`` (kind, tau2 / tau) also
    over the structure, an integer variable."""
    from scipy.optimize import differential_evolution

    x = np.asarray(op, float)
    x = x + op_offset(x)
    n = x.shape[0]
    w = score_weights(n, None, burn_in(x, 0.05))
    prob = Objective(x, np.asarray(pv, float), ts_s, w, 2, hp_tau_s)
    lo, hi = np.percentile(x, [0.5, 99.5])
    smax = float(hi - lo)
    dmax = int(min(n * ts_s / 10.0, 60 * ts_s) / ts_s)
    many = len(structures) > 1

    def unpack(v):
        S, J, f, lt, d = v[:5]
        kind, ratio = structures[int(round(v[5]))] if many else structures[0]
        return S, J, (1.0 if f >= 0 else -1.0), math.exp(lt), int(d), kind, ratio

    if engine == "kernel":
        def cost(v):
            S, J, f, tau, d, kind, ratio = unpack(v)
            cfg = ProcessGrid.of([(kind, tau, tau * ratio, d)], ts_s)
            return float(prob.score([S], [J], [f], cfg)[0][0, 0])
    else:
        # plain: the valve in plain Python (Kano's model as written for the tests, tests/kano.py,
        # equal to the compiled kernel), scipy.signal.lfilter, numpy least squares
        from scipy.signal import lfilter

        sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
        from kano import kano_valve

        a = math.exp(-ts_s / hp_tau_s) if hp_tau_s else None
        hp = (lambda v: lfilter([1.0, -1.0], [1.0, -a], v - v[0], axis=0)) if a is not None else (lambda v: v)
        B = legendre_basis(n, 2)
        Bf = hp(B[:, 1:]) if a is not None else B
        ws = w > 0
        yf = hp(np.asarray(pv, float))
        ynorm = prob.y_std

        def lag(u, tau):
            al = math.exp(-ts_s / tau)
            return lfilter([1.0 - al], [1.0, -al], u)

        def cost(v):
            S, J, f, tau, d, kind, ratio = unpack(v)
            mv = kano_valve(x, S, J, 1 if f > 0 else -1)
            u = np.concatenate([np.full(d, mv[0]), mv[: n - d]]) - mv[0]
            z = lag(u, tau)
            if kind == "soptd":
                z = lag(z, tau * ratio)
            elif kind == "integrating":
                z = ts_s * np.cumsum(z)
            A = np.column_stack([hp(z), Bf])
            coef, *_ = np.linalg.lstsq(A[ws], yf[ws], rcond=None)
            r = (yf - A @ coef)[ws]
            return float(r @ r) / ynorm ** 2

    bounds = [(0.0, smax), (0.0, 1.5 * smax), (-1.0, 1.0), (math.log(0.5 * ts_s), math.log(n * ts_s / 4)),
              (1.0, dmax + 0.999)]
    integrality = None
    if many:
        bounds.append((0, len(structures) - 1))
        integrality = [False] * 5 + [True]
    res = differential_evolution(cost, bounds, seed=seed, maxiter=maxiter, polish=False, popsize=popsize, tol=tol,
                                 integrality=integrality)
    S, J, f, tau, d, kind, ratio = unpack(res.x)
    return {"S": S, "J": J, "tau_s": tau, "delay_s": d * ts_s, "kind": kind, "cost": res.fun, "nfev": res.nfev}


#: Larger DE budgets for ``--de-budgets`` as (population, tolerance), beside scipy's default (15, 0.01)
#: that every run times. On the 12 loops of docs/validation.md ("DE budget sweep") they took a
#: median 4550, 6975 and 10 800 evaluations, against 1800 at the default.
DE_BUDGETS = ((20, 1e-3), (30, 1e-3), (40, 1e-4))
#: DE's parameters: S, J, starting direction, log lag, dead time (a generation is popsize x this;
#: one more with ``--de-same-model``: the structure)
DE_DIM = 5


def _parse_budgets(text: str) -> list[tuple[int, float]]:
    out = []
    for item in text.split(","):
        pop, _, tol = item.partition(":")
        try:
            out.append((int(pop), float(tol)))
        except ValueError:
            raise SystemExit(f"bench_fit: --de-budgets wants POP:TOL[,POP:TOL...], got {item!r}") from None
    return out


def compare(n_loops: int, seed: int, plain_too: bool = True, budgets=(),
            structures=(("foptd", 0.0),)) -> dict:
    warm = make_case(1, np.random.default_rng(0), n=500).record
    fit_hammerstein(warm.op, warm.pv, warm.ts_s)          # load the compiled kernels first
    rng = np.random.default_rng(seed)
    rows = []
    i = 0
    while len(rows) < n_loops:
        case = make_case(i, rng)
        i += 1
        if case.cls == "none" or case.info["kind"] == "integrating":
            continue      # DE here searches FOPTD only: compare on self-regulating sticky loops
        rec = case.record
        t0 = time.perf_counter()
        ours = fit_hammerstein(rec.op, rec.pv, rec.ts_s)
        t_ours = time.perf_counter() - t0
        t0 = time.perf_counter()
        ours_w = fit_hammerstein(rec.op, rec.pv, rec.ts_s, windows=FIT_WINDOWS)
        t_ours_w = time.perf_counter() - t0
        t0 = time.perf_counter()
        de = de_fit(rec.op, rec.pv, rec.ts_s, ours.hp_tau_s, engine="kernel", structures=structures)
        t_de = time.perf_counter() - t0
        t0 = time.perf_counter()
        plain = (de_fit(rec.op, rec.pv, rec.ts_s, ours.hp_tau_s, engine="plain", structures=structures)
                 if plain_too else None)
        t_plain = time.perf_counter() - t0
        swept = {}
        for pop, tol in budgets:
            t0 = time.perf_counter()
            r_ = de_fit(rec.op, rec.pv, rec.ts_s, ours.hp_tau_s, engine="plain", popsize=pop, tol=tol,
                        structures=structures)
            swept[f"de{pop}_{tol:g}"] = (r_, time.perf_counter() - t0)
        # our cost in the same units as DE's (the kernel's scaled SSE)
        x = rec.op + ours.op_offset_pct
        w = score_weights(rec.n, None, burn_in(x, 0.05))
        prob = Objective(x, rec.pv, rec.ts_s, w, 2, ours.hp_tau_s)
        p = ours.process
        cfg = ProcessGrid.of([(p.kind, p.tau_s, p.tau2_s, int(round(p.delay_s / rec.ts_s)))], rec.ts_s)
        c_ours = float(prob.score([ours.S_pct], [ours.J_pct], [ours.f0], cfg)[0][0, 0])
        row = {"loop": rec.name, "class": case.cls, "S_true": case.S_pct, "J_true": case.J_pct,
               "ours_S": ours.S_pct, "ours_J": ours.J_pct, "ours_cost": c_ours, "ours_s": t_ours,
               "ours_w_S": ours_w.S_pct, "ours_w_J": ours_w.J_pct, "ours_w_s": t_ours_w,
               "de_S": de["S"], "de_J": de["J"], "de_cost": de["cost"], "de_s": t_de, "de_nfev": int(de["nfev"])}
        if plain is not None:
            row.update({"plain_S": plain["S"], "plain_J": plain["J"], "plain_cost": plain["cost"],
                        "plain_s": t_plain, "plain_nfev": int(plain["nfev"])})
        for key, (r_, t_) in swept.items():
            row.update({f"{key}_S": r_["S"], f"{key}_J": r_["J"], f"{key}_s": t_, f"{key}_nfev": int(r_["nfev"])})
        rows.append(row)
        print(json.dumps({k: (round(v, 4) if isinstance(v, float) else v) for k, v in row.items()}), flush=True)

    def rel(a, b):
        return abs(a - b) / b

    def med(vals):
        vals = list(vals)
        return statistics.median(vals) if vals else None

    out = {"loops": len(rows),
           "median_time_ours_s": med(r["ours_s"] for r in rows),
           "median_time_de_s": med(r["de_s"] for r in rows),
           "median_speedup": med(r["de_s"] / r["ours_s"] for r in rows),
           "median_rel_err_S_ours": med(rel(r["ours_S"], r["S_true"]) for r in rows),
           "median_rel_err_S_de": med(rel(r["de_S"], r["S_true"]) for r in rows),
           "median_rel_err_J_ours": med(rel(r["ours_J"], r["J_true"]) for r in rows if r["J_true"] > 0),
           "median_rel_err_J_de": med(rel(r["de_J"], r["J_true"]) for r in rows if r["J_true"] > 0),
           "median_time_ours_windows_s": med(r["ours_w_s"] for r in rows),
           "median_rel_err_S_ours_windows": med(rel(r["ours_w_S"], r["S_true"]) for r in rows),
           "median_rel_err_J_ours_windows": med(rel(r["ours_w_J"], r["J_true"]) for r in rows if r["J_true"] > 0),
           "ours_cost_lower_or_equal_vs_de": int(sum(r["ours_cost"] <= r["de_cost"] * (1 + 1e-9) for r in rows))}
    if rows and "plain_s" in rows[0]:
        out.update({"median_time_plain_de_s": med(r["plain_s"] for r in rows),
                    "median_speedup_vs_plain": med(r["plain_s"] / r["ours_s"] for r in rows),
                    "median_speedup_windows_vs_plain": med(r["plain_s"] / r["ours_w_s"] for r in rows),
                    "median_rel_err_S_plain": med(rel(r["plain_S"], r["S_true"]) for r in rows),
                    "median_rel_err_J_plain": med(rel(r["plain_J"], r["J_true"]) for r in rows
                                                                if r["J_true"] > 0),
                    "ours_cost_lower_or_equal_vs_plain": int(sum(r["ours_cost"] <= r["plain_cost"] * (1 + 1e-9)
                                                                 for r in rows))})
    sweep = []
    dim = DE_DIM + (len(structures) > 1)
    # scipy's default budget is the "plain" columns
    runs = [(15, 0.01, "plain")] if budgets and plain_too else []
    runs += [(p, t, f"de{p}_{t:g}") for p, t in budgets]
    for pop, tol, key in runs:
        sweep.append({"popsize": pop, "tol": tol,
                      "median_time_s": med(r[f"{key}_s"] for r in rows),
                      "median_nfev": med(r[f"{key}_nfev"] for r in rows),
                      # a flat cost with narrow valleys looks converged to DE's tolerance test at
                      # once: it stops after its first generation, far off
                      "loops_stopped_after_first_generation": int(sum(r[f"{key}_nfev"] <= 2 * pop * dim
                                                                      for r in rows)),
                      "median_rel_err_S": med(rel(r[f"{key}_S"], r["S_true"]) for r in rows),
                      "median_rel_err_J": med(rel(r[f"{key}_J"], r["J_true"]) for r in rows if r["J_true"] > 0),
                      "median_speedup_single": med(r[f"{key}_s"] / r["ours_s"] for r in rows),
                      "median_speedup_windows": med(r[f"{key}_s"] / r["ours_w_s"] for r in rows)})
    if sweep:
        out["de_budgets"] = sweep
        # the target: faster by 10x than a DE whose accuracy is equal or better than ours; the
        # fastest budget that reaches the windowed fit's median errors in both S and J
        eS, eJ = out["median_rel_err_S_ours_windows"], out["median_rel_err_J_ours_windows"]

        def as_good(a, b):          # None: no loop with J > 0
            return b is None or (a is not None and a <= b)
        match = [b for b in sweep if as_good(b["median_rel_err_S"], eS) and as_good(b["median_rel_err_J"], eJ)]
        out["cheapest_budget_as_accurate_as_windows"] = (min(match, key=lambda b: b["median_time_s"])
                                                         if match else None)
    return {"summary": out, "rows": rows}


def cli_timing(runs: int) -> dict:
    from connectors.historian import write_wide
    from diagnose.simulate import sticky_loop

    rec = sticky_loop(3.0, 1.0, n=10000, noise_std=0.05, load_walk_std=0.01, seed=4, name="FIC10K")
    rec = rec.replace(mv=None)
    tmp = Path(tempfile.mkdtemp()) / "loop10k.csv"
    write_wide(rec, tmp)
    exe = str(Path(sys.executable).parent / "stiction")
    subprocess.run([exe, "identify", str(tmp), "--json"], capture_output=True, check=True)  # warm cache
    t_cli, t_py = [], []
    for _ in range(runs):
        t0 = time.perf_counter()
        subprocess.run([exe, "identify", str(tmp), "--json"], capture_output=True, check=True)
        t_cli.append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        subprocess.run([sys.executable, "-c", "pass"], capture_output=True, check=True)
        t_py.append(time.perf_counter() - t0)
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-c", "import numpy, scipy.optimize"], capture_output=True, check=True)
    t_imp = time.perf_counter() - t0
    return {"samples": rec.n, "runs": runs, "identify_wall_s_min": min(t_cli),
            "identify_wall_s_median": statistics.median(t_cli), "python_pass_s_median": statistics.median(t_py),
            "python_import_numpy_scipy_optimize_s": t_imp}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--loops", type=int, default=8)
    ap.add_argument("--seed", type=int, default=11)
    ap.add_argument("--cli-runs", type=int, default=5)
    ap.add_argument("--json")
    ap.add_argument("--de-same-model", action="store_true",
                    help="DE also searches the process structure, as our fit does (FOPTD, SOPTD with tau2 = "
                         "tau/3 or tau, integrating), instead of being handed FOPTD")
    ap.add_argument("--de-budgets", nargs="?", const=",".join(f"{p}:{t:g}" for p, t in DE_BUDGETS),
                    help="also run plain DE at these budgets, POP:TOL[,POP:TOL...] "
                         f"(no value: {','.join(f'{p}:{t:g}' for p, t in DE_BUDGETS)})")
    args = ap.parse_args(argv)
    budgets = _parse_budgets(args.de_budgets) if args.de_budgets else ()
    res = {"cli": cli_timing(args.cli_runs)}
    print(json.dumps(res["cli"], indent=2), flush=True)
    structures = SAME_STRUCTURES if args.de_same_model else (("foptd", 0.0),)
    res["fit_vs_de"] = compare(args.loops, args.seed, budgets=budgets, structures=structures)
    print(json.dumps(res["fit_vs_de"]["summary"], indent=2))
    if args.json:
        Path(args.json).write_text(json.dumps(res, indent=1, default=float))
    return 0


if __name__ == "__main__":
    sys.exit(main())
