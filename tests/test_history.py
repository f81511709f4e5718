"""History database: default path, WAL, one transaction per write, trend, degradation, CLI."""

from __future__ import annotations

import json
import sqlite3
import subprocess
import sys
import textwrap

import pytest

from diagnose.service import history as H
from diagnose.service.cli import main


def _res(loop: str, S: float, J: float = 1.0, h: str = "h", cls: str = "undershoot", p: float = 0.9) -> dict:
    return {"loop": loop, "stiction": p >= 0.5, "stiction_probability": p, "S": S, "J": J, "S_interval": [S - 0.1, S + 0.1], "J_interval": [J - 0.1, J + 0.1],
            "class": cls, "confidence": 0.9, "severity": {"score": 10.0 * S}, "tool_version": "t",
            "input_hash": h, "verdict": "v", "record": {"start": "2026-01-01T00:00:00+00:00"}}


def _fill(db, loop, S_values):
    with H.History(db) as hist:
        for i, S in enumerate(S_values):
            hist.add_rows([H.row_from_stored(_res(loop, S, h=f"h{i}"), run_at=f"2026-03-{i + 1:02d}T02:00:00+00:00")])


def test_default_path_follows_stiction_home(monkeypatch, tmp_path):
    monkeypatch.setenv("STICTION_HOME", str(tmp_path / "sh"))
    assert H.default_db_path() == tmp_path / "sh" / "history.sqlite"
    monkeypatch.delenv("STICTION_HOME")
    monkeypatch.setenv("XDG_DATA_HOME", str(tmp_path / "xdg"))
    assert H.default_db_path() == tmp_path / "xdg" / "stiction" / "history.sqlite"


def test_runs_are_stored_once_in_wal_mode_and_read_back_in_order(tmp_path):
    db = tmp_path / "h.sqlite"
    _fill(db, "FIC1", [1.0, 1.5, 1.2])
    with H.History(db) as hist:
        assert hist.conn.execute("PRAGMA journal_mode").fetchone()[0] == "wal"
        assert hist.add_rows([H.row_from_stored(_res("FIC1", 1.0, h="h0"))]) == 0  # same loop, input, version
        rows = hist.runs("FIC1")
        assert [r["S_pct"] for r in rows] == [1.0, 1.5, 1.2]
        assert rows[0]["S_lo"] == pytest.approx(0.9) and rows[0]["class"] == "undershoot"
        assert [r["S_pct"] for r in hist.runs("FIC1", limit=2)] == [1.5, 1.2]
        assert hist.loops() == ["FIC1"]


def test_a_failed_write_stores_nothing(tmp_path):
    db = tmp_path / "h.sqlite"
    good = H.row_from_stored(_res("A", 1.0))
    bad = dict(H.row_from_stored(_res("B", 2.0)), loop=None)  # violates NOT NULL
    with H.History(db) as hist:
        with pytest.raises(sqlite3.IntegrityError):
            hist.add_rows([good, bad])
        assert hist.loops() == []


def test_a_crash_mid_transaction_keeps_earlier_runs(tmp_path):
    db = tmp_path / "h.sqlite"
    code = textwrap.dedent(f"""
        import os, sys
        sys.path.insert(0, {str(sys.path[0])!r})
        from diagnose.service import history as H
        h = H.History({str(db)!r})
        h.add_rows([H.row_from_stored({{"loop": "L", "S": 1.0, "tool_version": "t", "input_hash": "a"}})])
        h.conn.execute("BEGIN")
        h.conn.execute("INSERT INTO runs (loop, run_at, input_hash) VALUES ('L', 'x', 'b')")
        os._exit(9)  # killed before COMMIT
    """)
    assert subprocess.run([sys.executable, "-c", code]).returncode == 9
    with H.History(db) as hist:
        assert hist.conn.execute("PRAGMA integrity_check").fetchone()[0] == "ok"
        assert [r["input_hash"] for r in hist.runs("L")] == ["a"]


def test_degradation_needs_steady_growth():
    rows = lambda vals: [{"run_at": f"2026-03-0{i + 1}", "S_pct": v} for i, v in enumerate(vals)]
    assert H.degradation(rows([1.0, 1.3, 1.7])) is not None
    assert "1.00 % to 1.70 %" in H.degradation(rows([0.5, 1.0, 1.3, 1.7]))
    assert H.degradation(rows([1.0, 1.7, 1.3])) is None       # not run over run
    assert H.degradation(rows([1.0, 1.06, 1.12])) is None     # too little in all
    assert H.degradation(rows([1.0, 2.0])) is None            # too few runs
    # a run that said no stiction has no size: its fitted band does not start a trend
    said = [dict(r, stiction=k > 0) for k, r in enumerate(rows([0.2, 1.0, 1.3]))]
    assert H.degradation(said) is None
    grown = said + [dict(rows([1.7])[0], stiction=True)]
    assert H.degradation(grown) is not None
    # the latest run found no stiction (a repair): nothing is degrading now
    assert H.degradation(grown + [dict(rows([0.1])[0], stiction=False)]) is None


