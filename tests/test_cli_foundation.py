"""The `stiction` shell: help, simulate, error handling, and every command documented."""

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from connectors.historian import read_wide
from diagnose.service.cli import COMMANDS, main
from diagnose.stiction_model import simulate_valve

ROOT = Path(__file__).resolve().parents[1]


def test_help_lists_every_command(capsys):
    assert main(["--help"]) == 0
    out = capsys.readouterr().out
    for name in COMMANDS:
        assert re.search(rf"^\s+{name}\s", out, re.M), name


def test_every_command_is_documented_in_the_readme():
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    for name in COMMANDS:
        assert f"stiction {name}" in readme, f"README does not document `stiction {name}`"


def test_every_command_module_exists():
    import importlib

    for name, (module, _) in COMMANDS.items():
        mod = importlib.import_module(f"diagnose.service.commands.{module}")
        assert callable(mod.add_arguments) and callable(mod.run), name


def test_simulate_writes_a_loop_with_the_true_mv(tmp_path, capsys):
    out = tmp_path / "loop.csv"
    rc = main(["simulate", "--S", "3", "--J", "1", "--n", "800", "--seed", "5", "--name", "FIC9",
               "--out", str(out)])
    assert rc == 0
    rec = read_wide(out)
    assert rec.name == "FIC9" and rec.n == 800 and rec.ts_s == pytest.approx(1.0)
    assert rec.mv is not None and rec.sp is not None
    # MV in the file is the valve model driven by the file's OP (6 significant digits in the file)
    assert np.abs(rec.mv - simulate_valve(rec.op, 3.0, 1.0, 1)).max() < 0.2
    assert "wrote" in capsys.readouterr().err


def test_simulate_refuses_an_overflow_and_warns_of_a_valve_that_never_moved(tmp_path, capsys):
    out = tmp_path / "x.csv"
    assert main(["simulate", "--S", "3", "--J", "1", "--n", "300", "--gain", "1e300", "--out", str(out)]) == 1
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: the simulated PV overflowed (--gain 1e+300") and len(err.splitlines()) == 1
    assert not out.exists()
    # a controller gain of the wrong sign: the loop runs away from the band and the stem never moves
    assert main(["simulate", "--S", "3", "--J", "1", "--n", "500", "--kc", "-1", "--out", str(out)]) == 0
    err = capsys.readouterr().err
    assert "warning: the simulated valve never moved" in err and "--kc" in err and out.exists()
    assert main(["simulate", "--S", "3", "--J", "1", "--n", "500", "--out", str(out)]) == 0
    assert "never moved" not in capsys.readouterr().err


def test_identify_refuses_values_no_plant_measures(tmp_path, capsys):
    rng = np.random.default_rng(4)
    t = np.arange(400)
    f = tmp_path / "huge.csv"
    f.write_text("t,OP,PV\n" + "".join(f"{k},{50 + np.sin(k / 9):.4f},{1e300 * (1 + rng.random()):.6g}\n"
                                       for k in t))
    assert main(["identify", str(f)]) == 1
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"error: {f}") and "PV reaches" in err and "magnitude" in err
    assert len(err.splitlines()) == 1

def test_simulate_start_sets_the_time_column_so_nightly_exports_make_a_history(tmp_path, capsys):
    # every simulated export began at 2026-01-01T00:00:00Z: a week of "nightly" files were one record
    # seven times over (the same start and end), so the batch found no earlier run for any of them
    nights = []
    for night in (1, 2):
        out = tmp_path / f"night{night}" / "FIC9.csv"
        out.parent.mkdir()
        assert main(["simulate", "--S", "3", "--J", "1", "--n", "600", "--seed", str(night), "--name", "FIC9",
                     "--start", f"2026-03-0{night}T22:00:00", "--out", str(out)]) == 0
        nights.append(out)
    first = nights[0].read_text().splitlines()
    assert first[1].startswith("2026-03-01T22:00:00Z,") and first[-1].startswith("2026-03-01T22:09:59Z,")
    assert read_wide(nights[1]).start == "2026-03-02T22:00:00Z"
    out = tmp_path / "offset.csv"   # an offset is converted to UTC
    assert main(["simulate", "--S", "3", "--J", "1", "--n", "600", "--start", "2026-03-01T23:00:00+01:00",
                 "--out", str(out)]) == 0
    assert out.read_text().splitlines()[1].startswith("2026-03-01T22:00:00Z,")
    capsys.readouterr()
    assert main(["simulate", "--S", "3", "--J", "1", "--start", "yesterday", "--out", str(tmp_path / "z.csv")]) == 2
    last = capsys.readouterr().err.strip().splitlines()[-1]
    assert last.startswith("stiction simulate: error: argument --start: 'yesterday': give an ISO 8601 time")
    assert not (tmp_path / "z.csv").exists()
    db = tmp_path / "h.sqlite"
    for night in nights:
        assert main(["batch", str(night.parent), "--out", str(night.parent / "out"), "--workers", "1",
                     "--no-pdf", "--no-narx", "--quiet", "--db", str(db)]) == 0
    summary = (nights[1].parent / "out" / "summary.md").read_text()
    assert "(2/2 runs)" in summary


