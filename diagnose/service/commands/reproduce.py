"""`stiction reproduce`: the seed paper's Section IV experiments under the fixed protocol.

Prints each table beside the paper's values (or one JSON object with --json) and writes figures
(docs/figures/narx_*.png when --out docs/figures). Protocol: docs/reproduction.md.
"""

from __future__ import annotations

import argparse
import io
import json
import os
import sys

from ...errors import DataError

EXPERIMENTS = ("table1", "table2", "table3", "model-mode", "all")


#: The longest model-mode run (samples): each step is a network evaluation, and the run's arrays are
#: held whole.
MAX_STEPS = 1_000_000


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("experiment", choices=EXPERIMENTS,
                   help="table1 (six networks x four classes), table2/table3 (robustness of base "
                        "models), model-mode (10 000-step free run), or all")
    p.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    p.add_argument("--out", default="reproduce_out",
                   help="folder for the figures (default reproduce_out); '' writes none")
    p.add_argument("--seeds", type=int, default=3, help="seeds per network for table1 (median)")
    p.add_argument("--networks", default=None,
                   help="comma-separated subset for table1 (ff,cascade,elman,lrn,narx,narxsp"
                        "[,narxsp_mlp])")
    p.add_argument("--steps", type=int, default=10_000, help="model-mode run length, samples")


def _clean(rows):
    return [{k: v for k, v in r.items() if not k.startswith("_")} for r in rows]


def _fmt(v, nd=4):
    return "-" if v is None else (f"{v:.{nd}f}" if isinstance(v, float) else str(v))


def format_table1(rows) -> str:
    lines = ["Table I (protocol test signal; RMSE in % of span; median of seeds; paper RMSE/CDC as "
             "printed, no units or protocol given)",
             f"{'network':<11}{'case':<12}{'1-step':>9}{'free-run':>10}{'CDC %':>8}{'dir %':>8}"
             f"{'train s':>9}{'paper RMSE':>12}{'paper CDC':>10}"]
    for r in rows:
        lines.append(f"{r['network']:<11}{r['case']:<12}{r['rmse_one_step']:>9.4f}"
                     f"{r['rmse_free_run']:>10.4f}{r['cdc']:>8.1f}{r['direction_agreement']:>8.1f}"
                     f"{r['train_s']:>9.1f}{_fmt(r['paper_rmse']):>12}{_fmt(r['paper_cdc']):>10}")
    return "\n".join(lines)


def format_robustness(rows, title) -> str:
    from ...narx.experiments import ROBUST_RMSE_PCT
    lines = [f"{title} (robust: free-run RMSE <= {ROBUST_RMSE_PCT:g} % of span)",
             f"{'base class':<12}{'base S,J':>10}{'test S,J':>10}{'1-step':>9}{'free-run':>10}"
             f"{'ours':>12}{'paper':>12}"]
    for r in rows:
        lines.append(f"{r['base_class']:<12}{r['base_S']:>5g},{r['base_J']:<4g}"
                     f"{r['test_S']:>5g},{r['test_J']:<4g}{r['rmse_one_step']:>9.4f}"
                     f"{r['rmse_free_run']:>10.4f}"
                     f"{'robust' if r['robust'] else 'not robust':>12}"
                     f"{'robust' if r['paper_robust'] else 'not robust':>12}")
    agree = sum(r["robust"] == r["paper_robust"] for r in rows)
    lines.append(f"verdicts agreeing with the paper: {agree} of {len(rows)}")
    return "\n".join(lines)


def format_model_mode(r) -> str:
    return (f"Model mode (Section IV-C): NARX-SP trained series-parallel for S={r['S']:g} %, "
            f"J={r['J']:g} %, run {r['n']} steps on an unseen input against the stiction model\n"
            f"free-run RMSE {r['rmse_free_run']:.3g} % of span, one-step RMSE "
            f"{r['rmse_one_step']:.3g} %, CDC {r['cdc']:.1f} %, free-run time "
            f"{1000 * r['free_run_s']:.2f} ms, training {r['train_s']:.1f} s")


def savefig(fig, path) -> None:
    """Write a matplotlib figure to ``path`` as PNG, atomically."""
    from connectors.historian import atomic_write

    buf = io.BytesIO()
    fig.savefig(buf, dpi=110, format="png")
    atomic_write(path, buf.getvalue())


def figures_table1(rows, out) -> list[str]:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np
    written = []
    cases = list(dict.fromkeys(r["case"] for r in rows))
    nets = list(dict.fromkeys(r["network"] for r in rows))
    fig, ax = plt.subplots(figsize=(8, 4))
    w = 0.8 / len(nets)
    for i, n in enumerate(nets):
        vals = [next(r["rmse_free_run"] for r in rows if r["network"] == n and r["case"] == c)
                for c in cases]
        ax.bar(np.arange(len(cases)) + i * w, np.maximum(vals, 1e-5), w, label=n)
    ax.set_yscale("log")
    ax.set_xticks(np.arange(len(cases)) + 0.4 - w / 2, cases)
    ax.set_ylabel("free-run RMSE, % of span (log)")
    ax.set_title("Table I: free-run RMSE on the unseen test signal")
    ax.legend(fontsize=8, ncol=3)
    fig.tight_layout()
    p = os.path.join(out, "narx_table1.png")
    savefig(fig, p)
    plt.close(fig)
    written.append(p)
    # Figs 8-13 analogue: undershoot, each network's free run
    sel = [r for r in rows if r["case"] == "undershoot"] or [r for r in rows if r["case"] == cases[0]]
    fig, axes = plt.subplots(len(sel), 1, figsize=(8, 1.6 * len(sel) + 0.5), sharex=True)
    axes = np.atleast_1d(axes)
    for ax, r in zip(axes, sel):
        t = np.arange(300)
        ax.plot(t, r["_y"][:300], "k-", lw=1.2, label="stiction model")
        ax.plot(t, r["_free"][:300], "r--", lw=1, label=f"{r['network']} free run")
        ax.set_ylabel("MV %")
        ax.legend(fontsize=7, loc="upper right")
    axes[-1].set_xlabel("sample")
    fig.suptitle(f"{sel[0]['case']}: model-mode outputs vs the stiction model (test signal)")
    fig.tight_layout()
    p = os.path.join(out, "narx_table1_series.png")
    savefig(fig, p)
    plt.close(fig)
    written.append(p)
    return written


