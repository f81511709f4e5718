"""The Python front door: `diagnose.identify` on files, DataFrames and records gives what
`stiction identify --json` prints; typed results; notebook display; the same options everywhere."""

from __future__ import annotations

import contextlib
import html
import io
import json
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

import diagnose
from connectors.historian import write_wide
from diagnose.service.cli import main
from diagnose.simulate import sticky_loop


def _cli_json(*argv: str) -> dict:
    """What `stiction identify --json` prints, run in this process."""
    out = io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(io.StringIO()):
        assert main(["identify", *argv, "--json"]) == 0
    return json.loads(out.getvalue())


def _json(ident) -> dict:
    return json.loads(json.dumps(ident.to_dict(), allow_nan=False))


@pytest.fixture(scope="module")
def loop(tmp_path_factory):
    """A sticky loop with its stem position, as a wide CSV export and as the frame pandas reads."""
    rec = sticky_loop(3.0, 1.0, n=1500, noise_std=0.03, load_walk_std=0.02, seed=6, name="FIC21")
    path = tmp_path_factory.mktemp("api") / "fic21.csv"
    write_wide(rec, path)
    df = pd.read_csv(path, parse_dates=["time"]).set_index("time")
    return rec, path, df, _cli_json(str(path))


def test_import_is_cheap_and_names_load_on_first_use():
    code = ("import sys, diagnose; "
            "heavy = [m for m in ('numpy', 'pandas', 'scipy', 'matplotlib') if m in sys.modules]; "
            "assert not heavy, heavy; f = diagnose.identify; import diagnose.api; assert f is diagnose.api.identify; "
            "assert 'pandas' not in sys.modules")
    subprocess.run([sys.executable, "-c", code], check=True)
    for name in diagnose.__all__:
        assert getattr(diagnose, name) is not None, name
    assert (Path(diagnose.__file__).parent / "py.typed").exists()
    with pytest.raises(AttributeError):
        diagnose.no_such_thing  # noqa: B018


def test_identifying_a_loop_leaves_scipy_unloaded(loop):
    # importing scipy.optimize and scipy.special costs a noticeable share of a command whose whole
    # budget is about a second: the identify path, read to result, does without them
    _, path, _, _ = loop
    code = ("import sys, dataclasses, diagnose; from diagnose.simulate import sticky_loop; "
            "r = sticky_loop(3.0, 1.0, n=1200, noise_std=0.03, seed=2); "
            "diagnose.identify(dataclasses.replace(r, mv=None)); diagnose.identify(sys.argv[1]); "
            "bad = sorted(m for m in sys.modules if m.split('.')[0] == 'scipy'); assert not bad, bad[:5]")
    subprocess.run([sys.executable, "-c", code, str(path)], check=True)


def test_a_path_gives_what_the_command_prints(loop):
    _, path, _, cli = loop
    ident = diagnose.identify(path)
    assert _json(ident) == cli
    assert cli["method"] == "op_mv"                          # the stem position found by itself
    assert cli["source"] == str(path) and cli["narx"]["model"] == ident.narx.model


def test_a_frame_with_a_datetime_index_or_a_time_column_gives_the_same(loop):
    _, _, df, cli = loop
    want = {**cli, "source": None}
    assert isinstance(df.index, pd.DatetimeIndex) and "FIC21.POS" in df.columns
    assert _json(diagnose.identify(df)) == want
    with_column = df.reset_index()
    assert _json(diagnose.identify(with_column)) == want
    renamed = with_column.rename(columns={"time": "when", "FIC21.OP": "out", "FIC21.PV": "meas"})
    assert _json(diagnose.identify(renamed, time="when", op="out", pv="meas", mv="FIC21.POS",
                                   sp="FIC21.SP")).items() >= {k: v for k, v in want.items() if k != "loop"}.items()