@pytest.mark.parametrize("seed", [0, 1])
def test_simulate_integrating_defaults_give_a_sticking_and_slipping_level(tmp_path, seed):
    # with the level balanced exactly where the stuck valve started, the stem never moved (POS
    # constant 50): the default "sticky" level loop showed no stick-slip at all
    out = tmp_path / "level.csv"
    assert main(["simulate", "--S", "3", "--J", "1", "--process", "integrating", "--seed", str(seed),
                 "--out", str(out)]) == 0
    rec = read_wide(out)
    moving = np.abs(np.diff(rec.mv)) > 1e-9
    slips = int(np.count_nonzero(moving[1:] & ~moving[:-1]))
    assert slips >= 6
    assert np.ptp(rec.mv) > 0.9 and np.ptp(rec.op) > 3.0   # OP crosses the band S, the stem jumps by J or more
    for x in (rec.op, rec.pv):   # both cycle: several crossings of their mean, PV well off its noise
        assert np.count_nonzero(np.diff(np.sign(x - x.mean())) != 0) >= 10
    assert rec.pv.std() > 0.5


def test_usage_and_domain_errors_exit_without_traceback(tmp_path, capsys):
    assert main(["simulate", "--S", "3"]) == 2                       # missing --J and --out
    assert main(["simulate", "--S", "-1", "--J", "1", "--out", str(tmp_path / "x.csv")]) == 1
    err = capsys.readouterr().err
    assert "error: --S and --J must be >= 0" in err
    assert "Traceback" not in err
    for flag in ("--S", "--J"):   # S and J are % of span: 150 % is a typo, not a valve
        argv = {"--S": "3", "--J": "1", flag: "150"}
        assert main(["simulate", *[a for kv in argv.items() for a in kv], "--out", str(tmp_path / "y.csv")]) == 1
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and err[0].startswith(f"error: {flag} 150: ") and "at most 50" in err[0]
    assert not (tmp_path / "y.csv").exists()
    assert main(["no-such-command"]) == 2


def test_simulate_refuses_times_past_the_year_9999_in_one_line(tmp_path, capsys):
    for extra in (["--ts-s", "1e9"], ["--start", "9999-12-31T23:59:00Z"]):
        out = tmp_path / "x.csv"
        assert main(["simulate", "--S", "3", "--J", "1", *extra, "--out", str(out)]) == 1
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and err[0].startswith("error: --n 3000 samples every") and "year 9999" in err[0]
        assert not out.exists()


