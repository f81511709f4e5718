"""Regenerate the connector test fixtures (seeded). Real exports are trimmed copies of
../shared/data files (see docs/data-sources.md for their origin and licences).

    python tests/data_connectors/make_fixtures.py [/path/to/shared/data]
"""

from __future__ import annotations

import sys
from datetime import datetime, timedelta, timezone
from pathlib import Path

import numpy as np

HERE = Path(__file__).parent


def sim(n=400, seed=0):
    rng = np.random.default_rng(seed)
    t = np.arange(n)
    # a sticky-looking limit cycle with noise: OP triangle, PV square-ish
    op = 50 + 5 * (2 * np.abs((t / 60.0) % 1 - 0.5) * 2 - 1) + rng.normal(0, 0.05, n)
    pv = 20 + 2 * np.sign(np.sin(2 * np.pi * t / 60.0)) + rng.normal(0, 0.05, n)
    return op, pv


def real(data: Path) -> None:
    src = data / "plant-dcs-stictiongpt/raw"
    f = sorted(src.glob("stic_2411FIC20102_1003*"))[0]
    lines = f.read_bytes().split(b"\n")
    (HERE / "dcs_2411FIC20102_trim.txt").write_bytes(b"\n".join(lines[:5 + 240]) + b"\n")
    for name in ("FIC-211_20241121-27.csv",):
        raw = (data / "historian-exports" / name).read_bytes().split(b"\n")
        (HERE / "historian_FIC211_trim.csv").write_bytes(b"\n".join(raw[:301]) + b"\n")
    raw = (data / "isdb-subset/PAP2.csv").read_bytes().split(b"\n")
    (HERE / "isdb_PAP2_trim.csv").write_bytes(b"\n".join(raw[:301]) + b"\n")


def synthetic() -> None:
    op, pv = sim()
    t0 = datetime(2024, 3, 1, 8, 0, 0)
    # wide, semicolon, decimal comma, European dates
    with open(HERE / "wide_semicolon_comma.csv", "w", encoding="utf-8", newline="") as fh:
        fh.write("Zeit;FIC101.OP;FIC101.PV;FIC101.SP\r\n")
        for k in range(op.size):
            ts = (t0 + timedelta(seconds=k)).strftime("%d.%m.%Y %H:%M:%S")
            fh.write(f"{ts};{op[k]:.3f};{pv[k]:.3f};20,000\r\n".replace(".", ",", 0))
    # fix decimal commas in value fields only
    text = (HERE / "wide_semicolon_comma.csv").read_text(encoding="utf-8").splitlines()
    out = [text[0]]
    for line in text[1:]:
        cells = line.split(";")
        out.append(";".join([cells[0]] + [c.replace(".", ",") for c in cells[1:]]))
    (HERE / "wide_semicolon_comma.csv").write_text("\r\n".join(out) + "\r\n", encoding="utf-8")
    # long/tall with OPC quality codes and vendor text states, two loops, rows not sorted by time
    rows = []
    for k in range(200):
        ts = (t0 + timedelta(seconds=k)).isoformat() + "Z"
        for tag, v in (("FIC101.OP", op[k]), ("FIC101.PV", pv[k]), ("FIC102.OP", op[k] * 0.9),
                       ("FIC102.PV", pv[k] + 1)):
            q = 192
            val = f"{v:.4f}"
            if tag == "FIC101.PV" and k in (50, 51):
                q = 0
            if tag == "FIC101.PV" and k == 120:
                val = "I/O Timeout"
            if tag == "FIC101.OP" and k == 200:
                val = "1.#QNAN"
            rows.append(f"{tag},{ts},{val},{q}")
    rows.sort(key=lambda r: r.split(",")[0])
    (HERE / "long_opc_quality.csv").write_text("Tag,Timestamp,Value,Quality\n" + "\n".join(rows) + "\n",
                                               encoding="utf-8")
    # PI DataLink ragged: compressed archive points, one (time, value) pair per tag
    tt = np.arange(op.size, dtype=float)
    from_idx_op = np.arange(0, op.size, 1)
    from_idx_pv = np.arange(0, op.size, 2)
    n = max(from_idx_op.size, from_idx_pv.size)
    lines = ["Timestamp,FIC103.OP,Timestamp,FIC103.PV"]
    for k in range(n):
        cells = []
        for idx, x in ((from_idx_op, op), (from_idx_pv, pv)):
            if k < idx.size:
                ts = (t0 + timedelta(seconds=float(tt[idx[k]]))).strftime("%d-%b-%Y %H:%M:%S")
                cells += [ts, f"{x[idx[k]]:.4f}"]
            else:
                cells += ["", ""]
        lines.append(",".join(cells))
    (HERE / "pi_datalink_ragged.csv").write_text("\n".join(lines) + "\n", encoding="utf-8")
    # InfluxDB annotated CSV
    lines = ["#datatype,string,long,dateTime:RFC3339,dateTime:RFC3339,dateTime:RFC3339,double,string,string,string",
             "#group,false,false,true,true,false,false,true,true,true",
             "#default,_result,,,,,,,,",
             ",result,table,_start,_stop,_time,_value,_field,_measurement,loop"]
    for ti, (field, x) in enumerate((("OP", op), ("PV", pv))):
        for k in range(200):
            ts = (t0 + timedelta(seconds=k)).isoformat() + "Z"
            lines.append(f",,{ti},2024-03-01T08:00:00Z,2024-03-01T09:00:00Z,{ts},{x[k]:.5f},{field},process,FIC104")
    (HERE / "influx_annotated.csv").write_text("\n".join(lines) + "\n", encoding="utf-8")
    # tab-separated wide, naive local times across the Europe/Berlin autumn DST change, 60 s,
    # newest row first, mode column with a manual stretch
    lines = ["Timestamp\tTIC105.OP\tTIC105.PV\tTIC105.MODE"]
    start_utc = datetime(2024, 10, 27, 0, 0, tzinfo=timezone.utc)  # 02:00 CEST
    from zoneinfo import ZoneInfo

    berlin = ZoneInfo("Europe/Berlin")
    body = []
    for k in range(240):
        local = (start_utc + timedelta(minutes=k)).astimezone(berlin).replace(tzinfo=None)
        mode = "MAN" if 100 <= k < 130 else "AUTO"
        body.append(f"{local:%Y-%m-%d %H:%M:%S}\t{op[k]:.3f}\t{pv[k]:.3f}\t{mode}")
    (HERE / "wide_tab_dst_berlin.tsv").write_text("\n".join(lines + body[::-1]) + "\n", encoding="utf-8")


