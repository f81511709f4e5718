"""How far the stiction verdict on the real plant windows depends on how the window was cut.

Each labelled two-hour window of ../shared/data/plant-dcs-stictiongpt is judged as exported and in
variants an engineer's own export could differ by:

* ``first_2_3`` / ``last_2_3``: the first or the last two thirds of the window (80 minutes);
* ``every_2nd``: every second sample (the historian's interval doubled);
* ``pv_noise``: PV with added white noise of half its own sample-to-sample spread (seeded).

For each variant: sensitivity, specificity and balanced accuracy per window, and the windows whose
verdict differs from the window as exported. Nothing here tunes anything: the packaged model judges
every variant. A verdict that flips between overlapping cuts of one valve's data tells how much
evidence a window of that length holds (docs/verdict.md, Limits).

    python benchmarks/validate_real.py ...        # the windows as exported
    python benchmarks/window_stability.py [--data DIR] [--json FILE]
"""

from __future__ import annotations

import argparse
import csv
import json
import sys
import warnings
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks.validate_real import DEFAULT_DATA, _finite_rows, read_columns  # noqa: E402
from diagnose.identification import identify  # noqa: E402
from diagnose.record import LoopRecord  # noqa: E402

VARIANTS = ("as_exported", "first_2_3", "last_2_3", "every_2nd", "pv_noise")


def variant(name: str, op, pv, sp, ts_s: float, rng: np.random.Generator):
    """(op, pv, sp, ts_s) of one variant of a window."""
    n = op.shape[0]
    cut = {"first_2_3": slice(0, 2 * n // 3), "last_2_3": slice(n - 2 * n // 3, n),
           "every_2nd": slice(None, None, 2)}.get(name)
    if cut is not None:
        return op[cut], pv[cut], None if sp is None else sp[cut], ts_s * (2 if name == "every_2nd" else 1)
    if name == "pv_noise":
        return op, pv + rng.normal(0.0, 0.5 * float(np.std(np.diff(pv))) + 1e-12, n), sp, ts_s
    return op, pv, sp, ts_s


def run(data: Path) -> dict:
    base = data / "plant-dcs-stictiongpt"
    labels = list(csv.DictReader(open(base / "labels.csv", encoding="utf-8")))
    rows = []
    for i, lab in enumerate(labels):
        c = read_columns(base / "loops" / lab["file"].replace(".txt", ".csv"))
        m = _finite_rows(c["OP"], c["PV"])
        sp = c.get("SP")
        sp = sp[m] if sp is not None and np.all(np.isfinite(sp[m])) else None
        row = {"file": lab["file"], "tag": lab["tag"], "sticky": lab["label"] == "stiction"}
        for v in VARIANTS:
            op, pv, s, ts = variant(v, c["OP"][m], c["PV"][m], sp, float(lab["sampling_time_s"]),
                                    np.random.default_rng(1000 + i))
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                res = identify(LoopRecord(name=lab["tag"], ts_s=ts, op=op, pv=pv, sp=s))
            row[v] = {"stiction": bool(res.stiction), "p": round(float(res.stiction_probability), 3)}
        rows.append(row)
    summary = {}
    for v in VARIANTS:
        tp = sum(r["sticky"] and r[v]["stiction"] for r in rows)
        tn = sum(not r["sticky"] and not r[v]["stiction"] for r in rows)
        pos = sum(r["sticky"] for r in rows)
        neg = len(rows) - pos
        flips = sum(r[v]["stiction"] != r["as_exported"]["stiction"] for r in rows)
        summary[v] = {"sensitivity": f"{tp}/{pos}", "specificity": f"{tn}/{neg}",
                      "balanced_accuracy": round(0.5 * (tp / pos + tn / neg), 3),
                      "verdicts_changed": flips}
    return {"summary": summary, "rows": rows}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", default=str(DEFAULT_DATA))
    ap.add_argument("--json", help="also write every window's probabilities to this file")
    args = ap.parse_args(argv)
    out = run(Path(args.data))
    print(f"{'variant':12s} {'sensitivity':>11s} {'specificity':>11s} {'BA':>6s} {'changed':>8s}")
    for v, s in out["summary"].items():
        print(f"{v:12s} {s['sensitivity']:>11s} {s['specificity']:>11s} {s['balanced_accuracy']:6.3f} "
              f"{s['verdicts_changed']:8d}")
    by_tag: dict[str, list] = {}
    for r in out["rows"]:
        by_tag.setdefault(r["tag"], []).append(r)
    print("\nwindows whose verdict changes with the cut (p as exported -> p of each variant):")
    for r in out["rows"]:
        ps = [r[v]["p"] for v in VARIANTS]
        if len({r[v]["stiction"] for v in VARIANTS}) > 1:
            print(f"  {r['tag']:14s} {'sticky ' if r['sticky'] else 'healthy'} {ps}")
    if args.json:
        Path(args.json).write_text(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
