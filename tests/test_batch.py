"""The nightly batch: discovery, reports, ranking, failures, resume, atomic writes, pools, Dask."""

from __future__ import annotations

import csv
import io
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import time
from datetime import datetime, timezone
from pathlib import Path

import pytest

from connectors.historian import format_wide, write_wide
from diagnose.service import batch as B
from diagnose.service.cli import main
from diagnose.service.history import History, row_from_stored
from diagnose.simulate import sticky_loop

# (name, S, J): a clearly sticky valve, a mildly sticky one, a healthy one
LOOPS = [("FIC1", 5.0, 2.0), ("FIC2", 1.5, 0.5), ("FIC3", 0.0, 0.0)]


def _write_loops(folder: Path, loops=LOOPS, n: int = 2000, start=None) -> None:
    """Simulated exports (start: a UTC datetime for their first sample, else 2026-01-01)."""
    folder.mkdir(parents=True, exist_ok=True)
    for i, (name, S, J) in enumerate(loops):
        rec = sticky_loop(S, J, n=n, noise_std=0.03, load_walk_std=0.02, seed=10 + i, name=name)
        if start is None:
            write_wide(rec.replace(mv=None), folder / f"{name}.csv")
        else:
            (folder / f"{name}.csv").write_text(format_wide(rec.replace(mv=None), start=start))


@pytest.fixture(scope="module")
def plant(tmp_path_factory):
    root = tmp_path_factory.mktemp("plant")
    _write_loops(root / "logs")
    (root / "logs" / "broken.csv").write_text("time,A.OP,A.PV\n2026-01-01T00:00:00Z,1,oops\n")
    return root


@pytest.fixture(scope="module")
def first_run(plant):
    out = plant / "out"
    res = B.run_batch([plant / "logs"], out, workers=1, explain=False, db=plant / "h.sqlite", progress=False)
    return out, res


def test_discover_skips_hidden_foreign_and_output(tmp_path):
    (tmp_path / "a").mkdir()
    (tmp_path / "a" / "x.csv").write_text("t")
    (tmp_path / "a" / ".hidden.csv").write_text("t")
    (tmp_path / "a" / "notes.md").write_text("t")
    (tmp_path / ".git").mkdir()
    (tmp_path / ".git" / "y.csv").write_text("t")
    (tmp_path / "out").mkdir()
    (tmp_path / "out" / "summary.csv").write_text("t")
    (tmp_path / "b.txt").write_text("t")
    files, missing = B.discover([tmp_path, tmp_path / "b.txt", tmp_path / "nope.csv"], exclude=[tmp_path / "out"])
    assert sorted(f.relative_to(tmp_path).as_posix() for f in files) == ["a/x.csv", "b.txt"]
    assert [m["status"] for m in missing] == ["failed"] and "nope.csv" in missing[0]["error"]
    # the output folder of an earlier run (another --out) is no input either, and is said so
    old = tmp_path / "reports_monday"
    (old / "loops" / "FIC1").mkdir(parents=True)
    for name in ("summary.csv", "summary.json"):
        (old / name).write_text("t")
    skipped = []
    files, _ = B.discover([tmp_path], exclude=[tmp_path / "out"], skipped=skipped)
    assert sorted(f.relative_to(tmp_path).as_posix() for f in files) == ["a/x.csv", "b.txt"]
    assert {"path": str(old), "reason": "the output folder of an earlier stiction batch"} in skipped


def test_reports_summary_and_ranking(first_run):
    out, res = first_run
    ok = [r for r in res.rows if r["status"] == "ok"]
    assert sorted(r["loop"] for r in ok) == ["FIC1", "FIC2", "FIC3"]
    for name in ("FIC1", "FIC2", "FIC3"):
        d = out / "loops" / name
        for suffix in (".md", ".pdf", ".json"):
            assert (d / f"{name}{suffix}").stat().st_size > 500
        assert (d / "trends.png").exists() and (d / "phase.png").exists()
    sev = [r["severity"] for r in ok]
    assert sev == sorted(sev, reverse=True) and [r["rank"] for r in ok] == [1, 2, 3]
    assert ok[0]["loop"] == "FIC1" and ok[-1]["loop"] == "FIC3"   # biggest stiction first, healthy last
    with open(out / "summary.csv", newline="") as fh:
        table = list(csv.DictReader(fh))
    assert [t["loop"] for t in table] == [r["loop"] for r in res.rows]
    # the probability of stiction behind the ranking, in the table and the CSV
    assert float(table[0]["stiction_probability"]) > float(table[2]["stiction_probability"])
    doc = json.loads((out / "summary.json").read_text())
    # the broken file is a file that could not be read, not a fourth loop
    assert doc["n_loops"] == 3 and doc["n_failed"] == 1 and doc["n_files_failed"] == 1
    md = (out / "summary.md").read_text()
    assert "3 loops: 3 diagnosed, 0 failed; " in md and " 1 file could not be read." in md
    assert "[FIC1](loops/FIC1/FIC1.md)" in md and "## Failed loops and files" in md and "P(stiction)" in md
    assert (out / "summary.pdf").read_bytes()[:5] == b"%PDF-"
    assert not [p for p in out.rglob("*.tmp")], "temporary files left behind"


def test_a_bad_file_is_recorded_and_the_rest_goes_on(first_run):
    _, res = first_run
    bad = [r for r in res.rows if r["status"] != "ok"]
    assert len(bad) == 1 and bad[0]["source"].endswith("broken.csv") and bad[0]["error"]
    assert res.n_failed == 1


def test_history_gets_one_row_per_loop(first_run, plant):
    with History(plant / "h.sqlite") as h:
        assert h.loops() == ["FIC1", "FIC2", "FIC3"]
        assert len(h.runs("FIC1")) == 1


def test_rerun_skips_what_is_done_and_redoes_what_changed(first_run, plant):
    out, first = first_run
    again = B.run_batch([plant / "logs"], out, workers=1, explain=False, db=plant / "h.sqlite", progress=False)
    assert again.n_skipped == 3 and again.n_failed == 1
    assert [r["loop"] for r in again.rows] == [r["loop"] for r in first.rows]
    # a changed file is diagnosed again; a loop whose result vanished (killed job) too
    _write_loops(plant / "logs", [("FIC2", 2.5, 0.5)])
    (out / "loops" / "FIC3" / "FIC3.json").unlink()
    third = B.run_batch([plant / "logs"], out, workers=1, explain=False, db=plant / "h.sqlite", progress=False)
    redone = sorted(r["loop"] for r in third.rows if r["status"] == "ok" and not r.get("skipped"))
    assert redone == ["FIC2", "FIC3"]
    with History(plant / "h.sqlite") as h:
        assert len(h.runs("FIC1")) == 1 and len(h.runs("FIC3")) == 1
        # FIC2's changed export covers the same span: both results are stored, the trend counts the
        # record once, by its latest run
        assert h.conn.execute("SELECT count(*) FROM runs WHERE loop = 'FIC2'").fetchone()[0] == 2
        assert [r["S_pct"] > 2.0 for r in h.runs("FIC2")] == [True]


def test_a_result_stored_without_its_summary_row_is_diagnosed_again(first_run, plant):
    """A LOOP.json of an earlier schema (no stored summary row) is read for its name and redone."""
    out, _ = first_run
    path = out / "loops" / "FIC1" / "FIC1.json"
    old = json.loads(path.read_text())
    assert old["summary"]["loop"] == "FIC1" and old["schema"] == "stiction.loop/2"
    del old["summary"]
    old["schema"] = "stiction.loop/1"
    path.write_text(json.dumps(old))
    again = B.run_batch([plant / "logs"], out, workers=1, explain=False, db=plant / "h.sqlite", progress=False)
    row = next(r for r in again.rows if r["loop"] == "FIC1")
    assert not row["skipped"] and row["S_pct"] > 3.0
    new = json.loads(path.read_text())
    assert new["summary"]["loop"] == "FIC1" and new["schema"] == "stiction.loop/2"
    with History(plant / "h.sqlite") as h:
        assert len(h.runs("FIC1")) == 1      # the same input and version: filed once