def test_cli_prints_the_trend_and_warns(tmp_path, capsys):
    db = tmp_path / "h.sqlite"
    _fill(db, "FIC9", [1.0, 1.4, 2.1])
    _fill(db, "TIC2", [2.0, 2.0])
    assert main(["history", "FIC9", "--db", str(db)]) == 0
    out = capsys.readouterr().out
    lines = out.splitlines()
    assert lines[0].startswith("FIC9: 3 run(s)")
    assert [ln.split()[1:4] for ln in lines[2:5]] == [["90", "%", "1.00"], ["90", "%", "1.40"], ["90", "%", "2.10"]]
    assert "Verdict: stiction in 3 of the last 3 runs, median probability 90 %" in out
    assert "WARNING: S grew" in out
    assert main(["history", "TIC2", "--db", str(db)]) == 0
    assert "WARNING" not in capsys.readouterr().out
    assert main(["history", "--db", str(db)]) == 0
    assert "FIC9" in capsys.readouterr().out


def test_cli_errors_are_one_line(tmp_path, capsys):
    db = tmp_path / "h.sqlite"
    assert main(["history", "X", "--db", str(db)]) == 1
    assert "no history database here yet" in capsys.readouterr().err
    _fill(db, "FIC9", [1.0])
    assert main(["history", "NOPE", "--db", str(db)]) == 1
    err = capsys.readouterr().err
    assert err.startswith("error: no runs of loop 'NOPE'") and "FIC9" in err and "Traceback" not in err
    # --db given a folder, reading or writing: named as one, not sqlite's "disk I/O error"
    for argv in (["history", "--db", str(tmp_path)],
                 ["batch", str(tmp_path / "none.csv"), "--out", str(tmp_path / "out"), "--db", str(tmp_path)]):
        assert main(argv) == 1
        err = capsys.readouterr().err.strip().splitlines()
        assert err == [f"error: {tmp_path}: is a folder; --db takes the database file (for example "
                       f"{tmp_path / 'history.sqlite'})"]


