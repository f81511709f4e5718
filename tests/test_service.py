"""The diagnosis pipeline's optional stages and `stiction demo` end to end."""

from __future__ import annotations

import json
from dataclasses import dataclass

import numpy as np
import pytest

from connectors.historian import write_wide
from diagnose.notes import Note
from diagnose.service import figures, pipeline
from diagnose.service.cli import main
from diagnose.simulate import sticky_loop


@pytest.fixture(scope="module")
def rec():
    return sticky_loop(3.0, 1.0, n=2000, noise_std=0.03, load_walk_std=0.02, seed=5, name="PIC4")


@dataclass(frozen=True)
class _Sel:
    model: str
    robust: bool
    S: float = 3.0
    J: float = 1.0
    distance: float = 0.1
    free_run_rmse: float = 0.2

    def to_dict(self):
        return {"model": self.model, "S": self.S, "J": self.J, "distance": self.distance, "robust": self.robust,
                "free_run_rmse": self.free_run_rmse}

    def warning(self):
        return None if self.robust else Note("robustness.outside_region", "outside")


class _Bank:
    def __init__(self, robust=True):
        self.robust = robust
        self.calls = []

    def select(self, S_pct, J_pct):
        self.calls.append((S_pct, J_pct))
        return _Sel("narx_S3_J1", self.robust)

    def free_run(self, sel, op_pct):
        return np.asarray(op_pct) * 0.5 + 25.0


def test_narx_stage_uses_the_identified_s_and_j(rec, monkeypatch):
    bank = _Bank(robust=False)
    monkeypatch.setattr(pipeline, "_bank", lambda: bank)
    d = pipeline.diagnose(rec)
    ident = d.identification
    assert bank.calls == [(ident.S_pct, ident.J_pct)]
    assert d.selection.model == "narx_S3_J1" and ident.narx is d.selection
    want = float(np.sqrt(np.mean((d.narx_mv_hat_pct - rec.mv) ** 2)))
    assert d.narx_run.rmse_record == pytest.approx(want) and d.narx_run.against == "mv"
    assert "robustness.outside_region" in [w.code for w in d.warnings]
    res = d.to_dict()
    assert res["narx"]["model"] == "narx_S3_J1" and res["narx"]["free_run_rmse_record"] == pytest.approx(want)
    assert "robustness.outside_region" in [w["code"] for w in res["warnings"]]
    assert figures.narx(d) is not None


def test_missing_or_broken_optional_stages_only_warn(rec, monkeypatch):
    def broken():
        raise RuntimeError("weights file truncated")

    monkeypatch.setattr(pipeline, "_bank", broken)
    real_optional = pipeline._optional
    monkeypatch.setattr(pipeline, "_optional",
                        lambda m: None if m == "diagnose.physics" else real_optional(m))
    d = pipeline.diagnose(rec, explain=True)
    res = d.to_dict()
    assert [w["code"] for w in res["warnings"]] == [w.code for w in d.warnings]
    codes = [w["code"] for w in res["warnings"]]
    assert "service.narx_unavailable" in codes and "service.explain_unavailable" in codes
    assert "truncated" in " ".join(w["message"] for w in res["warnings"])
    assert res["narx"] is None and res["explanation"] is None and res["S"] > 1.0
    json.dumps(res, allow_nan=False)  # the result is plain JSON


def test_identification_failure_raises_a_domain_error():
    from diagnose.errors import DataError

    short = sticky_loop(3.0, 1.0, n=30, seed=1, name="TINY")
    with pytest.raises(DataError):
        pipeline.diagnose(short)


def test_demo_is_quick_says_where_everything_is_and_history_reads_its_database(tmp_path, monkeypatch, capsys):
    from diagnose.service.commands import demo

    logs = tmp_path / "sample_logs"
    logs.mkdir()
    write_wide(sticky_loop(4.0, 2.0, n=2000, noise_std=0.03, load_walk_std=0.02, seed=2, name="FIC5"),
               logs / "FIC5.csv")
    monkeypatch.setattr(demo, "sample_logs", lambda: logs)
    monkeypatch.setenv("STICTION_HOME", str(tmp_path / "home"))
    out = tmp_path / "demo-out"
    assert main(["demo", "--out", str(out), "--workers", "1", "--quiet"]) == 0
    text = capsys.readouterr().out
    assert str(out / "summary.md") in text and "FIC5" in text
    res = json.loads((out / "loops" / "FIC5" / "FIC5.json").read_text())
    assert res["class"] == "undershoot" and res["S"] == pytest.approx(4.0, abs=0.5)
    # missing physics only on request (minutes per loop); the demo says how to ask for it
    assert res["explanation"] is None and "timings_s" in res and "explain" not in res["timings_s"]
    assert "stiction demo --explain on" in text and "stiction explain" in text
    assert res["narx"] is not None or "service.narx_unavailable" in [w["code"] for w in res["warnings"]]
    # the database the demo wrote is the one `stiction history` reads, and the demo prints it
    db = tmp_path / "home" / "history.sqlite"
    assert f"history: {db}" in text
    assert main(["history", "FIC5"]) == 0
    assert capsys.readouterr().out.startswith("FIC5: 1 run(s)")
    assert main(["demo", "--out", str(tmp_path / "o2"), "--workers", "1", "--quiet", "--explain", "auto"]) == 0
    res = json.loads((tmp_path / "o2" / "loops" / "FIC5" / "FIC5.json").read_text())
    assert "explains" in res["explain_auto"]   # asked for: judged per loop (a good fit needs no explanation)


def test_demo_finds_the_bundled_sample_logs():
    from diagnose.service.commands import demo

    found = demo.sample_logs()
    assert (found / "README.md").exists() and list(found.glob("*.csv"))