def test_cli_exit_code_says_whether_any_failed(plant, tmp_path, capsys):
    good = tmp_path / "good"
    good.mkdir()
    (good / "FIC1.csv").write_bytes((plant / "logs" / "FIC1.csv").read_bytes())
    args = ["batch", str(good), "--out", str(tmp_path / "o1"), "--workers", "1", "--no-explain", "--no-pdf",
            "--db", str(tmp_path / "h.sqlite"), "--quiet"]
    assert main(args) == 0
    out = capsys.readouterr().out
    assert "1 diagnosed" in out and "summary.md" in out
    assert main(args[:1] + [str(plant / "logs" / "broken.csv")] + args[2:]) == 1
    assert "failed: broken" in capsys.readouterr().err
    assert main(["batch", str(tmp_path / "empty-nothing"), "--out", str(tmp_path / "o3"), "--quiet",
                 "--db", str(tmp_path / "h.sqlite")]) == 1
    assert not (tmp_path / "o3").exists()       # a refused run leaves no folder behind
    (tmp_path / "o4").mkdir()
    assert main(["batch", str(tmp_path / "empty-nothing"), "--out", str(tmp_path / "o4"), "--quiet",
                 "--no-history"]) == 1
    assert (tmp_path / "o4").is_dir()           # ... but keeps one the user made


def test_degradation_reaches_report_and_summary(plant, tmp_path):
    db = tmp_path / "h.sqlite"
    with History(db) as h:
        for i, S in enumerate([0.5, 1.0, 2.0]):
            h.add_rows([row_from_stored({"loop": "FIC1", "S": S, "tool_version": "old", "input_hash": f"x{i}",
                                         "stiction": i > 0, "stiction_probability": 0.3 + 0.3 * i},
                                        run_at=f"2026-01-0{i + 1}T00:00:00+00:00")])   # runs of an older release
    logs = tmp_path / "logs"
    logs.mkdir()
    (logs / "FIC1.csv").write_bytes((plant / "logs" / "FIC1.csv").read_bytes())
    res = B.run_batch([logs], tmp_path / "out", workers=1, explain=False, pdf=False, db=db, progress=False)
    row = res.rows[0]
    assert row["S_pct"] > 3.0 and row["degradation"] and "S grew" in row["degradation"]
    md = (tmp_path / "out" / "loops" / "FIC1" / "FIC1.md").read_text()
    assert "history.degradation" in md and "## History" in md
    # the sticky FIC1 of this run makes three sticky runs of four; the healthy first run (S 0.5)
    # neither starts the growth nor shows a size in the History table
    assert "S grew over the last 3 runs, from 1.00 %" in row["degradation"]
    assert "Verdict over this loop's runs: stiction in 3 of the last 4 runs" in md
    assert "| P(stiction) |" in md and "| 30 % | - | - |" in md and "| 60 % | 1.00 |" in md
    # the table holds the four runs the sentence counts, this one last
    table = md.split("| Record end |", 1)[1].split("\n\n", 1)[0].strip().splitlines()[2:]
    assert len(table) == 4 and table[-1].rstrip().endswith("| this run |")
    assert f"| {row['S_pct']:.2f} |" in table[-1]
    assert row["sticky_runs"] == [3, 4]
    summary = (tmp_path / "out" / "summary.md").read_text()
    assert " (3/4 runs) |" in summary and "k said stiction" in summary
    import csv
    with open(tmp_path / "out" / "summary.csv", newline="") as fh:
        assert next(csv.DictReader(fh))["sticky_runs"] == "3/4"
    assert json.loads((tmp_path / "out" / "loops" / "FIC1" / "FIC1.json").read_text())["sticky_runs"] == [3, 4]
    assert "Degrading valves" in (tmp_path / "out" / "summary.md").read_text()


def test_a_healthy_run_after_sticky_growth_ends_the_degradation_in_history_report_and_summary(plant, tmp_path):
    # three runs that said stiction, S growing, then a run that says no stiction (a repaired
    # valve, or a window without stick-slip): no "degrading" beside "no stiction", and the batch's
    # report and summary say what `stiction history` says
    from diagnose.service.history import degradation
    db = tmp_path / "h.sqlite"
    with History(db) as h:
        for i, S in enumerate([1.0, 2.0, 3.0]):
            h.add_rows([row_from_stored({"loop": "FIC3", "S": S, "tool_version": "old", "input_hash": f"x{i}",
                                         "stiction": True, "stiction_probability": 0.9},
                                        run_at=f"2025-12-0{i + 1}T00:00:00+00:00")])
        assert "from 1.00 % to 3.00 %" in degradation(h.runs("FIC3"))   # before the healthy run
    logs = tmp_path / "logs"
    logs.mkdir()
    (logs / "FIC3.csv").write_bytes((plant / "logs" / "FIC3.csv").read_bytes())   # healthy (S 0)
    res = B.run_batch([logs], tmp_path / "out", workers=1, explain=False, pdf=False, db=db, progress=False)
    row = res.rows[0]
    assert row["sticky"] is False
    with History(db, readonly=True) as h:
        assert degradation(h.runs("FIC3")) is None
    assert row["degradation"] is None
    assert "Degrading valves" not in (tmp_path / "out" / "summary.md").read_text()


def test_killed_job_resumes(plant, tmp_path):
    out = tmp_path / "out"
    cmd = [sys.executable, "-m", "diagnose.service.cli", "batch", str(plant / "logs"), "--out", str(out),
           "--workers", "1", "--no-explain", "--no-narx", "--no-pdf", "--db", str(tmp_path / "h.sqlite"), "--quiet"]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and not list(out.glob("loops/*/*.json")):
        time.sleep(0.05)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    done = {p.stem for p in out.glob("loops/*/*.json")}
    assert 1 <= len(done) < 3 and not (out / "summary.json").exists()
    res = B.run_batch([plant / "logs"], out, workers=1, explain=False, narx=False, pdf=False,
                      db=tmp_path / "h.sqlite", progress=False)
    skipped = {r["loop"] for r in res.rows if r.get("skipped")}
    assert skipped == done and sum(r["status"] == "ok" for r in res.rows) == 3


def _sj(res):
    return {r["loop"]: (r["S_pct"], r["J_pct"], r["class"]) for r in res.rows if r["status"] == "ok"}


def test_process_pool_and_dask_localcluster_agree(plant, tmp_path):
    logs = tmp_path / "logs"
    logs.mkdir()
    for name in ("FIC1.csv", "FIC3.csv", "broken.csv"):
        (logs / name).write_bytes((plant / "logs" / name).read_bytes())
    kw = dict(explain=False, narx=False, pdf=False, history=False, progress=False)  # torch-free workers
    pool = B.run_batch([logs], tmp_path / "pool", workers=2, **kw)
    dask = B.run_batch([logs], tmp_path / "dask", workers=1, scheduler="local", **kw)
    want = _sj(pool)
    assert sorted(want) == ["FIC1", "FIC3"]
    assert want["FIC1"][0] == pytest.approx(5.0, abs=0.5) and want["FIC3"][2] == "none"  # the truth
    got = _sj(dask)
    assert sorted(got) == sorted(want)
    for k in want:  # the same computation wherever it runs
        assert got[k][2] == want[k][2]
        assert got[k][:2] == pytest.approx(want[k][:2], abs=1e-9)
    for res in (pool, dask):
        assert res.n_failed == 1 and (res.out_dir / "loops" / "FIC1" / "FIC1.md").exists()
        # each loop's CPU time in the process that diagnosed it (the pool's workers are not the
        # batch's children, so nothing else can count it)
        ok = [r for r in res.rows if r["status"] == "ok"]
        assert all(0.0 < r["cpu_s"] < 600.0 for r in ok)
        assert {r["loop"]: r["cpu_s"] for r in json.loads((res.out_dir / "summary.json").read_text())["loops"]
                if r["status"] == "ok"} == {r["loop"]: r["cpu_s"] for r in ok}


