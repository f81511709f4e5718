"""The file reader (`connectors.read_records`) against a baseline reader from git, in the same run.

Two checks, each running the current reader and the baseline (the `connectors/` package of git
revision ``--baseline``, unpacked into a temporary folder) in separate subprocesses:

``compare``
    Reads every connector test fixture and every file of ``/work/shared/data`` (and the vendor
    variants the tests build) with both readers, and compares the records field by field (names,
    sample period, start, findings, meta, arrays bit for bit) and errors message by message; then
    a seeded differential fuzz (``--fuzz N`` random CSVs in every layout): both readers must raise,
    or return equal records. Prints a Markdown table with the read times of both readers.

``large``
    Generates seeded exports of ``--rows`` rows (long/tall and wide layouts, about 50 bytes per
    row: 3 M rows is about 150 MB), reads each with both readers under ``/usr/bin/time -v`` (wall
    time, peak resident memory), the baseline with a time limit (``--baseline-timeout``), and then
    diagnoses the records read (`diagnose.identification.identify`, timed apart from reading).

    python benchmarks/bench_read.py compare --fuzz 400
    python benchmarks/bench_read.py large --rows 3000000 --md /tmp/read_large.md

``--md`` replaces the whole file with the table; the figures go into docs/_bench_connectors.md
by hand (it holds more than this table).
"""

from __future__ import annotations

import argparse
import io
import json
import os
import pickle
import re
import subprocess
import sys
import tarfile
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
from benchmarks.machine import cpu_model  # noqa: E402
FIXTURES = ROOT / "tests" / "data_connectors"
SHARED = Path("/work/shared/data")
#: The last revision with the hand-written reader (before connectors/ moved onto pandas).
BASELINE = "771abd294b05d48c236fe213c858c36d360ea304"


# ------------------------------------------------------------------------------------------ helpers

def baseline_tree(rev: str, dest: Path) -> Path:
    """Unpack ``connectors/`` of git revision ``rev`` into ``dest`` (returned, for PYTHONPATH)."""
    data = subprocess.run(["git", "-C", str(ROOT), "archive", "--format=tar", rev, "connectors"],
                          check=True, capture_output=True).stdout
    with tarfile.open(fileobj=io.BytesIO(data)) as tf:
        tf.extractall(dest, filter="data")
    return dest


def baseline_package(rev: str, dest: Path) -> str:
    """The baseline reader importable beside the current one, as package ``connectors_baseline``."""
    baseline_tree(rev, dest)
    pkg = dest / "connectors_baseline"
    (dest / "connectors").rename(pkg)
    for f in pkg.glob("*.py"):
        text = f.read_text()
        text = re.sub(r"\b(from|import) connectors\b", r"\1 connectors_baseline", text)
        f.write_text(text)
    return "connectors_baseline"


def interleaved_times(cases: list[dict], dest: Path, rev: str, reps: int) -> list[tuple[float, float]]:
    """(baseline, current) read time of each case: the fastest of ``reps`` runs, the two readers
    alternating case by case in this process, so that both see the same machine load."""
    import importlib

    import connectors as current
    from diagnose.errors import ConnectorError

    sys.path.insert(0, str(dest))
    baseline = importlib.import_module(baseline_package(rev, dest))
    out = []
    for case in cases:
        best = [float("inf"), float("inf")]
        for _ in range(reps):
            for i, mod in enumerate((baseline, current)):
                src = case["source"] if "source" in case else io.BytesIO(case["bytes"].encode("latin-1"))
                t0 = time.perf_counter()
                try:
                    mod.read_records(src, **(case.get("options") or {}))
                except ConnectorError:
                    pass
                best[i] = min(best[i], time.perf_counter() - t0)
        out.append((best[0], best[1]))
    return out


