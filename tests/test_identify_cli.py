"""`stiction identify`: JSON on stdout only, human summary, --ts, loops/segments, bad files."""

import json

import numpy as np
import pytest

import diagnose
from connectors.historian import write_wide
from diagnose.errors import DataError
from diagnose.record import LoopRecord
from diagnose.service.cli import main
from diagnose.service.commands._loopfile import select_record
from diagnose.simulate import sticky_loop

KEYS = {"loop", "stiction", "class", "S", "J", "S_interval", "J_interval", "process", "fit",
        "oscillation", "warnings"}


@pytest.fixture(scope="module")
def sticky_csv(tmp_path_factory):
    rec = sticky_loop(4.0, 1.5, n=1500, gain=1.5, tau_s=20.0, delay_s=3.0, noise_std=0.02,
                      load_walk_std=0.01, seed=1, name="FIC7").replace(mv=None)
    path = tmp_path_factory.mktemp("cli") / "fic7.csv"
    write_wide(rec, path)
    return path


def test_json_output_is_exactly_one_object(sticky_csv, capsys):
    assert main(["identify", str(sticky_csv), "--json"]) == 0
    out = capsys.readouterr().out
    d = json.loads(out)                                  # the whole stdout parses
    assert out.strip().count("\n") == 0
    assert KEYS <= set(d)
    assert d["loop"] == "FIC7" and d["stiction"] is True and d["class"] == "undershoot"
    assert 3.5 < d["S"] < 4.5


def test_human_summary(sticky_csv, capsys):
    assert main(["identify", str(sticky_csv)]) == 0
    out = capsys.readouterr().out
    assert "FIC7: STICTION" in out and "S = " in out and "process:" in out


def test_summary_gives_no_percent_sign_to_s_and_j_in_ops_own_units(tmp_path, capsys):
    # OP in engineering units (here 0..400 for 0..100 %): S and J come out in OP's units, and the
    # summary line must not call them % while saying they are not
    rec = sticky_loop(4.0, 1.5, n=1500, gain=1.5, tau_s=20.0, delay_s=3.0, noise_std=0.02,
                      load_walk_std=0.01, seed=1, name="FIC7").replace(mv=None)
    path = tmp_path / "eu.csv"
    write_wide(rec.replace(op=4.0 * rec.op), path)
    assert main(["identify", str(path)]) == 0
    line = next(ln for ln in capsys.readouterr().out.splitlines() if ln.strip().startswith("S = "))
    assert "OP's own units" in line and "%" not in line.split("(")[0]


def test_ts_seconds_overrides_the_sample_period(sticky_csv, capsys):
    assert main(["identify", str(sticky_csv), "--ts", "2", "--json"]) == 0
    d = json.loads(capsys.readouterr().out)
    assert d["ts_s"] == 2.0
    assert d["oscillation"]["period_s"] is None or d["oscillation"]["period_s"] > 0


def test_constant_op_is_a_one_line_error(tmp_path, capsys):
    rng = np.random.default_rng(0)
    rec = LoopRecord(name="FIC8", ts_s=1.0, op=np.full(400, 37.0), pv=rng.normal(size=400))
    path = tmp_path / "flat.csv"
    write_wide(rec, path)
    assert main(["identify", str(path), "--json"]) == 1
    cap = capsys.readouterr()
    assert cap.out == ""
    err = cap.err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error:") and "OP is constant" in err[0]
    assert err[0].startswith(f"error: {path}: ")   # the file given, not only the loop in it
    assert "Traceback" not in cap.err