def test_cli_limit_keeps_the_last_runs_and_refuses_less_than_one(tmp_path, capsys):
    db = tmp_path / "h.sqlite"
    _fill(db, "FIC9", [1.0, 1.4, 2.1])
    assert main(["history", "FIC9", "--db", str(db), "--limit", "2"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0] == "FIC9: 3 run(s), the last 2 shown"
    assert [ln.split()[3] for ln in lines[2:4]] == ["1.40", "2.10"]
    # the verdict's persistence and the degradation are the loop's, not the rows shown: the
    # summary and the report say 3 of 3 and "degrading" whatever --limit shows
    assert lines[4] == "Verdict: stiction in 3 of the last 3 runs, median probability 90 %"
    assert lines[5].startswith("WARNING: S grew over the last 3 runs, from 1.00 % to 2.10 %") and len(lines) == 6
    assert main(["history", "FIC9", "--db", str(db), "--limit", "1"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0] == "FIC9: 3 run(s), the last 1 shown" and len(lines) == 5
    assert lines[3].startswith("Verdict: stiction in 3 of the last 3 runs") and lines[4].startswith("WARNING: S grew")
    assert main(["history", "FIC9", "--db", str(db), "--limit", "1", "--json"]) == 0
    import json
    got = json.loads(capsys.readouterr().out)
    assert got["n_runs"] == 3 and [r["S_pct"] for r in got["runs"]] == [2.1]
    assert got["persistence"].startswith("stiction in 3 of the last 3 runs") and "S grew" in got["degradation"]
    assert main(["history", "FIC9", "--db", str(db), "--limit", "5"]) == 0
    assert capsys.readouterr().out.startswith("FIC9: 3 run(s)\n")
    for bad in ("0", "-1"):
        assert main(["history", "FIC9", "--db", str(db), "--limit", bad]) == 2
        captured = capsys.readouterr()
        assert captured.out == "" and f"argument --limit: {bad}: give 1 or more" in captured.err


def _dated(loop: str, S: float, start: str, h: str) -> dict:
    return {**_res(loop, S, h=h), "record": {"start": start, "n": 1441, "ts_s": 60.0}}


def test_backfilled_exports_are_ordered_by_their_records_not_by_the_run(tmp_path):
    db = tmp_path / "h.sqlite"
    run_at = "2026-04-01T02:00:00+00:00"   # one night back-fills three months
    with H.History(db) as hist:
        for month, S in (("03", 1.7), ("01", 1.0), ("02", 1.3)):
            hist.add_rows([H.row_from_stored(_dated("FIC1", S, f"2026-{month}-10T00:00:00Z", h=month), run_at=run_at)])
        rows = hist.runs("FIC1")
    assert [r["S_pct"] for r in rows] == [1.0, 1.3, 1.7]
    assert [r["data_end"] for r in rows] == ["2026-01-11T00:00:00Z", "2026-02-11T00:00:00Z",
                                            "2026-03-11T00:00:00Z"]
    assert {r["run_at"] for r in rows} == {"2026-04-01T02:00:00Z"}   # the run time is kept beside
    warn = H.degradation(rows)
    assert warn and "2026-01-11 to 2026-03-11" in warn
    text = H.format_trend("FIC1", rows)
    assert text.splitlines()[2].startswith("2026-01-11T00:00:00") and run_at[:19] in text


def test_record_end_is_the_last_sample_and_none_without_a_start():
    assert H.record_end({"record": {"start": "2026-01-01T00:00:00Z", "n": 3, "ts_s": 30.0}}) == \
        "2026-01-01T00:01:00Z"
    assert H.record_end({"record": {"start": "2026-01-01T01:00:00+01:00", "n": 1, "ts_s": 1.0}}) == \
        "2026-01-01T00:00:00Z"
    assert H.record_end({"record": {"start": None, "n": 100, "ts_s": 1.0}}) is None


_V1_DDL = """
CREATE TABLE runs (id INTEGER PRIMARY KEY, loop TEXT NOT NULL, run_at TEXT NOT NULL, data_start TEXT,
    source TEXT, input_hash TEXT NOT NULL DEFAULT '', tool_version TEXT NOT NULL DEFAULT '',
    status TEXT NOT NULL DEFAULT 'ok', class TEXT, S_pct REAL, S_lo REAL, S_hi REAL, J_pct REAL, J_lo REAL,
    J_hi REAL, confidence REAL, severity REAL, oscillation_period_s REAL, verdict TEXT, result_json TEXT,
    UNIQUE (loop, input_hash, tool_version));
CREATE INDEX runs_loop ON runs (loop, run_at);
CREATE TABLE meta (key TEXT PRIMARY KEY, value TEXT);
INSERT INTO meta VALUES ('schema_version', '1');
"""


def test_a_version_1_database_is_read_and_migrated_in_place(tmp_path, capsys):
    import json

    db = tmp_path / "old.sqlite"
    con = sqlite3.connect(db)
    con.executescript(_V1_DDL)
    for month, S in (("02", 1.3), ("01", 1.0)):
        res = _dated("FIC1", S, f"2026-{month}-10T00:00:00Z", h=month)
        con.execute("INSERT INTO runs (loop, run_at, input_hash, S_pct, result_json) VALUES (?, ?, ?, ?, ?)",
                    ("FIC1", "2026-04-01T02:00:00+00:00", month, S, json.dumps(res)))
    con.commit()
    con.close()
    assert main(["history", "FIC1", "--db", str(db)]) == 0   # read-only, before any migration
    assert "FIC1: 2 run(s)" in capsys.readouterr().out
    with H.History(db) as hist:
        assert hist.conn.execute("SELECT value FROM meta WHERE key = 'schema_version'").fetchone()[0] == str(H.SCHEMA_VERSION)
        rows = hist.runs("FIC1")
        assert [r["S_pct"] for r in rows] == [1.0, 1.3]   # by the records' ends, filled in
        assert rows[0]["data_end"] == "2026-01-11T00:00:00Z"
        assert hist.add_rows([H.row_from_stored(_dated("FIC1", 1.6, "2026-03-10T00:00:00Z", h="03"))]) == 1
        assert [r["S_pct"] for r in hist.runs("FIC1")] == [1.0, 1.3, 1.6]


def test_cli_finds_a_loop_by_its_tag_as_written(tmp_path, capsys):
    db = tmp_path / "h.sqlite"
    with H.History(db) as hist:
        hist.add_rows([H.row_from_stored(_res("FIC 9/A", 1.0))])   # filed under the file-safe tag
    assert H.History(db, readonly=True).loops() == ["FIC_9_A"]
    assert main(["history", "FIC 9/A", "--db", str(db)]) == 0
    assert capsys.readouterr().out.startswith("FIC_9_A: 1 run(s)")


def test_a_diagnosis_is_filed_as_its_stored_json_reads_back(tmp_path):
    """The row of a live diagnosis and the row read back from its LOOP.json are the same row."""
    import json

    from diagnose.service.pipeline import diagnose
    from diagnose.simulate import sticky_loop

    rec = sticky_loop(3.0, 1.0, n=1200, noise_std=0.03, load_walk_std=0.02, seed=4, name="FIC 4")
    diag = diagnose(rec.replace(start="2026-02-01T00:00:00Z"), narx=False)
    live = H.row_from_diagnosis(diag, run_at="2026-02-02T00:00:00+00:00", input_hash="x")
    stored = H.row_from_stored(json.loads(json.dumps(diag.to_dict())), run_at=live["run_at"], input_hash="x")
    assert {k: v for k, v in live.items() if k != "result_json"} == \
        {k: v for k, v in stored.items() if k != "result_json"}
    assert live["loop"] == "FIC_4" and live["data_end"] == "2026-02-01T00:19:59Z"
    assert live["S_pct"] == diag.identification.S_pct and live["verdict"] == diag.verdict_text
    with H.History(tmp_path / "h.sqlite") as hist:
        assert hist.add(diag, run_at=live["run_at"], input_hash="x")
        assert not hist.add(diag, run_at=live["run_at"], input_hash="x")     # stored once
        (row,) = hist.runs("FIC_4", with_result=True)
    assert json.loads(row["result_json"])["schema"] == "stiction.loop/2"


def test_cli_words_the_confidence_as_the_reports_do_and_gives_every_time_with_z(tmp_path, capsys):
    import json

    from diagnose.plain import percent

    db = tmp_path / "h.sqlite"
    with H.History(db) as hist:
        sure = dict(_dated("FIC1", 1.0, "2026-01-10T00:00:00Z", h="a"), confidence=0.9979)
        hist.add_rows([H.row_from_stored(sure, run_at="2026-04-01T02:00:00Z"),
                       H.row_from_stored(dict(_dated("FIC1", 1.2, "2026-02-10T00:00:00+01:00", h="b"),
                                              confidence=0.42))])
        # a row as an earlier release stored it, its times ending in +00:00
        hist.conn.execute("INSERT INTO runs (loop, run_at, data_start, data_end, input_hash, S_pct, confidence) "
                          "VALUES ('FIC1', '2026-04-02T02:00:00+00:00', '2026-03-10T00:00:00+00:00', "
                          "'2026-03-11T00:00:00+00:00', 'c', 1.4, 0.999)")
        hist.conn.commit()
    assert main(["history", "FIC1", "--db", str(db)]) == 0
    lines = capsys.readouterr().out.splitlines()[2:5]   # the runs (a degradation warning follows)
    assert "100%" not in "".join(lines)
    assert [percent(c) in line for c, line in zip((0.9979, 0.42, 0.999), lines)] == [True] * 3
    assert "> 99 %" in lines[0] and " 42 % " in lines[1]
    assert main(["history", "FIC1", "--db", str(db), "--json"]) == 0
    runs = json.loads(capsys.readouterr().out)["runs"]
    assert [(r["data_start"], r["data_end"]) for r in runs] == [
        ("2026-01-10T00:00:00Z", "2026-01-11T00:00:00Z"), ("2026-02-09T23:00:00Z", "2026-02-10T23:00:00Z"),
        ("2026-03-10T00:00:00Z", "2026-03-11T00:00:00Z")]
    assert all(r["run_at"].endswith("Z") for r in runs)


def test_persistence_counts_the_last_runs_that_stored_a_verdict():
    rows = [{"stiction": s, "stiction_probability": p} for s, p in
            [(1, 0.9), (0, 0.2), (None, None), (1, 0.8), (1, 0.7)]]
    assert H.persistence(rows) == "stiction in 3 of the last 4 runs, median probability 75 %"
    assert H.persistence(rows, runs=2) == "stiction in 2 of the last 2 runs, median probability 75 %"
    assert H.persistence(rows[:2] + rows[2:3]) == "stiction in 1 of the last 2 runs, median probability 55 %"
    assert H.persistence(rows[:1]) is None                 # one run says nothing of persistence


def test_a_version_2_database_gains_the_verdict_columns_from_its_stored_results(tmp_path):
    db = tmp_path / "old.sqlite"
    import json
    old_cols = [c for c in H._COLS if c not in ("stiction", "stiction_probability")]
    ddl = H._DDL.replace("    stiction INTEGER,\n    stiction_probability REAL,\n", "")
    assert "stiction INTEGER" not in ddl
    con = sqlite3.connect(db)
    con.executescript(ddl)
    for i, p in enumerate((0.9, 0.3)):
        row = H.row_from_stored(_res("OLD", 1.0, h=f"h{i}", p=p), run_at=f"2026-03-0{i + 1}T00:00:00+00:00")
        row["result_json"] = json.dumps(_res("OLD", 1.0, h=f"h{i}", p=p))
        con.execute(f"INSERT INTO runs ({', '.join(old_cols)}) VALUES ({', '.join('?' for _ in old_cols)})",
                    [row[c] for c in old_cols])
    con.commit()
    con.close()
    with H.History(db) as hist:      # opened for writing: migrated in place
        rows = hist.runs("OLD")
    assert [(r["stiction"], r["stiction_probability"]) for r in rows] == [(1, 0.9), (0, 0.3)]
    assert H.persistence(rows) == "stiction in 1 of the last 2 runs, median probability 60 %"


def test_a_corrected_export_rerun_counts_its_record_once(tmp_path, capsys):
    """A night's export edited and re-run makes a new input hash for the same record: the trend,
    its persistence and its degradation count that record once (by its latest run), as the
    summary and the report do, instead of two runs of one night."""
    import json

    import pandas as pd

    from datetime import datetime, timezone

    from connectors.historian import format_wide
    from diagnose.simulate import sticky_loop

    db = tmp_path / "h.sqlite"
    nights = []
    for night, S in enumerate((0.0, 3.0), start=1):   # healthy, then sticky
        folder = tmp_path / f"night{night}"
        folder.mkdir()
        rec = sticky_loop(S, 1.0 if S else 0.0, n=1000, noise_std=0.03, load_walk_std=0.02, seed=40 + night,
                          name="FIC7")
        start = datetime(2026, 3, night, 22, tzinfo=timezone.utc)
        (folder / "FIC7.csv").write_text(format_wide(rec.replace(mv=None), start=start))
        nights.append(folder)
    args = lambda folder: ["batch", str(folder), "--out", str(tmp_path / "out" / folder.name), "--workers", "1",
                           "--no-pdf", "--no-narx", "--quiet", "--db", str(db)]
    for folder in nights:
        assert main(args(folder)) == 0
    path = nights[1] / "FIC7.csv"                      # a corrected export of night 2
    df = pd.read_csv(path)
    df.loc[500, "FIC7.PV"] += 0.05
    df.to_csv(path, index=False)
    assert main(args(nights[1])) == 0
    capsys.readouterr()
    summary = json.loads((tmp_path / "out" / "night2" / "summary.json").read_text())
    assert summary["loops"][0]["sticky_runs"] == [1, 2] and not summary["loops"][0]["skipped"]
    with H.History(db) as h:
        assert h.conn.execute("SELECT count(*) FROM runs WHERE loop = 'FIC7'").fetchone()[0] == 3  # all kept
        rows = h.runs("FIC7")
    assert [r["data_end"][:10] for r in rows] == ["2026-03-01", "2026-03-02"]
    assert main(["history", "FIC7", "--db", str(db)]) == 0
    out = capsys.readouterr().out
    assert out.startswith("FIC7: 2 run(s)")
    assert "Verdict: stiction in 1 of the last 2 runs" in out
    assert main(["history", "FIC7", "--db", str(db), "--json"]) == 0
    got = json.loads(capsys.readouterr().out)
    assert len(got["runs"]) == 2 and got["persistence"].startswith("stiction in 1 of the last 2 runs")


def test_a_record_without_times_rediagnosed_by_a_later_release_counts_once(tmp_path):
    """An export of sample indices has no start or end: the same samples diagnosed by a later
    release are told by their digest, and count once in the trend and its persistence."""
    def untimed(digest):
        return {"record": {"start": None, "n": 1000, "ts_s": 1.0, "data_hash": digest}}

    db = tmp_path / "h.sqlite"
    with H.History(db) as hist:
        # a release's input hash differs from the last one's (the version is part of it)
        for version, when, p in (("0.1.0", "2026-03-01T02:00:00Z", 0.9), ("0.1.1", "2026-03-02T02:00:00Z", 0.3)):
            hist.add_rows([H.row_from_stored({**_res("CHEM1", 0.7, h=f"input-{version}", p=p), **untimed("d1"),
                                              "tool_version": version}, run_at=when)])
        hist.add_rows([H.row_from_stored({**_res("CHEM1", 0.8, h="next-file", p=0.95), **untimed("d2")},
                                         run_at="2026-03-03T02:00:00Z")])
        assert hist.conn.execute("SELECT count(*) FROM runs").fetchone()[0] == 3   # all kept
        rows = hist.runs("CHEM1")
    assert [(r["tool_version"], r["data_hash"]) for r in rows] == [("0.1.1", "d1"), ("t", "d2")]
    assert H.sticky_runs(rows)[:2] == (1, 2)


def test_a_batch_rerun_of_an_untimed_export_with_other_options_counts_once(tmp_path):
    """The bundled ISDB loop (sample indices, no times) diagnosed twice with other options (each
    run's input hash differs) is one record in the loop's history, by its latest run."""
    logs = tmp_path / "logs"
    logs.mkdir()
    from pathlib import Path

    from diagnose.service import batch as B

    sample = Path(__file__).resolve().parents[1] / "sample_logs" / "isdb_CHEM1.csv"
    (logs / "isdb_CHEM1.csv").write_bytes(sample.read_bytes())
    db = tmp_path / "h.sqlite"
    for narx in (False, True):
        res = B.run_batch([logs], tmp_path / f"out_{narx}", workers=1, explain=False, narx=narx, pdf=False,
                          db=db, progress=False)
        assert res.n_failed == 0
    with H.History(db) as hist:
        assert hist.conn.execute("SELECT count(*) FROM runs").fetchone()[0] == 2
        rows = hist.runs("isdb_CHEM1")
    assert len(rows) == 1 and rows[0]["data_start"] is None and len(rows[0]["data_hash"]) == 32


def test_the_loop_list_and_the_json_say_the_verdict_in_words(tmp_path, capsys):
    import json

    db = tmp_path / "h.sqlite"
    with H.History(db) as hist:
        hist.add_rows([H.row_from_stored(_res("FIC1", 2.5, h="a", p=0.9)),
                       H.row_from_stored(_res("TIC2", 0.0, J=0.0, h="b", cls="none", p=0.1))])
    assert main(["history", "--db", str(db)]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert any(ln.split() == ["FIC1", "S", "2.50", "%"] for ln in lines)
    assert any(ln.split() == ["TIC2", "no", "stiction"] for ln in lines)   # not "S 0.00 %"
    assert main(["history", "TIC2", "--db", str(db), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["runs"][0]["stiction"] is False


def test_history_figure_leaves_runs_without_stiction_as_gaps():
    from diagnose.service.figures import history as history_figure

    run = lambda day, S, sticky: {"run_at": f"2026-03-0{day}", "S_pct": S, "J_pct": S / 2, "stiction": sticky}
    # one sized run beside a healthy one: nothing to draw a trend from
    assert history_figure([run(1, 0.4, False), run(2, 1.0, True)]) is None
    png = history_figure([run(1, 0.4, False), run(2, 1.0, True), run(3, 1.5, True)])
    assert png is not None and png[:8] == b"\x89PNG\r\n\x1a\n"


def test_a_damaged_row_is_a_one_line_error_naming_the_database(tmp_path, capsys):
    """A page damaged on disk (bytes that are not UTF-8 in a text column) fails the query: the CLI
    says so in one line naming the file, exit 1, no traceback."""
    db = tmp_path / "h.sqlite"
    _fill(db, "FIC1", [1.0, 1.2])
    with sqlite3.connect(db) as c:
        c.execute("UPDATE runs SET data_start = CAST(X'323032362dff' AS TEXT) WHERE loop = 'FIC1'")
    assert main(["history", "FIC1", "--db", str(db)]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith(f"error: {db}: history database error while reading the runs of FIC1")
    with pytest.raises(H.StictionError, match="while reading the runs"):
        H.History(db, readonly=True).runs("FIC1")
    assert H.previous_runs(db, "FIC1") == []   # a report's history: left out, the report still written


def test_a_database_in_a_folder_that_cannot_be_written_is_read_but_not_written(tmp_path, monkeypatch, capsys):
    """WAL needs a -shm file beside the database, which SQLite cannot create in a read-only folder
    (it says "unable to open database file"): `stiction history` still reads such a copy
    (immutable), and a batch or monitor says in one line that the folder is read-only."""
    folder = tmp_path / "share"
    db = folder / "h.sqlite"
    _fill(db, "FIC1", [1.0, 1.2])
    real_connect, real_access = H.sqlite3.connect, H.os.access

    def connect(target, *a, **k):  # what SQLite does there, even for root (who may write anyway)
        if str(target).startswith("file:") and "immutable=1" not in str(target):
            raise_on = sqlite3.OperationalError("unable to open database file")

            class Refusing:
                def execute(self, *a, **k):
                    raise raise_on

                def close(self):
                    pass
            return Refusing()
        return real_connect(target, *a, **k)

    monkeypatch.setattr(H.sqlite3, "connect", connect)
    monkeypatch.setattr(H.os, "access", lambda p, mode: False if str(p).startswith(str(folder)) else real_access(p, mode))
    assert main(["history", "FIC1", "--db", str(db)]) == 0
    assert "FIC1: 2 run(s)" in capsys.readouterr().out
    with pytest.raises(H.StictionError, match=r"h\.sqlite: cannot write the history database: its folder is read-only"):
        H.History(db)
    with pytest.raises(H.StictionError, match=r"cannot create the history database's folder .*not_a_folder"):
        (tmp_path / "not_a_folder").write_text("x")
        H.History(tmp_path / "not_a_folder" / "h.sqlite")


def test_the_loop_list_words_each_loops_last_run_by_its_verdict(tmp_path, capsys):
    # the last run decides: a loop repaired since its sticky runs reads "no stiction" (its stored
    # S is the fit's, not a size); a loop whose last run said stiction reads its S; a run of a
    # release that stored no verdict reads its S as stored
    db = tmp_path / "h.sqlite"
    _fill(db, "FIC1", [3.0, 3.4])
    with H.History(db) as hist:
        hist.add_rows([H.row_from_stored(_res("FIC2", 2.5, h="a"), run_at="2026-03-01T02:00:00+00:00"),
                       H.row_from_stored(_res("FIC2", 0.07, h="b", cls="none", p=0.02),
                                         run_at="2026-03-02T02:00:00+00:00"),
                       dict(H.row_from_stored(_res("FIC3", 1.25, h="c")), stiction=None)])
        assert hist.runs("FIC2")[-1]["S_pct"] == pytest.approx(0.07)   # stored as fitted
    assert main(["history", "--db", str(db)]) == 0
    out = capsys.readouterr().out.splitlines()
    assert out[0] == f"3 loop(s) in {db}:"
    assert {ln.split()[0]: " ".join(ln.split()[1:]) for ln in out[1:]} == {
        "FIC1": "S 3.40 %", "FIC2": "no stiction", "FIC3": "S 1.25 %"}
    # the trend of the same loop agrees: no size for the run that said no stiction
    assert main(["history", "FIC2", "--db", str(db), "--json"]) == 0
    assert [r["S_pct"] for r in json.loads(capsys.readouterr().out)["runs"]] == [pytest.approx(2.5), None]


def test_a_database_locked_past_the_wait_is_busy_not_broken(tmp_path):
    db = tmp_path / "h.sqlite"
    H.History(db).close()
    conn = sqlite3.connect(db, isolation_level=None)
    conn.execute("BEGIN EXCLUSIVE")
    try:
        with pytest.raises(H.HistoryBusy) as err:
            H.History(db, busy_timeout_s=0.2)
    finally:
        conn.execute("ROLLBACK")
        conn.close()
    msg = str(err.value)
    assert msg.startswith(f"{db}: ") and "locked by another process" in msg and "not a usable" not in msg
    # a write that waits past the same limit is busy too, not a damaged file to check
    hist = H.History(db, busy_timeout_s=0.2)
    conn = sqlite3.connect(db, isolation_level=None)
    conn.execute("BEGIN EXCLUSIVE")
    try:
        with pytest.raises(H.HistoryBusy, match="while storing runs") as err:
            hist.add_rows([H.row_from_stored(_res("FIC1", 1.0))])
    finally:
        conn.execute("ROLLBACK")
        conn.close()
    assert "integrity_check" not in str(err.value)
    assert hist.add_rows([H.row_from_stored(_res("FIC1", 1.0))]) == 1   # stored once the lock is gone
    hist.close()


def _fraction(loop: str, S: float, start: str, h: str) -> dict:
    """A stored result of a loop whose OP was logged as a fraction of span (S and J in fractions)."""
    return {**_dated(loop, S, start, h), "J": S / 2, "S_interval": [S * 0.9, S * 1.1],
            "J_interval": [S * 0.4, S * 0.6], "sj_units": "fraction of span"}


def test_runs_in_fractions_of_span_keep_their_units_in_the_trend_and_degradation(tmp_path, capsys):
    db = tmp_path / "h.sqlite"
    with H.History(db) as hist:
        for month, S in (("01", 0.020), ("02", 0.025), ("03", 0.031)):
            hist.add_rows([H.row_from_stored(_fraction("FV2", S, f"2026-{month}-10T00:00:00Z", h=month))])
        rows = hist.runs("FV2")
    assert [r["sj_units"] for r in rows] == ["fraction of span"] * 3
    assert [H.size_pct(r) for r in rows] == pytest.approx([2.0, 2.5, 3.1])
    # S grew by 0.5 and 0.6 % of span a run: read in fractions, the steps (0.005) would be no growth
    warn = H.degradation(rows)
    assert warn and "from 2.00 % to 3.10 % of span" in warn
    text = H.format_trend("FV2", rows)
    head, first = text.splitlines()[1:3]
    assert "S %" not in head and head.rstrip().endswith("S, J units")
    assert "0.0200" in first and "[0.0180, 0.0220]" in first and "0.0100" in first
    assert first.rstrip().endswith("fraction of span")
    assert main(["history", "--db", str(db)]) == 0
    assert "S 0.0310 (fraction of span)" in capsys.readouterr().out
    from diagnose.service.figures import history as history_figure

    assert history_figure(rows)[:4] == b"\x89PNG"
    # runs in % of span print as they always did
    pct = H.format_trend("FIC1", [H.row_from_stored(_res("FIC1", 2.5))])
    assert " S % " in pct.splitlines()[1] and "units" not in pct


def test_the_loop_report_gives_a_fraction_run_s_history_in_its_units():
    from diagnose.service.report import loop_blocks

    rows = [H.row_from_stored(_fraction("FV2", S, f"2026-0{i + 1}-10T00:00:00Z", h=str(i)))
            for i, S in enumerate((0.020, 0.025))]
    diag = _diagnosis_of_fraction_loop()
    (table,) = [b for b in loop_blocks(diag, history_rows=rows) if b[0] == "table" and "Record end" in b[1]]
    head, body = table[1], table[2]
    assert head[2:4] == ["S", "J"]
    assert body[0][2] == "0.0200 (fraction of span)" and body[1][3] == "0.0125 (fraction of span)"
    # a run in % of span beside them (a tag map added later) says so too
    rows.append(H.row_from_stored(_dated("FV2", 2.6, "2026-03-10T00:00:00Z", h="pct")))
    (table,) = [b for b in loop_blocks(diag, history_rows=rows) if b[0] == "table" and "Record end" in b[1]]
    assert table[2][2][2:4] == ["2.60 %", "1.00 %"] and table[2][0][2] == "0.0200 (fraction of span)"


def _diagnosis_of_fraction_loop():
    from diagnose.service.pipeline import diagnose
    from diagnose.simulate import sticky_loop

    rec = sticky_loop(3.0, 1.0, n=1200, noise_std=0.03, load_walk_std=0.02, seed=4, name="FV2")
    rec = rec.replace(op=rec.op / 100.0, mv=None, start="2026-03-01T00:00:00Z")
    return diagnose(rec, narx=False)


@pytest.mark.parametrize("missing", [("sj_units", "data_hash"), ("data_hash",)])
def test_a_version_3_database_gets_the_units_of_its_stored_results(tmp_path, missing):
    db = tmp_path / "v3.sqlite"
    con = sqlite3.connect(db)
    ddl = H._DDL
    for c in missing:
        ddl = ddl.replace(f"    {c} TEXT,\n", "")
    con.executescript(ddl)
    con.execute("INSERT INTO meta VALUES ('schema_version', '3')")
    cols = [c for c in H._COLS if c not in missing]
    fraction = _fraction("FV2", 0.03, "2026-01-10T00:00:00Z", h="a")
    fraction["record"] = {**fraction["record"], "data_hash": "d1"}
    for i, res in enumerate((fraction, _dated("FV2", 3.0, "2026-02-10T00:00:00Z", h="b"))):
        row = H.row_from_stored(res, run_at=f"2026-04-0{i + 1}T02:00:00Z")
        con.execute(f"INSERT INTO runs ({', '.join(cols)}) VALUES ({', '.join('?' for _ in cols)})",
                    tuple(row[c] for c in cols))
    con.commit()
    con.close()
    with H.History(db) as hist:
        assert hist.conn.execute("SELECT value FROM meta WHERE key = 'schema_version'").fetchone()[0] == "4"
        rows = hist.runs("FV2")
    assert [H.run_units(r) for r in rows] == ["fraction of span", "% of span"]
    assert [r["data_hash"] for r in rows] == ["d1", None]
    assert [H.size_pct(r) for r in rows] == pytest.approx([3.0, 3.0])


def test_a_record_no_test_could_judge_is_no_healthy_run_in_the_history():
    # PV dead and OP a slow wander: "no evidence either way" must not count as a run that said no
    # stiction, nor show a size of 0
    import numpy as np

    from diagnose.record import LoopRecord
    from diagnose.service import pipeline
    from diagnose.service.history import row_from_stored, sticky_runs, verdict_of

    rng = np.random.default_rng(3)
    rec = LoopRecord(name="FIC9", ts_s=1.0, op=50.0 + np.cumsum(rng.normal(0.0, 0.05, 3000)),
                     pv=np.full(3000, 60.0))
    diag = pipeline.diagnose(rec, narx=False)
    assert not diag.identification.verdict.judged
    assert verdict_of(diag.identification) == {"stiction": None, "stiction_probability": None}
    row = row_from_stored(json.loads(json.dumps(diag.to_dict())))
    assert row["stiction"] is None and row["S_pct"] is None and row["J_pct"] is None
    sticky = [{"stiction": 1, "stiction_probability": 0.9}] * 2
    assert sticky_runs(sticky + [row]) == (2, 2, 0.9)