def run_worker(impl_path: Path | None, cases: list[dict], out: Path, timeout: float | None = None,
               measure: bool = False) -> dict:
    """Read ``cases`` in a subprocess with the reader at ``impl_path`` (None: the current one)."""
    env = dict(os.environ)
    if impl_path is not None:
        env["PYTHONPATH"] = os.pathsep.join([str(impl_path), str(ROOT)])
    else:
        env["PYTHONPATH"] = str(ROOT)
    case_file = out.with_suffix(".cases.json")
    case_file.write_text(json.dumps(cases))
    cmd = [sys.executable, str(Path(__file__).resolve()), "_worker", str(case_file), str(out)]
    if measure:
        cmd = ["/usr/bin/time", "-v"] + cmd
    t0 = time.perf_counter()
    try:
        proc = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=timeout)
    except subprocess.TimeoutExpired:
        return {"ok": False, "timeout": True, "wall_s": time.perf_counter() - t0}
    wall = time.perf_counter() - t0
    res = {"ok": proc.returncode == 0, "timeout": False, "wall_s": wall, "stderr": proc.stderr,
           "returncode": proc.returncode}
    m = re.search(r"Maximum resident set size \(kbytes\): (\d+)", proc.stderr)
    if m:
        res["max_rss_mib"] = int(m.group(1)) / 1024.0
    if proc.returncode == 0 and out.exists():
        with open(out, "rb") as fh:
            res["results"] = pickle.load(fh)
    return res


def _record_dict(rec) -> dict:
    return {"name": rec.name, "ts_s": rec.ts_s, "start": rec.start, "n": rec.n,
            "op": np.asarray(rec.op), "pv": np.asarray(rec.pv),
            "sp": None if rec.sp is None else np.asarray(rec.sp),
            "mv": None if rec.mv is None else np.asarray(rec.mv),
            "units": dict(rec.units), "ranges": {k: tuple(v) for k, v in rec.ranges.items()},
            "findings": [f.to_dict() for f in rec.findings], "source": rec.source, "meta": dict(rec.meta)}


def worker(case_file: str, out: str) -> None:
    """Read every case; store records (or the error line) and the time each read took."""
    import connectors
    from diagnose.errors import ConnectorError

    cases = json.loads(Path(case_file).read_text())
    results = []
    for case in cases:
        opts = dict(case.get("options") or {})
        src = case["source"] if "source" in case else io.BytesIO(case["bytes"].encode("latin-1"))
        t0 = time.perf_counter()
        try:
            recs = connectors.read_records(src, **opts)
            item = {"records": [_record_dict(r) for r in recs]}
        except ConnectorError as exc:
            item = {"error": str(exc), "error_type": type(exc).__name__}
        except Exception as exc:  # noqa: BLE001 - reported as a difference, not raised
            item = {"crash": f"{type(exc).__name__}: {exc}"}
        item["read_s"] = time.perf_counter() - t0
        item["id"] = case["id"]
        if case.get("identify") and "records" in item:
            from diagnose.identification import identify

            for r in recs:
                t1 = time.perf_counter()
                identify(r)
                item.setdefault("identify_s", []).append(time.perf_counter() - t1)
        if case.get("drop_arrays") and "records" in item:
            for r in item["records"]:
                for k in ("op", "pv", "sp", "mv"):
                    if r[k] is not None:
                        r[k] = (r[k].size, float(np.sum(r[k])))
        results.append(item)
    item_meta = {"connectors_file": connectors.__file__}
    with open(out, "wb") as fh:
        pickle.dump({"meta": item_meta, "items": results}, fh)


# ------------------------------------------------------------------------------------------ compare