def test_evenly_spaced_rows_with_ts_s(loop, tmp_path):
    _, _, df, _ = loop
    rows = df.reset_index(drop=True)
    path = tmp_path / "rows.csv"
    rows.to_csv(path, index=False)
    cli = _cli_json(str(path), "--ts-s", "1")
    assert _json(diagnose.identify(rows, ts_s=1.0)) == {**cli, "source": None}
    assert cli["ts_s"] == 1.0
    # the older spelling of the command line means the same
    assert _cli_json(str(path), "--ts", "1") == cli


def test_time_zones_across_a_clock_change(tmp_path):
    rec = sticky_loop(3.0, 1.0, n=1500, ts_s=10.0, tau_s=60.0, delay_s=10.0, noise_std=0.03, load_walk_std=0.02,
                      seed=8, name="TIC3")
    utc = pd.date_range("2026-03-29 00:00", periods=rec.n, freq="10s", tz="UTC")      # DST starts 01:00 UTC
    local = utc.tz_convert("Europe/Berlin").tz_localize(None)                           # wall clock jumps 1 h
    df = pd.DataFrame({"TIC3.OP": rec.op, "TIC3.PV": rec.pv, "TIC3.SP": rec.sp}, index=local.rename("time"))
    path = tmp_path / "tic3_local.csv"
    df.to_csv(path, date_format="%Y-%m-%d %H:%M:%S")
    cli = _cli_json(str(path), "--tz", "Europe/Berlin")
    api = _json(diagnose.identify(df, tz="Europe/Berlin"))
    assert api == {**cli, "source": None}
    assert cli["n_samples"] == rec.n and cli["ts_s"] == 10.0
    assert not [f for f in cli["data_quality"] if f["code"] in ("gap", "duplicates")]
    aware = _json(diagnose.identify(df.set_axis(utc, axis=0)))                          # tz-aware: no tz needed
    assert aware == api
    # read as UTC the local times have an hour's gap: a different record
    assert diagnose.read_loops(df)[0].n != rec.n


def test_gaps_are_read_alike(loop, tmp_path):
    _, _, df, _ = loop
    holes = df.drop(df.index[700:704])                       # four missing rows: filled
    path = tmp_path / "holes.csv"
    holes.reset_index().to_csv(path, index=False, date_format="%Y-%m-%dT%H:%M:%SZ")
    cli = _cli_json(str(path))
    assert _json(diagnose.identify(holes)) == {**cli, "source": None}
    assert any(f["code"] == "gap" for f in cli["data_quality"]) and cli["n_samples"] == len(df)
    split = df.drop(df.index[300:500])                       # a long gap: two segments, the longest identified
    path = tmp_path / "split.csv"
    split.reset_index().to_csv(path, index=False, date_format="%Y-%m-%dT%H:%M:%SZ")
    cli = _cli_json(str(path))
    api = diagnose.identify(split)
    assert _json(api) == {**cli, "source": None}
    assert api.warnings[0].code == "segments" and api.n == len(df) - 500
    # records are split at gaps only: a manual stretch (mode column) stays in the record
    assert "at gaps" in api.warnings[0].message and "mode change" not in api.warnings[0].message


def test_a_record_gives_the_core_identification_with_its_bank_model(loop):
    from diagnose.identification import identify

    rec, _, _, _ = loop
    ident = diagnose.identify(rec)
    core = identify(rec)
    assert core.narx is None and ident.narx is not None
    added = [w.to_dict() for w in ident.warnings[len(core.warnings):]]      # the bank's note, if any
    assert _json(ident) == {**_json(core), "narx": ident.narx.to_dict(), "warnings": [*_json(core)["warnings"], *added]}
    with pytest.raises(diagnose.DataError, match="op: reading options apply to files and frames"):
        diagnose.identify(rec, op="OP")


