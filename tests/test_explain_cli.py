"""`stiction explain`: one JSON object on stdout, a figure, a human summary, one-line errors."""

import json
import os

import pytest

from connectors.historian import write_wide
from diagnose.physics.concealed import concealed_loop
from diagnose.service.cli import main


@pytest.fixture(scope="module")
def csv_with_mv(tmp_path_factory):
    rec, _ = concealed_loop("asymmetric_stiction", 100, n=3000, with_mv=True)
    path = tmp_path_factory.mktemp("explain") / "loop.csv"
    write_wide(rec, path)
    return path


def test_json_is_one_object_and_the_figure_is_written(csv_with_mv, tmp_path, capsys):
    png = tmp_path / "explain.png"
    rc = main(["explain", str(csv_with_mv), "--json", "--figure", str(png)])
    out = capsys.readouterr().out
    assert rc == 0
    lines = [ln for ln in out.splitlines() if ln.strip()]
    assert len(lines) == 1
    d = json.loads(lines[0])
    assert {"missing_physics", "baseline_rmse", "improved_rmse", "hypotheses", "mismatch",
            "explanation", "warnings"} <= set(d)
    assert d["missing_physics"] == "asymmetric_stiction"
    assert d["target"] == "mv"           # a valve-side effect is judged on the stem position
    assert d["improved_rmse"] < d["baseline_rmse"]
    names = {h["name"] for h in d["hypotheses"]}
    assert {"actuator_lag", "asymmetric_stiction", "valve_characteristic", "external_disturbance",
            "time_varying_friction"} <= names
    assert png.exists() and png.stat().st_size > 10_000
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    umask = os.umask(0)
    os.umask(umask)
    assert png.stat().st_mode & 0o777 == 0o666 & ~umask   # as open() would: not the temporary file's 0600


def test_human_summary_with_a_subset_of_hypotheses(csv_with_mv, capsys):
    rc = main(["explain", str(csv_with_mv), "--target", "mv", "--hypotheses", "actuator_lag"])
    out = capsys.readouterr().out
    assert rc == 0
    assert "missing physics" in out and "actuator_lag" in out and "asymmetric" not in out.split("\n")[2]


def test_summary_heads_with_the_baseline_and_the_refit_the_hypotheses_are_judged_against():
    from diagnose.service.commands.explain import summary

    d = {"loop": "LIC1", "missing_physics": None, "baseline_rmse": 2.072, "improved_rmse": 2.072,
         "target": "pv", "hypotheses": [], "mismatch": {"reference_rmse": 0.1692}, "explanation": "x."}
    head = summary(d).splitlines()[1]
    assert head == "  held-out RMSE (PV, PV units): baseline 2.072, plain model refit here 0.1692; nothing named"
    named = dict(d, missing_physics="actuator_lag", improved_rmse=0.12, target="mv")
    assert summary(named).splitlines()[1].endswith("refit here 0.1692 -> with actuator_lag 0.12")
    # hypotheses judged on the stem are measured against the valve stage's own errors: shown too
    both = dict(d, mismatch={"reference_rmse": 0.1692,
                             "other_stages": {"valve": {"baseline_rmse": 0.0312, "reference_rmse": 0.0301}}})
    assert summary(both).splitlines()[2] == "  held-out RMSE (MV, % of span): baseline 0.0312, plain model refit here 0.0301"


@pytest.mark.parametrize("argv,msg", [
    (["--mv", "NOPE"], "no column named 'NOPE'"),
    (["--hypotheses", "gremlins"], "unknown hypothesis 'gremlins'"),
    (["--hypotheses", " , "], "name at least one hypothesis"),
    (["--train-fraction", "0.95"], "--train-fraction 0.95"),
])
def test_bad_input_is_one_line_and_exit_1(csv_with_mv, capsys, argv, msg):
    rc = main(["explain", str(csv_with_mv), *argv])
    err = capsys.readouterr().err
    assert rc == 1
    assert err.startswith("error: ") and msg in err and "Traceback" not in err


def test_a_too_short_record_names_the_file(tmp_path, capsys):
    rec, _ = concealed_loop("none", 2, n=200)
    path = tmp_path / "s200.csv"
    write_wide(rec, path)
    assert main(["explain", str(path)]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"error: {path}: ") and "explain needs at least" in err[0]
    assert err[0].count(str(path)) == 1


def test_target_mv_needs_the_stem_position(tmp_path, capsys):
    rec, _ = concealed_loop("none", 2, n=600)
    path = tmp_path / "nomv.csv"
    write_wide(rec, path)
    rc = main(["explain", str(path), "--target", "mv"])
    assert rc == 1
    assert "stem position" in capsys.readouterr().err


@pytest.mark.parametrize("flat,says", [
    ({"pv": 50.0}, "PV (50) is constant"),
    ({"mv": 42.0}, "MV (42) is constant"),
    ({"op": 40.0}, "OP (40) is constant"),
    ({"pv": 50.0, "op": 40.0}, "PV (50) and OP (40) are constant"),
])
def test_a_constant_signal_is_named(tmp_path, capsys, flat, says):
    import numpy as np

    rec, _ = concealed_loop("none", 2, n=600, with_mv=True)
    rec = rec.replace(**{role: np.full(rec.n, value) for role, value in flat.items()})
    path = tmp_path / "flat.csv"
    write_wide(rec, path)
    assert main(["explain", str(path)]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"error: {path}: ") and says in err[0], err
    assert ("--target pv" in err[0]) == (flat.keys() == {"mv"})   # the valve stage alone: judge PV instead


def test_a_folder_names_each_file_it_skipped(tmp_path, capsys):
    import numpy as np

    rec, _ = concealed_loop("none", 2, n=600)
    write_wide(rec.replace(pv=np.full(rec.n, 50.0)), tmp_path / "loop.csv")
    (tmp_path / "empty.csv").write_text("")
    assert main(["explain", str(tmp_path)]) == 1   # read from loop.csv: its flat PV is the error
    err = capsys.readouterr().err.strip().splitlines()
    assert err[0] == f"note: skipped {tmp_path / 'empty.csv'}: file is empty"
    assert len(err) == 2 and err[1].startswith(f"error: {tmp_path}: ") and "PV (50) is constant" in err[1]


def test_explanation_says_when_the_refit_chose_another_process_family():
    # the hypotheses are judged against the refit: a user must not read it as the baseline's own
    # structure when the grid swapped an integrating process for a slow first-order one
    from types import SimpleNamespace

    from diagnose.physics.explain import _refit_kind
    from diagnose.process_model import ProcessModel

    integ = ProcessModel("integrating", 0.02, 5.0, 3.0, 50.0)
    foptd = ProcessModel("foptd", 1.0, 107.0, 16.0, 0.0)

    def run(stage, old, new):
        return SimpleNamespace(stage=SimpleNamespace(name=stage), baseline=SimpleNamespace(
            structure=SimpleNamespace(process=old)), reference=SimpleNamespace(process=new))

    assert _refit_kind(run("loop", integ, foptd)) == \
        " (as a first-order process, where the baseline has an integrating one)"
    assert _refit_kind(run("loop", foptd, foptd)) == ""
    assert _refit_kind(run("valve", integ, foptd)) == ""