def _fixture_cases() -> list[dict]:
    tagmap = str(FIXTURES / "tagmap_historian.toml")
    cases = []
    for f in sorted(FIXTURES.iterdir()):
        if f.suffix not in (".csv", ".txt", ".tsv"):
            continue
        cases.append({"id": f"fixture:{f.name}", "source": str(f)})
        cases.append({"id": f"fixture:{f.name} tz=Europe/Berlin", "source": str(f),
                      "options": {"tz": "Europe/Berlin"}})
    h = str(FIXTURES / "historian_FIC211_trim.csv")
    cases.append({"id": "fixture:historian tags", "source": h, "options": {"tags": tagmap}})
    cases.append({"id": "fixture:historian op/pv", "source": h, "options": {"op": "FV_211", "pv": "FT_211"}})
    cases.append({"id": "fixture:historian op range", "source": h,
                  "options": {"tags": {"loops": {"FIC211": {"op": {"tag": "FV_211", "range": [20, 70]},
                                                            "pv": "FT_211"}}}}})
    d = str(FIXTURES / "wide_tab_dst_berlin.tsv")
    for dst in ("earliest", "latest", "raise"):
        cases.append({"id": f"fixture:dst {dst}", "source": d, "options": {"tz": "Europe/Berlin", "dst": dst}})
    cases.append({"id": "fixture:folder+tags", "source": str(FIXTURES), "options": {"tags": tagmap}})
    cases.append({"id": "fixture:isdb+tags", "source": str(FIXTURES / "isdb_PAP2_trim.csv"),
                  "options": {"tags": tagmap}})
    return cases


def _variant_cases() -> list[dict]:
    """Vendor variants built in memory (as the connector tests build them)."""
    n = 40
    texts = {
        "two-row ragged": ["FIC1.OP,,FIC1.PV,", "Timestamp,Value,Timestamp,Value"] + [
            f"27-Nov-2024 10:{k:02d}:00,{50 + k % 5},27-Nov-2024 10:{k:02d}:30,{20 + k % 3}" for k in range(n)],
        "german date+time": ["Datum;Zeit;FIC2.OP;FIC2.PV"] + [
            f"27.11.2024;10:{k:02d}:00;{50 + k % 5},5;{20 + k % 3},25" for k in range(n)],
        "quoted thousands": ['"time","FIC3.OP","FIC3.PV"'] + [
            f'"2024-11-27 10:{k:02d}:00","{50 + k % 5}.5","1,{200 + k}.5"' for k in range(n)],
        "many loops": ["time,A.OP,A.PV,B.OUT,B.MEAS,B.SP"] + [
            f"{k},{k % 7},{k % 5},{k % 3},{k % 11},1" for k in range(100)],
        "prefix rule": ["t,OP,MV,PV_flow_t_h,P1"] + [f"{k},{k % 9},{k % 9},{k % 4},1" for k in range(50)],
        "us dates pm": ["Timestamp,L.OP,L.PV"] + [
            f"11/27/2024 {1 + k // 60}:{k % 60:02d}:00 PM,{50 + k % 4},{k % 3}" for k in range(120)],
        "epoch ms": ["time,L.OP,L.PV"] + [f"{1732751940000 + 1000 * k},{50 + k % 4},{k % 3}" for k in range(60)],
        "excel serial": ["Timestamp,L.OP,L.PV"] + [f"{45623.5 + k / 1440:.8f},{50 + k % 4},{k % 3}" for k in range(60)],
        "offsets": ["time,L.OP,L.PV"] + [f"2024-11-27T10:{k:02d}:00+01:00,{50 + k % 4},{k % 3}" for k in range(60)],
        "pi flags": ["Tag,Timestamp,Value,Questionable,Substituted"] + [
            line for k in range(60) for line in (
                f"L1.OP,2024-03-01T08:{k:02d}:00Z,{50 + k % 4},{'True' if k == 10 else 'False'},False",
                f"L1.PV,2024-03-01T08:{k:02d}:00Z,{20 + k % 3},False,{'True' if k in (20, 21) else 'False'}")],
        "ip21 status text states": ["Tag,Timestamp,Value,Status"] + [
            line for k in range(60) for line in (
                f"L1.OP,2024-03-01 08:{k:02d}:00,{'Comm Fail' if k == 7 else 50 + k % 4},0",
                f"L1.PV,2024-03-01 08:{k:02d}:00,{20 + k % 3},{1 if k == 9 else 0}")],
        "dst spring local": ["time\tL.OP\tL.PV"] + [
            f"2024-03-31 {1 + (k // 60)}:{k % 60:02d}:00\t{50 + k % 4}\t{k % 3}" for k in range(180)],
        "comments and id": ["# exported by X", "# units: %", "id,time,L.OP,L.PV"] + [
            f"{k},2024-01-01 00:{k // 60:02d}:{k % 60:02d},{50 + k % 4},{k % 3}" for k in range(90)],
        "newest first seconds": ["t,OP,PV"] + [f"{k},{k % 7},{k % 5}" for k in range(99, -1, -1)],
        "cp1252 header": ["time,Temp °C.PV,Temp °C.OP"] + [f"{k},{k % 7},{k % 5}" for k in range(60)],
        "duplicates and gap": ["time_s,OP,PV"] + [f"{k if k < 50 else k + 100},{k % 7},{k % 5}" for k in range(120)]
        + ["10,1,1", "11,2,2"],
        "mode text": ["Timestamp\tT.OP\tT.PV\tT.MODE"] + [
            f"2024-05-01 00:{k // 60:02d}:{k % 60:02d}\t{50 + k % 4}\t{k % 3}\t{'MAN' if 20 <= k < 40 else 'AUTO'}"
            for k in range(120)],
    }
    out = []
    for name, lines in texts.items():
        data = "\n".join(lines) + "\n"
        enc = "cp1252" if "cp1252" in name else "utf-8"
        out.append({"id": f"variant:{name}", "bytes": data.encode(enc).decode("latin-1")})
    return out


