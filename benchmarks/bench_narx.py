"""Speed of the NARX-SP bank: training one model, a 10 000-step free run, the whole bank.

    python benchmarks/bench_narx.py [--full-bank]

The free run is timed for the compiled loop (what the package uses) and, as the baseline in the
same run, for the same network stepped through torch one sample at a time. Timings are wall-clock
and depend on what else the machine is doing.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time

import numpy as np
import torch

from diagnose.narx.bank import bank_grid, train_bank, train_bank_model
from diagnose.narx.metrics import rmse_pct
from diagnose.narx.networks import NarxSP
from diagnose.narx.protocol import long_signal, make_dataset
from diagnose.stiction_model import simulate_valve


def torch_step_loop(net: NarxSP, x, y0, y1):
    mod = net.module_
    out = [y0, y1]
    xt = torch.tensor(x)
    with torch.no_grad():
        for t in range(2, len(x)):
            ya, yb = out[-1], out[-2]
            d = (xt[t] - ya).reshape(1)
            dx = (xt[t] - xt[t - 1]).reshape(1)
            dy = torch.tensor([ya - yb], dtype=torch.float64)
            out.append(float(ya + mod(d, dx, dy, hard=True)[0, 0]))
    return np.asarray(out)


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("--full-bank", action="store_true", help="also time training the whole bank")
    a = ap.parse_args(argv)
    torch.set_num_threads(1)
    for S, J in ((3.0, 1.0), (10.0, 13.0)):
        t0 = time.perf_counter()
        entry, _ = train_bank_model(S, J)
        print(f"bank model S={S:g} J={J:g}: fit {entry['metrics']['train_s']:.1f} s "
              f"(with test scoring and robustness map {time.perf_counter() - t0:.1f} s), "
              f"free-run RMSE {entry['metrics']['rmse_free_run']:.2g} %")
    ds = make_dataset(3.0, 1.0)
    net = NarxSP(seed=0).fit(ds.x_train, ds.y_train, ds.x_val, ds.y_val)
    x = long_signal(10_000)
    y = simulate_valve(x, 3.0, 1.0, 1)
    net.free_run(x[:50], y[:2])
    times = []
    for _ in range(20):
        t0 = time.perf_counter()
        yh = net.free_run(x, y[:2])
        times.append(time.perf_counter() - t0)
    t0 = time.perf_counter()
    yt = torch_step_loop(net, x, y[0], y[1])
    t_torch = time.perf_counter() - t0
    print(f"10 000-step free run: compiled {1e3 * statistics.median(times):.2f} ms (median of 20), "
          f"torch per-step loop {1e3 * t_torch:.0f} ms; RMSE vs plant {rmse_pct(y, yh):.2g} %, "
          f"max |compiled - torch| {np.max(np.abs(yh - yt)):.1e} %")
    if a.full_bank:
        t0 = time.perf_counter()
        manifest, _ = train_bank(bank_grid())
        print(f"whole bank ({len(manifest['models'])} models): {time.perf_counter() - t0:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