def test_a_too_short_record_names_the_file(tmp_path, capsys):
    rec = sticky_loop(4.0, 1.5, n=20, seed=1, name="FIC9")
    path = tmp_path / "short20.csv"
    write_wide(rec, path)
    assert main(["identify", str(path)]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    # the minimum named is the diagnosis's (50), not the reader's shorter one
    assert len(err) == 1 and err[0] == (f"error: {path}: too few samples: the longest stretch without a gap "
                                        "has 20 samples (need at least 50)")


def test_too_few_samples_kept_by_max_samples_names_the_option(sticky_csv, capsys):
    # a limit below what a diagnosis needs is refused before reading, naming the minimum that
    # applies (the reader's own, 20, would only lead to the next error at 50)
    for n in ("10", "30"):
        assert main(["identify", str(sticky_csv), "--max-samples", n]) == 1
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and err[0].startswith(f"error: max_samples={n} (--max-samples): keeps fewer")
        assert "give 50 or more" in err[0]
    assert main(["identify", str(sticky_csv), "--max-samples", "50"]) == 0
    capsys.readouterr()
    with pytest.raises(diagnose.DataError, match=r"^max_samples=30 \(--max-samples\)"):
        diagnose.identify(sticky_csv, max_samples=30)
    # a record read short by the reader's limit still says which option cut it
    from connectors import read_records
    from diagnose.identification import identify

    (rec,) = read_records(sticky_csv, max_samples=30)
    with pytest.raises(diagnose.DataError, match="of its 1500") as info:
        identify(rec)
    assert "--max-samples" in str(info.value) and "longer record" not in str(info.value)


def test_missing_file_is_a_one_line_error(tmp_path, capsys):
    assert main(["identify", str(tmp_path / "nope.csv")]) == 1
    err = capsys.readouterr().err
    assert err.startswith("error:") and "Traceback" not in err


def test_stuck_valve_exits_zero_with_a_warning(tmp_path, capsys):
    rec = sticky_loop(3.0, 1.0, n=600, noise_std=0.02, load_walk_std=0.01, seed=3, name="FV3")
    rec = rec.replace(mv=np.full(rec.n, 20.0))
    path = tmp_path / "stuck.csv"
    write_wide(rec, path)
    assert main(["identify", str(path), "--json"]) == 0
    d = json.loads(capsys.readouterr().out)
    assert any(w["code"] == "valve_not_moving" for w in d["warnings"])
    assert d["class"] == "unknown" and d["J"] is None
    assert main(["identify", str(path)]) == 0
    out = capsys.readouterr().out
    assert "class unknown" in out and "deadband" not in out
    assert "S >= " in out and "J and the class are not judged" in out
    assert out.startswith("FV3: STICTION (")          # the verdict the JSON gives, not "no evidence"


def _rec(name, n, seg=0):
    return LoopRecord(name=name, ts_s=1.0, op=np.linspace(0, 1, n), pv=np.linspace(0, 1, n),
                      meta={"segment": seg})


def test_several_loops_need_loop_and_segments_take_the_longest():
    recs = [_rec("A", 100), _rec("B", 100)]
    with pytest.raises(DataError, match="2 loops .*A, B.*--loop"):
        select_record(recs, None, "f.csv")
    with pytest.raises(DataError, match="no loop named 'C'"):
        select_record(recs, "C", "f.csv")
    rec, notes = select_record([_rec("A", 100, 0), _rec("A", 300, 1), _rec("B", 50)], "A", "f.csv")
    assert rec.n == 300 and notes[0]["code"] == "segments"


def test_a_gapped_record_is_not_said_to_be_diagnosed_segment_by_segment(tmp_path, capsys):
    # identify takes the longest segment; the reader's finding must not claim each one is diagnosed
    rec = sticky_loop(4.0, 1.5, n=1200, noise_std=0.02, load_walk_std=0.01, seed=2, name="FIC8").replace(mv=None)
    path = tmp_path / "gapped.csv"
    write_wide(rec, path)
    lines = path.read_text().splitlines()
    path.write_text("\n".join(lines[:401] + lines[461:]) + "\n")      # a minute missing after 400 rows
    assert main(["identify", str(path)]) == 0
    out = capsys.readouterr().out
    seg = next(ln for ln in out.splitlines() if "[data_quality.segment]" in ln)
    assert "diagnosed on its own" not in seg and "identify takes the longest" in seg
    assert "identified the longest (740 samples)" in out


def test_a_folder_skips_the_files_it_cannot_read_and_says_so(sticky_csv, tmp_path, capsys):
    # one loop exported in two parts, an empty export and a stray CSV beside them
    folder = tmp_path / "fic7"
    folder.mkdir()
    header, *rows = sticky_csv.read_text().splitlines()
    half = len(rows) // 2
    (folder / "part1.csv").write_text("\n".join([header, *rows[:half]]) + "\n")
    (folder / "part2.csv").write_text("\n".join([header, *rows[half:]]) + "\n")
    (folder / "empty.csv").write_text("")
    (folder / "stray.csv").write_text("time,x\n1,2\n")
    assert main(["identify", str(folder), "--json"]) == 0
    captured = capsys.readouterr()
    d = json.loads(captured.out)
    assert d["loop"] == "FIC7" and d["n_samples"] == len(rows)          # both parts, joined
    notes = [ln for ln in captured.err.splitlines() if ln.startswith("note: ")]
    assert notes == [f"note: skipped {folder / 'empty.csv'}: file is empty",
                     f"note: skipped {folder / 'stray.csv'}: no OP or PV column found (columns: time, x); "
                     "name the columns with --op/--pv or give a tag map with --tags"]
    assert sorted(f["data"]["path"] for f in d["data_quality"] if f["code"] == "file_skipped") == \
        [str(folder / "empty.csv"), str(folder / "stray.csv")]
    assert not any(w["code"].endswith("file_skipped") for w in d["warnings"])   # the verdict is untouched
    # none readable: one line naming the folder, exit 1
    for name in ("part1.csv", "part2.csv"):
        (folder / name).unlink()
    assert main(["identify", str(folder)]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"error: {folder}: none of its 2 export files could be read (the first: "
                   f"{folder / 'empty.csv'}: file is empty)"]