def _shared_cases() -> list[dict]:
    cases = []
    if not SHARED.exists():
        return cases
    tagmap = str(FIXTURES / "tagmap_historian.toml")
    for f in sorted((SHARED / "plant-dcs-stictiongpt" / "raw").glob("*.txt")):
        cases.append({"id": f"dcs-raw:{f.name}", "source": str(f)})
    for f in sorted((SHARED / "plant-dcs-stictiongpt" / "loops").glob("*.csv")):
        cases.append({"id": f"dcs-loops:{f.name}", "source": str(f)})
    for f in sorted((SHARED / "historian-exports").glob("*.csv")):
        cases.append({"id": f"historian:{f.name}", "source": str(f), "options": {"tags": tagmap}})
        cases.append({"id": f"historian:{f.name} Berlin", "source": str(f),
                      "options": {"tags": tagmap, "tz": "Europe/Berlin"}})
    for sub in ("isdb-subset", "damadics-lublin", "tennessee-eastman"):
        for f in sorted((SHARED / sub).glob("*.csv")):
            if f.name != "labels.csv":
                cases.append({"id": f"{sub}:{f.name}", "source": str(f)})
    return cases


_CELLS = ["", "Bad", "I/O Timeout", "1.#QNAN", "12,5", "2024-01-01 00:00:00", "27-Nov-2024 23:59:00", '"',
          "NaN", "-", "1e309", "nan", "inf", "NULL", "192", "0", "Good", "AUTO", "MAN", " ", "1,234.5",
          "2024-10-27 02:30:00", "2024-03-01T08:00:00Z", "1732751940", "45623.5"]
_HEADERS = ["time", "OP", "PV", "SP", "FIC1.OP", "FIC1.PV", "Tag", "Value", "Timestamp", "date", "_time",
            "_value", "Quality", "x", "MODE", "t"]