@pytest.mark.parametrize("flag,value,says", [
    ("--noise", "-1", "0 or more"), ("--load", "-0.5", "0 or more"), ("--noise", "nan", "0 or more"),
    ("--n", "10", "50 to 1000000"), ("--n", "100000000", "50 to 1000000"), ("--seed", "-1", "0 or more"),
    ("--ts-s", "0", "more than 0 seconds"), ("--delay-s", "-1", "0 seconds or more"),
    ("--tau-s", "-2", "0 seconds or more"), ("--gain", "0", "other than 0"),
    # a controller that never moves OP (or fills it with NaN), or silently loses its integral action
    ("--kc", "0", "other than 0"), ("--kc", "nan", "other than 0"), ("--ti-s", "0", "more than 0 seconds"),
    ("--ti-s", "-5", "more than 0 seconds"), ("--ti-s", "nan", "more than 0 seconds"),
])
def test_simulate_refuses_a_bad_flag_value_as_a_usage_error_naming_the_flag(tmp_path, capsys, flag, value, says):
    from diagnose.objective import MIN_SAMPLES

    out = tmp_path / "x.csv"
    assert main(["simulate", "--S", "3", "--J", "1", flag, value, "--out", str(out)]) == 2
    err = capsys.readouterr().err
    last = err.strip().splitlines()[-1]   # argparse's usage synopsis comes first, as for every command
    assert last.startswith(f"stiction simulate: error: argument {flag}") and f"{value}: give" in last
    assert says.replace("50", str(MIN_SAMPLES)) in last
    assert "Traceback" not in err and "ts_s" not in err and not out.exists()


