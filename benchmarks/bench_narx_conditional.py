"""Beyond the paper: one conditional NARX-SP network (S, J as inputs) against the nearest-case bank.

    python benchmarks/bench_narx_conditional.py [--n-test 40] [--seed 0]

The conditional network trains on the bank's (S, J) grid (bank training signals, 3000 samples per
case). Both are scored by free-run RMSE (% of span) on the protocol test signal (amplitude factor
max(1, (S+J)/8)) for random plants (S uniform 0.3..10, J uniform 0..min(3S, S+3), seeded) that are
mostly between bank cases, and on the bank cases themselves.
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np
import torch

from diagnose.narx.bank import bank_grid, load_bank
from diagnose.narx.conditional import ConditionalNarxSP
from diagnose.narx.metrics import rmse_pct
from diagnose.narx.protocol import bank_train_signal, signal_scale, test_signal
from diagnose.stiction_model import simulate_valve


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("--n-test", type=int, default=40)
    ap.add_argument("--seed", type=int, default=0)
    a = ap.parse_args(argv)
    torch.set_num_threads(1)
    cases = []
    for S, J in bank_grid():
        x = bank_train_signal(3000, signal_scale(S, J))
        cases.append((S, J, x, simulate_valve(x, S, J, 1)))
    t0 = time.perf_counter()
    net = ConditionalNarxSP(seed=a.seed).fit(cases)
    fit_s = time.perf_counter() - t0
    f = net.fit_
    print(f"conditional network: fit {fit_s:.1f} s; theta_s = {f.p[0]:.4f} + {f.p[1]:.4f} S + "
          f"{f.p[2]:.4f} J; c_s = {f.q[0]:.4f} + {f.q[1]:.4f} S + {f.q[2]:.4f} J; "
          f"a_m = {f.a_m:.4f}, a_s = {f.a_s:.4f}; LP margin {f.margin_pct:.2e} %")
    bank = load_bank()
    rng = np.random.default_rng(a.seed)
    S_t = rng.uniform(0.3, 10.0, a.n_test)
    J_t = np.array([rng.uniform(0.0, min(3 * s, s + 3)) for s in S_t])
    res = {"random": [], "grid": []}
    for label, pts in (("random", zip(S_t, J_t)), ("grid", bank_grid())):
        for S, J in pts:
            x = test_signal(scale=signal_scale(S, J))
            y = simulate_valve(x, S, J, 1)
            sel = bank.select(S, J)
            e_bank = rmse_pct(y, bank.free_run(sel, x, y[:2]))
            e_cond = rmse_pct(y, net.free_run(S, J, x, y[:2]))
            res[label].append((S, J, sel.distance, e_bank, e_cond))
    lines = ["| plants | n | bank free-run median | bank max | bank share <= 0.5 % | "
             "conditional median | conditional max | conditional share <= 0.5 % |",
             "|---|---|---|---|---|---|---|---|"]
    for label, rows in res.items():
        r = np.array([row[3:] for row in rows])
        lines.append(f"| {label} | {len(rows)} | {np.median(r[:, 0]):.3f} | {r[:, 0].max():.3f} | "
                     f"{100 * np.mean(r[:, 0] <= 0.5):.0f} % | {np.median(r[:, 1]):.4f} | "
                     f"{r[:, 1].max():.4f} | {100 * np.mean(r[:, 1] <= 0.5):.0f} % |")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
