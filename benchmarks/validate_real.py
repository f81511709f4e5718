"""Validation of `diagnose.identification` on the real and third-party loop data in ../shared/data.

* plant-dcs-stictiongpt: the stiction verdict on every plant window against the plant engineers'
  label; balanced accuracy per window, weighted so that each tag counts once (one valve holds 23 of
  the 27 stiction windows), and per tag (majority verdict of its windows);
* isdb-subset: the verdict and class against the published comments;
* tennessee-eastman: the reactor cooling-water loop with IDV(14) (valve law about S = J = 2 %),
  the normal run d00 and the condenser loop with IDV(15);
* damadics-lublin: the valve fitted directly on OP -> stem position MV.

Files are read here with the csv module (their layouts are known) so the numbers do not depend on
the connectors' format detection. Run:  python benchmarks/validate_real.py [--data DIR] [--json F]
"""

from __future__ import annotations

import argparse
import csv
import json
import sys
import time
from collections import defaultdict
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from diagnose.identification import identify  # noqa: E402
from diagnose.record import LoopRecord  # noqa: E402

DEFAULT_DATA = Path(__file__).resolve().parents[2] / "shared" / "data"


def read_columns(path: Path) -> dict[str, np.ndarray]:
    """The numeric columns of a CSV file by header name (a cell that is not a number is NaN)."""
    with open(path, newline="", encoding="utf-8-sig") as fh:
        rows = list(csv.reader(fh))
    header = rows[0]
    out = {}
    for j, name in enumerate(header):
        vals = []
        for r in rows[1:]:
            try:
                vals.append(float(r[j]))
            except (ValueError, IndexError):
                vals.append(np.nan)
        out[name] = np.asarray(vals)
    return out


def _finite_rows(*cols):
    m = np.ones(cols[0].shape[0], bool)
    for c in cols:
        m &= np.isfinite(c)
    return m


def _run(rec: LoopRecord) -> tuple[dict, float]:
    t0 = time.perf_counter()
    try:
        d = identify(rec).to_dict()
    except Exception as exc:  # noqa: BLE001 - report, do not stop the validation
        d = {"error": f"{type(exc).__name__}: {exc}", "stiction": None, "class": None}
    return d, time.perf_counter() - t0


def balanced_accuracy(truth: list[bool], pred: list[bool], weights: list[float] | None = None) -> float:
    t = np.asarray(truth, bool)
    p = np.asarray(pred, bool)
    w = np.ones(t.shape) if weights is None else np.asarray(weights, float)
    tpr = float(np.sum(w * (t & p)) / max(np.sum(w * t), 1e-12))
    tnr = float(np.sum(w * (~t & ~p)) / max(np.sum(w * ~t), 1e-12))
    return 0.5 * (tpr + tnr)


def plant_windows(data: Path, verbose: bool) -> dict:
    base = data / "plant-dcs-stictiongpt"
    labels = list(csv.DictReader(open(base / "labels.csv", encoding="utf-8")))
    rows = []
    for lab in labels:
        path = base / "loops" / lab["file"].replace(".txt", ".csv")
        c = read_columns(path)
        m = _finite_rows(c["OP"], c["PV"])
        sp = c.get("SP")
        rec = LoopRecord(name=lab["tag"], ts_s=float(lab["sampling_time_s"]), op=c["OP"][m], pv=c["PV"][m],
                         sp=sp[m] if sp is not None and np.all(np.isfinite(sp[m])) else None,
                         source=str(path))
        d, dt = _run(rec)
        row = {"file": path.name, "tag": lab["tag"], "type": lab["loop_type"], "label": lab["label"],
               "stiction": d.get("stiction"), "class": d.get("class"), "S": d.get("S"), "J": d.get("J"),
               "confidence": d.get("confidence"), "improvement": (d.get("detection") or {}).get("improvement"),
               "t_stat": (d.get("detection") or {}).get("t_stat"), "r2": (d.get("fit") or {}).get("r2"),
               "insample": (d.get("detection") or {}).get("insample_improvement"),
               "S_fit": (d.get("detection") or {}).get("fitted_S_pct"),
               "J_fit": (d.get("detection") or {}).get("fitted_J_pct"),
               # how many times the fitted valve slips: S, J and the class need three (fitting.md)
               "slips": next(((e.get("extras") or {}).get("slips") for e in d.get("evidence") or []
                              if e.get("test") == "valve_band"), None),
               "oscillating": (d.get("oscillation") or {}).get("oscillating"), "error": d.get("error"),
               "time_s": dt, "n": rec.n}
        rows.append(row)
        if verbose:
            print(f"{row['tag']:32s} {row['label']:12s} -> {str(row['stiction']):5s} {str(row['class']):10s} "
                  f"S={row['S'] if row['S'] is None else round(row['S'], 2)} "
                  f"imp={row['improvement'] if row['improvement'] is None else round(row['improvement'], 3)} "
                  f"{dt:.2f}s {row['error'] or ''}", flush=True)
    ok = [r for r in rows if r["stiction"] is not None]
    truth = [r["label"] == "stiction" for r in ok]
    pred = [bool(r["stiction"]) for r in ok]
    per_tag = defaultdict(list)
    for r in ok:
        per_tag[r["tag"]].append(r)
    w = [1.0 / len(per_tag[r["tag"]]) for r in ok]
    tag_truth, tag_pred = [], []
    for tag, rs in per_tag.items():
        tag_truth.append(sum(r["label"] == "stiction" for r in rs) * 2 > len(rs))
        tag_pred.append(sum(bool(r["stiction"]) for r in rs) * 2 > len(rs))
    tp = sum(t and p for t, p in zip(truth, pred))
    tn = sum((not t) and (not p) for t, p in zip(truth, pred))
    return {"windows": len(rows), "errors": len(rows) - len(ok),
            "balanced_accuracy_windows": balanced_accuracy(truth, pred),
            "balanced_accuracy_tag_weighted": balanced_accuracy(truth, pred, w),
            "balanced_accuracy_tags": balanced_accuracy(tag_truth, tag_pred),
            "tags": len(per_tag), "stiction_tags": int(sum(tag_truth)),
            "confusion": {"tp": tp, "fn": sum(truth) - tp, "tn": tn, "fp": len(truth) - sum(truth) - tn},
            "time_s_median": float(np.median([r["time_s"] for r in rows])), "rows": rows}