def _fuzz_cases(n: int, seed: int) -> list[dict]:
    """Random CSVs like the connector tests' structured fuzzing, plus well-formed ones with noise."""
    rng = np.random.default_rng(seed)
    out = []
    for i in range(n):
        kind = rng.integers(3)
        sep = [",", ";", "\t"][rng.integers(3)]
        if kind == 0:   # structured junk
            header = [_HEADERS[j] for j in rng.integers(len(_HEADERS), size=rng.integers(1, 7))]
            rows = []
            for _ in range(rng.integers(0, 40)):
                cells = []
                for _ in range(rng.integers(0, 8)):
                    r = rng.random()
                    if r < 0.5:
                        cells.append(repr(float(rng.normal(50, 30))))
                    elif r < 0.9:
                        cells.append(_CELLS[rng.integers(len(_CELLS))])
                    else:
                        cells.append("".join(chr(c) for c in rng.integers(32, 127, size=rng.integers(0, 6))))
                rows.append(sep.join(cells))
            text = sep.join(header) + "\n" + "\n".join(rows)
        else:           # a plausible export with random defects
            nrow = int(rng.integers(5, 120))
            cols = ["time", "L.OP", "L.PV"] + (["L.SP"] if rng.random() < 0.5 else [])
            t0 = 1_700_000_000 + int(rng.integers(0, 10**7))
            step = [1, 10, 60][rng.integers(3)]
            lines = [sep.join(cols)]
            fmt = rng.integers(4)
            for k in range(nrow):
                tt = t0 + step * k + (int(rng.integers(-step, step + 1)) if rng.random() < 0.05 else 0)
                if rng.random() < 0.03:
                    tt += int(rng.integers(0, 100 * step))
                ts = time.gmtime(tt)
                stamp = [time.strftime("%Y-%m-%d %H:%M:%S", ts), time.strftime("%Y-%m-%dT%H:%M:%SZ", ts),
                         time.strftime("%d.%m.%Y %H:%M:%S", ts), str(tt)][fmt]
                vals = []
                for _ in cols[1:]:
                    r = rng.random()
                    v = f"{rng.normal(50, 10):.4f}"
                    if sep != "," and fmt == 2:
                        v = v.replace(".", ",")
                    vals.append(v if r > 0.04 else _CELLS[rng.integers(len(_CELLS))])
                line = sep.join([stamp] + vals)
                if rng.random() < 0.01:
                    line = line.rsplit(sep, 1)[0]
                lines.append(line)
            if rng.random() < 0.3:
                lines = [lines[0]] + lines[1:][::-1]
            text = "\n".join(lines) + "\n"
        fmt_opt = [None, None, None, "wide", "long", "ragged", "influx", "dcs"][rng.integers(8)]
        opts = {"min_samples": 2}
        if fmt_opt:
            opts["fmt"] = fmt_opt
        if rng.random() < 0.2:
            opts["tz"] = "Europe/Berlin"
        out.append({"id": f"fuzz:{i}", "bytes": text.encode("utf-8").decode("latin-1"), "options": opts})
    return out


def _same(a, b) -> tuple[bool, str, float]:
    """Are two results the same? (equal, what differs, largest array difference)."""
    if "crash" in a or "crash" in b:
        return False, f"crash old={a.get('crash')} new={b.get('crash')}", 0.0
    if "error" in a or "error" in b:
        if a.get("error") == b.get("error"):
            return True, "", 0.0
        return False, f"error old={a.get('error')!r} new={b.get('error')!r}", 0.0
    ra, rb = a["records"], b["records"]
    if len(ra) != len(rb):
        return False, f"{len(ra)} vs {len(rb)} records", 0.0
    worst = 0.0
    diffs = []
    for x, y in zip(ra, rb):
        for k in x:
            if k in ("op", "pv", "sp", "mv"):
                if (x[k] is None) != (y[k] is None):
                    diffs.append(f"{k} presence")
                elif x[k] is not None:
                    if x[k].shape != y[k].shape:
                        diffs.append(f"{k} shape {x[k].shape} vs {y[k].shape}")
                    elif not np.array_equal(x[k], y[k]):
                        d = float(np.max(np.abs(x[k] - y[k])))
                        worst = max(worst, d)
                        diffs.append(f"{k} max|diff| {d:.3g}")
            elif x[k] != y.get(k):
                diffs.append(f"{k}: {x[k]!r:.200} vs {y.get(k)!r:.200}")
        for k in y:
            if k not in x:
                diffs.append(f"new key {k}")
    return not diffs, "; ".join(diffs), worst