def vendors() -> None:
    """Exports in the layouts vendors' tools write (tests/test_vendor_exports.py)."""
    op, pv = sim(n=120, seed=3)
    t0 = datetime(2024, 3, 1, 8, 0, 0)
    # AVEVA (Wonderware) Historian query saved as CSV: Quality is AVEVA's own (0 good, 1 bad),
    # QualityDetail and OPCQuality are OPC codes (192 good); a bad sample's value is kept or NULL
    rows = ["DateTime,TagName,Value,Quality,QualityDetail,OPCQuality"]
    for k in range(op.size):
        ts = (t0 + timedelta(seconds=k)).strftime("%Y-%m-%d %H:%M:%S.000")
        for tag, v in (("FIC201.PV", pv[k]), ("FIC201.OP", op[k])):
            val, q, qd = f"{v:.4f}", 0, 192
            if tag == "FIC201.PV" and k == 40:
                q, qd = 1, 8                 # not connected: the last value, marked bad
            if tag == "FIC201.PV" and k == 41:
                val, q, qd = "NULL", 1, 8
            rows.append(f"{ts},{tag},{val},{q},{qd},{qd}")
    (HERE / "aveva_history_long.csv").write_bytes(("\r\n".join(rows) + "\r\n").encode())
    # DeltaV Continuous Historian export: module/block/parameter paths with their .CV field, status
    # (.ST) columns, the mode's ACTUAL and TARGET, US 12-hour times with milliseconds
    rows = ["Date/Time,FIC-201/PID1/PV.CV,FIC-201/PID1/PV.ST,FIC-201/PID1/OUT.CV,FIC-201/PID1/SP.CV,"
            "FIC-201/PID1/MODE.ACTUAL,FIC-201/PID1/MODE.TARGET"]
    for k in range(op.size):
        t = t0 + timedelta(seconds=k)
        ts = f"{t.month}/{t.day}/{t.year} {t.hour % 12 or 12}:{t:%M:%S}.000 {t:%p}"
        mode = "MAN" if 60 <= k < 70 else "AUTO"
        rows.append(f"{ts},{pv[k]:.4f},GoodCascade,{op[k]:.4f},20.0000,{mode},AUTO")
    (HERE / "deltav_history.csv").write_text("\n".join(rows) + "\n", encoding="utf-8")
    # Aspen Process Explorer / PHD style: tag row, then a descriptor row and an engineering-units
    # row above the data; 5 s, PI-style dates with two-digit years
    rows = ["Time,FIC301.PV,FIC301.OP,FIC301.SP",
            ",Reflux flow,Reflux valve output,Reflux flow setpoint",
            "Units,m3/h,%,m3/h"]
    for k in range(op.size):
        t = t0 + timedelta(seconds=5 * k)
        rows.append(f"{t:%d-%b-%y %H:%M:%S},{pv[k]:.3f},{op[k]:.3f},20.000")
    (HERE / "aspen_units_rows.csv").write_text("\r\n".join(rows) + "\r\n", encoding="utf-8")
    # Honeywell Uniformance PHD, read into Excel with the tags' confidence (0-100, 100 good) in the
    # column after each value, description and units rows under the header, PHD's dd-MMM-yy times;
    # a sample the PHD could not vouch for keeps a value, with its confidence low
    rows = ["Timestamp,FIC801.PV,FIC801.PV Confidence,FIC801.OP,FIC801.OP Confidence,FIC801.SP,"
            "FIC801.SP Confidence",
            ",Feed flow,,Feed valve output,,Feed flow setpoint,",
            "Units,m3/h,%,%,%,m3/h,%"]
    for k in range(op.size):
        t = t0 + timedelta(seconds=5 * k)
        conf_pv = {40: 0, 41: 30, 42: 50}.get(k, 100)      # 50 is still good
        rows.append(f"{t:%d-%b-%y %H:%M:%S},{pv[k]:.3f},{conf_pv},{op[k]:.3f},100,20.000,100")
    (HERE / "phd_confidence_wide.csv").write_text("\r\n".join(rows) + "\r\n", encoding="utf-8")
    # Aspen InfoPlus.21 SQLplus query on the history repeat area, saved as CSV: IP_TREND_* columns,
    # IP.21's upper-case month names, a text quality status
    rows = ["NAME,IP_TREND_TIME,IP_TREND_VALUE,IP_TREND_QSTATUS"]
    for k in range(op.size):
        t = t0 + timedelta(seconds=10 * k)
        for tag, v in (("FIC401.PV", pv[k]), ("FIC401.OP", op[k])):
            q = "Suspect" if tag == "FIC401.PV" and k == 30 else "Good"
            rows.append(f"{tag},{t:%d-%b-%y %H:%M:%S}.0,{v:.4f},{q}".upper().replace("GOOD", "Good")
                        .replace("SUSPECT", "Suspect"))
    (HERE / "ip21_trend_long.csv").write_text("\n".join(rows) + "\n", encoding="utf-8")
    # Excel in a UK locale saves dd/mm/yyyy hh:mm; 2-hourly over the 1st-10th of March, so no day
    # field is above 12
    rows = ["Date,FIC501.PV,FIC501.OP"]
    for k in range(op.size):
        t = datetime(2024, 3, 1) + timedelta(hours=2 * k)
        rows.append(f"{t:%d/%m/%Y %H:%M},{pv[k]:.3f},{op[k]:.3f}")
    (HERE / "excel_uk_dmy.csv").write_text("\r\n".join(rows) + "\r\n", encoding="utf-8")
    # the same UK locale with seconds, one morning of 5 March 2026: no field above 12 and a single
    # day, so nothing in the file tells 5 March from 3 May
    rows = ["Date,FIC503.PV,FIC503.OP"]
    for k in range(op.size):
        t = datetime(2026, 3, 5, 8, 0, 0) + timedelta(seconds=5 * k)
        rows.append(f"{t:%d/%m/%Y %H:%M:%S},{pv[k]:.3f},{op[k]:.3f}")
    (HERE / "excel_uk_one_day.csv").write_text("\r\n".join(rows) + "\r\n", encoding="utf-8")
    # Excel in a Dutch locale: d-m-yyyy h:mm, semicolons, decimal commas
    rows = ["Datum;FIC502.PV;FIC502.OP"]
    for k in range(op.size):
        t = datetime(2024, 3, 1) + timedelta(hours=2 * k)
        rows.append(f"{t.day}-{t.month}-{t.year} {t.hour}:{t:%M};{pv[k]:.3f};{op[k]:.3f}".replace(".", ","))
    (HERE / "excel_nl_dmy.csv").write_text("\r\n".join(rows) + "\r\n", encoding="cp1252")
    # Siemens WinCC tag logging archive exported as CSV: quoted names and text, decimal commas,
    # Validity 1/0 and Time_ms (Excel serial days x 1e6) beside the time string
    rows = ['"VarName";"TimeString";"VarValue";"Validity";"Time_ms"']
    for k in range(op.size):
        t = t0 + timedelta(seconds=2 * k)
        serial = (t - datetime(1899, 12, 30)) / timedelta(days=1) * 1e6
        for tag, v in (("FIC701.PV", pv[k]), ("FIC701.OP", op[k])):
            valid = 0 if tag == "FIC701.PV" and k == 50 else 1
            rows.append(f'"{tag}";"{t:%d.%m.%Y %H:%M:%S}";{v:.4f};{valid};{serial:.4f}'.replace(".", ",")
                        .replace('"FIC701,', '"FIC701.').replace(f'"{t:%d,%m,%Y}', f'"{t:%d.%m.%Y}'))
    (HERE / "wincc_taglogging.csv").write_text("\r\n".join(rows) + "\r\n", encoding="utf-8")


if __name__ == "__main__":
    data = Path(sys.argv[1]) if len(sys.argv) > 1 else Path(__file__).resolve().parents[3] / "shared/data"
    if data.exists():
        real(data)
    synthetic()
    vendors()
