"""Historian connectors: every layout, time handling, tag maps, folders, bad input, fuzzing."""

from __future__ import annotations

import io
import os
import re
import shutil
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from connectors import list_sources, read_records
from connectors.columns import role_of, split_tag
from connectors.historian import format_wide, read_wide, write_wide
from connectors.layouts import detect_layout
from connectors.tagmap import load_tagmap
from connectors.textio import open_source, quality_good
from connectors.timebase import parse_times
from diagnose.errors import ConnectorError
from diagnose.record import LoopRecord

DATA = Path(__file__).parent / "data_connectors"
FUZZ = int(os.environ.get("STICTION_FUZZ_EXAMPLES", "150"))  # raise for a longer fuzzing run
TAGMAP = DATA / "tagmap_historian.toml"


def codes(rec):
    return {f.code for f in rec.findings}


def wide_text(n=200, sep=",", header=("time", "FIC1.OP", "FIC1.PV"), seed=0, start_s=0):
    rng = np.random.default_rng(seed)
    lines = [sep.join(header)]
    for k in range(n):
        lines.append(sep.join([f"2024-05-01T00:{(start_s + k) // 60:02d}:{(start_s + k) % 60:02d}Z",
                               f"{50 + rng.normal():.4f}", f"{20 + rng.normal():.4f}"]))
    return "\n".join(lines) + "\n"


# ------------------------------------------------------------------------------------------ layouts

@pytest.mark.parametrize("fname, layout", [
    ("dcs_2411FIC20102_trim.txt", "dcs"), ("historian_FIC211_trim.csv", "wide"),
    ("isdb_PAP2_trim.csv", "wide"), ("long_opc_quality.csv", "long"),
    ("pi_datalink_ragged.csv", "ragged"), ("influx_annotated.csv", "influx"),
    ("wide_semicolon_comma.csv", "wide"), ("wide_tab_dst_berlin.tsv", "wide"),
])
def test_layout_detection(fname, layout):
    assert detect_layout(open_source(DATA / fname)) == layout


def test_dcs_export_mv_is_the_controller_output():
    (rec,) = read_records(DATA / "dcs_2411FIC20102_trim.txt")
    raw = (DATA / "dcs_2411FIC20102_trim.txt").read_text(encoding="utf-8").splitlines()
    first = raw[5].split("\t")
    assert rec.name == "2411FIC20102"
    assert rec.op[0] == pytest.approx(float(first[1]))      # <tag>.MV -> OP
    assert rec.pv[0] == pytest.approx(float(first[2]))
    assert rec.sp[0] == pytest.approx(float(first[3]))      # .SV -> SP
    assert rec.mv is None
    assert rec.ts_s == 10.0 and rec.n == 240
    assert rec.start == "2024-10-02T21:55:00Z"
    assert rec.meta["format"] == "dcs" and rec.meta["has_mode"] and rec.meta["manual_intervals"] == []


def test_historian_export_needs_a_tag_map_and_reads_newest_first():
    with pytest.raises(ConnectorError, match=r"historian_FIC211_trim\.csv: no OP or PV column.*--op/--pv.*--tags"):
        read_records(DATA / "historian_FIC211_trim.csv")
    (rec,) = read_records(DATA / "historian_FIC211_trim.csv", tags=TAGMAP)
    assert rec.name == "FIC211" and rec.ts_s == 60.0 and rec.n == 300
    assert rec.meta["order"] == "newest_first" and rec.meta["bom"] is True
    # oldest first after reading: the file's last data row is the record's first sample
    last = (DATA / "historian_FIC211_trim.csv").read_text(encoding="utf-8-sig").splitlines()[-1].split(",")
    assert rec.pv[0] == pytest.approx(float(last[3])) and rec.op[0] == pytest.approx(float(last[4]))
    assert rec.start == f"{last[1]}T{last[2]}Z"
    (rec2,) = read_records(DATA / "historian_FIC211_trim.csv", op="FV_211", pv="FT_211")
    np.testing.assert_allclose(rec2.op, rec.op)


def test_tag_map_scales_op_to_percent(tmp_path):
    tm = tmp_path / "map.toml"
    tm.write_text('[loops.FIC211]\nop = { tag = "FV_211", range = [20, 70] }\npv = "FT_211"\n')
    (rec,) = read_records(DATA / "historian_FIC211_trim.csv", tags=tm)
    (raw,) = read_records(DATA / "historian_FIC211_trim.csv", op="FV_211", pv="FT_211")
    np.testing.assert_allclose(rec.op, 100 * (raw.op - 20) / 50)
    assert rec.ranges["op"] == (20.0, 70.0)
    (same,) = read_records(DATA / "historian_FIC211_trim.csv",
                           tags={"loops": {"FIC211": {"op": {"tag": "FV_211", "range": [20, 70]}, "pv": "FT_211"}}})
    np.testing.assert_allclose(same.op, rec.op)


def test_isdb_seconds_column():
    (rec,) = read_records(DATA / "isdb_PAP2_trim.csv")
    assert rec.name == "isdb_PAP2_trim" and rec.ts_s == 1.0 and rec.n == 300 and rec.start is None
    assert rec.op[:2].tolist() == [18.48, 18.61]


def test_long_layout_with_quality_codes_and_text_states():
    recs = read_records(DATA / "long_opc_quality.csv")
    assert [r.name for r in recs] == ["FIC101", "FIC102"]
    r1 = recs[0]
    bad = next(f for f in r1.findings if f.code == "bad_values")
    assert bad.data["role"] == "pv" and bad.data["bad_quality"] == 2 and bad.data["text"] == 1
    assert "I/O Timeout" in bad.data["examples"]
    gap = next(f for f in r1.findings if f.code == "gap")
    assert gap.data["filled"] == 3                      # short gaps interpolated, counted
    assert np.all(np.isfinite(r1.pv)) and r1.n == 200
    assert "bad_values" not in codes(recs[1])


def test_pi_datalink_ragged_two_timestamp_columns():
    (rec,) = read_records(DATA / "pi_datalink_ragged.csv")
    assert rec.name == "FIC103" and rec.ts_s == 1.0
    assert rec.meta["format"] == "ragged"
    # PV archived every 2 s: odd samples interpolated halfway, not reported as gaps
    assert "gap" not in codes(rec)
    text = (DATA / "pi_datalink_ragged.csv").read_text().splitlines()
    pv0, pv2 = float(text[1].split(",")[3]), float(text[2].split(",")[3])
    assert rec.pv[1] == pytest.approx((pv0 + pv2) / 2)


def test_influx_annotated_csv():
    (rec,) = read_records(DATA / "influx_annotated.csv")
    assert rec.name == "FIC104" and rec.n == 200 and rec.meta["format"] == "influx"


def test_semicolon_decimal_comma_european_dates():
    (rec,) = read_records(DATA / "wide_semicolon_comma.csv")
    assert rec.meta["delimiter"] == "semicolon" and rec.meta["decimal"] == ","
    assert rec.op[0] == pytest.approx(55.006) and np.all(rec.sp == 20.0)
    assert rec.start == "2024-03-01T08:00:00Z"


def test_dst_local_times_and_mode_column():
    (naive,) = read_records(DATA / "wide_tab_dst_berlin.tsv")
    assert "duplicates" in codes(naive)                # the repeated hour read as UTC collides
    # ... and the reader says why and what to do (newest first: the clock steps forward once)
    back = next(f for f in naive.findings if f.code == "clock_back")
    assert back.severity == "warning" and "--tz" in back.message and back.data["after"].startswith("2024-10-27 02:")
    (rec,) = read_records(DATA / "wide_tab_dst_berlin.tsv", tz="Europe/Berlin")
    assert rec.n == 240 and rec.ts_s == 60.0 and not {"duplicates", "clock_back"} & codes(rec)
    assert rec.start == "2024-10-27T00:00:00Z"
    assert rec.meta["order"] == "newest_first"
    assert rec.meta["manual_intervals"] == [[100, 130]]
    man = next(f for f in rec.findings if f.code == "manual_mode")
    assert man.severity == "warning" and man.data["samples"] == 30
    with pytest.raises(ConnectorError, match=r"wide_tab_dst_berlin\.tsv:\d+ \(column 'Timestamp'\): local time .* ambiguous"):
        read_records(DATA / "wide_tab_dst_berlin.tsv", tz="Europe/Berlin", dst="raise")


def test_clock_back_is_one_step_back_of_half_an_hour_to_an_hour():
    from connectors.timebase import clock_back

    t = np.arange(0.0, 7200.0, 10.0)
    autumn = np.concatenate((t[:360], t[:360] + 0.0, t[360:] + 0.0))     # 00:00-00:59 twice
    assert clock_back(autumn) == 3590.0
    assert clock_back(autumn[::-1]) == 0.0                               # newest first: the mirror
    assert clock_back(t) is None                                         # in order
    assert clock_back(np.concatenate((t[:100], t[95:]))) is None         # a stray row, not a clock change
    twice = np.concatenate((t[:360], t[:360], t[:360]))
    assert clock_back(twice) is None                                     # two exports pasted together
    swapped = np.concatenate((t[200:560], t[:200]))                       # pieces pasted in the wrong order
    assert clock_back(swapped) is None and clock_back(swapped[::-1]) is None