def test_tag_map_names_the_loop_and_is_part_of_the_input_hash(plant, tmp_path):
    logs = tmp_path / "logs"
    logs.mkdir()
    text = (plant / "logs" / "FIC3.csv").read_text().splitlines()
    text[0] = "time,FV_7,FT_7,FC_7_SETP"
    (logs / "unit7.csv").write_text("\n".join(text) + "\n")
    kw = dict(workers=1, explain=False, narx=False, pdf=False, history=False, progress=False)
    plain = B.run_batch([logs], tmp_path / "o1", **kw)
    assert plain.n_failed == 1 and "OP" in plain.rows[0]["error"]
    tags = tmp_path / "tags.toml"
    tags.write_text('[loops.FIC7]\nop = "FV_7"\npv = "FT_7"\nsp = "FC_7_SETP"\n')
    mapped = B.run_batch([logs], tmp_path / "o2", tags=str(tags), **kw)
    assert mapped.n_failed == 0 and mapped.rows[0]["loop"] == "FIC7"
    again = B.run_batch([logs], tmp_path / "o2", tags=str(tags), **kw)
    assert again.n_skipped == 1
    tags.write_text('[loops.FIC7]\nop = "FV_7"\npv = "FT_7"\n')  # another map: diagnosed again
    changed = B.run_batch([logs], tmp_path / "o2", tags=str(tags), **kw)
    assert changed.n_skipped == 0 and changed.n_failed == 0


def test_two_exports_of_one_tag_keep_both_reports_and_one_history(plant, tmp_path):
    logs = tmp_path / "logs"
    (logs / "jan").mkdir(parents=True)
    (logs / "feb").mkdir()
    (logs / "jan" / "FIC1.csv").write_bytes((plant / "logs" / "FIC1.csv").read_bytes())
    _write_loops(logs / "feb", [("FIC1", 2.5, 0.5)], start=datetime(2026, 2, 1, tzinfo=timezone.utc))
    kw = dict(explain=False, narx=False, pdf=False, db=tmp_path / "h.sqlite", progress=False)
    first = B.run_batch([logs], tmp_path / "out", workers=2, **kw)
    names = {r["source"]: r["loop"] for r in first.rows}
    assert len(set(names.values())) == 2 and first.n_failed == 0
    for src, name in names.items():   # each report holds its own input
        res = json.loads((tmp_path / "out" / "loops" / name / f"{name}.json").read_text())
        assert res["record"]["source"] == src
    again = B.run_batch([logs], tmp_path / "out", workers=1, **kw)   # stable: every name found again
    assert {r["source"]: r["loop"] for r in again.rows} == names and again.n_skipped == 2
    feb = names[str(logs / "feb" / "FIC1.csv")]
    (tmp_path / "out" / "loops" / feb / f"{feb}.json").unlink()   # resume after a lost result
    third = B.run_batch([logs], tmp_path / "out", workers=1, **kw)
    assert {r["source"]: r["loop"] for r in third.rows} == names and third.n_skipped == 1
    with History(tmp_path / "h.sqlite") as h:   # one loop, one history: both exports under the tag
        assert h.loops() == ["FIC1"] and len(h.runs("FIC1")) == 2


def test_the_summary_names_the_file_each_loop_came_from(plant, tmp_path):
    # three copies of one folder: the loops are FIC1, FIC1__FIC1 and FIC1__FIC1_<hash>, and only
    # the file tells a reader of the summary which is which
    copies = [tmp_path / "plant" / day for day in ("mon", "tue", "wed")]
    for c in copies:
        c.mkdir(parents=True)
        shutil.copy(plant / "logs" / "FIC1.csv", c / "FIC1.csv")
    res = B.run_batch(copies, tmp_path / "out", workers=1, explain=False, narx=False, db=tmp_path / "h.sqlite",
                      progress=False)
    assert res.n_failed == 0 and len({r["loop"] for r in res.rows}) == 3
    out = tmp_path / "out"
    truth = {}
    for r in res.rows:   # each loop's own result says which file it read
        src = json.loads((out / "loops" / r["loop"] / f"{r['loop']}.json").read_text())["record"]["source"]
        truth[r["loop"]] = Path(src).relative_to(tmp_path / "plant").as_posix()
    assert sorted(truth.values()) == ["mon/FIC1.csv", "tue/FIC1.csv", "wed/FIC1.csv"]
    with open(out / "summary.csv", newline="") as fh:
        assert {t["loop"]: t["file"] for t in csv.DictReader(fh)} == truth
    assert {r["loop"]: r["file"] for r in json.loads((out / "summary.json").read_text())["loops"]} == truth
    md = (out / "summary.md").read_text()
    header = next(ln for ln in md.splitlines() if ln.startswith("| # | Loop"))
    assert header.rstrip(" |").endswith("| File")
    ranked = [ln for ln in md.splitlines() if ln.startswith("| ") and "](loops/" in ln]
    assert {ln.split("|")[2].strip().split("]")[0].lstrip("["): ln.split("|")[-2].strip() for ln in ranked} == truth
    text = subprocess.run(["pdftotext", "-layout", str(out / "summary.pdf"), "-"], capture_output=True, text=True,
                          check=True).stdout
    for loop, file in truth.items():   # each loop's row holds its file in the PDF too
        assert any(loop + " " in ln and file in ln for ln in text.splitlines()), (loop, file)


def test_a_tag_map_applies_where_it_matches_and_the_rest_is_auto_detected(plant, tmp_path):
    logs = tmp_path / "logs"
    logs.mkdir()
    text = (plant / "logs" / "FIC3.csv").read_text().splitlines()
    text[0] = "time,FV_7,FT_7,FC_7_SETP"
    (logs / "unit7.csv").write_text("\n".join(text) + "\n")
    (logs / "FIC1.csv").write_bytes((plant / "logs" / "FIC1.csv").read_bytes())
    (logs / "broken.csv").write_bytes((plant / "logs" / "broken.csv").read_bytes())
    tags = tmp_path / "tags.toml"
    tags.write_text('[loops.FIC7]\nop = "FV_7"\npv = "FT_7"\nsp = "FC_7_SETP"\n')
    res = B.run_batch([logs], tmp_path / "out", tags=str(tags), workers=1, explain=False, narx=False,
                      pdf=False, history=False, progress=False)
    ok = {r["loop"] for r in res.rows if r["status"] == "ok"}
    assert ok == {"FIC7", "FIC1"}
    bad = [r for r in res.rows if r["status"] != "ok"]
    assert len(bad) == 1 and bad[0]["source"].endswith("broken.csv")
    assert "tag map" in bad[0]["error"] and "without the tag map" in bad[0]["error"]
    fic1 = json.loads((tmp_path / "out" / "loops" / "FIC1" / "FIC1.json").read_text())
    assert any(f["code"] == "tag_map" for f in fic1["data_quality"])
    tags.write_text("[loops.FIC7\nop = ")
    with pytest.raises(Exception) as err:   # a broken map is one error up front
        B.run_batch([logs], tmp_path / "o2", tags=str(tags), workers=1, history=False, progress=False)
    assert "tags.toml" in str(err.value)


def test_prn_exports_are_read_and_other_files_are_listed_as_left_alone(tmp_path, capsys):
    logs = tmp_path / "logs"
    logs.mkdir()
    rec = sticky_loop(4.0, 1.0, n=1500, noise_std=0.03, load_walk_std=0.02, seed=21, name="FIC9")
    with open(logs / "FIC9.prn", "w") as fh:   # a space-aligned export with date and time
        fh.write("Date        Time        FIC9.OP    FIC9.PV    FIC9.SP\n")
        for i in range(rec.n):
            hh, mm, ss = i // 3600, i // 60 % 60, i % 60
            fh.write(f"2026-01-05  {hh:02d}:{mm:02d}:{ss:02d}  {rec.op[i]:9.4f}  {rec.pv[i]:9.4f}  {rec.sp[i]:9.4f}\n")
    (logs / "readme.md").write_text("notes")
    (logs / "plant.xlsx").write_bytes(b"PK\x03\x04")
    rc = main(["batch", str(logs), "--out", str(tmp_path / "out"), "--workers", "1", "--no-narx", "--no-pdf",
               "--no-history", "--quiet"])
    out = capsys.readouterr().out
    assert rc == 0
    doc = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert [r["loop"] for r in doc["loops"]] == ["FIC9"] and doc["loops"][0]["S_pct"] == pytest.approx(4.0, abs=0.6)
    assert sorted(Path(f["path"]).name for f in doc["skipped_files"]) == ["plant.xlsx", "readme.md"]
    assert "left alone: 2 file(s)" in out and "plant.xlsx" in out
    assert "Files left alone" in (tmp_path / "out" / "summary.md").read_text()


