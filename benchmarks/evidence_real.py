"""The non-invasive stiction tests (diagnose.evidence.run_all) on the real data in ../shared/data.

* plant-dcs-stictiongpt: every window against the plant engineers' label. Per test: its decision on
  each window; sensitivity, specificity and balanced accuracy over all windows (a test that does
  not say "stiction" - no_stiction, undetermined or cannot_judge - counts as not flagging) and over
  the windows it decided (stiction or no_stiction only), each per window and with every tag
  weighted once (one valve holds 23 of the 27 stiction windows); how often it cannot judge, and why.
* isdb-subset: every loop's decisions against the published comments.

The process type comes from the tag type (LIC: integrating; FIC, PIC, PDIC, AIC: self-regulating)
and from the ISDB's own column. The published thresholds are used as they are: nothing here is
tuned on this data. Run:  python benchmarks/evidence_real.py [--data DIR] [--json OUT] [--quiet]
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import sys
import tempfile
import time
from collections import Counter, defaultdict
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks.validate_real import read_columns  # noqa: E402
from diagnose.evidence import TESTS, run_all  # noqa: E402

# the shared data sit beside the checkout (../shared/data), or one level up from a worktree
DEFAULT_DATA = next((p / "shared" / "data" for p in Path(__file__).resolve().parents[2:4]
                     if (p / "shared" / "data").is_dir()), Path(__file__).resolve().parents[2] / "shared" / "data")
SHORT = {"stiction": "STIC", "no_stiction": "no", "undetermined": "?", "cannot_judge": "-"}


def _rates(truth: np.ndarray, flag: np.ndarray, w: np.ndarray) -> dict[str, float | None]:
    pos, neg = w[truth].sum(), w[~truth].sum()
    sens = float((w * (truth & flag)).sum() / pos) if pos > 0 else None
    spec = float((w * (~truth & ~flag)).sum() / neg) if neg > 0 else None
    ba = 0.5 * (sens + spec) if sens is not None and spec is not None else None
    return {"sensitivity": sens, "specificity": spec, "balanced_accuracy": ba}


def score(rows: list[dict]) -> dict[str, dict]:
    """Per test: rates over all windows and over decided ones, per window and tag-weighted."""
    truth = np.array([r["label"] == "stiction" for r in rows])
    per_tag = Counter(r["tag"] for r in rows)
    w_tag = np.array([1.0 / per_tag[r["tag"]] for r in rows])
    out = {}
    for t in TESTS:
        dec = np.array([r["decisions"][t] for r in rows])
        flag = dec == "stiction"
        decided = (dec == "stiction") | (dec == "no_stiction")
        reasons = Counter(r["reasons"][t] for r in rows if r["decisions"][t] == "cannot_judge")
        out[t] = {
            "all_windows": _rates(truth, flag, np.ones(len(rows))),
            "all_tag_weighted": _rates(truth, flag, w_tag),
            "decided_windows": _rates(truth[decided], flag[decided], np.ones(int(decided.sum()))),
            "decided_tag_weighted": _rates(truth[decided], flag[decided], w_tag[decided]),
            "decided": int(decided.sum()), "undetermined": int((dec == "undetermined").sum()),
            "cannot_judge": int((dec == "cannot_judge").sum()), "cannot_judge_reasons": dict(reasons),
            "stiction_calls": int(flag.sum()),
        }
    return out


def plant(data: Path) -> dict:
    base = data / "plant-dcs-stictiongpt"
    labels = list(csv.DictReader(open(base / "labels.csv", encoding="utf-8")))
    rows, times = [], []
    for lab in labels:
        path = base / "loops" / lab["file"].replace(".txt", ".csv")
        c = read_columns(path)
        m = np.isfinite(c["OP"]) & np.isfinite(c["PV"])
        sp = c.get("SP")
        sp = sp[m] if sp is not None and np.all(np.isfinite(sp[m])) else None
        integrating = lab["loop_type"] == "LIC"
        t0 = time.perf_counter()
        ev = run_all(c["OP"][m], c["PV"][m], float(lab["sampling_time_s"]), sp=sp, integrating=integrating)
        times.append(time.perf_counter() - t0)
        rows.append({"file": path.name, "tag": lab["tag"], "type": lab["loop_type"], "label": lab["label"],
                     "integrating": integrating, "n": int(m.sum()),
                     "decisions": {e.test: e.decision for e in ev}, "reasons": {e.test: e.reason for e in ev},
                     "values": {e.test: e.value for e in ev}})
    return {"rows": rows, "scores": score(rows), "tags": len({r["tag"] for r in rows}),
            "stiction_tags": len({r["tag"] for r in rows if r["label"] == "stiction"}),
            "run_all_time_s_median": float(np.median(times))}


def isdb(data: Path) -> dict:
    base = data / "isdb-subset"
    rows = []
    for lab in csv.DictReader(open(base / "labels.csv", encoding="utf-8")):
        c = read_columns(base / f"{lab['loop']}.csv")
        integrating = lab["integrating"].strip().lower() == "true"
        ev = run_all(c["OP"], c["PV"], float(lab["sampling_time_s"]), integrating=integrating)
        rows.append({"loop": lab["loop"], "label": lab["label"] or "(none)", "integrating": integrating,
                     "decisions": {e.test: e.decision for e in ev}, "reasons": {e.test: e.reason for e in ev},
                     "values": {e.test: e.value for e in ev}, "notes": {e.test: e.note for e in ev}})
    return {"rows": rows}


def _fmt(x) -> str:
    return "  -  " if x is None else f"{x:5.2f}"


def report(res: dict) -> str:
    p = res["plant"]
    lines = [f"plant-dcs-stictiongpt: {len(p['rows'])} windows, {p['tags']} tags "
             f"({p['stiction_tags']} with stiction windows); run_all median {1000 * p['run_all_time_s_median']:.1f} ms"
             " per window", "", "decisions per window (STIC stiction, no, ? undetermined, - cannot judge):",
             f"{'tag':>16} {'type':4} {'label':5} " + " ".join(f"{t[:8]:>8}" for t in TESTS)]
    for r in sorted(p["rows"], key=lambda r: (r["label"], r["tag"])):
        lines.append(f"{r['tag'][-16:]:>16} {r['type']:4} {r['label'][:5]:5} "
                     + " ".join(f"{SHORT[r['decisions'][t]]:>8}" for t in TESTS))
    lines += ["", "per test; 'all': every window, not flagging = no stiction; 'decided': stiction/no_stiction only",
              f"{'test':22} {'sens':>5} {'spec':>5} {'BA':>5} | {'tag-weighted':^17} | {'decided':>7} "
              f"{'sens':>5} {'spec':>5} {'BA':>5} | {'tag-w BA':>8} | {'undet':>5} {'cannot':>6}  reasons"]
    for t, s in p["scores"].items():
        a, aw, d, dw = s["all_windows"], s["all_tag_weighted"], s["decided_windows"], s["decided_tag_weighted"]
        lines.append(f"{t:22} {_fmt(a['sensitivity'])} {_fmt(a['specificity'])} {_fmt(a['balanced_accuracy'])} | "
                     f"{_fmt(aw['sensitivity'])} {_fmt(aw['specificity'])} {_fmt(aw['balanced_accuracy'])} | "
                     f"{s['decided']:7d} {_fmt(d['sensitivity'])} {_fmt(d['specificity'])} "
                     f"{_fmt(d['balanced_accuracy'])} | {_fmt(dw['balanced_accuracy']):>8} | "
                     f"{s['undetermined']:5d} {s['cannot_judge']:6d}  "
                     + ", ".join(f"{k} {v}" for k, v in sorted(s["cannot_judge_reasons"].items())))
    lines += ["", "isdb-subset (published comment -> decisions):",
              f"{'loop':6} {'label':22} " + " ".join(f"{t[:8]:>8}" for t in TESTS)]
    for r in res["isdb"]["rows"]:
        lines.append(f"{r['loop']:6} {r['label'][:22]:22} " + " ".join(f"{SHORT[r['decisions'][t]]:>8}" for t in TESTS))
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", default=str(DEFAULT_DATA), help="folder holding the shared data sets")
    ap.add_argument("--json", help="also write the results to this JSON file")
    ap.add_argument("--quiet", action="store_true", help="print nothing")
    args = ap.parse_args(argv)
    data = Path(args.data)
    for sub in ("plant-dcs-stictiongpt", "isdb-subset"):
        if not (data / sub / "labels.csv").is_file():
            print(f"error: {data / sub / 'labels.csv'} not found; give the shared data folder with --data",
                  file=sys.stderr)
            return 1
    res = {"plant": plant(data), "isdb": isdb(data)}
    if not args.quiet:
        print(report(res))
    if args.json:
        out = Path(args.json)
        fd, tmp = tempfile.mkstemp(dir=out.parent if str(out.parent) else ".", suffix=".tmp")
        with os.fdopen(fd, "w", encoding="utf-8") as fh:
            json.dump(res, fh, indent=1)
        os.replace(tmp, out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