def _stamped_csv(path, stamps, rng):
    op = 50 + np.cumsum(rng.normal(0, 0.3, stamps.size))
    pv = op + rng.normal(0, 0.1, stamps.size)
    lines = ["time,FIC7.OP,FIC7.PV"] + [f"{s},{o:.4f},{v:.4f}" for s, o, v in zip(stamps, op, pv)]
    path.write_text("\n".join(lines) + "\n")


def test_clock_back_is_said_only_of_naive_times_that_repeat_a_stretch(tmp_path):
    # a DST change read without --tz repeats an hour; pieces pasted out of order, or times with an
    # offset, step back too but --tz would not help them, and nothing was dropped from the former
    rng = np.random.default_rng(3)
    base = np.datetime64("2026-01-01T00:00:00") + np.arange(3000).astype("timedelta64[s]")
    text = np.datetime_as_string(base, unit="s")
    cases = {"swapped_Z.csv": np.concatenate((text[1500:], text[:1500])) + "Z",
             "swapped.csv": np.concatenate((text[1500:], text[:1500])),
             "overlap_Z.csv": np.concatenate((text[:2400], text)) + "Z",
             "overlap.csv": np.concatenate((text[:2400], text))}
    said = {}
    for name, stamps in cases.items():
        _stamped_csv(tmp_path / name, stamps, rng)
        (rec,) = read_records(tmp_path / name)
        said[name] = "clock_back" in codes(rec)
        if name.startswith("swapped"):
            assert rec.n == 3000 and "duplicates" not in codes(rec)
    assert said == {"swapped_Z.csv": False, "swapped.csv": False, "overlap_Z.csv": False, "overlap.csv": True}
    (rec,) = read_records(tmp_path / "overlap.csv", tz="Europe/Berlin")   # read in its zone: no DST in January
    assert "clock_back" not in codes(rec)


def test_a_signal_given_as_the_time_column_is_named(tmp_path):
    # it vanished from the loop: "no PV column found (columns: ..., FIC7.PV)", or a stem position
    # read as time stamps was diagnosed without a word
    rng = np.random.default_rng(4)
    stamps = np.datetime_as_string(np.datetime64("2026-01-01T00:00:00") + np.arange(300).astype("timedelta64[s]"))
    _stamped_csv(tmp_path / "fic7.csv", stamps, rng)
    text = (tmp_path / "fic7.csv").read_text().splitlines()
    (tmp_path / "fic7.csv").write_text("\n".join([text[0] + ",FIC7.POS"] + [f"{r},{50 + i % 7}" for i, r in
                                                                         enumerate(text[1:])]) + "\n")
    for col, role in (("FIC7.PV", "PV"), ("FIC7.POS", "MV")):
        with pytest.raises(ConnectorError, match=rf"fic7\.csv: column '{re.escape(col)}' given as the time "
                                                 rf"\(--time\) is named as a loop's {role}; give the time column"):
            read_records(tmp_path / "fic7.csv", time=col)
    with pytest.raises(ConnectorError, match=r"column 'FIC7.OP' is given for both the time \(--time\) and OP"):
        read_records(tmp_path / "fic7.csv", time="FIC7.OP", op="FIC7.OP")
    (rec,) = read_records(tmp_path / "fic7.csv", time="time")
    assert rec.n == 300 and rec.mv is not None


@pytest.mark.parametrize("newest_first", [False, True])
def test_a_record_within_the_repeated_hour_is_read_in_one_piece(tmp_path, newest_first):
    # 02:30-02:59 summer time, then 02:00-02:19 winter time: the last stamp is earlier than the
    # first, yet the file runs oldest first; read with --tz it is 50 minutes without a gap
    rng = np.random.default_rng(5)
    wall = np.datetime64("2026-10-25T02:30:00") + np.arange(0, 1800, 10).astype("timedelta64[s]")
    wall = np.concatenate((wall, wall[:120] - np.timedelta64(1800, "s")))
    stamps = np.datetime_as_string(wall[::-1] if newest_first else wall, unit="s")
    _stamped_csv(tmp_path / "fic7.csv", stamps, rng)
    (rec,) = read_records(tmp_path / "fic7.csv", tz="Europe/Berlin")
    assert rec.n == 300 and rec.ts_s == 10.0 and "segment" not in codes(rec)
    assert rec.start == "2026-10-25T00:30:00Z"
    line = 301 if newest_first else 2            # the first ambiguous time in file order
    with pytest.raises(ConnectorError, match=rf"fic7\.csv:{line} \(column 'time'\): local time 2026-10-25 02:30:00 is ambiguous"):
        read_records(tmp_path / "fic7.csv", tz="Europe/Berlin", dst="raise")


def test_dst_spring_forward_gap_is_shifted():
    pt = parse_times(["2024-03-31 01:59:00", "2024-03-31 02:30:00", "2024-03-31 03:01:00"], tz="Europe/Berlin")
    d = np.diff(pt.seconds)
    assert d[0] == pytest.approx(31 * 60 - 3600 + 3600)  # 02:30 does not exist -> 03:30 CEST = 01:30Z
    with pytest.raises(ConnectorError, match="does not exist"):
        parse_times(["2024-03-31 02:30:00"], tz="Europe/Berlin", dst="raise")


@pytest.mark.parametrize("texts, expect", [
    (["2024-11-27 23:59:00", "2024-11-28 00:00:00"], 1732751940.0),
    (["2024-11-27T23:59:00Z"], 1732751940.0),
    (["2024-11-27T23:59:00+01:00"], 1732751940.0 - 3600),
    (["27-Nov-2024 23:59:00"], 1732751940.0),
    (["11/27/2024 11:59:00 PM"], 1732751940.0),
    (["27/11/2024 23:59"], 1732751940.0),
    (["27.11.2024 23:59:00,000"], 1732751940.0),
    (["2024/11/27 23:59:00"], 1732751940.0),
    (["1732751940"], 1732751940.0),
    (["1732751940000"], 1732751940.0),
])
def test_vendor_timestamp_formats(texts, expect):
    assert parse_times(texts).seconds[0] == pytest.approx(expect)


def test_excel_serial_days_in_a_timestamp_column():
    pt = parse_times(["45623.5", "45623.50069444444"], column="Timestamp")
    assert pt.absolute and pt.fmt == "excel_serial"
    assert pt.seconds[0] == pytest.approx(1732708800.0) and pt.seconds[1] - pt.seconds[0] == pytest.approx(60, abs=0.01)
    assert not parse_times(["45623.5", "45624.5"], column="t").absolute   # a seconds column stays seconds


def test_day_first_decided_by_the_column():
    pt = parse_times(["01/02/2024 00:00", "13/02/2024 00:00"])
    assert pt.seconds[1] - pt.seconds[0] == pytest.approx(12 * 86400)


def test_irregular_duplicates_and_long_gap_make_segments():
    rng = np.random.default_rng(3)
    t = np.cumsum(rng.uniform(0.7, 1.3, 400))
    t = np.concatenate([t[:200], t[200:] + 100.0])             # a 100 s hole
    rows = ["time_s,OP,PV"] + [f"{a:.3f},{50 + np.sin(a / 9):.4f},{np.cos(a / 9):.4f}" for a in t]
    rows.insert(50, rows[50])                                   # a duplicated row
    recs = read_records(io.StringIO("\n".join(rows)), ts_s=1.0)
    assert len(recs) == 2
    assert [r.meta["segment"] for r in recs] == [0, 1] and recs[0].meta["n_segments"] == 2
    c = codes(recs[0])
    assert {"segment", "irregular_sampling", "duplicates"} <= c
    # the grid is uniform and values follow the interpolated signal
    tt = recs[0].t_s + float(t[0])
    np.testing.assert_allclose(recs[0].op, 50 + np.sin(tt / 9), atol=0.01)


def test_too_few_samples_between_gaps():
    text = "time_s,OP,PV\n" + "".join(f"{k * 100},{k},{k}\n" for k in range(30))
    with pytest.raises(ConnectorError, match="too few samples"):
        read_records(io.StringIO(text), ts_s=1.0)


def test_many_loops_in_one_file_and_loop_selection():
    text = "time,A.OP,A.PV,B.OUT,B.MEAS,B.SP\n" + "".join(
        f"{k},{k % 7},{k % 5},{k % 3},{k % 11},1\n" for k in range(100))
    recs = read_records(io.StringIO(text))
    assert [r.name for r in recs] == ["A", "B"] and recs[1].sp is not None
    (b,) = read_records(io.StringIO(text), loop="B")
    assert b.name == "B"
    with pytest.raises(ConnectorError, match="no loop named 'C'"):
        read_records(io.StringIO(text), loop="C")