def test_files_left_alone_are_reported_with_their_own_reason(plant, tmp_path, capsys):
    logs = tmp_path / "logs"
    logs.mkdir()
    for name in ("FIC1.csv", "FIC2.csv", "FIC3.csv"):
        (logs / name).write_bytes((plant / "logs" / name).read_bytes())
    (logs / "notes.md").write_text("notes")
    rc = main(["batch", str(logs), "--out", str(tmp_path / "out"), "--loop", "FIC2", "--workers", "1", "--no-narx",
               "--no-pdf", "--no-history", "--quiet"])
    out = capsys.readouterr().out
    assert rc == 0
    left = [ln for ln in out.splitlines() if ln.startswith("left alone:")]
    assert left == ["left alone: 1 file(s), not a historian text export: notes.md; listed in the summary",
                    "left alone: 2 file(s), no loop named 'FIC2': FIC1.csv, FIC3.csv; listed in the summary"]


def test_the_batch_counts_loops_apart_from_the_files_and_inputs_it_could_not_read(tmp_path):
    from diagnose.service.commands.batch import report

    ok = {"loop": "FIC1", "status": "ok", "source": "a.csv"}
    cases = [  # (rows, files found) -> the first line
        ([ok, B.failure_row("empty", "empty.csv", "empty.csv: file is empty", "file")], 2,
         "1 loop from 1 file: 1 diagnosed (0 unchanged since the last run), 0 failed; 1 file could not be read"),
        ([B.failure_row("nope.csv", "nope.csv", "nope.csv: no such file or folder", "input")], 0,
         "0 loops from 0 files: 0 diagnosed (0 unchanged since the last run), 0 failed; 1 input not found or "
         "not readable"),
        ([ok, dict(ok, loop="FIC2"), B.failure_row("FIC3", "a.csv", "a.csv: too short")]
         + [B.failure_row(f"x{i}", f"x{i}.csv", "unreadable", "file") for i in range(2)], 3,
         "3 loops from 1 file: 2 diagnosed (0 unchanged since the last run), 1 failed; 2 files could not be read"),
    ]
    for rows, n_files, says in cases:
        stream = io.StringIO()
        report(B.BatchResult(rows=rows, out_dir=tmp_path, n_files=n_files, elapsed_s=1.0, pdf=False), stream)
        assert stream.getvalue().splitlines()[0] == says + ", 1.0 s"


def _two_cases_of_one_tag(folder: Path) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    a = sticky_loop(4.0, 1.0, n=800, noise_std=0.03, seed=31, name="FIC7")
    b = sticky_loop(0.0, 0.0, n=800, noise_std=0.03, seed=32, name="fic7")
    path = folder / "plant.csv"
    with open(path, "w") as fh:
        fh.write("time,FIC7.OP,FIC7.PV,fic7.OP,fic7.PV\n")
        for i in range(a.n):
            fh.write(f"{i},{a.op[i]:.4f},{a.pv[i]:.4f},{b.op[i]:.4f},{b.pv[i]:.4f}\n")
    return path


def test_loop_names_the_loop_exactly_as_identify_does(tmp_path, capsys):
    # the reader keeps FIC7 and fic7 as two loops; --loop FIC7 diagnosed both
    path = _two_cases_of_one_tag(tmp_path / "logs")
    common = ["--workers", "1", "--no-narx", "--no-pdf", "--no-history", "--quiet"]
    for want in ("FIC7", "fic7"):
        out = tmp_path / f"out_{want}"
        assert main(["batch", str(path), "--out", str(out), "--loop", want, *common]) == 0
        doc = json.loads((out / "summary.json").read_text())
        assert [r["loop"] for r in doc["loops"]] == [want]
        capsys.readouterr()
        assert main(["identify", str(path), "--loop", want, "--json"]) == 0
        assert json.loads(capsys.readouterr().out)["loop"] == want
    # a loop that no file holds is an error, as in identify: a nightly job must not pass diagnosing nothing
    assert main(["batch", str(path), "--out", str(tmp_path / "out_x"), "--loop", "Fic7", *common]) == 1
    cap = capsys.readouterr()
    assert "left alone: 1 file(s), no loop named 'Fic7': plant.csv" in cap.out
    assert cap.err.splitlines() == [f"error: no file read holds a loop named 'Fic7'; the loops each file holds "
                                    f"are listed in {tmp_path / 'out_x' / 'summary.md'}"]
    assert "(loops: FIC7, fic7)" in (tmp_path / "out_x" / "summary.md").read_text()


def test_a_tag_without_pv_is_listed_as_left_alone(tmp_path, capsys):
    logs = tmp_path / "logs"
    logs.mkdir()
    rec = sticky_loop(4.0, 1.0, n=1500, noise_std=0.03, seed=22, name="FIC9")
    with open(logs / "plant.csv", "w") as fh:   # FIC8 has its OP exported but not its PV
        fh.write("time,FIC9.OP,FIC9.PV,FIC8.OP\n")
        for i in range(rec.n):
            fh.write(f"{i},{rec.op[i]:.4f},{rec.pv[i]:.4f},{rec.op[i] - 3:.4f}\n")
    rc = main(["batch", str(logs), "--out", str(tmp_path / "out"), "--workers", "1", "--no-narx", "--no-pdf",
               "--no-history", "--quiet"])
    out = capsys.readouterr().out
    assert rc == 0
    doc = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert [r["loop"] for r in doc["loops"]] == ["FIC9"]
    assert [f["reason"] for f in doc["skipped_files"]] == ["a loop without PV: FIC8"]
    assert "left alone: 1 file(s), a loop without PV: FIC8: plant.csv" in out


def test_unreadable_folders_and_files_are_failed_rows_naming_them(plant, tmp_path, monkeypatch, capsys):
    # root reads through chmod 000, so the refusal the kernel would give another user is simulated
    logs = tmp_path / "logs"
    (logs / "locked").mkdir(parents=True)
    (logs / "FIC1.csv").write_bytes((plant / "logs" / "FIC1.csv").read_bytes())
    (logs / "FIC2.csv").write_bytes((plant / "logs" / "FIC2.csv").read_bytes())
    (logs / "locked" / "FIC3.csv").write_bytes((plant / "logs" / "FIC3.csv").read_bytes())
    real_scandir, real_digest = os.scandir, B._file_digest

    def scandir(path="."):
        if Path(path) == logs / "locked":
            raise PermissionError(13, "Permission denied", str(path))
        return real_scandir(path)

    def digest(path):
        if path is not None and Path(path).name == "FIC2.csv":
            raise PermissionError(13, "Permission denied", str(path))
        return real_digest(path)

    monkeypatch.setattr(os, "scandir", scandir)
    monkeypatch.setattr(B, "_file_digest", digest)
    rc = main(["batch", str(logs), "--out", str(tmp_path / "out"), "--workers", "1", "--no-narx", "--no-pdf",
               "--no-history", "--quiet"])
    err = capsys.readouterr().err
    assert rc == 1
    doc = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert [r["loop"] for r in doc["loops"] if r["status"] == "ok"] == ["FIC1"]
    errors = {r["loop"]: r["error"] for r in doc["loops"] if r["status"] != "ok"}
    assert errors == {"FIC2": f"{logs / 'FIC2.csv'}: cannot read: Permission denied",
                      "locked": f"{logs / 'locked'}: cannot read the folder: Permission denied"}
    assert f"failed: locked ({logs / 'locked'}): {logs / 'locked'}: cannot read the folder" in err


def test_out_must_be_a_folder(plant, tmp_path):
    taken = tmp_path / "loop.csv"
    taken.write_text("a file, not a folder")
    for out, says in ((taken, "--out must be a folder"), (taken / "sub", "cannot create the output folder")):
        proc = subprocess.run([sys.executable, "-m", "diagnose.service.cli", "batch", str(plant / "logs" / "FIC1.csv"),
                               "--out", str(out), "--no-history", "--quiet"], capture_output=True, text=True,
                              timeout=120)
        err = proc.stderr.strip().splitlines()
        assert proc.returncode == 1 and len(err) == 1 and err[0].startswith(f"error: {out}: "), proc.stderr
        assert says in err[0] and "Errno" not in err[0]