def compare(args) -> int:
    cases = _fixture_cases() + _variant_cases() + _shared_cases()
    fuzz = _fuzz_cases(args.fuzz, args.seed) if args.fuzz else []
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        old_tree = baseline_tree(args.baseline, tmp / "old")
        res = {}
        for impl, path in (("old", old_tree), ("new", None)):
            r = run_worker(path, cases + fuzz, tmp / f"{impl}.pkl")
            if not r["ok"]:
                print(r.get("stderr", "")[-3000:], file=sys.stderr)
                return 2
            res[impl] = r
        times = interleaved_times(cases, tmp / "timing", args.baseline, args.reps)
    old, new = res["old"]["results"], res["new"]["results"]
    print(f"baseline {args.baseline[:10]} read from {old['meta']['connectors_file']}; "
          f"current from {new['meta']['connectors_file']}", file=sys.stderr)
    case_index = {c["id"]: k for k, c in enumerate(cases)}
    groups: dict[str, dict] = {}
    n_bad = 0
    for a, b in zip(old["items"], new["items"]):
        group = a["id"].split(":", 1)[0]
        g = groups.setdefault(group, {"cases": 0, "same": 0, "bitwise": 0, "errors": 0, "old_s": 0.0,
                                      "new_s": 0.0, "worst": 0.0, "records": 0})
        ok, why, worst = _same(a, b)
        if not ok:
            kind = ("both raise, other message" if "error" in a and "error" in b else
                    "baseline raises, current reads" if "error" in a else
                    "baseline reads, current raises" if "error" in b else "records differ")
            g.setdefault("kinds", {}).setdefault(kind, 0)
            g["kinds"][kind] += 1
        g["cases"] += 1
        g["same"] += ok
        g["errors"] += "error" in a
        g["records"] += len(a.get("records", []))
        if a["id"].startswith("fuzz:"):
            g["old_s"] += a["read_s"]
            g["new_s"] += b["read_s"]
        else:
            g["old_s"] += times[case_index[a["id"]]][0]
            g["new_s"] += times[case_index[a["id"]]][1]
        g["worst"] = max(g["worst"], worst)
        if not ok:
            n_bad += 1
            if args.verbose or group != "fuzz" or not ("error" in a and "error" in b):
                print(f"DIFF {a['id']}: {why}", file=sys.stderr)
    lines = [f"CPU: {cpu_model()}, {os.cpu_count()} cores; load average {os.getloadavg()[0]:.1f}; baseline "
             f"reader: git {args.baseline[:10]}; read times: the fastest of {args.reps} runs per file, the two "
             "readers alternating in one process",
             "", "| files | cases | records | errors (same message) | equal | baseline read s | current read s | "
             "baseline / current |", "|---|---|---|---|---|---|---|---|"]
    for name, g in groups.items():
        if name == "fuzz":      # for equality only: one run each, pandas' import in the first
            lines.append(f"| {name} | {g['cases']} | {g['records']} | {g['errors']} | {g['same']}/{g['cases']} "
                         "| | | |")
            continue
        ratio = g["old_s"] / g["new_s"] if g["new_s"] > 0 else float("nan")
        lines.append(f"| {name} | {g['cases']} | {g['records']} | {g['errors']} | {g['same']}/{g['cases']} | "
                     f"{g['old_s']:.2f} | {g['new_s']:.2f} | {ratio:.2f}x |")
    for name, g in groups.items():
        for kind, n in g.get("kinds", {}).items():
            lines.append(f"- {name}: {n} case(s) where {kind}")
    print("\n".join(lines))
    return 0 if n_bad == 0 else 1


# -------------------------------------------------------------------------------------------- large

