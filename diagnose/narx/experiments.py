"""The seed paper's Section IV experiments under the fixed protocol (docs/reproduction.md).

Pure computation: each function returns plain rows (dicts); printing, JSON and figures are done by
``stiction reproduce``.
"""

from __future__ import annotations

import time

import numpy as np

from ..stiction_model import simulate_valve
from .metrics import cdc_pct, direction_agreement_pct, rmse_pct
from .protocol import CASES, SCORE_FROM, long_signal, make_dataset, test_signal

#: Free-run RMSE (% of span) at or below which a model counts as robust for a test plant.
ROBUST_RMSE_PCT = 0.5

#: Table I of the paper (RMSE as printed; units not stated there). None: not given.
PAPER_TABLE1 = {
    ("narxsp", "deadband"): (0.0097, 83), ("narxsp", "overshoot"): (0.0123, 83),
    ("narxsp", "no_offset"): (0.0234, 69), ("narxsp", "undershoot"): (0.0907, None),
    ("ff", "deadband"): (0.1221, 83), ("ff", "overshoot"): (0.1312, 83),
    ("ff", "no_offset"): (0.1930, 69), ("ff", "undershoot"): (0.3416, None),
    ("cascade", "deadband"): (0.1223, 83), ("cascade", "overshoot"): (0.1345, 83),
    ("cascade", "no_offset"): (0.1929, 69), ("cascade", "undershoot"): (0.3442, None),
    ("elman", "deadband"): (0.0971, 83), ("elman", "overshoot"): (0.1117, 83),
    ("elman", "no_offset"): (0.1975, 69), ("elman", "undershoot"): (0.2059, None),
    ("lrn", "deadband"): (0.1035, 83), ("lrn", "overshoot"): (0.1997, 83),
    ("lrn", "no_offset"): (0.1573, 69), ("lrn", "undershoot"): (0.206, None),
    ("narx", "deadband"): (0.1331, 83), ("narx", "overshoot"): (0.1312, 83),
    ("narx", "no_offset"): (0.1962, 69), ("narx", "undershoot"): (0.27, None),
}

#: Table II: base (S, J) -> [(test S, test J, paper verdict robust?)]
PAPER_TABLE2 = {
    (1.0, 0.0): [(5, 0, True), (4, 0, True), (3, 0, True), (2, 0, True)],
    (1.0, 1.0): [(5, 5, False), (4, 4, False), (3, 3, False), (2, 2, True)],
    (1.0, 3.0): [(1, 5, True), (1, 4, True), (1, 3, True), (1, 2, True), (2, 5, True), (2, 4, True),
                 (2, 3, True), (3, 5, True), (3, 4, True), (4, 5, True)],
    (3.0, 1.0): [(5, 4, True), (5, 3, True), (5, 2, True), (4, 3, True), (4, 2, True), (4, 1, True),
                 (3, 2, True), (2, 1, True)],
}

#: Table III: base (S, J) -> [(test S, test J, paper verdict)]
PAPER_TABLE3 = {
    (1.0, 0.0): [(1, 1, True), (1, 3, True), (3, 1, True)],
    (1.0, 1.0): [(1, 0, True), (1, 3, False), (3, 1, False)],
    (1.0, 3.0): [(1, 0, True), (1, 1, True), (3, 1, True)],
    (3.0, 1.0): [(1, 0, True), (1, 1, True), (1, 3, True)],
}

BASE_CLASS = {(1.0, 0.0): "deadband", (1.0, 1.0): "no_offset", (1.0, 3.0): "overshoot",
              (3.0, 1.0): "undershoot"}


def _torch_setup():
    import torch
    torch.set_num_threads(1)


def evaluate(net, x, y) -> dict:
    """One-step and free-run scores of a fitted network on one series (protocol scoring)."""
    one = net.predict_one_step(x, y)
    t0 = time.perf_counter()
    free = net.free_run(x, y[:2])
    run_s = time.perf_counter() - t0
    return {"rmse_one_step": rmse_pct(y, one, SCORE_FROM), "rmse_free_run": rmse_pct(y, free, SCORE_FROM),
            "cdc": cdc_pct(y, free, SCORE_FROM), "cdc_one_step": cdc_pct(y, one, SCORE_FROM),
            "direction_agreement": direction_agreement_pct(y, free, SCORE_FROM),
            "free_run_s": run_s, "_free": free, "_one": one}