def isdb(data: Path, verbose: bool) -> dict:
    base = data / "isdb-subset"
    labels = list(csv.DictReader(open(base / "labels.csv", encoding="utf-8")))
    rows = []
    for lab in labels:
        c = read_columns(base / f"{lab['loop']}.csv")
        rec = LoopRecord(name=lab["loop"], ts_s=float(lab["sampling_time_s"]), op=c["OP"], pv=c["PV"])
        d, dt = _run(rec)
        row = {"loop": lab["loop"], "label": lab["label"] or "(none)", "stiction": d.get("stiction"),
               "probability": d.get("stiction_probability"), "class": d.get("class"), "S": d.get("S"), "J": d.get("J"), "confidence": d.get("confidence"),
               "improvement": (d.get("detection") or {}).get("improvement"),
               "oscillation_period_s": (d.get("oscillation") or {}).get("period_s"),
               "warnings": [w["code"] for w in d.get("warnings", [])], "error": d.get("error"), "time_s": dt}
        rows.append(row)
        if verbose:
            print(row, flush=True)
    return {"rows": rows}


def tennessee(data: Path, verbose: bool) -> dict:
    base = data / "tennessee-eastman"
    rows = []
    for name, onset in [("d14_te_loop_reactorCW_XMV10_XMEAS21", 160), ("d14_loop_reactorCW_XMV10_XMEAS21", 0),
                        ("d00_te_loop_reactorCW_XMV10_XMEAS21", 0), ("d00_loop_reactorCW_XMV10_XMEAS21", 0),
                        ("d15_te_loop_condenserCW_XMV11_XMEAS17", 160), ("d00_te_loop_condenserCW_XMV11_XMEAS17", 0)]:
        c = read_columns(base / f"{name}.csv")
        op, pv = c["OP"][onset:], c["PV"][onset:]
        rec = LoopRecord(name=name, ts_s=180.0, op=op, pv=pv)
        d, dt = _run(rec)
        row = {"file": name, "from_sample": onset, "n": int(op.shape[0]), "stiction": d.get("stiction"),
               "class": d.get("class"), "S": d.get("S"), "J": d.get("J"), "S_interval": d.get("S_interval"),
               "J_interval": d.get("J_interval"), "fitted_S_J": [(d.get("detection") or {}).get("fitted_S_pct"),
                                                           (d.get("detection") or {}).get("fitted_J_pct")],
               "confidence": d.get("confidence"),
               "improvement": (d.get("detection") or {}).get("improvement"), "error": d.get("error"),
               "time_s": dt}
        rows.append(row)
        if verbose:
            print(row, flush=True)
    return {"rows": rows}


def damadics(data: Path, verbose: bool) -> dict:
    from diagnose.valve_fit import fit_valve

    path = data / "damadics-lublin" / "lublin_actuator3_2001-10-11_1h.csv"
    c = read_columns(path)
    m = _finite_rows(c["OP"], c["MV"])
    op, mv = c["OP"][m], c["MV"][m]
    t0 = time.perf_counter()
    vf = fit_valve(op, mv, 1.0)
    dt = time.perf_counter() - t0
    rec = LoopRecord(name="DAMADICS-A3", ts_s=1.0, op=op, pv=c["PV_flow_F_t_per_h"][m], mv=mv)
    d, dt2 = _run(rec)
    out = {"valve_fit": {k: (list(v) if isinstance(v, tuple) else v) for k, v in vf.to_dict().items()},
           "valve_fit_time_s": dt, "identify": {k: d.get(k) for k in ("stiction", "class", "S", "J", "S_interval",
                                                                        "J_interval", "method", "confidence")},
           "identify_time_s": dt2, "op_range": [float(op.min()), float(op.max())],
           "mv_minus_op_median": float(np.median(mv - op))}
    if verbose:
        print(json.dumps(out, default=float), flush=True)
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", default=str(DEFAULT_DATA))
    ap.add_argument("--json", help="write all results to this JSON file")
    ap.add_argument("--quiet", action="store_true")
    ap.add_argument("--only", choices=["plant", "isdb", "te", "damadics"], action="append")
    args = ap.parse_args(argv)
    data = Path(args.data)
    parts = args.only or ["plant", "isdb", "te", "damadics"]
    out = {}
    fns = {"plant": plant_windows, "isdb": isdb, "te": tennessee, "damadics": damadics}
    for p in parts:
        out[p] = fns[p](data, not args.quiet)
    summary = {}
    if "plant" in out:
        summary["plant"] = {k: v for k, v in out["plant"].items() if k != "rows"}
    print(json.dumps(summary, indent=2, default=float))
    if args.json:
        Path(args.json).write_text(json.dumps(out, indent=1, default=float))
    return 0


if __name__ == "__main__":
    sys.exit(main())