def make_export(path: Path, layout: str, rows: int, seed: int = 0, stray: bool = False) -> None:
    """A seeded historian export of ``rows`` data rows (about 50 bytes each) at 1 s, naive times.

    ``wide``: ``Timestamp,UNIT1.FIC101.OP,.PV,.SP,.MODE``; ``long``: ``Tag,Timestamp,Value,Quality``
    with OP, PV and SP rows for each time. ``stray`` appends one more time a year after the rest.
    """
    rng = np.random.default_rng(seed)
    n_t = rows // 3 if layout == "long" else rows
    t0 = np.datetime64("2024-05-01T00:00:00")
    k = np.arange(n_t)
    op = 50 + 8 * np.sin(2 * np.pi * k / 600) + rng.normal(0, 0.3, n_t)
    pv = 20 + 3 * np.sign(np.sin(2 * np.pi * (k - 40) / 600)) + rng.normal(0, 0.05, n_t)
    sp = np.full(n_t, 20.0)
    stamps = np.char.replace(np.datetime_as_string(t0 + k.astype("timedelta64[s]"), unit="s"), "T", " ")
    tag = "UNIT1.FIC101"
    with open(path, "w", encoding="utf-8", newline="\n") as fh:
        block = 200_000
        if layout == "wide":
            fh.write(f"Timestamp,{tag}.OP,{tag}.PV,{tag}.SP,{tag}.MODE\n")
            for a in range(0, n_t, block):
                b = min(n_t, a + block)
                fh.write("".join(f"{s},{o:.5f},{p:.5f},{q:.3f},AUTO\n"
                                 for s, o, p, q in zip(stamps[a:b], op[a:b], pv[a:b], sp[a:b])))
        else:
            fh.write("Tag,Timestamp,Value,Quality\n")
            for a in range(0, n_t, block):
                b = min(n_t, a + block)
                fh.write("".join(f"{tag}.OP,{s},{o:.5f},192\n{tag}.PV,{s},{p:.5f},192\n{tag}.SP,{s},{q:.3f},192\n"
                                 for s, o, p, q in zip(stamps[a:b], op[a:b], pv[a:b], sp[a:b])))
        if stray:
            s = str(t0 + np.timedelta64(n_t + 365 * 86400, "s")).replace("T", " ")
            if layout == "wide":
                fh.write(f"{s},50.0,20.0,20.0,AUTO\n")
            else:
                fh.write(f"{tag}.OP,{s},50.0,192\n{tag}.PV,{s},20.0,192\n{tag}.SP,{s},20.0,192\n")