def test_results_are_typed_all_the_way(loop):
    from diagnose.evidence import Evidence
    from diagnose.identification import Detection
    from diagnose.narx.bank import Selection
    from diagnose.notes import Note
    from diagnose.process_model import ProcessModel
    from diagnose.verdict import Verdict

    rec, _, _, _ = loop
    ident = diagnose.identify(rec.replace(mv=None))
    assert isinstance(ident, diagnose.Identification) and ident.method == "op_pv"
    assert isinstance(ident.detection, Detection) and ident.detection.insample_improvement is not None
    assert isinstance(ident.process, ProcessModel) and isinstance(ident.verdict, Verdict)
    assert isinstance(ident.narx, Selection)
    assert ident.evidence and all(isinstance(e, Evidence) for e in ident.evidence)
    assert all(isinstance(w, Note) for w in ident.warnings)
    with pytest.raises(AttributeError):
        ident.cls = "none"                                    # frozen
    assert ident.to_dict()["detection"] == ident.detection.to_dict()


def test_a_result_shows_itself_in_a_notebook(loop):
    from matplotlib.figure import Figure

    rec, _, _, _ = loop
    ident = diagnose.identify(rec)
    text = repr(ident)
    assert text.startswith("Identification(loop='FIC21', stiction=True, cls=") and "S_pct=" in text
    page = ident._repr_html_()
    assert "<table>" in page and "Identification of FIC21" in page and f"{ident.S_pct:.3g}" in page
    # the notebook shows what the command line shows: the whole process and every decision
    assert html.escape(ident.process.describe()) in page and ident.process.kind in page
    assert html.escape(ident.evidence_text) in page
    soptd = replace(ident, process=replace(ident.process, kind="soptd", tau2_s=4.0))
    assert "second time constant 4 s" in soptd._repr_html_()
    fig = ident.plot()
    assert isinstance(fig, Figure) and len(fig.axes) == 2
    t_end_min = rec.t_s[-1] / 60.0                            # the whole record, in minutes
    assert max(float(np.max(ln.get_xdata())) for ln in fig.axes[1].get_lines()) == pytest.approx(t_end_min)
    assert {ln.get_label() for ln in fig.axes[1].get_lines()} >= {"OP", "MV", "model valve"}
    assert len(ident.plot("phase").axes) == 2 and ident.plot("surface").axes
    with pytest.raises(diagnose.DataError, match="unknown figure"):
        ident.plot("pie")
    healthy = replace(ident, stiction=False, cls="none")
    labels = {ln.get_label() for ln in healthy.plot().axes[1].get_lines()}
    assert "model valve" not in labels                        # no sticky valve path on a healthy verdict


def test_figures_give_op_and_the_band_in_op_s_own_units(loop):
    """OP logged as a fraction of span (no stem to scale it): the axes of OP, the valve path and the
    error surface say "fraction of span", as S and J are given, not "% of span"."""
    rec, _, _, _ = loop
    frac = rec.replace(op=rec.op / 100.0, mv=None)
    ident = diagnose.identify(frac)
    assert ident.op_units == "fraction of span"
    assert ident.plot().axes[1].get_ylabel() == "fraction of span"
    assert ident.plot("phase").axes[0].get_xlabel() == "OP (fraction of span)"
    surface = ident.plot("surface").axes[0]
    assert (surface.get_xlabel(), surface.get_ylabel()) == ("S (fraction of span)", "J (fraction of span)")
    assert diagnose.identify(rec).plot("phase").axes[0].get_xlabel() == "OP (% of span)"
    from diagnose import figures

    fig = figures.draw_narx(figures.new_figure("narx"), frac, frac.op, None, op_units=ident.op_units)
    assert fig.axes[0].get_ylabel() == "fraction of span"     # OP and the free run, without PV's model


def test_same_options_on_every_file_command():
    from diagnose.service.cli import build_parser

    shared = {"--op", "--pv", "--sp", "--mv", "--time", "--ts-s", "--tz", "--dst", "--dayfirst", "--monthfirst",
              "--format", "--tags", "--loop", "--max-samples"}
    for command in ("identify", "explain", "batch"):
        parser = build_parser(command)
        sub = next(a for a in parser._actions if a.dest == "command").choices[command]
        options = {s for a in sub._actions for s in a.option_strings}
        assert shared <= options, (command, shared - options)
        assert "--ts" in options                              # the older spelling still parses
    for command in ("batch", "demo", "monitor"):
        parser = build_parser(command)
        sub = next(a for a in parser._actions if a.dest == "command").choices[command]
        explain = next(a for a in sub._actions if "--explain" in a.option_strings)
        assert explain.choices == ["off", "auto", "on"] and explain.const == "on" and explain.default == "off"
    from diagnose.api import READ_OPTIONS
    import inspect

    for fn in (diagnose.identify, diagnose.explain, diagnose.read_loops):
        assert set(READ_OPTIONS) <= set(inspect.signature(fn).parameters), fn.__name__