def train_case(kind: str, S_pct: float, J_pct: float, seed: int = 0, **kwargs):
    """Train one network under the protocol; returns (network, dataset)."""
    from .networks import make_network
    _torch_setup()
    ds = make_dataset(S_pct, J_pct)
    net = make_network(kind, seed=seed, **kwargs).fit(ds.x_train, ds.y_train, ds.x_val, ds.y_val)
    return net, ds


def table1(networks=None, seeds=(0, 1, 2), cases=None, kwargs_by_kind=None) -> list[dict]:
    """Table I: each network x each class; medians over seeds (per-seed values under 'seeds')."""
    from .networks import PAPER_NETWORKS
    networks = tuple(networks or PAPER_NETWORKS)
    cases = tuple(cases or CASES)
    kwargs_by_kind = kwargs_by_kind or {}
    rows = []
    for case in cases:
        S, J = CASES[case]
        for kind in networks:
            per = []
            series = None
            for seed in seeds:
                net, ds = train_case(kind, S, J, seed, **kwargs_by_kind.get(kind, {}))
                ev = evaluate(net, ds.x_test, ds.y_test)
                if series is None:
                    series = {"_x": ds.x_test, "_y": ds.y_test, "_free": ev["_free"]}
                per.append({k: v for k, v in ev.items() if not k.startswith("_")}
                           | {"seed": seed, "train_s": net.fit_time_s_})
            med = {k: float(np.median([p[k] for p in per]))
                   for k in ("rmse_one_step", "rmse_free_run", "cdc", "cdc_one_step",
                             "direction_agreement", "train_s")}
            paper = PAPER_TABLE1.get((kind, case), (None, None))
            rows.append({"network": kind, "case": case, "S": S, "J": J, **med,
                         "paper_rmse": paper[0], "paper_cdc": paper[1], "seeds": per, **series})
    return rows


def _robustness(table, seed=0) -> list[dict]:
    rows = []
    for (Sb, Jb), tests in table.items():
        net, _ = train_case("narxsp", Sb, Jb, seed)
        x = test_signal()
        for St, Jt, verdict in tests:
            y = simulate_valve(x, St, Jt, 1)
            ev = evaluate(net, x, y)
            rows.append({"base_class": BASE_CLASS[(Sb, Jb)], "base_S": Sb, "base_J": Jb,
                         "test_S": float(St), "test_J": float(Jt),
                         "rmse_one_step": ev["rmse_one_step"], "rmse_free_run": ev["rmse_free_run"],
                         "cdc": ev["cdc"], "robust": bool(ev["rmse_free_run"] <= ROBUST_RMSE_PCT + 1e-6),
                         "paper_robust": verdict})
    return rows


def table2(seed: int = 0) -> list[dict]:
    """Table II: base models against other (S, J) of their own class (protocol test signal)."""
    return _robustness(PAPER_TABLE2, seed)


def table3(seed: int = 0) -> list[dict]:
    """Table III: base models against other classes (protocol test signal)."""
    return _robustness(PAPER_TABLE3, seed)


def model_mode(n: int = 10_000, S_pct: float = 3.0, J_pct: float = 1.0, seed: int = 0) -> dict:
    """Section IV-C: the NARX-SP network trained series-parallel, converted to model mode, run
    ``n`` steps on an unseen input against the stiction model (initial outputs: the plant's)."""
    net, _ = train_case("narxsp", S_pct, J_pct, seed)
    model = net.to_model_mode()
    x = long_signal(n)
    y = simulate_valve(x, S_pct, J_pct, 1)
    model.free_run(x[:100], y[:2])          # compile/warm
    t0 = time.perf_counter()
    free = model.free_run(x, y[:2])
    run_s = time.perf_counter() - t0
    return {"S": S_pct, "J": J_pct, "n": n, "rmse_free_run": rmse_pct(y, free, SCORE_FROM),
            "rmse_one_step": rmse_pct(y, model.predict_one_step(x, y), SCORE_FROM),
            "cdc": cdc_pct(y, free, SCORE_FROM), "free_run_s": run_s, "train_s": net.fit_time_s_,
            "x": x, "y": y, "y_hat": free}
