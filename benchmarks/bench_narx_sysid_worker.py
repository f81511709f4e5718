"""Worker for bench_narx_sysid.py: trains sysidentpy's NARXNN in its own environment.

Run by bench_narx_sysid.py with the sysidentpy venv's python (sysidentpy pins numpy <= 2.3.5, so it
does not live in the project's .venv):  python bench_narx_sysid_worker.py DATA.npz OUT.npz
"""

import sys
import time

import numpy as np
import torch
from sysidentpy.basis_function import Polynomial
from sysidentpy.neural_network import NARXNN
from torch import nn

torch.set_num_threads(1)


class Net(nn.Module):
    def __init__(self, hidden=20):
        super().__init__()
        self.l1 = nn.Linear(4, hidden)
        self.l2 = nn.Linear(hidden, hidden)
        self.l3 = nn.Linear(hidden, 1)

    def forward(self, z):
        return self.l3(torch.tanh(self.l2(torch.tanh(self.l1(z)))))


def shift(x):
    # sysidentpy's input lags start at 1; feed u(t) = x(t+1) so that its lags 1, 2 are x(t), x(t-1)
    return np.r_[x[1:], x[-1]]


def main(data_path, out_path):
    d = np.load(data_path)
    cases = [str(c) for c in d["cases"]]
    seeds = [int(s) for s in d["seeds"]]
    epochs = int(d["epochs"])
    out = {}
    for c in cases:
        xtr, ytr, xva, yva, xte, yte = (d[f"{c}_{k}"] for k in ("xtr", "ytr", "xva", "yva", "xte", "yte"))
        n = lambda v: ((v - 50.0) / 10.0).reshape(-1, 1)
        for s in seeds:
            torch.manual_seed(s)
            np.random.seed(s)
            m = NARXNN(net=Net().float(), ylag=2, xlag=2, basis_function=Polynomial(degree=1),
                       model_type="NARMAX", loss_func="mse_loss", optimizer="Adam", epochs=epochs,
                       batch_size=100, learning_rate=0.01, verbose=False, random_state=s)
            t0 = time.perf_counter()
            m.fit(X=n(shift(xtr)), y=n(ytr), X_test=n(shift(xva)), y_test=n(yva))
            fit_s = time.perf_counter() - t0
            free = m.predict(X=n(shift(xte)), y=n(yte)).ravel() * 10.0 + 50.0
            one = m.predict(X=n(shift(xte)), y=n(yte), steps_ahead=1).ravel() * 10.0 + 50.0
            out[f"{c}_{s}_free"] = free
            out[f"{c}_{s}_one"] = one
            out[f"{c}_{s}_fit_s"] = np.array(fit_s)
            print(f"NARXNN {c} seed {s}: {fit_s:.1f} s", file=sys.stderr, flush=True)
    np.savez(out_path, **out)


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2])