def test_batch_takes_loop_tz_and_max_samples(tmp_path):
    from diagnose.service import batch as B

    folder = tmp_path / "logs"
    folder.mkdir()
    for i, name in enumerate(("FIC1", "FIC2")):
        rec = sticky_loop(3.0, 1.0, n=900, noise_std=0.03, load_walk_std=0.02, seed=20 + i, name=name)
        write_wide(rec.replace(mv=None), folder / f"{name}.csv")
    out = tmp_path / "out"
    assert main(["batch", str(folder), "--out", str(out), "--workers", "1", "--no-pdf", "--no-narx", "--quiet",
                 "--no-history", "--loop", "FIC2", "--tz", "Europe/Berlin", "--max-samples", "800"]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert [r["loop"] for r in summary["loops"]] == ["FIC2"]
    assert [Path(f["path"]).name for f in summary["skipped_files"]] == ["FIC1.csv"]
    assert "no loop named 'FIC2'" in summary["skipped_files"][0]["reason"]
    res = json.loads((out / "loops" / "FIC2" / "FIC2.json").read_text())
    assert res["n_samples"] == 800 and any(f["code"] == "window" for f in res["data_quality"])
    assert res["summary"]["loop"] == "FIC2"
    assert B.BatchConfig(out_dir="x", read_options={"loop": "FIC2"}).options_key() != \
        B.BatchConfig(out_dir="x").options_key()           # a different selection is a different result


def test_explain_is_the_command_on_the_same_data(loop, capsys):
    rec, path, df, _ = loop
    short = df.iloc[:750]
    opts = dict(hypotheses=["actuator_lag"], target="pv")
    expl = diagnose.explain(short, **opts)
    p = path.parent / "short.csv"
    short.reset_index().to_csv(p, index=False, date_format="%Y-%m-%dT%H:%M:%SZ")
    capsys.readouterr()
    assert main(["explain", str(p), "--hypotheses", "actuator_lag", "--target", "pv", "--json"]) == 0
    cli = json.loads(capsys.readouterr().out)
    assert json.loads(json.dumps(expl.to_dict())) == cli
    assert [h["name"] for h in cli["hypotheses"]] == ["actuator_lag"]
    with pytest.raises(diagnose.DataError, match="train_fraction"):
        diagnose.explain(short, train_fraction=0.95)


@pytest.mark.parametrize("call, match", [
    (lambda df: diagnose.identify(df, ts_s=0), r"^ts_s=0 \(--ts-s\): the sample period must be a positive"),
    (lambda df: diagnose.identify(df, ts_s=-1), r"^ts_s=-1 "),
    (lambda df: diagnose.identify(df, ts_s=float("nan")), r"^ts_s=nan "),
    (lambda df: diagnose.identify(df, ts_s="abc"), r"^ts_s='abc' "),
    (lambda df: diagnose.identify(df, max_samples="x"), r"^max_samples='x' \(--max-samples\): give a whole number"),
    (lambda df: diagnose.identify(df, max_samples=-1), r"^max_samples=-1 "),
    (lambda df: diagnose.read_loops(df.tz_localize(None), tz="Europe/Berlin", dst="bogus"),
     r"^dst='bogus' \(--dst\): use one of infer, earliest, latest, raise$"),
    (lambda df: diagnose.identify(df.tz_localize(None), tz="+25:00"), r"^tz='\+25:00' \(--tz\): time zone offset '\+25:00' is out of range"),
    (lambda df: diagnose.identify(df.tz_localize(None), tz=5), r"^tz=5 "),
    (lambda df: diagnose.identify(123), r"^data=123: give a path \(file or folder\), a file object, a pandas "
                                        r"DataFrame or a LoopRecord$"),
    (lambda df: diagnose.identify(None), r"^data=None: "),
    (lambda df: diagnose.identify(np.zeros((100, 2))), r"^data=<numpy.ndarray>: "),
    (lambda df: diagnose.read_loops(123), r"^data=123: "),
    (lambda df: diagnose.explain(123), r"^data=123: "),
])
def test_bad_arguments_are_one_line_data_errors_naming_the_keyword(loop, call, match):
    _, _, df, _ = loop
    with pytest.raises(diagnose.DataError, match=match) as err:
        call(df)
    assert "\n" not in str(err.value)


def test_the_commands_and_the_batch_check_options_the_same_way(loop, tmp_path, capsys):
    from diagnose.service.batch import run_batch

    _, path, _, _ = loop
    assert main(["identify", str(path), "--ts-s", "0"]) != 0
    assert "ts_s=0.0 (--ts-s): the sample period must be a positive number of seconds" in capsys.readouterr().err
    with pytest.raises(diagnose.DataError, match=r"^max_samples=-5 "):
        run_batch([path], tmp_path / "out", workers=1, read_options={"max_samples": -5}, history=False,
                  progress=False)


@pytest.mark.parametrize("call, match", [
    (lambda rec: diagnose.StictionEstimator().fit(rec.op, rec.pv, "1"),
     r"^sample period ts_s must be a positive number of seconds, got '1'$"),
    (lambda rec: diagnose.LoopRecord(name="X", ts_s=None, op=rec.op, pv=rec.pv), r"^sample period ts_s .* got None$"),
    (lambda rec: diagnose.LoopRecord(name="X", ts_s=1.0, op=["a", "b"], pv=[1.0, 2.0]), r"^OP must be numbers"),
    (lambda rec: diagnose.StictionEstimator().set_params(S=3), r"^invalid parameter 'S' for StictionEstimator"),
])
def test_records_and_the_estimator_refuse_bad_arguments_with_a_data_error(loop, call, match):
    rec, _, _, _ = loop
    with pytest.raises(diagnose.DataError, match=match) as err:
        call(rec)
    assert "\n" not in str(err.value)


def test_a_frames_errors_name_python_keywords_and_rows_not_flags_and_lines(loop):
    # a frame is read from Python: its hints name ts_s=, op=, dst= (no tag map: files only), and a
    # bad cell is placed by column and row position, not by the reader's line number
    _, _, df, _ = loop
    msgs = []
    for call in (lambda: diagnose.read_loops(df.reset_index(drop=True)),
                 lambda: diagnose.read_loops(df.drop(columns=["FIC21.PV"])),
                 lambda: diagnose.read_loops(df.assign(**{"FIC21.OUT": df["FIC21.OP"]}))):
        with pytest.raises(diagnose.DataError) as err:
            call()
        msgs.append(str(err.value))
    assert msgs[0].endswith("give the sample period with ts_s=SECONDS or add a DatetimeIndex or a time column")
    assert msgs[1].endswith("name the columns with op=, pv=")
    assert msgs[2].endswith("choose one with op=")
    times = df.index.tz_localize(None).strftime("%Y-%m-%d %H:%M:%S").to_series(index=range(len(df)))
    bad = df.reset_index(drop=True).assign(time=times)
    bad.loc[7, "time"] = "garbage"
    with pytest.raises(diagnose.DataError, match=r"^column 'time', row 7: cannot read timestamp 'garbage'"):
        diagnose.read_loops(bad)
    autumn = df.set_index(pd.date_range("2025-10-26 01:58", periods=len(df), freq="1s"))
    with pytest.raises(diagnose.DataError, match=r"choose dst='earliest', 'latest' or 'infer' or give UTC times$"):
        diagnose.read_loops(autumn, tz="Europe/Berlin", dst="raise")
    for msg in msgs:
        assert "--" not in msg and "tag map" not in msg


def test_a_clock_change_in_a_frames_index_names_the_index_and_the_row(loop):
    # the index is no column: "column 'index'" sent users looking for one, and no row was given
    _, _, df, _ = loop
    autumn = pd.date_range("2025-10-26 01:58", periods=len(df), freq="1s")   # 02:00 Berlin is row 120
    spring = pd.date_range("2025-03-30 01:59", periods=len(df), freq="1s")   # 02:00 does not exist: row 60
    cases = [(df.set_index(autumn), r"^the frame's index, row 120: local time 2025-10-26 02:00:00 is ambiguous in "
              r"Europe/Berlin \(DST change\); choose dst='earliest', 'latest' or 'infer' or give UTC times$"),
             (df.set_index(autumn.rename("time")), r"^the frame's index, row 120: local time 2025-10-26 02:00:00 "),
             (df.set_index(spring), r"^the frame's index, row 60: local time 2025-03-30 02:00:00 does not exist in "
              r"Europe/Berlin \(DST change\); choose dst='earliest' or 'latest' or give UTC times$"),
             # a column of datetimes is a column, now with its row too
             (df.reset_index(drop=True).assign(stamp=autumn),
              r"^column 'stamp', row 120: local time 2025-10-26 02:00:00 ")]
    for frame, match in cases:
        time = "stamp" if "stamp" in frame else None
        with pytest.raises(diagnose.DataError, match=match):
            diagnose.read_loops(frame, tz="Europe/Berlin", dst="raise", time=time)


def test_a_files_errors_still_name_the_command_line_flags(tmp_path, capsys):
    rec = sticky_loop(3.0, 1.0, n=300, seed=1, name="FIC1")
    path = tmp_path / "nopv.csv"
    rec.to_frame().drop(columns=["PV"]).rename(columns={"OP": "FIC1.OP"}).to_csv(path)
    assert main(["identify", str(path)]) != 0
    assert capsys.readouterr().err.strip().endswith("name the columns with --op/--pv or give a tag map with --tags")


def test_explain_checks_its_own_options_and_takes_one_hypothesis_as_a_string(loop, monkeypatch):
    import diagnose.physics

    _, path, _, _ = loop
    for kw, match in ((dict(train_fraction="0.5"), r"^train_fraction='0.5' \(--train-fraction\): use a value"),
                      (dict(min_reduction="x"), r"^min_reduction='x' \(--min-reduction\): use a value"),
                      (dict(train_fraction=True), r"^train_fraction=True ")):
        with pytest.raises(diagnose.DataError, match=match):
            diagnose.explain(path, **kw)
    seen = []
    monkeypatch.setattr(diagnose.physics, "explain", lambda rec, **kw: seen.append(kw["hypotheses"]) or "done")
    assert diagnose.explain(path, hypotheses="actuator_lag") == "done"
    assert diagnose.explain(path, hypotheses="actuator_lag, valve_characteristic") == "done"
    assert seen == [["actuator_lag"], ["actuator_lag", "valve_characteristic"]]


@pytest.mark.parametrize("data", [np.zeros((100, 2)), [[1.0, 2.0]] * 100, {"OP": [1.0] * 100},
                                  pd.Series(np.zeros(100))])
def test_arrays_are_refused_with_how_to_make_them_a_frame(data):
    with pytest.raises(diagnose.DataError, match=r"for arrays: pandas.DataFrame\(\{'OP': op, 'PV': pv\}\) "
                                                 r"with ts_s=SECONDS\)$"):
        diagnose.identify(data)


def test_frames_as_a_notebook_user_hands_them_over(loop):
    rec, path, df, _ = loop
    # times left as text in the index (read_csv without parse_dates) read as a time column
    text_index = pd.read_csv(path, index_col="time")
    (got,) = diagnose.read_loops(text_index)
    assert got.n == rec.n and got.ts_s == rec.ts_s and got.start == diagnose.read_loops(df)[0].start
    assert diagnose.read_loops(text_index, time="time")[0].n == rec.n
    # ... also with a period given (resampled to it, not read by row order), or a name a column has
    (got,) = diagnose.read_loops(text_index, ts_s=2.0)
    assert got.ts_s == 2.0 and got.n == rec.n // 2 and "resampled" in {f.code for f in got.findings}
    clash = text_index.rename_axis("FIC21.OP")
    assert diagnose.read_loops(clash)[0].start == diagnose.read_loops(df)[0].start
    # a text index of labels is no time axis where a period is given, and is said to be none without
    labels = pd.DataFrame({"OP": rec.op, "PV": rec.pv}, index=[f"s{k}" for k in range(rec.n)])
    assert diagnose.read_loops(labels, ts_s=1.0)[0].n == rec.n
    with pytest.raises(diagnose.DataError, match=r"^the frame's index, row 0: cannot read timestamp 's0'"):
        diagnose.read_loops(labels)
    # columns named by numbers, chosen by number
    numbered = df.set_axis(range(df.shape[1]), axis=1)
    cols = list(df.columns)
    (got,) = diagnose.read_loops(numbered, op=cols.index("FIC21.OP"), pv=cols.index("FIC21.PV"))
    np.testing.assert_allclose(got.op, rec.op, atol=1e-3)
    # a period given that is not the data's own: resampled, and said so (not "irregular sampling")
    (got,) = diagnose.read_loops(df, ts_s=5.0)
    codes = {f.code for f in got.findings}
    assert "resampled" in codes and "irregular_sampling" not in codes and got.ts_s == 5.0
    said = next(f for f in got.findings if f.code == "resampled")
    assert said.data == {"data_ts_s": 1.0, "ts_s": 5.0} and "leave ts_s= out" in said.message
    assert "resampled" not in {f.code for f in diagnose.read_loops(df)[0].findings}
    # too short: the minimum named is the diagnosis's, and a file's is a DataError too (as documented)
    with pytest.raises(diagnose.DataError, match=r"has 30 samples \(need at least 50\)"):
        diagnose.identify(df.iloc[:30])
    short = path.parent / "short40.csv"
    short.write_text("\n".join(path.read_text().splitlines()[:41]) + "\n")
    with pytest.raises(diagnose.DataError, match=r"short40.csv: too few samples: .* has 40 samples \(need at least 50\)"):
        diagnose.identify(short)
    # a MultiIndex is not a text index
    multi = df.reset_index().assign(unit="U1").set_index(["unit", "time"])
    (got,) = diagnose.read_loops(multi, ts_s=1.0)
    assert got.n == rec.n


def test_a_record_checks_what_it_is_given_and_survives_a_frame_round_trip():
    op = 50.0 + np.sin(np.arange(200) / 5.0)
    pv = 2.0 * op
    assert diagnose.LoopRecord(5, 1.0, op, pv).name == "5"         # a numeric tag is still a name
    for kw, says in (({"start": "yesterday"}, r"^start='yesterday': give the first sample's time in ISO 8601"),
                     ({"findings": ["x"]}, r"^findings must be Finding objects")):
        with pytest.raises(diagnose.DataError, match=says):
            diagnose.LoopRecord("X", 1.0, op, pv, **kw)
    with pytest.raises(diagnose.DataError, match="complex"):
        diagnose.LoopRecord("X", 1.0, op + 0j, pv)
    for start, ts in ((None, 1.0), ("2026-01-01T01:00:00+01:00", 1.0 / 3.0), ("2026-03-01T00:00:00Z", 2.0)):
        rec = diagnose.LoopRecord("X", ts, op, pv, start=start)
        back = diagnose.LoopRecord.from_frame(rec.to_frame())
        assert (back.start, back.ts_s) == (start, ts)
        np.testing.assert_array_equal(back.op, rec.op)
        # a slice keeps the frame's attributes but not its first time: the index decides
        part = diagnose.LoopRecord.from_frame(rec.to_frame().iloc[10:])
        assert part.start != start and part.ts_s == pytest.approx(ts)
    with pytest.raises(diagnose.DataError, match=r"^the frame's times are not in increasing order"):
        diagnose.LoopRecord.from_frame(rec.to_frame().iloc[::-1])
