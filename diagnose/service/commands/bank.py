"""`stiction bank train|show|select`: rebuild, list or query the NARX-SP model bank."""

from __future__ import annotations

import argparse
import io
import json
import sys
from pathlib import Path

from ...errors import DataError


def _default_dir() -> Path:
    return Path(__file__).resolve().parents[2] / "narx" / "bank"


def add_arguments(p: argparse.ArgumentParser) -> None:
    sub = p.add_subparsers(dest="action", metavar="ACTION", required=True)
    t = sub.add_parser("train", help="train every bank case and write weights + manifest.json")
    t.add_argument("--out", default=None, help="bank folder (default: the package's bank folder, rebuilt with the "
                                               "whole grid; --cases needs --out)")
    t.add_argument("--seed", type=int, default=0, help="training seed")
    t.add_argument("--cases", default=None,
                   help="only these cases, e.g. '3:1,1:3' (S:J in %% of span); default the grid")
    s = sub.add_parser("show", help="list the bank's models")
    s.add_argument("--json", action="store_true", help="print the list as JSON")
    s.add_argument("--figure", default=None,
                   help="also write a PNG of the robustness maps of the paper's four base cases")
    q = sub.add_parser("select", help="the bank model for an identified (S, J)")
    q.add_argument("--S", type=float, required=True, help="S, %% of span")
    q.add_argument("--J", type=float, required=True, help="J, %% of span")


def _parse_cases(text):
    cases = []
    for item in text.split(","):
        try:
            S, J = (float(v) for v in item.split(":"))
        except ValueError:
            raise DataError(f"--cases: cannot read {item!r}; write S:J pairs like 3:1,1:3") from None
        if S <= 0 or J < 0:
            raise DataError(f"--cases: {item!r} needs S > 0 and J >= 0")
        cases.append((S, J))
    return cases


def _atomic_torch_save(obj, path: Path) -> None:
    import torch
    from connectors.historian import atomic_write

    buf = io.BytesIO()
    torch.save(obj, buf)
    atomic_write(path, buf.getvalue())


def run(args: argparse.Namespace) -> int:
    from connectors.historian import atomic_write

    from ...narx.bank import bank_grid, load_bank, train_bank

    if args.action == "train":
        cases = _parse_cases(args.cases) if args.cases else bank_grid()
        if args.cases and not args.out:
            # a manifest of a few cases would replace the installed bank's, leaving its other
            # models unlisted: only the whole grid may rebuild it in place
            raise DataError(f"--cases {args.cases}: a bank of these cases only would replace the installed "
                            f"bank ({_default_dir()}); give --out DIR for it")
        out = Path(args.out) if args.out else _default_dir()
        out.mkdir(parents=True, exist_ok=True)

        def progress(i, n, e):
            m = e["metrics"]
            print(f"[{i}/{n}] {e['name']}: free-run {m['rmse_free_run']:.4f} %, one-step "
                  f"{m['rmse_one_step']:.4f} %, {m['train_s']:.1f} s", file=sys.stderr)

        manifest, states = train_bank(cases, seed=args.seed, progress=progress)
        for name, state in states.items():
            _atomic_torch_save(state, out / f"{name}.pt")
        atomic_write(out / "manifest.json", json.dumps(manifest, indent=1) + "\n")
        print(f"wrote {len(states)} models and manifest.json to {out} "
              f"({manifest['train_total_s']:.0f} s)", file=sys.stderr)
        return 0
    bank = load_bank()
    if args.action == "select":
        sel = bank.select(args.S, args.J)
        note = sel.warning()
        print(json.dumps({"narx": sel.to_dict(), "warning": None if note is None else note.to_dict()}))
        return 0
    if args.figure:
        _map_figure(bank, args.figure)
        print(f"wrote {args.figure}", file=sys.stderr)
    rows = [{"model": m.name, "S": m.S_pct, "J": m.J_pct, "class": m.cls,
             "rmse_one_step": m.metrics["rmse_one_step"], "rmse_free_run": m.metrics["rmse_free_run"],
             "cdc": m.metrics["cdc"], "train_s": m.metrics["train_s"],
             "robust_radius": m.robust_radius_pct} for m in bank.models]
    if args.json:
        print(json.dumps({"models": rows, "robust_threshold_pct": bank.manifest["robust_threshold_pct"],
                          "distance": bank.manifest["distance"]}))
        return 0
    print(f"NARX-SP bank: {len(rows)} models; distance {bank.manifest['distance']}; robust = "
          f"free-run RMSE <= {bank.manifest['robust_threshold_pct']:g} % of span")
    print(f"{'model':<22}{'S':>6}{'J':>7}  {'class':<11}{'1-step':>9}{'free-run':>10}"
          f"{'train s':>9}{'robust r':>10}")
    for r in rows:
        print(f"{r['model']:<22}{r['S']:>6g}{r['J']:>7g}  {r['class']:<11}{r['rmse_one_step']:>9.4f}"
              f"{r['rmse_free_run']:>10.4f}{r['train_s']:>9.1f}{r['robust_radius']:>10.2f}")
    return 0


def _map_figure(bank, path) -> None:
    """Free-run RMSE maps of the bank models for the paper's base cases, robust region outlined."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    from ...narx.bank import MAP_J, MAP_S
    from .reproduce import savefig
    thr = bank.manifest["robust_threshold_pct"]
    S, J = np.asarray(MAP_S), np.asarray(MAP_J)
    fig, axes = plt.subplots(1, 4, figsize=(15, 3.9), sharey=True)
    for ax, (Sb, Jb) in zip(axes, [(1.0, 0.0), (1.0, 1.0), (1.0, 3.0), (3.0, 1.0)]):
        m = bank.models[[i for i, mm in enumerate(bank.models)
                         if (mm.S_pct, mm.J_pct) == (Sb, Jb)][0]]
        ks, kj = S <= 6.0, J <= 6.0
        z = m.robust_map[np.ix_(ks, kj)].T
        im = ax.pcolormesh(S[ks], J[kj], z, vmin=0, vmax=2.0, cmap="viridis", shading="nearest")
        ax.contour(S[ks], J[kj], z, levels=[thr], colors="w", linewidths=1.5)
        ax.plot([0, 6], [0, 6], "w:", lw=0.8)
        ax.plot(Sb, Jb, "r*", ms=14)
        ax.set_title(f"{m.name} ({m.cls})", fontsize=9)
        ax.set_xlabel("plant S, % of span")
    axes[0].set_ylabel("plant J, % of span")
    fig.colorbar(im, ax=axes, label="free-run RMSE, % of span (white: robust limit)")
    fig.suptitle("Robustness maps of bank models (red star: training case)")
    savefig(fig, path)
    plt.close(fig)
