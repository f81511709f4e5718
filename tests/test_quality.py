"""Data-quality assessment: compression (own swinging-door / box-car compressors), quantisation,
saturation, frozen values, manual mode."""

from __future__ import annotations

import io
import json

import numpy as np
import pytest

from connectors import read_records
from connectors.historian import format_wide
from diagnose.quality import assess, boxcar, decompress, straight_and_flat, swinging_door
from diagnose.record import LoopRecord
from diagnose.simulate import sticky_loop


def codes(findings, role=None):
    return {f.code for f in findings if role is None or f.data.get("role") == role}


def sine_record(n=3000, noise=0.0, seed=0):
    t = np.arange(n, dtype=float)
    rng = np.random.default_rng(seed)
    op = 50 + 20 * np.sin(2 * np.pi * t / 300) + rng.normal(0, noise, n)
    pv = 10 + 4 * np.sin(2 * np.pi * (t - 20) / 300) + rng.normal(0, noise * 0.2, n)
    return LoopRecord("SINE", 1.0, op, pv)


def healthy(seed):
    return sticky_loop(0.0, 0.0, n=3000, seed=seed, noise_std=0.05, load_walk_std=0.05)


def test_swinging_door_stays_within_deviation():
    rec = sine_record(noise=0.3, seed=1)
    t = rec.t_s
    for dev in (0.5, 1.0):
        idx = swinging_door(t, rec.op, dev)
        back = decompress(t, rec.op, idx)
        err = np.abs(back - rec.op)
        assert np.max(err) <= 2 * dev + 1e-9              # archives actual values: <= 2 x dev
        assert np.mean(err) < dev
        assert idx.size < 0.5 * rec.n                  # it really compresses
        assert idx[0] == 0 and idx[-1] == rec.n - 1
    idx = boxcar(rec.op, 1.0)
    assert np.max(np.abs(decompress(t, rec.op, idx, kind="step") - rec.op)) <= 1.0 + 1e-9


@pytest.mark.parametrize("dev_pct", [0.5, 0.75, 1.0])
def test_compressed_clean_sine_is_detected(dev_pct):
    rec = sine_record()
    t = rec.t_s
    op = decompress(t, rec.op, swinging_door(t, rec.op, dev_pct))          # OP in % of span
    pv = decompress(t, rec.pv, swinging_door(t, rec.pv, dev_pct / 100 * 20))  # PV span 20 units
    f = [x for x in assess(rec.replace(op=op, pv=pv)) if x.code == "compression"]
    assert {x.data["role"] for x in f} == {"op", "pv"}
    assert all(x.severity == "warning" and x.data["kind"] == "swinging-door" for x in f)


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("dev_pct", [0.5, 1.0])
def test_compressed_healthy_simulated_loop_is_detected_raw_is_not(seed, dev_pct):
    rec = healthy(seed)
    assert "compression" not in codes(assess(rec))                     # raw noisy record
    t = rec.t_s
    op = decompress(t, rec.op, swinging_door(t, rec.op, dev_pct))
    comp = rec.replace(op=op)
    f = assess(comp)
    assert "compression" in codes(f, "op")
    # through a CSV file written with 6 significant digits, as exports are
    (back,) = read_records(io.StringIO(format_wide(comp)))
    assert "compression" in codes(back.findings, "op")
    (raw,) = read_records(io.StringIO(format_wide(rec)))
    assert "compression" not in codes(raw.findings)


def test_boxcar_step_export_is_detected():
    rec = healthy(4)
    t = rec.t_s
    op = decompress(t, rec.op, boxcar(rec.op, 1.0), kind="step")
    f = [x for x in assess(rec.replace(op=op)) if x.code == "compression"]
    assert f and f[0].data["role"] == "op"


