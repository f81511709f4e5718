"""Exports as vendors' tools write them: AVEVA Historian, DeltaV, IP.21, Aspen/PHD header rows."""

from __future__ import annotations

import io
import json
import re
import shutil
from pathlib import Path

import numpy as np
import pytest

from connectors import read_records
from diagnose.errors import ConnectorError

DATA = Path(__file__).parent / "data_connectors"


def bad_values(rec):
    return {f.data["role"]: f.data for f in rec.findings if f.code == "bad_values"}


def test_aveva_history_quality_detail_is_the_opc_code():
    # AVEVA's own Quality column is 0 for good rows; read as OPC quality it made every row bad
    (rec,) = read_records(DATA / "aveva_history_long.csv")
    assert rec.name == "FIC201" and rec.n == 120 and rec.ts_s == 1.0
    assert rec.meta["quality_scheme"] == "opc"
    bad = bad_values(rec)
    assert set(bad) == {"pv"} and bad["pv"]["bad_quality"] == 1 and bad["pv"]["text"] == 1


def test_no_good_quality_names_the_column_and_its_reading(tmp_path):
    rows = (DATA / "aveva_history_long.csv").read_text().splitlines()
    f = tmp_path / "aveva_quality_only.csv"
    f.write_text("\n".join(",".join(r.split(",")[:4]) for r in rows) + "\n")
    with pytest.raises(ConnectorError, match=r"aveva_quality_only\.csv:\d+ \(column 'FIC201\.\w\w'\): \w\w column "
                                             r"has no value with good quality \(column 'Quality' read as [^)]+, "
                                             r"good at [^)]+\); if the export's quality codes mean "
                                             r"something else, delete that column"):
        read_records(f)


def test_deltav_parameter_paths_with_their_field():
    (rec,) = read_records(DATA / "deltav_history.csv")
    assert rec.name == "FIC-201/PID1" and rec.n == 120 and rec.ts_s == 1.0
    assert rec.meta["columns"] == {"op": "FIC-201/PID1/OUT.CV", "pv": "FIC-201/PID1/PV.CV",
                                   "sp": "FIC-201/PID1/SP.CV", "mode": "FIC-201/PID1/MODE.ACTUAL"}
    assert rec.meta["manual_intervals"] == [[60, 70]]
    assert rec.start == "2024-03-01T08:00:00Z" and np.all(rec.sp == 20.0)


def test_description_and_units_rows_under_the_header():
    (rec,) = read_records(DATA / "aspen_units_rows.csv")
    assert rec.name == "FIC301" and rec.n == 120 and rec.ts_s == 5.0 and rec.start == "2024-03-01T08:00:00Z"
    assert rec.units["pv"] == "m3/h" and rec.meta["label_rows"] == ["", "Units"]
    assert not rec.findings
    first = (DATA / "aspen_units_rows.csv").read_text().splitlines()[3].split(",")
    assert rec.pv[0] == float(first[1]) and rec.op[0] == float(first[2])


def test_a_text_row_under_the_header_that_is_data_is_not_skipped(tmp_path):
    # a first row of text states with a readable time is data (a gap), not a label row
    lines = (DATA / "aspen_units_rows.csv").read_text().splitlines()
    t = lines[3].split(",")[0]
    f = tmp_path / "states.csv"
    f.write_text("\n".join([lines[0], f"{t},I/O Timeout,Bad,Bad"] + lines[4:]) + "\n")
    (rec,) = read_records(f)
    assert rec.start == "2024-03-01T08:00:05Z" and rec.n == 119 and "label_rows" not in rec.meta
    assert bad_values(rec)["pv"]["text"] == 1 and bad_values(rec)["op"]["text"] == 1