def _cli_row(f: Path, name: str, size: float, rows: int) -> str:
    """`stiction identify FILE --json` (current tree) under /usr/bin/time -v: reading and diagnosis."""
    code = "import sys; from diagnose.service.cli import main; sys.exit(main(sys.argv[1:]))"
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    t0 = time.perf_counter()
    proc = subprocess.run(["/usr/bin/time", "-v", sys.executable, "-c", code, "identify", str(f), "--json"],
                          env=env, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    m = re.search(r"Maximum resident set size \(kbytes\): (\d+)", proc.stderr)
    rss = int(m.group(1)) / 1024.0 if m else float("nan")
    progress = [ln for ln in proc.stderr.splitlines() if ln.startswith(f"{f}: ")]
    verdict = "?"
    if proc.returncode == 0:
        d = json.loads(proc.stdout.strip().splitlines()[-1])
        verdict = f"{d.get('n_samples', '?')} samples diagnosed, stiction = {d.get('stiction')}"
    return (f"| {name} | {size:.0f} | {rows} | `stiction identify` (read + diagnose) | {wall:.1f} | {rss:.0f} | "
            f"exit {proc.returncode} | {verdict} | | {len(progress)} |")


def large(args) -> int:
    out_lines = [f"CPU: {cpu_model()}, {os.cpu_count()} cores; load average at start "
                 f"{os.getloadavg()[0]:.1f}; baseline reader: git {args.baseline[:10]}", "",
                 "| export | size MB | rows | reader | read wall s | peak RSS MiB | records | samples kept | "
                 "diagnosis s | progress lines |", "|---|---|---|---|---|---|---|---|---|---|"]
    with tempfile.TemporaryDirectory(dir=args.tmp) as tmp:
        tmp = Path(tmp)
        old_tree = baseline_tree(args.baseline, tmp / "old")
        for layout in args.layouts.split(","):
            for stray in ([False, True] if args.stray else [False]):
                f = tmp / f"export_{layout}{'_stray' if stray else ''}.csv"
                make_export(f, layout, args.rows, seed=args.seed, stray=stray)
                size = f.stat().st_size / 1e6
                name = f"{layout}{' + 1 stray row a year later' if stray else ''}"
                for impl, path in (("baseline", old_tree), ("current", None)):
                    if impl == "baseline" and args.no_baseline:
                        continue
                    case = [{"id": name, "source": str(f), "identify": impl == "current" and args.identify,
                             "drop_arrays": True}]
                    r = run_worker(path, case, tmp / f"{impl}.pkl", measure=True,
                                   timeout=args.baseline_timeout if impl == "baseline" else None)
                    if r.get("timeout"):
                        out_lines.append(f"| {name} | {size:.0f} | {args.rows} | {impl} | > {args.baseline_timeout:.0f} "
                                         f"(stopped) | | | | | |")
                        continue
                    if not r["ok"]:
                        err = r.get("stderr", "").strip().splitlines()
                        tail = next((ln for ln in reversed(err) if "Error" in ln), err[-1] if err else "?")
                        out_lines.append(f"| {name} | {size:.0f} | {args.rows} | {impl} | failed: {tail[:80]} | "
                                         f"{r.get('max_rss_mib', float('nan')):.0f} | | | | |")
                        continue
                    item = r["results"]["items"][0]
                    progress = [ln for ln in r["stderr"].splitlines() if ln.startswith(f"{f}: ")]
                    if "error" in item or "crash" in item:
                        out_lines.append(f"| {name} | {size:.0f} | {args.rows} | {impl} | error: "
                                         f"{(item.get('error') or item.get('crash'))[:80]} | "
                                         f"{r.get('max_rss_mib', 0):.0f} | | | | |")
                        continue
                    recs = item["records"]
                    kept = sum(rr["n"] for rr in recs)
                    ident = sum(item.get("identify_s", [])) if "identify_s" in item else None
                    out_lines.append(
                        f"| {name} | {size:.0f} | {args.rows} | {impl} | {item['read_s']:.1f} | "
                        f"{r.get('max_rss_mib', float('nan')):.0f} | {len(recs)} | {kept} | "
                        f"{'' if ident is None else f'{ident:.1f}'} | {len(progress)} |")
                    if args.show_progress and progress:
                        print("\n".join(progress), file=sys.stderr)
                if args.cli:
                    out_lines.append(_cli_row(f, name, size, args.rows))
                f.unlink()
    text = "\n".join(out_lines)
    print(text)
    if args.md:
        Path(args.md).write_text(text + "\n")
    return 0


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if argv and argv[0] == "_worker":
        worker(argv[1], argv[2])
        return 0
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = p.add_subparsers(dest="cmd", required=True)
    c = sub.add_parser("compare", help="old vs new records on every fixture and shared data file")
    c.add_argument("--fuzz", type=int, default=0, help="random CSVs for the differential fuzz")
    c.add_argument("--seed", type=int, default=0)
    c.add_argument("--verbose", action="store_true")
    c.add_argument("--reps", type=int, default=5, help="timing runs per file (the fastest counts)")
    g = sub.add_parser("large", help="a 150 MB export: time and peak memory, old vs new")
    g.add_argument("--rows", type=int, default=3_000_000)
    g.add_argument("--layouts", default="long,wide")
    g.add_argument("--stray", action="store_true", help="also each export with one row a year later")
    g.add_argument("--seed", type=int, default=0)
    g.add_argument("--identify", action=argparse.BooleanOptionalAction, default=True,
                   help="diagnose the records read by the current reader (timed apart)")
    g.add_argument("--baseline-timeout", type=float, default=600.0)
    g.add_argument("--no-baseline", action="store_true")
    g.add_argument("--show-progress", action="store_true")
    g.add_argument("--cli", action="store_true", help="also time `stiction identify FILE --json` on each export")
    g.add_argument("--tmp", default=None, help="folder for the generated exports")
    g.add_argument("--md", default=None, help="also write the table to this Markdown file")
    for q in (c, g):
        q.add_argument("--baseline", default=BASELINE, help="git revision of the baseline reader")
    args = p.parse_args(argv)
    return compare(args) if args.cmd == "compare" else large(args)


if __name__ == "__main__":
    sys.exit(main())