def test_raw_noisy_sine_and_smooth_real_like_record_are_not_compression():
    assert "compression" not in codes(assess(sine_record(noise=0.05)))
    # a slow record printed with 2 decimals (ISDB style), OP carrying a little PV noise, is not
    # "straight" (a noise-free smooth signal rounded this coarsely would be: documented limit)
    t = np.arange(1200.0)
    rng = np.random.default_rng(0)
    op = np.round(19 + 2 * np.sin(t / 40) + rng.normal(0, 0.03, t.size), 2)
    pv = np.round(35 + np.sin((t - 5) / 40) + rng.normal(0, 0.02, t.size), 3)
    assert "compression" not in codes(assess(LoopRecord("X", 1.0, op, pv)))


def test_quantisation():
    rng = np.random.default_rng(0)
    pv = np.round(rng.normal(0, 1, 2000) / 0.5) * 0.5               # 0.5-unit steps, ~13 levels
    op = 50 + rng.normal(0, 1, 2000)
    f = [x for x in assess(LoopRecord("Q", 1.0, op, pv)) if x.code == "quantisation"]
    assert len(f) == 1 and f[0].data["role"] == "pv" and f[0].data["step"] == pytest.approx(0.5)
    assert "compression" not in codes(assess(LoopRecord("Q", 1.0, op, pv)))


def test_saturation_frozen_and_manual():
    rng = np.random.default_rng(0)
    op = np.clip(60 + 50 * np.sin(np.arange(1000) / 30) + rng.normal(0, 1, 1000), 0, 100)
    pv = rng.normal(0, 1, 1000)
    pv[300:700] = 1.2345                                            # frozen transmitter
    rec = LoopRecord("S", 1.0, op, pv, meta={"manual_intervals": [[10, 60]]})
    f = {x.code: x for x in assess(rec)}
    assert f["op_saturation"].severity == "warning" and f["op_saturation"].data["frac_high"] > 0.1
    assert f["frozen"].data["role"] == "pv" and f["frozen"].data["samples"] == 400
    assert f["manual_mode"].data["samples"] == 50
    # mean-centred OP (ISDB CHEM10 style) is not "saturated at 0 %"
    centred = LoopRecord("C", 1.0, np.sin(np.arange(500) / 9), rng.normal(0, 1, 500))
    assert "op_saturation" not in codes(assess(centred))


def test_straight_and_flat_numbers():
    x = np.concatenate([np.linspace(0, 10, 50), np.full(30, 10.0), np.linspace(10, 0, 20)])
    sf = straight_and_flat(x)
    assert sf["linear_frac"] == pytest.approx(0.7, abs=0.03)
    assert sf["flat_frac"] == pytest.approx(0.3, abs=0.03)


def test_op_logged_as_a_fraction_is_a_warning():
    rec = sticky_loop(4.0, 1.0, n=2000, seed=7, noise_std=0.03, load_walk_std=0.02)
    frac = rec.replace(op=rec.op / 100.0, mv=None)
    found = [f for f in assess(frac) if f.code == "op_fraction"]
    assert len(found) == 1 and found[0].severity == "warning"
    # arrays in Python: no command line to give --op on
    assert "scale OP to %" in found[0].message and found[0].message.endswith("before passing it as op=")
    assert "op_saturation" not in codes(assess(frac))
    assert "op_fraction" not in codes(assess(rec))                       # OP in %
    still = frac.replace(op=np.full(frac.n, 0.5))
    assert "op_fraction" not in codes(assess(still))                     # a still OP is another finding


def test_op_fraction_reaches_the_diagnosis_warnings():
    from diagnose.service.pipeline import diagnose

    rec = sticky_loop(4.0, 1.0, n=1500, seed=8, noise_std=0.03, load_walk_std=0.02)
    diag = diagnose(rec.replace(op=rec.op / 100.0, mv=None), narx=False)
    assert "data_quality.op_fraction" in [w.code for w in diag.warnings]
    assert "data_quality.op_fraction" in [w["code"] for w in diag.to_dict()["warnings"]]