def test_phd_confidence_columns_are_the_quality_of_the_values_beside_them(tmp_path):
    # read as signals they were ignored, and a sample PHD could not vouch for passed for a good one
    path = DATA / "phd_confidence_wide.csv"
    lines = path.read_text().splitlines()
    pv_in_file = np.array([float(ln.split(",")[1]) for ln in lines[3:]])
    (rec,) = read_records(path)
    assert rec.name == "FIC801" and rec.n == 120 and rec.ts_s == 5.0 and rec.start == "2024-03-01T08:00:00Z"
    assert rec.meta["columns"] == {"pv": "FIC801.PV", "op": "FIC801.OP", "sp": "FIC801.SP"}
    assert rec.meta["quality_scheme"] == "phd_confidence" and rec.units["pv"] == "m3/h"
    assert rec.meta["quality_columns"]["FIC801.PV"] == "FIC801.PV Confidence"
    bad = bad_values(rec)
    assert set(bad) == {"pv"} and bad["pv"]["bad_quality"] == 2 and bad["pv"]["text"] == 0
    # confidence 0 and 30: gaps, filled between their neighbours; 50 and up: the value as written
    np.testing.assert_allclose(rec.pv[40:42], np.interp([40, 41], [39, 42], pv_in_file[[39, 42]]))
    assert abs(rec.pv[40] - pv_in_file[40]) > 1e-3
    np.testing.assert_array_equal(np.delete(rec.pv, [40, 41]), np.delete(pv_in_file, [40, 41]))
    # the same export with a bare "Confidence" after each value column
    bare = tmp_path / "phd_bare.csv"
    head = ",".join("Confidence" if "Confidence" in h else h for h in lines[0].split(","))
    bare.write_text("\n".join([head] + lines[1:]) + "\n")
    (rec2,) = read_records(bare)
    np.testing.assert_array_equal(rec2.pv, rec.pv)
    assert bad_values(rec2)["pv"]["bad_quality"] == 2 and rec2.meta["columns"] == rec.meta["columns"]
    # no sample with good confidence: OP's is an error, PV's a finding, each naming the confidence
    # column and how it was read
    def zero(column):
        f = tmp_path / f"phd_dead_{column}.csv"
        f.write_text("\n".join(lines[:3] + [",".join("0" if j == column else c for j, c in enumerate(ln.split(",")))
                                            for ln in lines[3:]]) + "\n")
        return f

    rule = r"no value with good quality \(column 'FIC801\.{} Confidence' read as PHD confidence, good at 50-100\)"
    with pytest.raises(ConnectorError, match=r"OP column has " + rule.format("OP")):
        read_records(zero(4))
    (dead_pv,) = read_records(zero(2))
    (f,) = [f for f in dead_pv.findings if f.code == "pv_missing"]
    assert re.search(rule.format("PV"), f.message) and f.message.endswith("the loop is judged without PV, from OP alone (and the stem position where recorded)")


def test_ip21_trend_columns_are_a_long_layout():
    (rec,) = read_records(DATA / "ip21_trend_long.csv")
    assert rec.meta["format"] == "long" and rec.meta["quality_scheme"] == "text"
    assert rec.name == "FIC401" and rec.n == 120 and rec.ts_s == 10.0 and rec.start == "2024-03-01T08:00:00Z"
    assert bad_values(rec)["pv"]["bad_quality"] == 1 and "op" not in bad_values(rec)


@pytest.mark.parametrize("fname, fmt", [("excel_uk_dmy.csv", "%d/%m/%Y %H:%M"), ("excel_nl_dmy.csv", "%d-%m-%Y %H:%M")])
def test_day_first_dates_without_a_day_above_12(fname, fmt):
    # month-first, the ten days spread over ten months and split the loop into ten segments
    (rec,) = read_records(DATA / fname)
    assert rec.meta["time_format"] == fmt
    assert rec.start == "2024-03-01T00:00:00Z" and rec.n == 120 and rec.ts_s == 7200.0 and not rec.findings