def test_simulate_writes_the_shortest_record_identify_takes_and_help_gives_the_defaults(tmp_path, capsys):
    from diagnose.objective import MIN_SAMPLES

    out = tmp_path / "x.csv"
    assert main(["simulate", "--S", "3", "--J", "1", "--n", str(MIN_SAMPLES), "--out", str(out)]) == 0
    assert read_wide(out).n == MIN_SAMPLES
    assert main(["identify", str(out), "--json"]) == 0   # the shortest simulation is one identify takes
    capsys.readouterr()
    # a foptd process with no time constant: named by its flag, not the simulator's tau_s
    assert main(["simulate", "--S", "3", "--J", "1", "--tau-s", "0", "--out", str(tmp_path / "y.csv")]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: --tau-s 0: ")
    assert main(["simulate", "--help"]) == 0
    help_ = " ".join(capsys.readouterr().out.split())
    for flag, default in (("--tau-s", "20.0"), ("--delay-s", "3.0"), ("--n", "3000"), ("--noise", "0.02"),
                          ("--load", "0.01")):
        assert re.search(rf"{flag} \S+ (?:(?! --).)*?\(default {re.escape(default)}\)", help_), flag


def test_an_output_that_cannot_be_written_is_named_not_its_temporary_file(tmp_path, capsys):
    taken = tmp_path / "taken.csv"
    taken.write_text("a file")
    cases = ((tmp_path, f"error: {tmp_path}: is a folder; give the name of the file to write"),
             (taken / "x.csv", f"error: {taken / 'x.csv'}: cannot write: {taken} is a file, not a folder"))
    for out, says in cases:
        assert main(["simulate", "--S", "3", "--J", "1", "--n", "100", "--out", str(out)]) == 1
        err = capsys.readouterr().err.strip().splitlines()
        assert err == [says]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["taken.csv"]    # no temporary file left


def test_a_reader_that_stops_reading_ends_the_command_quietly(tmp_path):
    # `stiction history | head -1`: stdout's reader is gone; no "error: [Errno 32] Broken pipe"
    from diagnose.service.history import History

    loop = tmp_path / "loop.csv"
    assert main(["simulate", "--S", "3", "--J", "1", "--n", "600", "--out", str(loop)]) == 0
    History(tmp_path / "h.sqlite").close()
    r, w = os.pipe()
    os.close(r)   # the reader has read what it wanted and left
    try:
        for argv in (["history", "--db", str(tmp_path / "h.sqlite")], ["identify", str(loop)]):
            proc = subprocess.run([sys.executable, "-m", "diagnose.service.cli", *argv], stdout=w,
                                  stderr=subprocess.PIPE, text=True, timeout=120)
            assert (proc.returncode, proc.stderr) == (141, ""), argv   # 128 + SIGPIPE, as a Unix tool
    finally:
        os.close(w)


def test_the_installed_program_skips_teardown_but_runs_exit_handlers_and_keeps_exit_codes(tmp_path):
    # `console` ends the process with os._exit: exit handlers must still run, stdout must be whole,
    # and every exit code must come through
    loop = tmp_path / "loop.csv"
    assert main(["simulate", "--S", "3", "--J", "1", "--n", "600", "--out", str(loop)]) == 0
    mark = tmp_path / "exit-handler-ran"
    code = ("import atexit, sys; from diagnose.service.cli import console; "
            f"atexit.register(lambda: open({str(mark)!r}, 'w').close()); "
            "sys.argv = ['stiction', *sys.argv[1:]]; console()")
    for argv, rc in ((["identify", str(loop), "--json"], 0), (["identify", str(tmp_path / "none.csv")], 1),
                     (["identify", "--no-such-option"], 2)):
        if mark.exists():
            mark.unlink()
        proc = subprocess.run([sys.executable, "-c", code, *argv], capture_output=True, text=True, timeout=120)
        assert proc.returncode == rc, (argv, proc.stderr)
        assert mark.exists(), argv
        if rc == 0:
            assert json.loads(proc.stdout)["n_samples"] == 600
        else:
            assert proc.stderr.strip() and "Traceback" not in proc.stderr


def test_an_export_whose_pv_is_all_bad_is_judged_from_op_alone(tmp_path, capsys):
    # a dead transmitter exported as "Bad": the loop is not refused; OP's shape is judged, or the
    # valve is sized from its stem position where one is recorded
    good = tmp_path / "loop.csv"
    assert main(["simulate", "--S", "4", "--J", "1", "--n", "3000", "--seed", "1", "--name", "FIC7",
                 "--out", str(good)]) == 0
    lines = good.read_text().splitlines()
    head = lines[0].split(",")
    pv_col, pos_col = head.index("FIC7.PV"), head.index("FIC7.POS")

    def write(name, drop_pos):
        rows = [[("Bad" if j == pv_col and k else c) for j, c in enumerate(line.split(","))
                 if not (drop_pos and j == pos_col)] for k, line in enumerate(lines)]
        path = tmp_path / name
        path.write_text("\n".join(",".join(r) for r in rows) + "\n")
        return path

    capsys.readouterr()
    assert main(["identify", str(write("bad_pv.csv", drop_pos=True)), "--json"]) == 0
    d = json.loads(capsys.readouterr().out)
    codes = [w["code"] for w in d["warnings"]]
    assert d["method"] == "op_only" and d["S"] is None
    assert "data_quality.pv_missing" in codes and "pv_unusable" in codes and "mv_unused" not in codes
    said = next(w["message"] for w in d["warnings"] if w["code"] == "pv_unusable")
    assert "S and J need a usable PV or a recorded stem position that moves" in said
    assert not any(c == "data_quality.frozen" for c in codes)      # the stand-in PV is not assessed
    assert d["confidence"] <= 0.75
    # with the stem position the valve is seen directly: sized from OP -> MV, no process model
    assert main(["identify", str(write("bad_pv_pos.csv", drop_pos=False)), "--json"]) == 0
    d = json.loads(capsys.readouterr().out)
    said = next(w["message"] for w in d["warnings"] if w["code"] == "pv_unusable")
    assert d["method"] == "op_mv" and d["stiction"] and not d["process"] and "sized from the stem" in said
    assert d["S"] == pytest.approx(4.0, rel=0.02) and d["J"] == pytest.approx(1.0, abs=0.04)
    assert d["class"] == "undershoot" and d["detection"]["pv_unusable"]
    judged = {e["test"] for e in d["evidence"] if e["decision"] != "cannot_judge"}
    assert {"model_fit", "valve_band"} <= judged and "kano_stuck" not in judged


@pytest.mark.parametrize("argv, says", [
    (["bank", "train", "--cases", "3:1"], "would replace the installed bank"),
    (["reproduce", "model-mode", "--steps", "99999999999"], "--steps 99999999999: give 100 to 1000000"),
    (["reproduce", "table1", "--networks", ""], "name at least one network"),
])
def test_commands_that_would_overwrite_or_exhaust_refuse_in_one_line(capsys, argv, says):
    # a bank of one case written over the installed one, a model-mode run of 745 GiB, and an
    # empty network list that silently ran all six
    assert main(argv) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: ") and says in err[0]


def test_demo_refuses_zero_workers(capsys):
    assert main(["demo", "--workers", "0"]) == 2
    assert "--workers: 0: give 1 or more" in capsys.readouterr().err