def test_no_pdf_announces_no_pdf(plant, tmp_path, capsys):
    logs = tmp_path / "logs"
    logs.mkdir()
    (logs / "FIC3.csv").write_bytes((plant / "logs" / "FIC3.csv").read_bytes())
    base = ["batch", str(logs), "--workers", "1", "--no-narx", "--no-history", "--quiet"]
    assert main(base + ["--out", str(tmp_path / "o1"), "--no-pdf"]) == 0
    out = capsys.readouterr().out
    assert ".pdf" not in out and not list((tmp_path / "o1").rglob("*.pdf"))
    assert main(base + ["--out", str(tmp_path / "o2")]) == 0
    assert ".pdf" in capsys.readouterr().out and (tmp_path / "o2" / "summary.pdf").exists()
    assert len(list((tmp_path / "o2" / "loops").rglob("*.pdf"))) == 1


def test_no_pdf_over_an_earlier_run_leaves_no_pdf_of_that_run(plant, tmp_path):
    # a PDF from the run before would sit beside this run's summary and loop reports and disagree
    logs = tmp_path / "logs"
    logs.mkdir()
    (logs / "FIC3.csv").write_bytes((plant / "logs" / "FIC3.csv").read_bytes())
    base = ["batch", str(logs), "--out", str(tmp_path / "o"), "--workers", "1", "--no-narx", "--no-history",
            "--quiet"]
    assert main(base) == 0
    assert len(list((tmp_path / "o").rglob("*.pdf"))) == 2
    # the loop's data change, so its reports are written again, without a PDF
    lines = (logs / "FIC3.csv").read_text().splitlines(keepends=True)
    (logs / "FIC3.csv").write_text("".join(lines[:-200]))
    assert main(base + ["--no-pdf"]) == 0
    assert not list((tmp_path / "o").rglob("*.pdf"))
    assert (tmp_path / "o" / "summary.md").is_file() and list((tmp_path / "o" / "loops").rglob("*.md"))
    assert len(set(B.summary_run_ids(tmp_path / "o").values())) == 1


def _children(pid: int) -> list[int]:
    """Every live descendant of a process (from /proc)."""
    parent: dict[int, int] = {}
    for d in Path("/proc").iterdir():
        if d.name.isdigit():
            try:
                stat = (d / "stat").read_text()
            except OSError:
                continue
            fields = stat[stat.rfind(")") + 2:].split()
            if fields[0] != "Z":
                parent[int(d.name)] = int(fields[1])
    out, todo = [], [pid]
    while todo:
        p = todo.pop()
        kids = [c for c, pp in parent.items() if pp == p]
        out += kids
        todo += kids
    return out


def _unit_files(logs: Path, n_files: int = 4, n: int = 1500) -> None:
    """Files of three loops each (four by default): a worker's task lasts several seconds."""
    logs.mkdir()
    for k in range(n_files):
        recs = [sticky_loop(3.0, 1.0, n=n, noise_std=0.03, seed=40 + 3 * k + j, name=f"L{k}{j}")
                for j in range(3)]
        cols = [f"{r.name}.{role.upper()}" for r in recs for role in ("op", "pv", "sp")]
        lines = ["time," + ",".join(cols)]
        for i in range(n):
            lines.append(f"{i}," + ",".join(f"{getattr(r, role)[i]:.4f}" for r in recs for role in ("op", "pv", "sp")))
        (logs / f"unit{k}.csv").write_text("\n".join(lines) + "\n")


def _alive(pids: list[int]) -> list[int]:
    return [p for p in pids if Path(f"/proc/{p}").exists()
            and "Z" not in Path(f"/proc/{p}/stat").read_text().split(")")[-1][:3]]


@pytest.mark.skipif(not Path("/proc").is_dir(), reason="needs /proc to find the worker processes")
def test_kill_9_of_the_batch_takes_its_workers_with_it(tmp_path):
    logs = tmp_path / "logs"
    _unit_files(logs)
    out = tmp_path / "out"
    cmd = [sys.executable, "-m", "diagnose.service.cli", "batch", str(logs), "--out", str(out), "--workers", "2",
           "--no-narx", "--no-pdf", "--no-history", "--quiet"]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and not list(out.glob("loops/*/*.png")):
            time.sleep(0.05)   # workers are diagnosing and writing
        workers = _children(proc.pid)
        assert len(workers) >= 2, "no worker processes found"
        proc.send_signal(signal.SIGKILL)
        proc.wait()
        deadline = time.monotonic() + 5.0
        while time.monotonic() < deadline and _alive(workers):
            time.sleep(0.1)
        left = _alive(workers)
        assert not left, f"workers {left} outlived the batch"
        written = sorted(p for p in out.rglob("*") if p.is_file())
        time.sleep(3.0)
        assert sorted(p for p in out.rglob("*") if p.is_file()) == written, "files written after the kill"
    finally:
        for p in _children(proc.pid):
            try:
                os.kill(p, signal.SIGKILL)
            except OSError:
                pass
        if proc.poll() is None:
            proc.kill()


@pytest.mark.skipif(not Path("/proc").is_dir(), reason="needs /proc to find the worker processes")
def test_ctrl_c_stops_a_parallel_batch_at_once_and_a_rerun_resumes(tmp_path):
    # Ctrl-C goes to the whole process group. The batch used to wait for its workers: they ran the
    # files already queued to the end, and now and then hung for good on a half-read task queue.
    logs = tmp_path / "logs"
    _unit_files(logs, n_files=6, n=3000)   # long enough that Ctrl-C lands mid-run on a busy machine
    interrupted, last = 0, None
    for attempt in range(5):   # the hang was a race: Ctrl-C at a few different moments
        if interrupted == 3:
            break
        out, db = tmp_path / f"out{attempt}", tmp_path / f"h{attempt}.sqlite"
        cmd = [sys.executable, "-m", "diagnose.service.cli", "batch", str(logs), "--out", str(out), "--workers",
               "2", "--no-narx", "--no-pdf", "--db", str(db), "--quiet"]
        # a test run started in the background (CI, nohup) ignores SIGINT, and a child would inherit
        # that: the batch is started as from a terminal, with Ctrl-C's default action
        proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                                start_new_session=True,
                                preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
        try:
            deadline = time.monotonic() + 120
            while time.monotonic() < deadline and not list(out.glob("loops/*/*.json")):
                time.sleep(0.05)
            time.sleep(0.3 * (attempt % 3))
            workers = _children(proc.pid)
            if proc.poll() is not None:
                continue   # the test was starved and the batch finished first: not a Ctrl-C run
            assert len(workers) >= 2, "no worker processes found"
            os.killpg(proc.pid, signal.SIGINT)
            t0 = time.monotonic()
            try:
                _, err = proc.communicate(timeout=20)
            except subprocess.TimeoutExpired:
                pytest.fail(f"attempt {attempt}: the batch did not stop within 20 s of Ctrl-C")
            took = time.monotonic() - t0
            if proc.returncode == 0 and (out / "summary.json").exists():
                continue   # finished between the last look and the signal
            interrupted, last = interrupted + 1, (out, db)
            assert proc.returncode == 130 and err.strip().endswith("interrupted"), err
            # at once: the workers are killed, not waited for (waiting took 1.7 s here, or forever)
            assert took < 1.0, f"attempt {attempt}: Ctrl-C took {took:.1f} s"
            deadline = time.monotonic() + 5.0
            while time.monotonic() < deadline and _alive(workers):
                time.sleep(0.1)
            assert not _alive(workers), "workers outlived the interrupted batch"
        finally:
            if proc.poll() is None:
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait()
    assert interrupted >= 2, f"only {interrupted} of the runs were interrupted mid-way"
    out, db = last
    done = {p.stem for p in out.glob("loops/*/*.json")}
    assert 1 <= len(done) < 18 and not (out / "summary.json").exists()
    res = B.run_batch([logs], out, workers=2, explain=False, narx=False, pdf=False, db=db, progress=False)
    assert {r["loop"] for r in res.rows if r.get("skipped")} == done and res.n_failed == 0
    ref = B.run_batch([logs], tmp_path / "ref", workers=2, explain=False, narx=False, pdf=False, history=False,
                      progress=False)
    assert _sj(res) == _sj(ref) and len(_sj(ref)) == 18
    with History(db) as h:   # loops finished but not collected before Ctrl-C reach history on the re-run
        assert all(len(h.runs(loop)) == 1 for loop in _sj(ref))


