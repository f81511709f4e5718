"""Test the seed paper's robustness claims against the shipped bank's robustness maps.

    python benchmarks/bench_narx_claims.py

Claim 1 (Table II, conclusion): a NARX-SP model is robust to (S, J) mismatch within its class while
stiction is below ~6 % of span. Claim 2 (Table III): across classes it is fairly robust, except
that the no-offset model has a very small margin. Reads diagnose/narx/bank/manifest.json only.
"""

from __future__ import annotations

import sys

import numpy as np

from diagnose.narx.bank import MAP_J, MAP_S, load_bank
from diagnose.narx.experiments import ROBUST_RMSE_PCT
from diagnose.stiction_model import stiction_class


def main():
    bank = load_bank()
    Sg, Jg = np.meshgrid(np.asarray(MAP_S), np.asarray(MAP_J), indexing="ij")
    cls = np.vectorize(lambda s, j: stiction_class(s, j))(Sg, Jg)
    print("| model | class | robust radius % | in-class map points with S <= 6 robust | "
          "all map points with S <= 6 robust |")
    print("|---|---|---|---|---|")
    by_class = {}
    for m in bank.models:
        ok = m.robust_map <= ROBUST_RMSE_PCT + 1e-6
        same = (cls == m.cls) & (Sg <= 6.0) & (Sg > 0)
        allp = (Sg <= 6.0) & (Sg > 0)
        by_class.setdefault(m.cls, []).append(m.robust_radius_pct)
        print(f"| {m.name} | {m.cls} | {m.robust_radius_pct:.2f} | "
              f"{ok[same].sum()}/{same.sum()} | {ok[allp].sum()}/{allp.sum()} |")
    print()
    for c, r in by_class.items():
        print(f"{c}: robust radius median {np.median(r):.2f} % (min {min(r):.2f}, max {max(r):.2f})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
