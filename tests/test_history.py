"""History database: default path, WAL, one transaction per write, trend, degradation, CLI."""

from __future__ import annotations

import sqlite3
import subprocess
import sys
import textwrap

import pytest

from diagnose.service import history as H
from diagnose.service.cli import main


def _res(loop: str, S: float, J: float = 1.0, h: str = "h", cls: str = "undershoot") -> dict:
    return {"loop": loop, "S": S, "J": J, "S_interval": [S - 0.1, S + 0.1], "J_interval": [J - 0.1, J + 0.1],
            "class": cls, "confidence": 0.9, "severity": {"score": 10.0 * S}, "tool_version": "t",
            "input_hash": h, "verdict": "v", "record": {"start": "2026-01-01T00:00:00+00:00"}}


def _fill(db, loop, S_values):
    with H.History(db) as hist:
        for i, S in enumerate(S_values):
            hist.add(_res(loop, S, h=f"h{i}"), run_at=f"2026-03-{i + 1:02d}T02:00:00+00:00")


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
        assert not hist.add(_res("FIC1", 1.0, h="h0"))  # same loop, input and version: not again
        rows = hist.runs("FIC1")
        assert [r["S_pct"] for r in rows] == [1.0, 1.5, 1.2]
        assert rows[0]["S_lo"] == pytest.approx(0.9) and rows[0]["class"] == "undershoot"
        assert [r["S_pct"] for r in hist.runs("FIC1", limit=2)] == [1.5, 1.2]
        assert hist.loops() == ["FIC1"]


def test_a_failed_write_stores_nothing(tmp_path):
    db = tmp_path / "h.sqlite"
    good = H.row_from_result(_res("A", 1.0))
    bad = dict(H.row_from_result(_res("B", 2.0)), loop=None)  # violates NOT NULL
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
        h.add({{"loop": "L", "S": 1.0, "tool_version": "t", "input_hash": "a"}})
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


def test_cli_prints_the_trend_and_warns(tmp_path, capsys):
    db = tmp_path / "h.sqlite"
    _fill(db, "FIC9", [1.0, 1.4, 2.1])
    _fill(db, "TIC2", [2.0, 2.0])
    assert main(["history", "FIC9", "--db", str(db)]) == 0
    out = capsys.readouterr().out
    lines = out.splitlines()
    assert lines[0].startswith("FIC9: 3 run(s)")
    assert [ln.split()[1] for ln in lines[2:5]] == ["1.00", "1.40", "2.10"]
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
