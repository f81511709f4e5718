"""NARX-SP (this package) against sysidentpy's NARXNN on the fixed protocol (narx-protocol.md).

    python benchmarks/bench_narx_sysid.py [--venv /work/venv-sysid] [--seeds 3] [--epochs 200]
                                          [--md /tmp/narx_sysid.md]

``--md`` replaces the whole file with the table: docs/_bench_narx.md holds more than this table,
so write elsewhere and merge the figures into it by hand.

sysidentpy pins numpy <= 2.3.5, so it runs in its own environment, created once with
    python3 -m venv /work/venv-sysid && /work/venv-sysid/bin/pip install sysidentpy "numpy<=2.3.5" torch
Both models are trained and scored in the same run on the same data; RMSE in % of span over test
samples 10..1999; medians over seeds. NARXNN gets the same regressors (y(t-1), y(t-2), x(t), x(t-1)),
standardised inputs/outputs, a 4-20-20-1 tanh network, Adam, and the validation signal as its
X_test. Timings are wall-clock on whatever else the machine is doing: compare within one run.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time

import numpy as np
import torch

from diagnose.narx.metrics import rmse_pct
from diagnose.narx.networks import NarxSP
from diagnose.narx.protocol import CASES, make_dataset

HERE = os.path.dirname(os.path.abspath(__file__))


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("--venv", default="/work/venv-sysid")
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--epochs", type=int, default=200)
    ap.add_argument("--md", default=None, help="write the markdown table here too, replacing the file "
                    "(not docs/_bench_narx.md: merge into it by hand)")
    a = ap.parse_args(argv)
    py = os.path.join(a.venv, "bin", "python")
    if not os.path.exists(py):
        print(f"no sysidentpy environment at {a.venv}; create it with:\n  python3 -m venv {a.venv} "
              f"&& {a.venv}/bin/pip install sysidentpy 'numpy<=2.3.5' torch", file=sys.stderr)
        return 2
    torch.set_num_threads(1)
    seeds = list(range(a.seeds))
    data = {"cases": np.array(list(CASES)), "seeds": np.array(seeds), "epochs": np.array(a.epochs)}
    dsets = {}
    for c, (S, J) in CASES.items():
        ds = make_dataset(S, J)
        dsets[c] = ds
        for k, v in (("xtr", ds.x_train), ("ytr", ds.y_train), ("xva", ds.x_val), ("yva", ds.y_val),
                     ("xte", ds.x_test), ("yte", ds.y_test)):
            data[f"{c}_{k}"] = v
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        dpath, opath = os.path.join(tmp, "data.npz"), os.path.join(tmp, "out.npz")
        np.savez(dpath, **data)
        t0 = time.perf_counter()
        subprocess.run([py, os.path.join(HERE, "bench_narx_sysid_worker.py"), dpath, opath], check=True)
        print(f"NARXNN total {time.perf_counter() - t0:.0f} s", file=sys.stderr)
        res = dict(np.load(opath))
    for c, ds in dsets.items():
        ours, theirs = [], []
        for s in seeds:
            net = NarxSP(seed=s).fit(ds.x_train, ds.y_train, ds.x_val, ds.y_val)
            ours.append((rmse_pct(ds.y_test, net.predict_one_step(ds.x_test, ds.y_test)),
                         rmse_pct(ds.y_test, net.free_run(ds.x_test, ds.y_test[:2])), net.fit_time_s_))
            theirs.append((rmse_pct(ds.y_test, res[f"{c}_{s}_one"]), rmse_pct(ds.y_test, res[f"{c}_{s}_free"]),
                           float(res[f"{c}_{s}_fit_s"])))
        o, t = np.median(ours, axis=0), np.median(theirs, axis=0)
        rows.append((c, t, o, [x[1] for x in theirs]))
    lines = [f"NARX-SP (gated, this package) vs sysidentpy NARXNN ({a.epochs} epochs), protocol test "
             f"signal, median of {a.seeds} seeds, RMSE % of span",
             "",
             "| case | NARXNN one-step | NARXNN free-run (per seed) | NARXNN train s | NARX-SP one-step "
             "| NARX-SP free-run | NARX-SP train s | free-run ratio |",
             "|---|---|---|---|---|---|---|---|"]
    for c, t, o, per in rows:
        ratio = t[1] / max(o[1], 1e-12)
        lines.append(f"| {c} | {t[0]:.4f} | {t[1]:.3f} ({', '.join(f'{v:.2f}' for v in per)}) | "
                     f"{t[2]:.1f} | {o[0]:.2g} | {o[1]:.2g} | {o[2]:.1f} | "
                     f"{'>1e6' if ratio > 1e6 else f'{ratio:.0f}'}x |")
    text = "\n".join(lines)
    print(text)
    if a.md:
        from connectors.historian import atomic_write
        atomic_write(a.md, text + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