def test_month_first_dates_without_a_day_above_12_stay_month_first(tmp_path):
    rows = (DATA / "excel_uk_dmy.csv").read_text().splitlines()
    us = [rows[0]] + [f"{r[3:5]}/{r[:2]}{r[5:]}" for r in rows[1:]]     # the same times, mm/dd/yyyy
    f = tmp_path / "us.csv"
    f.write_text("\n".join(us) + "\n")
    (rec,) = read_records(f)
    assert rec.meta["time_format"] == "%m/%d/%Y %H:%M" and rec.start == "2024-03-01T00:00:00Z" and rec.n == 120


def test_a_one_day_export_that_reads_both_ways_says_so_and_dayfirst_decides(tmp_path, capsys):
    # 05/03/2026 all morning: 5 March or 3 May? Read month first as before, but no longer silently
    import pandas as pd

    import diagnose
    from diagnose.service.cli import main

    path = DATA / "excel_uk_one_day.csv"
    (rec,) = read_records(path)
    assert rec.start == "2026-05-03T08:00:00Z" and rec.n == 120 and rec.ts_s == 5.0   # the reading is unchanged
    (f,) = [f for f in rec.findings if f.code == "date_order"]
    assert f.severity == "warning" and f.message.startswith(f"{path}: the date order is ambiguous")
    assert "'05/03/2026 08:00:00'" in f.message and "read month first (2026-05-03)" in f.message
    assert f.message.endswith("if the day comes first, give --dayfirst (dayfirst=True in Python)")
    (uk,) = read_records(path, dayfirst=True)
    assert uk.start == "2026-03-05T08:00:00Z" and not [f for f in uk.findings if f.code == "date_order"]
    np.testing.assert_array_equal(uk.pv, rec.pv)
    (us,) = read_records(path, dayfirst=False)
    assert us.start == rec.start and not [f for f in us.findings if f.code == "date_order"]
    # the command shows it, and takes --dayfirst
    assert main(["identify", str(path)]) == 0
    out = capsys.readouterr().out
    assert f"warning [data_quality.date_order]: {path}: the date order is ambiguous" in out
    assert main(["identify", str(path), "--dayfirst", "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert "data_quality.date_order" not in {w["code"] for w in doc["warnings"]}
    assert "date_order" not in {f["code"] for f in doc["data_quality"]}
    # the frame pandas reads from the file: the keyword, not the flag
    df = pd.read_csv(path)
    (fr,) = diagnose.read_loops(df)
    (g,) = [f for f in fr.findings if f.code == "date_order"]
    assert g.message.startswith("the frame's time column 'Date': the date order is ambiguous")
    assert g.message.endswith("give dayfirst=True") and "--" not in g.message
    assert diagnose.read_loops(df, dayfirst=True)[0].start == "2026-03-05T08:00:00Z"
    with pytest.raises(diagnose.DataError, match=r"^dayfirst='yes' \(--dayfirst/--monthfirst\): give True"):
        diagnose.read_loops(df, dayfirst="yes")
    # what the file does decide stays quiet: dotted dates are day first wherever written, and a
    # day equal to its month reads the same either way
    lines = path.read_text().splitlines()
    for name, date in (("dotted.csv", "05.03.2026"), ("same.csv", "05/05/2026")):
        p = tmp_path / name
        p.write_text("\n".join([lines[0]] + [date + ln[10:] for ln in lines[1:]]) + "\n")
        (r,) = read_records(p)
        assert r.n == 120 and not [f for f in r.findings if f.code == "date_order"], name


def test_seven_digit_fractions_with_a_12_hour_clock():
    # .NET's "M/d/yyyy h:mm:ss.fffffff tt": 100 ms data across noon
    rng = np.random.default_rng(5)
    rows = ["Timestamp,FIC601.PV,FIC601.OP"]
    for k in range(200):
        ms = 11 * 3600_000 + 59 * 60_000 + 50_000 + 100 * k
        h, rest = divmod(ms, 3600_000)
        m, rest = divmod(rest, 60_000)
        rows.append(f"3/1/2024 {h % 12 or 12}:{m:02d}:{rest // 1000:02d}.{rest % 1000:03d}0000 {'AM' if h < 12 else 'PM'},"
                    f"{20 + rng.normal():.3f},{50 + rng.normal():.3f}")
    (rec,) = read_records(io.StringIO("\n".join(rows) + "\n"))
    assert rec.start == "2024-03-01T11:59:50Z" and rec.ts_s == 0.1 and rec.n == 200
    # one day, 3/1: 3 January reads as well (a 12-hour clock is written day first too, en-AU)
    assert [(f.code, f.data["read"]) for f in rec.findings] == [("date_order", "month first")]


def test_units_in_brackets_after_the_column_name(tmp_path):
    rows = (DATA / "excel_nl_dmy.csv").read_text(encoding="cp1252").splitlines()
    f = tmp_path / "units.csv"
    f.write_text("\n".join(["Datum;FIC502.PV [m³/h];FIC502.OP (%)"] + rows[1:]) + "\n", encoding="cp1252")
    (rec,) = read_records(f)
    assert rec.name == "FIC502" and rec.n == 120 and rec.units["pv"] == "m³/h"
    assert rec.meta["columns"] == {"pv": "FIC502.PV [m³/h]", "op": "FIC502.OP (%)"}


def test_wincc_tag_logging_export():
    (rec,) = read_records(DATA / "wincc_taglogging.csv")
    assert rec.meta["format"] == "long" and rec.meta["quality_scheme"] == "wincc_validity"
    assert rec.name == "FIC701" and rec.n == 120 and rec.ts_s == 2.0 and rec.start == "2024-03-01T08:00:00Z"
    assert bad_values(rec)["pv"]["bad_quality"] == 1 and "op" not in bad_values(rec)
    first = (DATA / "wincc_taglogging.csv").read_text().splitlines()[1].split(";")
    assert rec.pv[0] == float(first[2].replace(",", "."))


def test_scada_tag_names_with_an_underscore_before_the_role(tmp_path):
    # InTouch-style tag names (FIC_301_PV): the role after the last underscore when it is one of
    # the abbreviations; a word such as _OUT stays another measurement
    f = tmp_path / "scada.csv"
    rows = ["Time,FIC_301_PV,FIC_301_OP,FIC_301_SP,REACTOR_TEMP_OUT"]
    rows += [f"2024-03-01 08:{k // 60:02d}:{k % 60:02d},{20 + np.sin(k / 9):.3f},{50 + 3 * np.cos(k / 9):.3f},20,"
             f"{80 + k / 100:.2f}" for k in range(120)]
    f.write_text("\n".join(rows) + "\n")
    (rec,) = read_records(f)
    assert rec.name == "FIC_301" and rec.n == 120
    assert rec.meta["columns"] == {"pv": "FIC_301_PV", "op": "FIC_301_OP", "sp": "FIC_301_SP"}


def _bracket_day(path, day: int, pv_units: str, seed: int, units_row: bool = False) -> None:
    """One day's export of FIC101 with its units in the header's brackets (or in a units row)."""
    rng = np.random.default_rng(seed)
    head = ["Time,FIC101.PV [%s],FIC101.OP [%%]" % pv_units]
    if units_row:
        head = ["Time,FIC101.PV,FIC101.OP", f"Units,{pv_units},%"]
    rows = [f"2024-03-{day:02d} 08:{k // 60:02d}:{k % 60:02d},{20 + np.sin(k / 9) + 0.1 * rng.normal():.3f},"
            f"{50 + 3 * np.cos(k / 9):.3f}" for k in range(0, 600, 5)]
    path.write_text("\n".join(head + rows) + "\n")


@pytest.mark.parametrize("units_row", [False, True])
def test_a_loop_joined_from_several_files_keeps_its_units(tmp_path, units_row):
    for day in (1, 2):
        _bracket_day(tmp_path / f"day{day}.csv", day, "m3/h", seed=day, units_row=units_row)
    (rec,) = [r for r in read_records(tmp_path) if r.meta.get("segment", 0) == 0]
    assert rec.name == "FIC101" and rec.units["pv"] == "m3/h"


@pytest.mark.parametrize("units_row", [False, True])
def test_a_loop_joined_from_files_in_other_units_is_an_error_naming_both(tmp_path, units_row):
    _bracket_day(tmp_path / "day1.csv", 1, "m3/h", seed=1, units_row=units_row)
    _bracket_day(tmp_path / "day2.csv", 2, "l/s", seed=2, units_row=units_row)
    with pytest.raises(ConnectorError) as exc:
        read_records(tmp_path)
    msg = str(exc.value)
    assert "\n" not in msg and "'m3/h'" in msg and "'l/s'" in msg
    assert str(tmp_path / "day1.csv") in msg and str(tmp_path / "day2.csv") in msg


def test_a_tag_map_gives_the_date_order_and_the_command_line_overrides_it(tmp_path, capsys):
    from diagnose.service.cli import main

    export = tmp_path / "FIC503.csv"
    shutil.copy(DATA / "excel_uk_one_day.csv", export)     # 05/03/2026 all morning
    tags = tmp_path / "map.toml"
    tags.write_text('dayfirst = true\n\n[loops.FIC503]\nop = "FIC503.OP"\npv = "FIC503.PV"\n')
    (rec,) = read_records(export, tags=tags)
    assert rec.start == "2026-03-05T08:00:00Z" and not [f for f in rec.findings if f.code == "date_order"]
    (us,) = read_records(export, tags=tags, dayfirst=False)
    assert us.start == "2026-05-03T08:00:00Z"
    # the command reads the map's order: no date_order warning (without the map it has one)
    for extra in ([], ["--tags", str(tags)]):
        assert main(["identify", str(export), "--json"] + extra) == 0
        codes = {w["code"] for w in json.loads(capsys.readouterr().out)["warnings"]}
        assert ("data_quality.date_order" in codes) == (not extra)
    tags.write_text('dayfirst = "yes"\n\n[loops.FIC503]\nop = "FIC503.OP"\npv = "FIC503.PV"\n')
    with pytest.raises(ConnectorError, match=r"map\.toml: dayfirst must be true .* or false .*, not 'yes'$"):
        read_records(export, tags=tags)
    assert main(["identify", str(export), "--tags", str(tags)]) != 0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "map.toml" in err[0] and "dayfirst must be true" in err[0]


def _one_day(path, date: str, tag: str = "FIC503") -> None:
    """The one-day UK export (Excel, dd/mm/yyyy) dated ``date``, its loop named ``tag``."""
    lines = (DATA / "excel_uk_one_day.csv").read_text().splitlines()
    path.write_text("\n".join([lines[0].replace("FIC503", tag)] + [date + ln[10:] for ln in lines[1:]]) + "\n")


def _orders(recs):
    return sorted((r.name, r.start[:10], [f.code for f in r.findings if f.code == "date_order"]) for r in recs)


def test_a_folder_of_one_day_exports_shares_one_date_order(tmp_path):
    # each file alone reads alike both ways (and was read month first: 3 May, 3 June); together
    # 05/03 and 06/03 are two days of March, not two months
    for day in (5, 6):
        _one_day(tmp_path / f"day{day}.csv", f"{day:02d}/03/2026")
    recs = read_records(tmp_path)
    assert _orders(recs) == [("FIC503", "2026-03-05", []), ("FIC503", "2026-03-06", [])]
    assert all(r.meta["time_format"].startswith("%d/%m/%Y") for r in recs)
    # the same dates month first (a US folder: 03/05, 03/06) stay month first, no longer warned
    us = tmp_path / "us"
    us.mkdir()
    for day in (5, 6):
        _one_day(us / f"day{day}.csv", f"03/{day:02d}/2026")
    assert _orders(read_records(us)) == [("FIC503", "2026-03-05", []), ("FIC503", "2026-03-06", [])]
    # a file whose dates say it (13/03) decides for the ambiguous one beside it
    mixed = tmp_path / "mixed"
    mixed.mkdir()
    _one_day(mixed / "a.csv", "05/03/2026", tag="FIC1")
    _one_day(mixed / "b.csv", "13/04/2026", tag="FIC2")
    assert _orders(read_records(mixed)) == [("FIC1", "2026-03-05", []), ("FIC2", "2026-04-13", [])]
    # --monthfirst still overrides the folder
    assert [r.start[:10] for r in read_records(tmp_path, dayfirst=False)] == ["2026-05-03", "2026-06-03"]


def test_the_shared_date_order_reads_only_files_whose_dates_could_be_either_way(tmp_path, monkeypatch):
    import connectors
    import connectors.layouts

    for day in (5, 6):
        _one_day(tmp_path / f"day{day}.csv", f"{day:02d}/03/2026")
    iso = tmp_path / "iso.csv"
    iso.write_text("time,FIC1.OP,FIC1.PV\n" + "".join(f"2026-03-05T00:00:{k:02d}Z,{50 + k % 3},{40 + k % 2}\n"
                                                      for k in range(40)))
    utf16 = tmp_path / "utf16.csv"
    utf16.write_text((DATA / "excel_uk_one_day.csv").read_text(), encoding="utf-16")
    parsed = []
    real_parse = connectors.layouts.parse
    monkeypatch.setattr(connectors.layouts, "parse", lambda src, opts: parsed.append(src.label) or real_parse(src, opts))
    files = [tmp_path / "day5.csv", tmp_path / "day6.csv", iso, utf16]
    orders = connectors.date_orders([str(f) for f in files])
    assert orders[:3] == [True, True, None]
    # the ISO file is never read whole; a head the sniff cannot read as ASCII (UTF-16) is
    assert str(iso) not in parsed
    assert str(utf16) in parsed and str(tmp_path / "day5.csv") in parsed


def test_a_folder_that_is_ambiguous_as_a_whole_warns_as_a_file_does(tmp_path):
    # two loops exported on the same day: the folder cannot tell either, each file says so
    for tag in ("FIC1", "FIC2"):
        _one_day(tmp_path / f"{tag}.csv", "05/03/2026", tag=tag)
    recs = read_records(tmp_path)
    assert _orders(recs) == [("FIC1", "2026-05-03", ["date_order"]), ("FIC2", "2026-05-03", ["date_order"])]
    assert [r.start[:10] for r in read_records(tmp_path, dayfirst=True)] == ["2026-03-05", "2026-03-05"]


def test_a_file_of_another_export_in_the_folder_does_not_lend_its_date_order(tmp_path):
    # a US export (month first, AM/PM) of one day beside a UK export whose 13/04 says day first:
    # the US file keeps its own reading (a guess, warned about), not the UK file's order
    _one_day(tmp_path / "uk.csv", "13/04/2026", tag="FIC2")
    lines = (DATA / "excel_uk_one_day.csv").read_text().splitlines()
    us = [lines[0].replace("FIC503", "FIC1")]
    for ln in lines[1:]:
        hh, rest = int(ln[11:13]), ln[13:]
        us.append(f"03/05/2026 {hh % 12 or 12:02d}{rest[:6]} {'AM' if hh < 12 else 'PM'}{rest[6:]}")
    (tmp_path / "us.csv").write_text("\n".join(us) + "\n")
    recs = {r.name: r for r in read_records(tmp_path)}
    assert recs["FIC2"].start[:10] == "2026-04-13"
    assert recs["FIC1"].start[:10] == "2026-03-05"
    assert [f.code for f in recs["FIC1"].findings if f.code == "date_order"] == ["date_order"]