def figures_robustness(rows, out, name) -> list[str]:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(6, 5))
    marks = {"deadband": "s", "no_offset": "o", "overshoot": "^", "undershoot": "v"}
    for r in rows:
        c = "tab:green" if r["robust"] else "tab:red"
        ax.scatter(r["test_S"], r["test_J"], c=c, marker=marks[r["base_class"]], s=60,
                   edgecolors="k" if r["paper_robust"] else "none")
        ax.annotate(f"{r['rmse_free_run']:.2f}", (r["test_S"], r["test_J"]), fontsize=7,
                    xytext=(4, 4), textcoords="offset points")
    for (S, J), cls in {(1, 0): "deadband", (1, 1): "no_offset", (1, 3): "overshoot",
                        (3, 1): "undershoot"}.items():
        ax.scatter(S, J, marker="*", s=200, c="gold", edgecolors="k")
    ax.set_xlabel("test S, % of span")
    ax.set_ylabel("test J, % of span")
    ax.set_title(f"{name}: free-run RMSE of base models (stars); green = robust")
    fig.tight_layout()
    p = os.path.join(out, f"narx_{name}.png")
    savefig(fig, p)
    plt.close(fig)
    return [p]


def figures_model_mode(r, out) -> list[str]:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(10, 3.8))
    n = len(r["x"])
    t = range(n - 600, n)
    a1.plot(t, r["y"][-600:], "k-", lw=1.2, label="stiction model")
    a1.plot(t, r["y_hat"][-600:], "r--", lw=1, label="NARX-SP model mode")
    a1.set_xlabel("sample (last 600 of 10 000)")
    a1.set_ylabel("MV, % of span")
    a1.legend(fontsize=8)
    a2.plot(r["x"], r["y"], "k-", lw=0.8, label="stiction model")
    a2.plot(r["x"], r["y_hat"], "r--", lw=0.6, label="NARX-SP")
    a2.set_xlabel("OP, % of span")
    a2.set_ylabel("MV, % of span")
    a2.legend(fontsize=8)
    fig.suptitle(f"Model mode, S={r['S']:g} J={r['J']:g}: free-run RMSE {r['rmse_free_run']:.2g} %")
    fig.tight_layout()
    p = os.path.join(out, "narx_model_mode.png")
    savefig(fig, p)
    plt.close(fig)
    return [p]


def run(args: argparse.Namespace) -> int:
    from ...narx import experiments as E
    from ...narx.networks import NETWORKS, PAPER_NETWORKS

    if args.seeds < 1:
        raise DataError("--seeds must be at least 1")
    if not 100 <= args.steps <= MAX_STEPS:
        raise DataError(f"--steps {args.steps}: give 100 to {MAX_STEPS} samples")
    nets = PAPER_NETWORKS
    if args.networks is not None:
        nets = tuple(n.strip() for n in args.networks.split(",") if n.strip())
        if not nets:
            raise DataError(f"--networks {args.networks!r}: name at least one network, or leave the option out "
                            "for the paper's six")
        bad = [n for n in nets if n not in NETWORKS]
        if bad:
            raise DataError(f"unknown network(s) {', '.join(bad)} in --networks; choose from "
                            f"{', '.join(NETWORKS)}")
    todo = EXPERIMENTS[:-1] if args.experiment == "all" else (args.experiment,)
    result, texts, figs = {}, [], []
    for exp in todo:
        if exp == "table1":
            rows = E.table1(nets, seeds=tuple(range(args.seeds)))
            result["table1"] = _clean(rows)
            texts.append(format_table1(rows))
            if args.out:
                figs += figures_table1(rows, args.out)
        elif exp in ("table2", "table3"):
            rows = E.table2() if exp == "table2" else E.table3()
            result[exp] = _clean(rows)
            texts.append(format_robustness(rows, "Table II" if exp == "table2" else "Table III"))
            if args.out:
                figs += figures_robustness(rows, args.out, exp)
        else:
            r = E.model_mode(n=args.steps)
            result["model_mode"] = {k: v for k, v in r.items() if k not in ("x", "y", "y_hat")}
            texts.append(format_model_mode(r))
            if args.out:
                figs += figures_model_mode(r, args.out)
    if args.json:
        print(json.dumps(result))
    else:
        print("\n\n".join(texts))
    for f in figs:
        print(f"wrote {f}", file=sys.stderr)
    return 0