def test_folder_of_files_merges_a_loop_over_days(tmp_path):
    (tmp_path / "day1.csv").write_text(wide_text(100, start_s=0))
    (tmp_path / "day2.csv").write_text(wide_text(100, start_s=100, seed=1))
    (tmp_path / "notes.md").write_text("not data")
    assert [Path(p).name for p in list_sources(tmp_path)] == ["day1.csv", "day2.csv"]
    (rec,) = read_records(tmp_path)
    assert rec.name == "FIC1" and rec.n == 200


def test_folder_with_tag_map_skips_files_without_its_loops(tmp_path):
    shutil.copy(DATA / "historian_FIC211_trim.csv", tmp_path)
    shutil.copy(DATA / "isdb_PAP2_trim.csv", tmp_path)
    recs = read_records(tmp_path, tags=TAGMAP)
    assert [r.name for r in recs] == ["FIC211"]


def test_tag_map_errors(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text("[loops.X]\nop = 'A'\n")
    with pytest.raises(ConnectorError, match=r"bad\.toml: loops\.X needs an pv tag"):
        load_tagmap(bad)
    bad.write_text("[loops.X\n")
    with pytest.raises(ConnectorError, match="not valid TOML"):
        load_tagmap(bad)
    with pytest.raises(ConnectorError, match="none of the tag map's loops"):
        read_records(DATA / "isdb_PAP2_trim.csv", tags=TAGMAP)


def test_write_then_read_round_trip(tmp_path):
    rec = LoopRecord("FIC7", 2.0, np.linspace(10, 20, 50), np.linspace(0, 1, 50), sp=np.ones(50),
                     mv=np.linspace(10, 20, 50))
    write_wide(rec, tmp_path / "x.csv")
    back = read_wide(tmp_path / "x.csv")
    assert back.name == "FIC7" and back.ts_s == 2.0 and back.mv is not None
    np.testing.assert_allclose(back.op, rec.op, atol=1e-4)
    assert format_wide(rec).startswith("time,FIC7.OP,FIC7.PV,FIC7.SP,FIC7.POS\n")


def test_columns_naming_rule():
    assert split_tag("LYCDU.CDU.7040-312_LIC63001.MV") == ("LYCDU.CDU.7040-312_LIC63001", "mv")
    assert role_of("FIC1.MV") == "op" and role_of("MV") == "mv" and role_of("FIC1.SV") == "sp"
    assert role_of("FIC1.MODE") == "mode" and role_of("time") == "time" and role_of("FT_211") is None


def test_quality_schemes():
    assert quality_good(["192", "0", "216", "64"], "Quality")[0].tolist() == [True, False, True, False]
    assert quality_good(["0", "1", "2"], "Status")[0].tolist() == [True, False, False]
    assert quality_good(["100", "20"], "Confidence")[0].tolist() == [True, False]
    assert quality_good(["Good", "Bad", "Questionable", "Substituted"], "q")[0].tolist() == [True, False, False, False]


def test_prefix_rule_for_bare_loop_columns():
    text = "t,OP,MV,PV_flow_t_h,P1\n" + "".join(f"{k},{k % 9},{k % 9},{k % 4},1\n" for k in range(50))
    (rec,) = read_records(io.StringIO(text))
    assert rec.meta["columns"]["pv"] == "PV_flow_t_h" and rec.mv is not None


# -------------------------------------------------------------------------------------- bad input

@pytest.mark.parametrize("content, pattern", [
    (b"", "file is empty"),
    (b"   \n\n", "file is empty"),
    (b"time,OP,PV\n", "header only"),
    (b"time,FIC1.PV,X\n1,2,3\n2,3,4\n", "no OP column found"),
    (b"time,OP,PV\n" + b"".join(b"%d,Bad,%d\n" % (k, k) for k in range(30)), "only text values"),
    (b"time,OP,PV\n" + b"".join(b"%d,nan,inf\n" % k for k in range(30)), "only NaN/inf"),
    (b"time,OP,PV\n1,2,3\n2,3,4\n3,4,5\n", "too few samples"),
    (b"PK\x03\x04\x14\x00\x06\x00garbage", "zip/Excel"),
    (b"\x00\x01\x02\x03binary\x00\x00", "binary"),
    (b"time,OP,PV\n1,2,3\n2,3\n3,4,5\n", r":3: row has 2 fields but the header has 3"),
    (b'time,OP,PV\n1,2,3\n2,"3,4\n', "unterminated quote"),
    (b"time,OP,PV\n1,2,3\n2,3,4,5\n", "row has 4 fields"),
])
def test_bad_input_one_line_errors(tmp_path, content, pattern):
    f = tmp_path / "loop.csv"
    f.write_bytes(content)
    with pytest.raises(ConnectorError, match=pattern) as ei:
        read_records(f)
    msg = str(ei.value)
    assert msg.startswith(str(f)) and "\n" not in msg
    assert msg.count(str(f)) == 1   # named once, not "FILE: cannot read: FILE: ..."


def test_missing_file_and_empty_folder(tmp_path):
    with pytest.raises(ConnectorError, match=r"nope\.csv: file not found"):
        read_records(tmp_path / "nope.csv")
    with pytest.raises(ConnectorError, match="folder has no export files"):
        read_records(tmp_path)


def test_newest_first_is_not_an_error():
    rows = wide_text(100).splitlines()
    (rec,) = read_records(io.StringIO("\n".join([rows[0]] + rows[1:][::-1])))
    (fwd,) = read_records(io.StringIO("\n".join(rows)))
    np.testing.assert_allclose(rec.op, fwd.op)
    assert rec.meta["order"] == "newest_first"


def test_op_never_moves_is_a_warning_finding():
    text = "time,OP,PV\n" + "".join(f"{k},37.5,{np.sin(k / 5):.4f}\n" for k in range(100))
    (rec,) = read_records(io.StringIO(text))
    f = next(f for f in rec.findings if f.code == "frozen" and f.data["role"] == "op")
    assert f.severity == "warning" and f.data["whole_record"] is True and "never moves" in f.message


def test_binary_stream_and_cli_error(tmp_path, capsys):
    from diagnose.service.cli import main

    f = tmp_path / "x.xlsx"
    f.write_bytes(b"PK\x03\x04" + bytes(range(256)))
    assert main(["identify", str(f)]) == 1
    err = capsys.readouterr().err
    assert err.startswith("error: ") and "Traceback" not in err and "x.xlsx" in err


@settings(max_examples=FUZZ, deadline=None, suppress_health_check=[HealthCheck.too_slow], derandomize=True)
@given(st.binary(max_size=600))
def test_fuzz_bytes_only_connector_error(data):
    try:
        recs = read_records(io.BytesIO(data))
    except ConnectorError:
        return
    assert all(isinstance(r, LoopRecord) for r in recs)


_cell = st.one_of(st.floats(allow_nan=True, allow_infinity=True).map(repr),
                  st.sampled_from(["", "Bad", "I/O Timeout", "1.#QNAN", "12,5", "2024-01-01 00:00:00",
                                   "27-Nov-2024 23:59:00", '"', "NaN", "-", "1e309"]),
                  st.text(max_size=6))


@settings(max_examples=FUZZ, deadline=None, suppress_health_check=[HealthCheck.too_slow], derandomize=True)
@given(header=st.lists(st.sampled_from(["time", "OP", "PV", "SP", "FIC1.OP", "FIC1.PV", "Tag", "Value",
                                         "Timestamp", "date", "_time", "_value", "Quality", "x"]),
                       min_size=1, max_size=6),
       rows=st.lists(st.lists(_cell, min_size=0, max_size=7), max_size=40),
       sep=st.sampled_from([",", ";", "\t"]),
       fmt=st.sampled_from([None, "wide", "long", "ragged", "influx", "dcs"]))
def test_fuzz_structured_only_connector_error(header, rows, sep, fmt):
    text = sep.join(header) + "\n" + "\n".join(sep.join(r) for r in rows)
    try:
        recs = read_records(io.StringIO(text), fmt=fmt, min_samples=2)
    except ConnectorError:
        return
    for r in recs:
        assert np.all(np.isfinite(r.op)) and np.all(np.isfinite(r.pv)) and r.n >= 2


def test_findings_and_meta_are_json_serialisable():
    import json

    for fname in ("dcs_2411FIC20102_trim.txt", "long_opc_quality.csv", "wide_tab_dst_berlin.tsv",
                  "pi_datalink_ragged.csv"):
        for rec in read_records(DATA / fname, tz="Europe/Berlin"):
            json.dumps([f.to_dict() for f in rec.findings], allow_nan=False)
            json.dumps(dict(rec.meta), allow_nan=False)


def test_file_objects_text_and_binary():
    text = wide_text(60)
    (a,) = read_records(io.StringIO(text))
    (b,) = read_records(io.BytesIO(b"\xef\xbb\xbf" + text.replace("\n", "\r\n").encode()))
    np.testing.assert_allclose(a.op, b.op)
    assert b.meta["bom"] is True


def test_vendor_variants_two_row_ragged_german_date_time_thousands():
    n = 40
    rows = ["FIC1.OP,,FIC1.PV,", "Timestamp,Value,Timestamp,Value"] + [
        f"27-Nov-2024 10:{k:02d}:00,{50 + k % 5},27-Nov-2024 10:{k:02d}:30,{20 + k % 3}" for k in range(n)]
    (r,) = read_records(io.StringIO("\n".join(rows)))
    assert r.name == "FIC1" and r.meta["format"] == "ragged" and r.ts_s == 60.0
    rows = ["Datum;Zeit;FIC2.OP;FIC2.PV"] + [f"27.11.2024;10:{k:02d}:00;{50 + k % 5},5;{20 + k % 3},25"
                                             for k in range(n)]
    (r,) = read_records(io.StringIO("\n".join(rows)))
    assert r.start == "2024-11-27T10:00:00Z" and r.op[0] == 50.5 and r.pv[1] == 21.25
    rows = ['"time","FIC3.OP","FIC3.PV"'] + [f'"2024-11-27 10:{k:02d}:00","{50 + k % 5}.5","1,{200 + k}.5"'
                                             for k in range(n)]
    (r,) = read_records(io.StringIO("\n".join(rows)))
    assert r.pv[0] == 1200.5


def test_long_layout_pi_flag_columns():
    lines = ["Tag,Timestamp,Value,Questionable,Substituted"]
    for k in range(60):
        ts = f"2024-03-01T08:{k:02d}:00Z"
        lines.append(f"L1.OP,{ts},{50 + k % 4},{'True' if k == 10 else 'False'},False")
        lines.append(f"L1.PV,{ts},{20 + k % 3},False,{'True' if k in (20, 21) else 'False'}")
    (r,) = read_records(io.StringIO("\n".join(lines)))
    bad = {f.data["role"]: f.data["bad_quality"] for f in r.findings if f.code == "bad_values"}
    assert bad == {"op": 1, "pv": 2} and r.meta["quality_scheme"] == "pi_flags"


def test_to_grid_interpolates_short_gaps_only():
    from connectors.timebase import to_grid

    t = np.array([0, 1, 2, 5, 6, 20, 21], float)
    x = np.array([0, 1, 2, 5, 6, 20, 21], float)
    g, filled = to_grid(t, x, np.arange(22.0), max_gap_s=3.0)
    np.testing.assert_allclose(g[:7], np.arange(7.0))           # 3 s gap filled
    assert np.all(np.isnan(g[7:20])) and g[20] == 20 and g[21] == 21
    assert filled.sum() == 2


def test_first_row_wider_than_the_header_is_an_error_not_dropped_data():
    # pandas would take the extra field of a first row for an index and drop it without a word
    text = "time,OP,PV\n1,2,3,4\n" + "".join(f"{k},{k % 7},{k % 5}\n" for k in range(2, 40))
    with pytest.raises(ConnectorError, match=r"<stream>:2: row has 4 fields but the header has 3"):
        read_records(io.StringIO(text))
    text = "time,OP,PV\n1,2,3,\n" + "".join(f"{k},{k % 7},{k % 5},\n" for k in range(2, 40))
    (rec,) = read_records(io.StringIO(text))                 # trailing separators are fine
    assert rec.n == 39


def test_line_numbers_count_line_breaks_inside_quoted_cells():
    text = 'time,OP,PV\n1,2,3\n2,"a\nb",4\n3,4\n' + "".join(f"{k},{k},{k}\n" for k in range(4, 30))
    with pytest.raises(ConnectorError, match=r"<stream>:5: row has 2 fields"):
        read_records(io.StringIO(text))


def test_empty_quality_cell_flags_nothing():
    good, scheme = quality_good(["192", "", "0", "216"], "Quality")
    assert scheme == "opc" and good.tolist() == [True, True, False, True]


def test_stray_row_a_year_later_builds_no_giant_grid(monkeypatch):
    import connectors.records as records

    # a grid over the whole year at 1 s would be 31.5 M points; only the points near data are built
    monkeypatch.setattr(records, "MAX_GRID_SAMPLES", 100_000)
    rows = wide_text(2000).splitlines()
    rows.append("2025-05-01T00:00:00Z,50.0,20.0")
    (rec,) = read_records(io.StringIO("\n".join(rows)))
    assert rec.n == 2000 and rec.start == "2024-05-01T00:00:00Z"
    far = next(f for f in rec.findings if f.code == "isolated")
    assert far.severity == "warning" and far.data["samples"] == 1 and far.data["max_distance_s"] > 364 * 86400
    assert "2025-05-01T00:00:00Z" in far.message
    seg = next(f for f in rec.findings if f.code == "segment")
    assert seg.data["dropped"] == 1


def test_grid_too_large_is_a_one_line_error(monkeypatch):
    import connectors.records as records

    monkeypatch.setattr(records, "MAX_GRID_SAMPLES", 100_000)
    with pytest.raises(ConnectorError, match=r"<stream>: \d+ samples at 0.01 s is too many .*--ts-s"):
        read_records(io.StringIO(wide_text(2000)), ts_s=0.01, max_gap_s=10.0)


def wide_text_long(n, seed=0):
    rng = np.random.default_rng(seed)
    t0 = np.datetime64("2024-05-01T00:00:00")
    stamps = np.datetime_as_string(t0 + np.arange(n).astype("timedelta64[s]"), unit="s")
    op = 50 + 5 * np.sin(np.arange(n) / 30) + rng.normal(0, 0.1, n)
    pv = 20 + np.cos(np.arange(n) / 30) + rng.normal(0, 0.01, n)
    return "time,FIC1.OP,FIC1.PV\n" + "".join(f"{s},{a:.4f},{b:.4f}\n" for s, a, b in zip(stamps, op, pv))


def test_long_records_keep_their_newest_max_samples():
    text = wide_text_long(5000)
    (full,) = read_records(io.StringIO(text), max_samples=0)
    assert full.n == 5000 and "window" not in codes(full)
    lines: list[str] = []
    (rec,) = read_records(io.StringIO(text), max_samples=1200, progress=lines.append)
    assert rec.n == 1200
    np.testing.assert_array_equal(rec.op, full.op[-1200:])
    assert rec.start == "2024-05-01T01:03:20Z"                     # 5000 - 1200 s after the first
    win = next(f for f in rec.findings if f.code == "window")
    assert win.data == {"samples": 5000, "kept": 1200, "max_samples": 1200} and "max_samples" in win.message
    assert any("newest 1200" in ln and "max_samples" in ln for ln in lines)
    assert all(ln.startswith("<stream>: ") for ln in lines)
    (dflt,) = read_records(io.StringIO(text))
    assert dflt.n == 5000                                          # under the default limit


def test_window_takes_the_newest_segments_first():
    t = np.concatenate([np.arange(600), 1000 + np.arange(600)])
    text = "time_s,OP,PV\n" + "".join(f"{a},{50 + np.sin(a / 9):.4f},{np.cos(a / 9):.4f}\n" for a in t)
    recs = read_records(io.StringIO(text), ts_s=1.0, max_samples=900)
    assert [r.n for r in recs] == [300, 600] and all("window" in codes(r) for r in recs)
    assert recs[-1].meta["segment_samples"] == [1000, 1600]


def test_progress_is_silent_for_small_files_unless_asked(capsys):
    read_records(DATA / "long_opc_quality.csv")
    assert capsys.readouterr().err == ""
    read_records(DATA / "long_opc_quality.csv", progress=True)
    err = capsys.readouterr().err.splitlines()
    assert err and all(ln.startswith(str(DATA / "long_opc_quality.csv")) for ln in err)
    assert any("rows parsed" in ln for ln in err)


def test_progress_default_is_on_for_large_sources_only():
    from connectors.textio import PROGRESS_MIN_BYTES, Progress

    assert Progress("x.csv", PROGRESS_MIN_BYTES) and not Progress("x.csv", PROGRESS_MIN_BYTES - 1)
    assert not Progress("x.csv", 10 * PROGRESS_MIN_BYTES, False)
    got: list[str] = []
    p = Progress("x.csv", 100, got.append, every_s=0.0)
    p.rows_read(500_000, 50)
    assert got and got[0].startswith("x.csv: reading, 500000 rows, 0 of 0 MB (50 %)")


def test_read_loops_is_read_records_with_named_options():
    from connectors import read_loops

    (a,) = read_loops(DATA / "historian_FIC211_trim.csv", tags=TAGMAP, tz="Europe/Berlin")
    (b,) = read_records(DATA / "historian_FIC211_trim.csv", tags=TAGMAP, tz="Europe/Berlin")
    np.testing.assert_array_equal(a.op, b.op)
    assert a.start == b.start == "2024-11-27T18:00:00Z"
    with pytest.raises(TypeError):
        read_loops(DATA / "isdb_PAP2_trim.csv", colour="red")


# ---------------------------------------------------------------------------------------- DataFrames

def frame_loop(n=600, seed=0, freq="1s"):
    import pandas as pd

    rng = np.random.default_rng(seed)
    k = np.arange(n)
    return pd.DataFrame({"OP": 50 + 5 * np.sin(k / 40) + rng.normal(0, 0.1, n),
                         "PV": 20 + np.cos(k / 40) + rng.normal(0, 0.01, n),
                         "SP": np.full(n, 20.0)},
                        index=pd.date_range("2024-05-01 00:00", periods=n, freq=freq, name="time"))


def _one(df, **options):
    """The one record `diagnose.read_loops` reads from a frame of one loop and one segment."""
    import diagnose

    (rec,) = diagnose.read_loops(df, **options)
    return rec


def test_read_loops_frame_with_datetime_index_and_to_frame_round_trip():
    import pandas as pd

    df = frame_loop()
    rec = _one(df).replace(name="FIC9")
    assert rec.n == 600 and rec.ts_s == 1.0 and rec.start == "2024-05-01T00:00:00Z"
    np.testing.assert_array_equal(rec.op, df["OP"].to_numpy())
    np.testing.assert_array_equal(rec.sp, df["SP"].to_numpy())
    assert rec.mv is None and rec.meta["format"] == "dataframe" and rec.meta["quality_checked"]
    out = rec.to_frame()
    assert list(out.columns) == ["OP", "PV", "SP"] and isinstance(out.index, pd.DatetimeIndex)
    assert str(out.index.tz) == "UTC" and out.index[0] == pd.Timestamp("2024-05-01", tz="UTC")
    assert out.index[1] - out.index[0] == pd.Timedelta(seconds=1) and out.attrs["name"] == "FIC9"
    back = LoopRecord.from_frame(out)                     # the strict constructor takes what to_frame writes
    assert back.name == "FIC9" and back.start == rec.start and back.ts_s == rec.ts_s
    for role in ("op", "pv", "sp"):
        np.testing.assert_array_equal(getattr(back, role), getattr(rec, role))
    again = _one(out)                                     # and the reader reads it the same
    assert again.name == "FIC9" and again.start == rec.start
    np.testing.assert_array_equal(again.op, rec.op)


def test_read_loops_frame_time_column_and_naming_rule():
    df = frame_loop().reset_index()
    df.columns = ["Timestamp", "FIC7.OUT", "FIC7.MEAS", "FIC7.SP"]
    df["Timestamp"] = df["Timestamp"].dt.strftime("%d-%b-%Y %H:%M:%S")     # PI-style text times
    rec = _one(df)
    assert rec.name == "FIC7" and rec.n == 600 and rec.start == "2024-05-01T00:00:00Z" and rec.sp is not None
    assert rec.meta["columns"] == {"op": "FIC7.OUT", "pv": "FIC7.MEAS", "sp": "FIC7.SP"}
    named = _one(df.rename(columns={"FIC7.OUT": "valve", "FIC7.MEAS": "flow", "Timestamp": "when"}), op="valve",
                 pv="flow", time="when")
    np.testing.assert_array_equal(named.op, rec.op)


def test_frames_of_evenly_spaced_rows_need_ts_s():
    from diagnose.errors import DataError

    df = frame_loop().reset_index(drop=True)
    rec = _one(df, ts_s=0.5)
    assert rec.ts_s == 0.5 and rec.n == 600 and rec.start is None
    with pytest.raises(DataError, match="no time column; give the sample period"):
        _one(df)
    strict = LoopRecord.from_frame(df, ts_s=0.5)
    assert strict.ts_s == 0.5 and strict.start is None
    np.testing.assert_array_equal(strict.op, rec.op)
    with pytest.raises(DataError, match="no DatetimeIndex: give the sample period ts_s=.*diagnose.read_loops"):
        LoopRecord.from_frame(df)


def test_frames_time_zones_and_dst():
    import pandas as pd

    from diagnose.errors import DataError

    # naive local times across the autumn change, the repeated hour written twice
    local = pd.date_range("2024-10-27 00:00", "2024-10-27 05:00", freq="1min", tz="Europe/Berlin")
    df = frame_loop(len(local)).set_axis(local.tz_localize(None), axis=0)
    rec = _one(df, tz="Europe/Berlin")
    assert rec.n == len(local) and rec.ts_s == 60.0 and "duplicates" not in codes(rec)
    assert rec.start == "2024-10-26T22:00:00Z"
    aware = _one(df.set_axis(local, axis=0))            # tz-aware index: converted to UTC
    np.testing.assert_array_equal(aware.op, rec.op)
    assert aware.start == rec.start
    utc = _one(df.set_axis(local.tz_localize(None), axis=0))   # naive = UTC by default
    assert {"duplicates", "clock_back"} <= codes(utc)                   # the repeated hour collides
    assert "clock_back" not in codes(rec)
    # the strict constructor: a tz-aware uniform index is fine; the naive local one is not uniform
    strict = LoopRecord.from_frame(df.set_axis(local, axis=0))
    assert strict.start == rec.start and strict.ts_s == 60.0
    np.testing.assert_array_equal(strict.op, rec.op)
    with pytest.raises(DataError, match="cannot be read as local times in Europe/Berlin"):
        LoopRecord.from_frame(df, tz="Europe/Berlin")


def test_frames_gaps_and_duplicates():
    import pandas as pd

    from diagnose.errors import DataError

    df = frame_loop()
    holes = df.drop(df.index[100:103])                                 # 3 missing rows: filled
    rec = _one(pd.concat([holes, holes.iloc[[10]]]).sort_index(kind="stable"))
    assert rec.n == 600 and next(f for f in rec.findings if f.code == "duplicates").data["count"] == 1
    assert next(f for f in rec.findings if f.code == "gap").data["filled"] == 3
    op = df["OP"].to_numpy()
    np.testing.assert_allclose(rec.op[100:103], op[99] + (op[103] - op[99]) * np.arange(1, 4) / 4)
    np.testing.assert_array_equal(rec.op[:100], op[:100])
    with pytest.raises(DataError, match=r"time steps are not equal \(from 1 s to 4 s\).*diagnose.read_loops"):
        LoopRecord.from_frame(holes)                                   # the strict constructor refuses
    nan = df.copy()
    nan.iloc[200:205, 0] = np.nan                                       # NaN values: filled too
    assert next(f for f in _one(nan).findings if f.code == "gap").data["filled"] == 5
    with pytest.raises(DataError, match="'OP' \\(OP\\) has 5 missing or non-numeric values.*diagnose.read_loops"):
        LoopRecord.from_frame(nan)
    import diagnose

    long_gap = df.drop(df.index[200:260])
    parts = diagnose.read_loops(long_gap)
    assert [r.n for r in parts] == [200, 340] and parts[1].start == "2024-05-01T00:04:20Z"
    assert [r.meta["n_segments"] for r in parts] == [2, 2]


def test_frame_errors_are_data_errors():
    import pandas as pd

    import diagnose
    from diagnose.errors import DataError

    with pytest.raises(DataError, match=r"no PV column found \(columns: OP, X\)"):
        diagnose.read_loops(pd.DataFrame({"OP": np.arange(50.0), "X": np.arange(50.0)}), ts_s=1.0)
    with pytest.raises(DataError, match=r"no PV column \(columns: OP, X\): name it PV or give pv="):
        LoopRecord.from_frame(pd.DataFrame({"OP": np.arange(50.0), "X": np.arange(50.0)}), ts_s=1.0)
    two = pd.DataFrame({"A.OP": np.arange(50.0) % 7, "A.PV": np.arange(50.0) % 5,
                        "B.OP": np.arange(50.0) % 3, "B.PV": np.arange(50.0) % 4})
    with pytest.raises(DataError, match=r"holds 2 loops \(A, B\); choose one"):
        diagnose.identify(two, ts_s=1.0)
    (b,) = diagnose.read_loops(two, ts_s=1.0, loop="B")
    assert b.n == 50 and b.name == "B"
    with pytest.raises(DataError, match="expected a pandas DataFrame"):
        LoopRecord.from_frame({"OP": [1, 2]})
    with pytest.raises(DataError, match="tags= applies to files"):
        diagnose.read_loops(two, ts_s=1.0, tags={"loops": {}})


# ---------------------------------------------------------------------------------- time zone options

@pytest.mark.parametrize("tz", ["+24:00", "+25:00", "+30", "-24", "+14:61"])
def test_time_zone_offset_out_of_range_is_a_one_line_error(tmp_path, capsys, tz):
    from diagnose.service.cli import main

    f = tmp_path / "loop.csv"
    f.write_text(wide_text(60, header=("time", "FIC1.OP", "FIC1.PV")).replace("Z", ""))
    with pytest.raises(ConnectorError, match=r"offset .* out of range; offsets run from -23:59 to \+23:59"):
        read_records(f, tz=tz)
    assert main(["identify", str(f), "--tz", tz]) != 0
    err = capsys.readouterr().err
    assert err.startswith("error: ") and "Traceback" not in err and err.count("\n") == 1


def test_time_zone_that_is_not_a_string_is_a_data_error():
    import diagnose
    from diagnose.errors import DataError

    with pytest.raises(DataError, match="time zone 5 is not a zone name or an offset string"):
        diagnose.read_loops(frame_loop().reset_index().astype({"time": str}), tz=5)
    (rec,) = read_records(io.StringIO(wide_text(60).replace("Z", "")), tz="+23:59")
    assert rec.start == "2024-04-30T00:01:00Z"


# ------------------------------------------------------------------------ compressed (exception) archives

def _compressed_long(path, *, silent=None, op_silent=None, op_bad_at=None):
    """A PI recorded-values export: PV every 10 s, OP only at its swinging-door archive points."""
    from diagnose.quality import swinging_door

    rng = np.random.default_rng(7)
    t = np.arange(3000) * 10.0
    op = 50 + 5 * np.sin(t / 900) + rng.normal(0, 0.02, t.size)
    pv = 20 + np.cos(t / 900) + rng.normal(0, 0.02, t.size)
    rows = [(t[k], "FIC1.OP", f"{op[k]:.4f}") for k in swinging_door(t, op, 0.1)]
    rows += [(t[k], "FIC1.PV", f"{pv[k]:.4f}") for k in range(t.size)]
    if op_bad_at is not None:
        rows.append((op_bad_at, "FIC1.OP", "I/O Timeout"))
    lo, hi = silent or (-1, -1)
    op_lo, op_hi = op_silent or (-1, -1)
    rows = [r for r in rows if not lo <= r[0] < hi and not (r[1] == "FIC1.OP" and op_lo <= r[0] < op_hi)]
    rows.sort()
    path.write_text("tag,timestamp,value\n" + "".join(
        f"{tag},{np.datetime64('2024-05-01T00:00:00') + np.timedelta64(int(s), 's')},{v}\n" for s, tag, v in rows))
    return path


def test_compressed_tag_is_interpolated_between_its_archive_points(tmp_path):
    (rec,) = read_records(_compressed_long(tmp_path / "sdt.csv"))
    assert rec.ts_s == 10.0 and rec.n == 3000
    assert "compression" in codes(rec) and "gap" not in codes(rec) and "segment" not in codes(rec)


def test_outages_of_a_compressed_tag_are_still_gaps(tmp_path):
    # OP and PV both silent for an hour
    recs = read_records(_compressed_long(tmp_path / "both.csv", silent=(12000, 15600)))
    assert len(recs) == 2 and "segment" in codes(recs[0])
    # OP alone silent far longer than its usual archive spacing (a mean of about 9 min)
    recs = read_records(_compressed_long(tmp_path / "op.csv", op_silent=(12000, 24000)))
    assert len(recs) == 2 and recs[0].meta["n_segments"] == 2
    # a bad value between two OP archive points marks an outage, not a straight run
    recs = read_records(_compressed_long(tmp_path / "bad.csv", op_bad_at=15005.0))
    assert len(recs) == 2 and "bad_values" in codes(recs[0])


# ------------------------------------------------------------------------------- inferred periods

def test_inferred_period_is_free_of_float_noise_and_keeps_the_last_sample(tmp_path):
    rng = np.random.default_rng(11)
    op, pv = 50 + rng.normal(0, 1, 800), 20 + rng.normal(0, 1, 800)
    start = np.datetime64("2026-01-01T00:00:00.000")
    iso = tmp_path / "ms100.csv"          # epoch seconds near 1.8e9 hold 100 ms only to about 0.2 µs
    iso.write_text("time,FIC1.OP,FIC1.PV\n" + "".join(
        f"{start + np.timedelta64(100 * k, 'ms')}Z,{op[k]:.4f},{pv[k]:.4f}\n" for k in range(800)))
    serial = tmp_path / "serial.csv"      # 8 decimals of a day: 0.9 ms, the last time 0.2 ms short
    serial.write_text("Date,FIC1.OP,FIC1.PV\n" + "".join(
        f"{46023 + 10 * k / 86400:.8f},{op[k]:.4f},{pv[k]:.4f}\n" for k in range(800)))
    short = tmp_path / "short.csv"        # plain seconds, the last one 0.2 ms short of the grid
    short.write_text("time_s,OP,PV\n" + "".join(
        f"{10 * k - (0.0002 if k == 799 else 0):.4f},{op[k]:.4f},{pv[k]:.4f}\n" for k in range(800)))
    for f, ts in ((iso, 0.1), (serial, 10.0), (short, 10.0)):
        (rec,) = read_records(f)
        assert rec.ts_s == ts and rec.n == 800, f.name
        np.testing.assert_allclose(rec.op[[0, -1]], op[[0, -1]], atol=1e-4)
# ------------------------------------------------------------------------------- Excel serial days

def _serial_rows(n=120, step_s=10.0, seed=5):
    """Excel serial days from 2026-01-01 (46023) with OP and PV values."""
    rng = np.random.default_rng(seed)
    days = 46023 + np.arange(n) * step_s / 86400
    return days, 50 + rng.normal(0, 1, n), 20 + rng.normal(0, 1, n)


def test_excel_serial_days_with_a_decimal_comma(tmp_path):
    days, op, pv = _serial_rows()
    comma = lambda v, d: f"{v:.{d}f}".replace(".", ",")      # noqa: E731
    wide = tmp_path / "wide.csv"
    wide.write_text("time;FIC1.OP;FIC1.PV\n" + "".join(
        f"{comma(d, 10)};{comma(a, 4)};{comma(b, 4)}\n" for d, a, b in zip(days, op, pv)))
    long = tmp_path / "long.csv"
    long.write_text("tag;timestamp;value\n" + "".join(
        f"FIC1.{r};{comma(d, 10)};{comma(v, 4)}\n" for d, a, b in zip(days, op, pv) for r, v in (("OP", a), ("PV", b))))
    for f in (wide, long):
        (rec,) = read_records(f)
        assert rec.n == 120 and rec.ts_s == pytest.approx(10.0) and rec.start == "2026-01-01T00:00:00Z"
        assert rec.meta["time_format"] == "excel_serial"
        np.testing.assert_allclose(rec.op, op, atol=1e-4)


@pytest.mark.parametrize("header", ["Datum", "Fecha", "Date"])
def test_date_named_time_column_holds_serial_days_or_text(tmp_path, header):
    days, op, pv = _serial_rows(seed=6)
    serial = tmp_path / "serial.csv"
    serial.write_text(f"{header},FIC1.OP,FIC1.PV\n" + "".join(
        f"{d:.10f},{a:.4f},{b:.4f}\n" for d, a, b in zip(days, op, pv)))
    text = tmp_path / "text.csv"          # the time column need not come first
    text.write_text(f"FIC1.OP;{header};FIC1.PV\n" + "".join(
        f"{a:.4f};{np.datetime64('2026-01-01T00:00:00') + np.timedelta64(10 * k, 's')};{b:.4f}\n"
        for k, (a, b) in enumerate(zip(op, pv))))
    for f in (serial, text):
        (rec,) = read_records(f)
        assert rec.n == 120 and rec.ts_s == 10.0 and rec.start == "2026-01-01T00:00:00Z"
        assert rec.meta["time_columns"] == [header]
        np.testing.assert_allclose(rec.pv, pv, atol=1e-4)


def test_max_samples_below_the_shortest_record_is_a_one_line_error(tmp_path, capsys):
    from diagnose.service.cli import main

    f = tmp_path / "loop.csv"
    f.write_text(wide_text(200, seed=4))
    with pytest.raises(ConnectorError, match=r"max_samples \(--max-samples\) is 10, below the shortest record "
                                             r"of 20 samples"):
        read_records(f, max_samples=10)
    assert main(["identify", str(f), "--max-samples", "10"]) != 0
    err = capsys.readouterr().err
    assert err.startswith("error: ") and "--max-samples" in err and "no loop found" not in err
    (rec,) = read_records(f, max_samples=20)
    assert rec.n == 20


def test_gap_finding_counts_each_filled_sample_once(tmp_path):
    rng = np.random.default_rng(8)
    op, pv = 50 + rng.normal(0, 1, 300), 20 + rng.normal(0, 1, 300)
    rows = []
    for k in range(300):
        a = "" if 100 <= k <= 102 else f"{op[k]:.4f}"        # OP missing at 100-102
        b = "" if 101 <= k <= 104 else f"{pv[k]:.4f}"        # PV missing at 101-104
        rows.append(f"{k},{a},{b}\n")
    f = tmp_path / "holes.csv"
    f.write_text("time_s,OP,PV\n" + "".join(rows))
    (rec,) = read_records(f)
    gap = next(x for x in rec.findings if x.code == "gap")
    assert gap.data["filled"] == 5 and gap.message.startswith("5 samples where OP or PV was missing or bad")


def test_one_column_for_two_roles_is_a_one_line_error(tmp_path, capsys):
    from diagnose.service.cli import main

    f = tmp_path / "loop.csv"
    f.write_text(wide_text(100, seed=9))
    with pytest.raises(ConnectorError, match=r"column 'FIC1.PV' is given for both OP and PV"):
        read_records(f, op="FIC1.PV", pv="FIC1.PV")
    with pytest.raises(ConnectorError, match=r"column 'FIC1.OP' is given for both OP and SP"):
        read_records(f, op="FIC1.OP", pv="FIC1.PV", sp="fic1.op")
    with pytest.raises(ConnectorError, match=r"column 'FIC1.PV' is given for both OP and PV"):
        read_records(f, tags={"loops": {"L1": {"op": "FIC1.PV", "pv": "FIC1.PV"}}})
    # OP's own column given for SP alone: OP is left without one, which the error says (not "no OP
    # column found" beside a list that shows it)
    with pytest.raises(ConnectorError, match=r"column 'FIC1.OP' looks like OP but is given for SP \(--sp\), "
                                             r"which leaves OP without a column"):
        read_records(f, sp="FIC1.OP")
    assert main(["identify", str(f), "--op", "FIC1.PV", "--pv", "FIC1.PV"]) != 0
    err = capsys.readouterr().err
    assert err.startswith("error: ") and err.count("\n") == 1 and "both OP and PV" in err


def test_compressed_op_is_not_reported_as_irregular_sampling(tmp_path):
    from diagnose.quality import swinging_door

    rng = np.random.default_rng(12)
    t = np.arange(800) * 10.0
    op = 50 + 3 * np.sin(t / 100) + rng.normal(0, 0.05, t.size)     # archive points 20-100 s apart
    pv = 20 + np.cos(t / 100) + rng.normal(0, 0.02, t.size)
    keep = swinging_door(t, op, 0.1)
    assert np.mean(np.diff(t[keep]) <= 100) > 0.5
    rows = sorted([(t[k], "FIC1.OP", op[k]) for k in keep] + [(t[k], "FIC1.PV", pv[k]) for k in range(t.size)])
    f = tmp_path / "sdt.csv"
    f.write_text("tag,timestamp,value\n" + "".join(f"{tag},{s:.0f},{v:.4f}\n" for s, tag, v in rows))
    (rec,) = read_records(f)
    assert rec.n == 800 and "compression" in codes(rec) and "irregular_sampling" not in codes(rec)


def test_a_tag_with_op_but_no_pv_is_said_on_the_records_of_its_file(tmp_path):
    rng = np.random.default_rng(3)
    n = 200
    t = [f"2026-01-01T00:{k // 60:02d}:{k % 60:02d}Z" for k in range(n)]
    cols = {"FIC101.OP": 50 + rng.normal(0, 1, n), "FIC101.PV": 20 + rng.normal(0, 1, n),
            "FIC102.OP": 40 + rng.normal(0, 1, n), "FIC103.PV": 7 + rng.normal(0, 1, n)}
    p = tmp_path / "plant.csv"
    p.write_text("time," + ",".join(cols) + "\n"
                 + "".join(f"{t[k]}," + ",".join(f"{v[k]:.4f}" for v in cols.values()) + "\n" for k in range(n)))
    recs = read_records(p)
    assert [r.name for r in recs] == ["FIC101"]
    f = next(f for f in recs[0].findings if f.code == "loop_left_out")
    assert f.severity == "info" and f.data["tags"] == {"FIC102": "PV", "FIC103": "OP"}
    assert "FIC102 (no PV)" in f.message and "FIC103 (no OP)" in f.message


def _jittered_csv(path, jitter_s, *, bad=(), seed=7, n=800):
    rng = np.random.default_rng(seed)
    t = 1_767_225_600 + 10.0 * np.arange(n) + rng.uniform(-jitter_s, jitter_s, n)
    op = [f"{v:.4f}" for v in 50 + 3 * np.sin(np.arange(n) / 20)]
    for k in bad:
        op[k] = "Bad"
    pv = 20 + np.cos(np.arange(n) / 20) + rng.normal(0, 0.05, n)
    stamps = [np.datetime_as_string(np.datetime64(int(s * 1e6), "us"), unit="us") + "Z" for s in t]
    path.write_text("time,FIC1.OP,FIC1.PV\n" + "".join(f"{s},{o},{p:.4f}\n" for s, o, p in zip(stamps, op, pv)))
    return path


def test_jittered_sampling_gets_the_clock_period_and_no_invented_gaps(tmp_path):
    # +-3 s on 10 s stamps: intervals spread over 4-16 s and their median (10.07 s) drifts a
    # sample over the record, which used to be reported as samples "missing ... filled"
    (rec,) = read_records(_jittered_csv(tmp_path / "jit.csv", 3.0))
    assert rec.ts_s == 10.0 and rec.n >= 799
    assert "gap" not in codes(rec) and "irregular_sampling" in codes(rec)
    # a bad value is still counted, once, though jittered intervals exceed 1.5 periods anyway
    (rec,) = read_records(_jittered_csv(tmp_path / "bad.csv", 3.0, bad=(100, 300, 301)))
    assert rec.ts_s == 10.0 and next(f for f in rec.findings if f.code == "gap").data["filled"] == 3
    # milder jitter too (intervals within 10 %, so no irregular_sampling finding)
    (rec,) = read_records(_jittered_csv(tmp_path / "mild.csv", 0.5, bad=(100,)))
    assert rec.ts_s == 10.0 and next(f for f in rec.findings if f.code == "gap").data["filled"] == 1


def test_jittered_sampling_with_outages_keeps_the_clock_and_reports_the_gaps(tmp_path):
    # the same +-3 s jitter with two outages of 10 and 30 minutes: the clock runs on through them
    f = _jittered_csv(tmp_path / "jitgap.csv", 3.0, n=1000)
    lines = f.read_text().splitlines(keepends=True)
    f.write_text("".join(lines[:301] + lines[361:601] + lines[781:]))
    recs = read_records(f)
    # the median spacing read 9.97 s and called 23 samples missing that no outage removed
    assert [r.ts_s for r in recs] == [10.0, 10.0, 10.0] and [r.n for r in recs] == [299, 239, 218]
    for rec in recs:
        assert "gap" not in codes(rec) and {"segment", "irregular_sampling"} <= codes(rec)


def test_random_intervals_without_a_clock_keep_the_median_spacing(tmp_path):
    # intervals drawn at random (no regular clock behind them): there are no slots to fit
    rng = np.random.default_rng(5)
    t = np.cumsum(rng.uniform(7, 13, 800))
    f = tmp_path / "renewal.csv"
    f.write_text("t,OP,PV\n" + "".join(f"{s:.3f},{50 + np.sin(s / 100):.4f},{np.cos(s / 100):.4f}\n" for s in t))
    (rec,) = read_records(f)
    assert rec.ts_s == pytest.approx(float(np.median(np.diff(np.round(t, 3)))), rel=1e-9)


def _excel_minutes_csv(path, *, newest_first=False, n=800, first_offset_s=0):
    # 10 s data saved by a spreadsheet as M/D/YYYY H:MM: the seconds are dropped
    rng = np.random.default_rng(11)
    op = 50 + 3 * np.sin(np.arange(n) / 20) + rng.normal(0, 0.05, n)
    pv = 20 + np.cos(np.arange(n) / 20) + rng.normal(0, 0.05, n)
    secs = first_offset_s + 10 * np.arange(n)
    stamps = [f"1/1/2026 {s // 3600}:{s // 60 % 60:02d}" for s in secs]
    rows = [f"{s},{o:.4f},{p:.4f}\n" for s, o, p in zip(stamps, op, pv)]
    path.write_text("Date,FIC200.OP,FIC200.PV\n" + "".join(rows[::-1] if newest_first else rows))
    return path, op


def test_truncated_time_stamps_are_a_warning_that_says_what_to_do(tmp_path):
    f, _ = _excel_minutes_csv(tmp_path / "excel.csv")
    (rec,) = read_records(f)
    dup = next(x for x in rec.findings if x.code == "duplicates")
    assert dup.severity == "warning" and dup.data["share"] == 1.0
    assert "truncated to whole minutes" in dup.message and "re-export" in dup.message and "--ts-s" in dup.message
    # a few repeated rows stay an info finding
    rows = wide_text(300).splitlines(keepends=True)
    rows[1:1] = rows[1:4]
    g = tmp_path / "few.csv"
    g.write_text("".join(rows))
    (rec,) = read_records(g)
    assert next(x for x in rec.findings if x.code == "duplicates").severity == "info"


@pytest.mark.parametrize("newest_first", [False, True])
def test_truncated_time_stamps_are_spread_at_the_period_given(tmp_path, newest_first):
    f, op = _excel_minutes_csv(tmp_path / "excel.csv", newest_first=newest_first, first_offset_s=30)
    (rec,) = read_records(f, ts_s=10)
    assert rec.n == 800 and rec.ts_s == 10.0 and rec.start == "2026-01-01T00:00:30Z"
    np.testing.assert_allclose(rec.op, np.round(op, 4))
    dup = next(x for x in rec.findings if x.code == "duplicates")
    assert dup.severity == "info" and dup.data["spread"] == 800
    # runs of unequal length (a row missing mid-minute) cannot be placed: rows are dropped as before
    lines = f.read_text().splitlines(keepends=True)
    del lines[100]
    f.write_text("".join(lines))
    (rec,) = read_records(f, ts_s=10)
    assert any(x.code == "duplicates" and x.severity == "warning" for x in rec.findings)


def test_a_mode_archived_on_change_holds_between_its_events(tmp_path):
    # a long (tag, time, value) export: OP and PV every 10 s for two hours, the mode only when it
    # changed (a PI digital state's recorded values): manual from 00:30 to 01:00, unknown before
    # its first event at 00:05
    from diagnose.identification import record_activity

    rng = np.random.default_rng(7)
    lines = ["Tag,Timestamp,Value"]
    for k in range(720):
        t = f"2026-03-05T{k * 10 // 3600:02d}:{k * 10 % 3600 // 60:02d}:{k * 10 % 60:02d}Z"
        lines += [f"FIC7.OP,{t},{50 + 5 * np.sin(k / 20) + rng.normal(0, 0.1):.3f}",
                  f"FIC7.PV,{t},{40 + 4 * np.sin((k - 3) / 20) + rng.normal(0, 0.1):.3f}"]
    lines += ["FIC7.MODE,2026-03-05T00:05:00Z,AUTO", "FIC7.MODE,2026-03-05T00:30:00Z,MAN",
              "FIC7.MODE,2026-03-05T01:00:00Z,AUTO"]
    path = tmp_path / "fic7_long.csv"
    path.write_text("\n".join(lines) + "\n")
    (rec,) = read_records(path)
    assert rec.n == 720 and rec.meta["has_mode"]
    assert rec.meta["manual_intervals"] == [[180, 360]]        # 00:30 to 01:00 at 10 s
    assert rec.meta["mode_unknown_intervals"] == [[0, 30]]     # before the first event
    man = next(f for f in rec.findings if f.code == "manual_mode")
    assert man.data["samples"] == 180
    # the service factor counts the samples whose mode is known: 510 of 690 in automatic
    assert record_activity(rec).service_factor == pytest.approx(510 / 690)


@pytest.mark.parametrize("mode_cells", [("AUTO", "MAN", "AUTO"), ("1", "0", "1")])
def test_a_wide_mode_column_with_empty_cells_holds_between_its_events(tmp_path, mode_cells):
    # a wide export: OP and PV on every row, the mode written only on the rows where it changed
    # (empty cells between): manual from 00:30 to 01:00, unknown before its first value at 00:05;
    # an empty cell is no event (the state holds), not a bad value
    from diagnose.identification import record_activity

    rng = np.random.default_rng(11)
    events = {30: mode_cells[0], 180: mode_cells[1], 360: mode_cells[2]}
    lines = ["Time,FIC7.OP,FIC7.PV,FIC7.MODE"]
    for k in range(720):
        t = f"2026-03-05T{k * 10 // 3600:02d}:{k * 10 % 3600 // 60:02d}:{k * 10 % 60:02d}Z"
        lines.append(f"{t},{50 + 5 * np.sin(k / 20) + rng.normal(0, 0.1):.3f},"
                     f"{40 + 4 * np.sin((k - 3) / 20) + rng.normal(0, 0.1):.3f},{events.get(k, '')}")
    path = tmp_path / "fic7_wide.csv"
    path.write_text("\n".join(lines) + "\n")
    (rec,) = read_records(path)
    assert rec.n == 720 and rec.meta["has_mode"]
    assert rec.meta["manual_intervals"] == [[180, 360]]
    assert rec.meta["mode_unknown_intervals"] == [[0, 30]]
    man = next(f for f in rec.findings if f.code == "manual_mode")
    assert man.data["samples"] == 180
    assert record_activity(rec).service_factor == pytest.approx(510 / 690)
    # a DataFrame with NaN between the mode's values reads the same
    import pandas as pd
    from connectors import read_frame
    df = pd.read_csv(path)
    df["Time"] = pd.to_datetime(df["Time"])
    (frec,) = read_frame(df.set_index("Time"))
    assert frec.meta["manual_intervals"] == [[180, 360]]


def test_spikes_and_sentinels_are_read_as_bad_values(tmp_path):
    from connectors.records import gross_outliers

    text = wide_text(1200, seed=11).splitlines()
    # line 301: one spike in PV; lines 401-406: a bad-value sentinel in OP (a gap short enough to fill)
    cells = text[300].split(",")
    text[300] = ",".join(cells[:2] + ["1e6"])
    for k in range(400, 406):
        cells = text[k].split(",")
        text[k] = ",".join([cells[0], "-9999", cells[2]])
    f = tmp_path / "spiky.csv"
    f.write_text("\n".join(text) + "\n")
    (rec,) = read_records(f)
    found = {x.data["role"]: x for x in rec.findings if x.code == "outliers"}
    assert set(found) == {"op", "pv"} and found["pv"].data["count"] == 1 and found["op"].data["count"] == 6
    assert found["pv"].severity == "warning" and "1e+06 at 2024-05-01T00:04:59Z" in found["pv"].message
    # filled like a gap: in range, between its neighbours
    assert 15 < rec.pv[299] < 25 and np.all((rec.op[399:405] > 45) & (rec.op[399:405] < 55))
    assert any(x.code == "gap" for x in rec.findings)

    rng = np.random.default_rng(2)
    x = 50 + 0.01 * rng.normal(size=3000)
    assert not gross_outliers(x).any()
    # the plant's own moves are kept: a slip at the very end, a varying excursion, a step off a flat line
    end = x.copy()
    end[-2:] = 55.0
    assert not gross_outliers(end).any()
    varying = x.copy()
    varying[1000:1020] = 55.0 + np.arange(20)
    assert not gross_outliers(varying).any()
    flat = np.full(3000, 50.0)
    flat[2990:] = 60.0
    assert not gross_outliers(flat).any()
    # a plant's own extremes: a trip to 0, OP saturated at 100 %, a derivative kick
    for a, b, v in ((1000, 1040, 0.0), (2000, 2030, 100.0), (2500, 2501, 65.0)):
        event = x.copy()
        event[a:b] = v
        assert not gross_outliers(event).any(), (a, b, v)
    # more than 1 % far away is the signal's own spread
    many = x.copy()
    many[::50] = 1e6
    assert not gross_outliers(many).any()
    one = x.copy()
    one[1500] = 1e300
    assert np.flatnonzero(gross_outliers(one)).tolist() == [1500]
    # a known sentinel not 50 times the signal's size: -9999 on a flow of thousands, -999 on a level
    flow = 3000.0 + 20.0 * rng.normal(size=3000)
    flow[700:704] = -9999.0
    assert np.flatnonzero(gross_outliers(flow)).tolist() == [700, 701, 702, 703]
    level = 50.0 + 5.0 * rng.normal(size=3000)
    level[100] = -999.0
    assert np.flatnonzero(gross_outliers(level)).tolist() == [100]
    # the same values inside the signal's own spread are measurements
    wide = -5000.0 + 3000.0 * rng.normal(size=3000)
    wide[50] = -9999.0
    assert not gross_outliers(wide).any()


def test_too_few_samples_says_which_column_was_unreadable(tmp_path):
    # PV written with decimal commas the reader cannot take for numbers, except a few rows: the
    # error names the column and what it held, not only the length of the longest stretch
    lines = wide_text(400, seed=5).splitlines()
    out = [lines[0]]
    for k, line in enumerate(lines[1:]):
        t, op, pv = line.split(",")
        out.append(",".join([t, op, pv if k % 20 < 5 else f'"{float(pv):.2f}"'.replace(".", ";")]))
    f = tmp_path / "commas.csv"
    f.write_text("\n".join(out) + "\n")
    with pytest.raises(ConnectorError, match=r"too few samples: .* \(need at least 20\); PV column 'FIC1.PV' is "
                                             r"mostly unreadable \(\d+ text states \("):
        read_records(f)