@pytest.mark.parametrize("workers,scheduler", [(1, None), (2, None), (3, "local"), (2, "tcp://10.0.0.1:8786")])
def test_workers_share_the_cores_between_their_threads(plant, tmp_path, monkeypatch, workers, scheduler):
    # each worker's fits run on threads too: workers x threads must not exceed the cores here, and
    # a remote scheduler's machines are unknown (one thread each)
    seen = []
    monkeypatch.setattr(B, "make_executor", lambda n, sched: B._Inline())
    monkeypatch.setattr(B, "process_file", lambda cfg, path: seen.append(cfg.threads) or {
        "path": path, "digest": None, "rows": []})
    from diagnose import parallel

    monkeypatch.setattr(parallel, "usable_cores", lambda: 4)
    logs = tmp_path / "logs"
    logs.mkdir()
    for name in ("FIC1.csv", "FIC2.csv", "FIC3.csv"):
        (logs / name).write_bytes((plant / "logs" / name).read_bytes())
    B.run_batch([logs], tmp_path / "out", workers=workers, scheduler=scheduler, history=False, progress=False)
    want = 1 if scheduler and scheduler != "local" else 4 // min(workers, 3)
    assert seen == [want] * 3


def test_a_missing_input_folder_is_a_one_line_error_and_writes_no_summary(tmp_path, capsys):
    out = tmp_path / "out"
    rc = main(["batch", str(tmp_path / "nope"), "--out", str(out), "--workers", "1", "--no-history", "--quiet"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 1
    assert err == [f"error: {tmp_path / 'nope'}: no such file or folder"]
    assert not (out / "summary.json").exists() and not (out / "summary.md").exists()
    # as an empty folder is
    (tmp_path / "empty").mkdir()
    assert main(["batch", str(tmp_path / "empty"), "--out", str(out), "--quiet", "--no-history"]) == 1
    assert capsys.readouterr().err.startswith("error: no input files found")


def test_the_summary_bullets_name_the_file_each_loop_came_from():
    from diagnose.service.report import summary_blocks, to_markdown

    # two exports of one tag, both sticky and degrading: only the file tells the bullets apart
    rows = [{"loop": loop, "status": "ok", "rank": i + 1, "severity": 60.0, "sticky": True, "S_pct": 3.0,
             "J_pct": 1.0, "degradation": "S grew from 1.00 % to 3.00 %", "action": "Schedule valve maintenance.",
             "file": file, "source": f"/plant/{file}"}
            for i, (loop, file) in enumerate([("FIC1", "mon/FIC1.csv"), ("FIC1__FIC1", "tue/FIC1.csv")])]
    md = to_markdown(summary_blocks(rows))
    bullets = [ln for ln in md.splitlines() if ln.startswith("- ")]
    assert bullets == ["- FIC1 (mon/FIC1.csv): S grew from 1.00 % to 3.00 %",
                       "- FIC1__FIC1 (tue/FIC1.csv): S grew from 1.00 % to 3.00 %",
                       "- FIC1 (mon/FIC1.csv): Schedule valve maintenance.",
                       "- FIC1__FIC1 (tue/FIC1.csv): Schedule valve maintenance."]
    # a row of a batch without a shown file (an earlier release) names its source
    md = to_markdown(summary_blocks([dict(rows[0], file=None)]))
    assert "- FIC1 (/plant/mon/FIC1.csv): Schedule valve maintenance." in md.splitlines()


def test_healthy_loops_have_no_s_or_j_in_the_summary_and_history_shows_none(first_run, plant, capsys):
    out, res = first_run
    healthy = {r["loop"] for r in res.rows if r["status"] == "ok" and not r["sticky"]}
    sticky = {r["loop"] for r in res.rows if r["status"] == "ok" and r["sticky"]}
    assert "FIC3" in healthy and "FIC1" in sticky
    size = ("S_pct", "S_lo", "S_hi", "J_pct", "J_lo", "J_hi")
    with open(out / "summary.csv", newline="") as fh:
        csv_rows = {r["loop"]: r for r in csv.DictReader(fh)}
    json_rows = {r["loop"]: r for r in json.loads((out / "summary.json").read_text())["loops"]}
    for loop in healthy:
        assert [csv_rows[loop][k] for k in size] == [""] * 6
        assert [json_rows[loop][k] for k in size] == [None] * 6
    for loop in sticky:
        assert float(csv_rows[loop]["S_pct"]) > 1.0 and json_rows[loop]["S_lo"] is not None
    # the history keeps the full result as stored; what `stiction history` prints shows no size
    with History(plant / "h.sqlite") as h:
        stored = h.runs("FIC3")[-1]
    assert stored["stiction"] == 0 and stored["S_pct"] is not None

    def size_cells(loop):   # the S %, S interval and J % cells of the loop's run
        assert main(["history", loop, "--db", str(plant / "h.sqlite")]) == 0
        head, line = capsys.readouterr().out.splitlines()[1:3]
        return line[head.index("P(st.)") + len("P(st.)"):head.index("class")].split()

    assert size_cells("FIC3") == ["-", "-", "-"]
    assert float(size_cells("FIC1")[0]) > 3.0
    assert main(["history", "FIC3", "--db", str(plant / "h.sqlite"), "--json"]) == 0
    assert [r["S_pct"] for r in json.loads(capsys.readouterr().out)["runs"]] == [None]


def test_a_folder_of_one_day_exports_shares_one_date_order_in_the_batch(tmp_path):
    # the batch reads each file on its own: alone, 05/03/2026 and 06/03/2026 each read month first
    src = Path(__file__).parent / "data_connectors" / "excel_uk_one_day.csv"
    lines = src.read_text().splitlines()
    logs = tmp_path / "logs"
    logs.mkdir()
    for day in (5, 6):
        (logs / f"day{day}.csv").write_text("\n".join([lines[0]] + [f"{day:02d}/03/2026" + ln[10:]
                                                                     for ln in lines[1:]]) + "\n")

    def starts(out, **kw):
        res = B.run_batch([logs], out, workers=1, explain=False, narx=False, pdf=False, history=False,
                          progress=False, **kw)
        assert res.n_failed == 0
        got = {}
        for r in res.rows:
            doc = json.loads((out / "loops" / r["loop"] / f"{r['loop']}.json").read_text())
            codes = {w["code"] for w in doc["warnings"]}
            got[Path(doc["record"]["source"]).name] = (doc["record"]["start"][:10], "data_quality.date_order" in codes)
        return got

    assert starts(tmp_path / "out") == {"day5.csv": ("2026-03-05", False), "day6.csv": ("2026-03-06", False)}
    # --monthfirst still decides
    assert starts(tmp_path / "us", read_options={"dayfirst": False}) == {"day5.csv": ("2026-05-03", False),
                                                                        "day6.csv": ("2026-06-03", False)}


def test_the_summary_keeps_a_small_probability_small_not_zero():
    # P(stiction) of a healthy loop is about 2e-5: the summary says "< 1 %", as the history does
    from diagnose.plain import percent
    from diagnose.service.batch import loop_row
    from diagnose.service.pipeline import diagnose
    from diagnose.simulate import sticky_loop

    d = diagnose(sticky_loop(0.0, 0.0, n=1500, noise_std=0.02, load_walk_std=0.02, seed=0), narx=False)
    p = d.identification.stiction_probability
    assert 0 < p < 0.005
    row = loop_row(d, None)
    assert row["stiction_probability"] == pytest.approx(p, rel=1e-3)
    assert percent(row["stiction_probability"]) == "< 1 %"


def test_second_batch_on_the_same_out_is_refused_in_one_line(tmp_path, capsys):
    """Two batches writing one output folder would overwrite each other's summary: while one holds
    the folder (`lock_out_dir`, an flock), another is refused before it reads anything, in one line."""
    _write_loops(tmp_path / "logs", loops=LOOPS[:1], n=600)
    out = tmp_path / "out"
    out.mkdir()
    held = B.lock_out_dir(out)
    try:
        rc = main(["batch", str(tmp_path / "logs"), "--out", str(out), "--no-history", "--workers", "1",
                   "--no-pdf", "--quiet"])
        err = capsys.readouterr().err
        assert rc == 1
        assert err.count("\n") == 1 and "Traceback" not in err
        assert f"{out}: another stiction batch (process {os.getpid()})" in err and "--out" in err
        assert not (out / "summary.json").exists() and not (out / "loops").exists()
    finally:
        held.close()
    B.lock_out_dir(out).close()  # released: the folder is free again


def test_out_folder_that_cannot_be_written_is_one_line_before_any_work(tmp_path, monkeypatch):
    """An output folder that exists but cannot be written (read-only mount, no permission) is said
    up front, naming the folder, not after every loop was diagnosed and the summary failed."""
    out = tmp_path / "out"
    out.mkdir()
    real_open = open

    def ro_open(file, *a, **k):
        if str(file).startswith(str(out)):
            raise OSError(30, "Read-only file system")
        return real_open(file, *a, **k)

    monkeypatch.setattr("builtins.open", ro_open)
    with pytest.raises(B.DataError, match=r"out: cannot write to the output folder: Read-only file system"):
        B.run_batch([tmp_path], out, workers=1, history=False, progress=False)


def test_pdfs_on_or_off_do_not_store_a_second_history_row_and_a_pdf_run_writes_them(plant, tmp_path):
    logs = tmp_path / "logs"
    logs.mkdir()
    (logs / "FIC1.csv").write_bytes((plant / "logs" / "FIC1.csv").read_bytes())
    db, out = tmp_path / "h.sqlite", tmp_path / "out"
    B.run_batch([logs], out, workers=1, explain=False, narx=False, pdf=False, db=db, progress=False)
    assert not (out / "loops" / "FIC1" / "FIC1.pdf").exists()
    # a run that wants the PDFs writes them (the earlier run did not), under the same input hash
    res = B.run_batch([logs], out, workers=1, explain=False, narx=False, pdf=True, db=db, progress=False)
    assert not res.rows[0].get("skipped") and (out / "loops" / "FIC1" / "FIC1.pdf").is_file()
    # and a run without them afterwards reuses the loop as it is
    res = B.run_batch([logs], out, workers=1, explain=False, narx=False, pdf=False, db=db, progress=False)
    assert res.rows[0].get("skipped")
    with History(db, readonly=True) as h:
        assert len(h.runs("FIC1")) == 1


@pytest.mark.parametrize("kind", ["missing", "broken"])
def test_a_bad_tag_map_is_one_line_and_leaves_no_output_folder(plant, tmp_path, capsys, kind):
    tags = tmp_path / "tags.toml"
    if kind == "broken":
        tags.write_text("[loops.FIC1]\nop = { tag = \"FIC1.OP\", range = [0, 0] }\n")
    out = tmp_path / "new" / "out"
    rc = main(["batch", str(plant / "logs" / "FIC1.csv"), "--out", str(out), "--workers", "1", "--no-pdf",
               "--tags", str(tags), "--db", str(tmp_path / "h.sqlite"), "--quiet"])
    cap = capsys.readouterr()
    assert rc == 1
    assert cap.err.startswith("error: ") and str(tags.name) in cap.err and cap.err.count("\n") == 1, cap.err
    assert "Traceback" not in cap.err and cap.out == ""
    assert not out.exists() and not (tmp_path / "new").exists()


@pytest.mark.parametrize("kind", ["folder", "damaged", "under_a_file"])
def test_a_bad_db_is_one_line_and_leaves_no_output_folder(plant, tmp_path, capsys, kind):
    """A --db the batch cannot use is refused before the output folder (and its lock) is made."""
    db = {"folder": tmp_path / "dbdir", "damaged": tmp_path / "h.sqlite",
          "under_a_file": tmp_path / "plain" / "h.sqlite"}[kind]
    if kind == "folder":
        db.mkdir()
    elif kind == "damaged":
        db.write_bytes(b"this is no sqlite database\n" * 200)
    else:
        (tmp_path / "plain").write_text("a file, not a folder\n")
    out = tmp_path / "new" / "out"
    rc = main(["batch", str(plant / "logs" / "FIC1.csv"), "--out", str(out), "--workers", "1", "--no-pdf",
               "--db", str(db), "--quiet"])
    cap = capsys.readouterr()
    assert rc == 1
    assert cap.err.startswith(f"error: {db}: ") and cap.err.count("\n") == 1, cap.err
    assert "Traceback" not in cap.err and cap.out == ""
    assert not out.exists() and not (tmp_path / "new").exists()


def _pdf_run_id(path: Path) -> str | None:
    info = subprocess.run(["pdfinfo", str(path)], capture_output=True, text=True, check=True).stdout
    subject = [ln.split(":", 1)[1].strip() for ln in info.splitlines() if ln.startswith("Subject:")]
    return subject[0].removeprefix("stiction run ") if subject else None


def _summary_ids(out: Path) -> dict[str, str | None]:
    return {**B.summary_run_ids(out), "summary.pdf": _pdf_run_id(out / "summary.pdf")}


def _summary_bytes(out: Path) -> dict[str, bytes]:
    return {name: (out / name).read_bytes() for name in B.SUMMARY_FILES}


def test_the_summary_files_are_replaced_as_one_set(first_run, tmp_path, monkeypatch):
    """A summary whose PDF cannot be made leaves the last run's four files as they were; one cut
    off while its files were being moved into place is recognisable by its run ids and is finished
    by the next batch on the folder."""
    import diagnose.service.pdf as pdf_mod

    rows = B.rank([dict(r) for r in first_run[1].rows])
    out = tmp_path / "out"
    first = B.write_summary(out, rows, meta={"generated_at": "2026-11-26T01:00:00Z"})
    assert set(_summary_ids(out).values()) == {first}
    old = _summary_bytes(out)

    def broken_pdf(*args, **kw):
        raise RuntimeError("no room for the PDF")

    # a later file fails: the earlier ones of this run must not have replaced the last run's
    monkeypatch.setattr(pdf_mod, "to_pdf", broken_pdf)
    with pytest.raises(RuntimeError, match="no room"):
        B.write_summary(out, rows[:1], meta={"generated_at": "2026-11-26T02:00:00Z"})
    monkeypatch.undo()
    assert _summary_bytes(out) == old
    assert not (out / B.STATE_DIR / "summary-next").exists()

    # killed between two renames: summary.csv is the new run's, summary.json still the last one's
    real_replace = os.replace

    def killed_at_the_markdown(src, dst):
        if Path(dst) == out / "summary.md":
            raise KeyboardInterrupt
        return real_replace(src, dst)

    monkeypatch.setattr(os, "replace", killed_at_the_markdown)
    with pytest.raises(KeyboardInterrupt):
        B.write_summary(out, rows[:1], meta={"generated_at": "2026-11-26T03:00:00Z"})
    monkeypatch.undo()
    ids = _summary_ids(out)
    cut = ids["summary.csv"]
    assert cut not in (None, first) and ids["summary.json"] == first != cut   # told apart by their ids
    # the next batch on the folder (here one with nothing to read) finishes that set first
    empty = tmp_path / "empty"
    empty.mkdir()
    assert main(["batch", str(empty), "--out", str(out), "--quiet", "--no-history"]) == 1
    assert set(_summary_ids(out).values()) == {cut}
    doc = json.loads((out / "summary.json").read_text())
    assert doc["generated_at"] == "2026-11-26T03:00:00Z" and len(doc["loops"]) == 1
    assert not (out / B.STATE_DIR / "summary-next").exists()


def test_a_file_the_tag_map_names_no_loop_in_is_read_with_the_maps_reading_options(tmp_path):
    """The naming rule finds the loops of such a file; the map's date order and time zone still
    read its times."""
    rec = sticky_loop(3.0, 1.0, n=600, noise_std=0.03, load_walk_std=0.02, seed=7, name="FIC9").replace(mv=None)
    lines = ["time,FIC9.OP,FIC9.PV"]
    for k in range(rec.n):   # 5 March 2026 from midnight, local time, day first: 05/03 alone cannot say which
        hh, mm, ss = k // 3600, k // 60 % 60, k % 60
        lines.append(f"05/03/2026 {hh:02d}:{mm:02d}:{ss:02d},{rec.op[k]:.6g},{rec.pv[k]:.6g}")
    path = tmp_path / "FIC9.csv"
    path.write_text("\n".join(lines) + "\n")
    tags = tmp_path / "map.toml"
    tags.write_text('dayfirst = true\ntz = "Europe/Berlin"\n\n[loops.TIC1]\nop = "TV_1"\npv = "TT_1"\n')
    records = B.read_file(B.BatchConfig(out_dir=str(tmp_path / "out"), tags=str(tags)), path)
    assert [r.name for r in records] == ["FIC9"]
    rec9 = records[0]
    assert any(f.code == "tag_map" for f in rec9.findings)
    # 00:00 on 5 March in Berlin (UTC+1): not 3 May, not read as UTC
    assert str(rec9.start).startswith("2026-03-04T23:00:00"), rec9.start
    assert not any("date" in f.code for f in rec9.findings), [f.code for f in rec9.findings]
    # an option given to the batch wins over the map's, as where the map names a loop
    cfg = B.BatchConfig(out_dir=str(tmp_path / "out"), tags=str(tags), read_options={"tz": "UTC"})
    assert str(B.read_file(cfg, path)[0].start).startswith("2026-03-05T00:00:00")


def test_the_summary_pdf_keeps_its_words_and_shows_valve_activity_in_each_loops_units(tmp_path):
    # a plant's deep export folders give long paths: on a portrait page the table's narrow columns
    # cut words ("Severi/ty"). Three units of OP: % of span, a fraction of span (0..1, no stem
    # position to rescale it) and engineering units (outside 0..100)
    from diagnose.plain import number

    logs = tmp_path / "plant_north" / "unit_400_distillation" / "nightly_historian_exports" / "area_51_cooling"
    logs.mkdir(parents=True)
    ops = {"FIC1": lambda op: op, "FV2": lambda op: op / 100.0, "TV3": lambda op: 4.0 + 0.16 * op - 20.0}
    for i, (name, scale) in enumerate(ops.items()):
        rec = sticky_loop(4.0, 1.0, n=1500, noise_std=0.03, load_walk_std=0.02, seed=20 + i, name=name)
        write_wide(rec.replace(op=scale(rec.op), mv=None), logs / f"{name}_export_2026-11-26.csv")
    out = tmp_path / "out"
    res = B.run_batch([tmp_path / "plant_north"], out, workers=1, explain=False, narx=False, history=False,
                      progress=False)
    assert res.n_failed == 0
    with open(out / "summary.csv", newline="") as fh:
        rows = {r["loop"]: r for r in csv.DictReader(fh)}
    assert {k: (r["sj_units"], r["sj_in_op_units"]) for k, r in rows.items()} == {
        "FIC1": ("% of span", "False"), "FV2": ("fraction of span", "True"), "TV3": ("OP units", "True")}
    assert all(float(r["travel_pct_per_day"]) > 0 and float(r["reversals_per_day"]) > 0 for r in rows.values())

    # Markdown: the two activity columns, each loop's travel in its own units
    md = (out / "summary.md").read_text()
    header = next(ln for ln in md.splitlines() if ln.startswith("| # | Loop"))
    cols = [c.strip() for c in header.strip("|").split("|")]
    assert "Travel %/day" in cols and "Reversals/day" in cols
    for loop, r in rows.items():
        line = next(ln for ln in md.splitlines() if f"[{loop}](" in ln)
        cells = [c.strip() for c in line.strip("|").split("|")]
        travel = number(float(r["travel_pct_per_day"]))
        want = travel if r["sj_units"] == "% of span" else f"{travel} ({r['sj_units']})"
        assert cells[cols.index("Travel %/day")] == want
        assert cells[cols.index("Reversals/day")] == number(float(r["reversals_per_day"]))

    # the PDF, read by poppler: landscape, every header word whole, the new columns and values there
    pdf = out / "summary.pdf"
    info = subprocess.run(["pdfinfo", str(pdf)], capture_output=True, text=True, check=True).stdout
    w, h = (float(v) for v in next(ln for ln in info.splitlines() if ln.startswith("Page size:")).split()[2:5:2])
    assert w > h, info
    # -raw: the text in the order it was drawn, so a cell's lines follow each other
    text = subprocess.run(["pdftotext", "-raw", str(pdf), "-"], capture_output=True, text=True, check=True).stdout
    table = text.split("Loops ranked by severity", 1)[1].split("Recommended actions", 1)[0]
    words = table.split()
    for word in "# Loop Severity Class S % J % P(stiction) Conf. Oscillation Travel %/day Reversals/day DQ warn. File".split():
        assert word in words, f"header word {word!r} split or missing"
    segments = re.split(r"^\d+ (?=(?:FIC1|FV2|TV3) )", table, flags=re.M)[1:]
    assert [seg.split()[0] for seg in segments] == [loop for loop, _ in sorted(rows.items(), key=lambda kv: int(kv[1]["rank"]))]
    for seg in segments:
        r = rows[seg.split()[0]]
        assert number(float(r["travel_pct_per_day"])) in seg.split()
        assert number(float(r["reversals_per_day"])) in seg.split()
        # a path too long for its column breaks after a '/', never inside a name
        lines = seg.splitlines()
        start = next(i for i, ln in enumerate(lines) if ln.startswith("plant_north/"))
        path = []
        while len("".join(path)) < len(r["file"]):
            path.append(lines[start + len(path)].strip())
        assert "".join(path) == r["file"] and all(p.endswith("/") for p in path[:-1]), path


def test_a_fraction_of_span_loop_s_history_figure_gets_this_run_in_its_units(tmp_path, monkeypatch):
    """The loop report's history figure adds this run to the stored ones: in the same units, or a
    fraction-of-span S would be drawn as a size in % of span."""
    from diagnose.service import figures as figs

    logs = tmp_path / "logs"
    logs.mkdir()
    seen = []
    real = figs.history
    monkeypatch.setattr(figs, "history", lambda rows: seen.append(list(rows)) or real(rows))
    for day, seed in (("2026-11-25", 31), ("2026-11-26", 32)):
        rec = sticky_loop(4.0, 1.0, n=1500, noise_std=0.03, load_walk_std=0.02, seed=seed, name="FV2")
        write_wide(rec.replace(op=rec.op / 100.0, mv=None, start=f"{day}T00:00:00Z"), logs / f"FV2_{day}.csv")
        B.run_batch([logs / f"FV2_{day}.csv"], tmp_path / f"out_{day}", workers=1, explain=False, narx=False,
                    pdf=False, db=tmp_path / "h.sqlite", progress=False)
    rows = seen[-1]
    assert len(rows) == 2 and {r.get("sj_units") for r in rows} == {"fraction of span"}
    assert all(r["S_pct"] < 0.2 for r in rows)     # fractions of span, both runs


def test_a_scheduler_address_dask_cannot_parse_is_a_one_line_error(tmp_path, capsys):
    src = tmp_path / "FIC1.csv"
    write_wide(sticky_loop(3.0, 1.0, n=600, seed=1, name="FIC1"), src)
    assert main(["batch", str(src), "--out", str(tmp_path / "out"), "--scheduler", "bogus", "--no-history",
                 "--no-pdf", "--quiet"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: cannot reach the Dask scheduler at 'bogus'")
    assert "tcp://" in err[0] and "Traceback" not in err[0]


def test_tags_with_letters_beyond_ascii_keep_their_own_names(tmp_path):
    # two valves whose tags differ only in an umlaut: each keeps its name in the summary, its own
    # report folder and its own history
    _write_loops(tmp_path / "in", loops=[("Ventil_ü", 3.0, 1.0), ("Ventil_ä", 2.0, 0.0)], n=1000)
    assert B.safe_name("Ventil_ü") == "Ventil_ü" and B.safe_name("FIC 101/A") == "FIC_101_A"
    db = tmp_path / "h.sqlite"
    res = B.run_batch([tmp_path / "in"], tmp_path / "out", workers=1, history=True, db=db, pdf=False,
                      progress=False)
    loops = sorted(r["loop"] for r in res.rows)
    assert loops == ["Ventil_ä", "Ventil_ü"]
    assert (tmp_path / "out" / "loops" / "Ventil_ü" / "Ventil_ü.json").exists()
    with History(db) as h:
        assert sorted(h.loops()) == loops