def test_op_fraction_advice_fits_where_the_record_came_from(tmp_path, capsys):
    # the same export read by the command (--op), and as the DataFrame pandas reads from it (op=)
    import pandas as pd

    import diagnose
    from connectors.historian import write_wide
    from diagnose.service.cli import main

    rec = sticky_loop(4.0, 1.0, n=1500, seed=8, noise_std=0.03, load_walk_std=0.02, name="FIC9")
    path = tmp_path / "FIC9.csv"
    write_wide(rec.replace(op=rec.op / 100.0, mv=None), path)
    assert main(["identify", str(path)]) == 0
    (line,) = [ln for ln in capsys.readouterr().out.splitlines() if "[data_quality.op_fraction]" in ln]
    assert line.endswith('read OP as % of span with a tag map (--tags MAP.toml) holding [loops.FIC9] with '
                         'op = { tag = "FIC9.OP", range = [0, 1] } and pv = "FIC9.PV", or pass the right column '
                         'with --op')
    df = pd.read_csv(path, parse_dates=["time"], index_col="time")
    frame = diagnose.identify(df, narx=False)
    (w,) = [w for w in frame.warnings if w.code == "data_quality.op_fraction"]
    assert w.message.endswith("scale OP's column to % (multiply by 100) or name the right column with op='COLUMN'")
    assert "--op" not in w.message
    # a record made from a frame that is already one loop says the same
    back = diagnose.LoopRecord.from_frame(df.rename(columns=lambda c: c.split(".")[-1]))
    (f,) = [f for f in assess(back) if f.code == "op_fraction"]
    assert f.message.endswith("name the right column with op='COLUMN'")



def test_the_tag_map_the_op_fraction_advice_gives_reads_op_in_percent(tmp_path, capsys):
    # the map written exactly as the warning words it: its range scales OP to % of span, the
    # warning goes, and S and J come out as the same export logged in % gives them
    import re

    from connectors.historian import write_wide
    from diagnose.service.cli import main

    rec = sticky_loop(4.0, 1.0, n=1500, seed=8, noise_std=0.03, load_walk_std=0.02, name="FIC9")
    frac, pct = tmp_path / "frac" / "FIC9.csv", tmp_path / "pct" / "FIC9.csv"
    frac.parent.mkdir()
    pct.parent.mkdir()
    write_wide(rec.replace(op=rec.op / 100.0, mv=None), frac)
    write_wide(rec.replace(mv=None), pct)
    assert main(["identify", str(frac), "--json"]) == 0
    warned = json.loads(capsys.readouterr().out)
    (advice,) = [w["message"] for w in warned["warnings"] if w["code"] == "data_quality.op_fraction"]
    loop, op, pv = re.search(r"\[loops\.(\S+)\] with (op = \{.*?\}) and (pv = \"[^\"]+\")", advice).groups()
    tags = tmp_path / "map.toml"
    tags.write_text(f"[loops.{loop}]\n{op}\n{pv}\n")
    assert main(["identify", str(frac), "--tags", str(tags), "--json"]) == 0
    mapped = json.loads(capsys.readouterr().out)
    assert main(["identify", str(pct), "--json"]) == 0
    plain = json.loads(capsys.readouterr().out)
    codes = {w["code"] for w in mapped["warnings"]}
    assert "data_quality.op_fraction" not in codes and "op_not_percent" not in codes
    assert mapped["stiction"] and mapped["S"] == pytest.approx(plain["S"], abs=0.05)
    assert mapped["J"] == pytest.approx(plain["J"], abs=0.05) and mapped["S"] == pytest.approx(4.0, abs=0.4)
    # unscaled, S and J come out in fractions of span (the same valve), the units said with them
    assert warned["S"] == pytest.approx(plain["S"] / 100, rel=0.05) and warned["class"] == plain["class"]
    assert (warned["sj_units"], mapped["sj_units"], plain["sj_units"]) == ("fraction of span", "% of span", "% of span")
