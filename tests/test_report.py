"""Loop reports: Markdown sections and figures, PDF that a reader opens (pdftoppm), pure content."""

from __future__ import annotations

import shutil
import subprocess

import numpy as np
import pytest

from diagnose.service import figures, pipeline, report
from diagnose.service.batch import BatchConfig, write_loop_outputs
from diagnose.service.pdf import latin1, to_pdf
from diagnose.simulate import sticky_loop

SECTIONS = ["## Verdict", "## Recommended action", "## Warnings", "## Trends", "## Phase plots",
            "## Error surface", "## NARX-SP free run", "## Spectrum"]


@pytest.fixture(scope="module")
def sticky_diag():
    rec = sticky_loop(4.0, 1.0, n=2000, noise_std=0.03, load_walk_std=0.02, seed=3, name="FIC7")
    return pipeline.diagnose(rec)


@pytest.fixture(scope="module")
def written(sticky_diag, tmp_path_factory):
    out = tmp_path_factory.mktemp("rep")
    cfg = BatchConfig(out_dir=str(out))
    rel = write_loop_outputs(cfg, sticky_diag, "FIC7")
    return out, out / rel


def _ink_fraction(png_path) -> float:
    from matplotlib.image import imread

    img = imread(str(png_path))[..., :3]
    return float(np.mean(np.any(img < 0.9, axis=-1)))


def test_markdown_has_every_section_and_its_figures(written, sticky_diag):
    out, md_path = written
    md = md_path.read_text()
    pos = [md.index(s) for s in SECTIONS]
    assert pos == sorted(pos), "sections out of order"
    res = sticky_diag.result
    assert f"{res['S']:.2f} % of span" in md and f"{res['J']:.2f} % of span" in md
    assert res["class"] in md and res["action"] in md
    for name in ("trends", "phase", "surface", "spectrum"):
        assert f"]({name}.png)" in md
        assert (md_path.parent / f"{name}.png").stat().st_size > 1000
    assert not list(md_path.parent.glob(".*.tmp")), "a temporary file was left behind"
    import os

    umask = os.umask(0)
    os.umask(umask)
    assert md_path.stat().st_mode & 0o777 == 0o666 & ~umask  # not mkstemp's private 0600


def test_json_beside_report_is_the_result(written, sticky_diag):
    import json

    _, md_path = written
    data = json.loads(md_path.with_suffix(".json").read_text())
    assert data["S"] == pytest.approx(sticky_diag.result["S"])
    assert data["schema"] == pipeline.SCHEMA and data["tool_version"] == pipeline.tool_version()


def test_pdf_opens_and_pages_are_not_blank(written, tmp_path):
    _, md_path = written
    pdf_path = md_path.with_suffix(".pdf")
    assert pdf_path.read_bytes()[:5] == b"%PDF-"
    assert shutil.which("pdftoppm"), "pdftoppm (poppler-utils) is needed to check the PDF"
    subprocess.run(["pdftoppm", "-r", "40", "-png", str(pdf_path), str(tmp_path / "page")], check=True)
    pages = sorted(tmp_path.glob("page*.png"))
    assert len(pages) >= 2
    for p in pages:
        assert _ink_fraction(p) > 0.01, f"{p.name} is blank"


def test_phase_plot_gets_an_op_mv_panel_only_with_mv(sticky_diag):
    from PIL import Image
    import io

    with_mv = figures.phase(sticky_diag)
    no_mv = pipeline.Diagnosis(record=sticky_diag.record.replace(mv=None), result=sticky_diag.result,
                               identification=sticky_diag.identification)
    w1 = Image.open(io.BytesIO(with_mv)).size[0]
    w2 = Image.open(io.BytesIO(figures.phase(no_mv))).size[0]
    assert sticky_diag.record.mv is not None and w1 > 1.5 * w2


def test_error_surface_needs_a_fit(sticky_diag):
    assert figures.surface(sticky_diag) is not None
    bare = pipeline.Diagnosis(record=sticky_diag.record, result=sticky_diag.result)
    assert figures.surface(bare) is None
    blocks = report.loop_blocks(sticky_diag.result, figures=["trends"])
    md = report.to_markdown(blocks)
    assert "No error surface" in md and "](surface.png)" not in md and "## Spectrum" not in md
    bare_md = report.to_markdown(report.loop_blocks(sticky_diag.result))  # a monitor window: no figures
    assert "## Trends" not in bare_md and "## Verdict" in bare_md and "## NARX-SP free run" in bare_md


def test_envelope_keeps_extremes_of_a_long_series():
    t = np.arange(100_000, dtype=float)
    y = np.sin(2 * np.pi * t / 977.0) + 0.01 * np.random.default_rng(0).standard_normal(t.size)
    tt, yy = figures.envelope(t, y, max_points=500)
    assert yy.size <= 1000
    assert yy.max() == y.max() and yy.min() == y.min()
    assert np.all(np.diff(tt) >= 0)


def test_spectrum_peak_is_at_the_oscillation_period():
    ts = 1.0
    t = np.arange(4000) * ts
    pv = np.sin(2 * np.pi * t / 125.0) + 0.1 * np.random.default_rng(1).standard_normal(t.size)
    period, power = figures.pv_spectrum(pv, ts)
    assert period[np.argmax(power)] == pytest.approx(125.0, rel=0.05)


def _result(**kw):
    base = {"loop": "X1", "stiction": True, "class": "undershoot", "S": 3.0, "J": 1.0,
            "S_interval": [2.8, 3.2], "J_interval": [0.8, 1.2], "confidence": 0.9,
            "oscillation": {"oscillating": True, "period_s": 100.0, "regularity": 2.5},
            "warnings": [], "process": {"kind": "foptd", "gain": 1.0, "tau_s": 20.0, "delay_s": 3.0},
            "fit": {"rmse": 0.1, "r2": 0.9}}
    base.update(kw)
    base["severity"] = pipeline.severity(base)
    base["verdict"] = pipeline.verdict(base)
    base["action"] = pipeline.recommended_action(base)
    return base


def test_severity_orders_loops_the_way_an_engineer_would():
    big = _result(S=5.0)["severity"]["score"]
    small = _result(S=0.5)["severity"]["score"]
    unsure = _result(S=5.0, confidence=0.3)["severity"]["score"]
    healthy = _result(stiction=False, S=0.0, J=0.0, **{"class": "none"},
                      oscillation={"oscillating": False})["severity"]["score"]
    dq = _result(S=0.5, warnings=[{"code": "data_quality.gap", "message": "g"}])["severity"]["score"]
    assert big > unsure > small > healthy == 0
    assert dq == pytest.approx(small + 5.0)


def test_plain_words_follow_the_evidence():
    assert "inspected" in _result()["action"]
    comp = _result(warnings=[{"code": "data_quality.compression", "message": "c"}])
    assert "compress" in comp["action"] and comp["verdict"].startswith("Possible stiction")
    tune = _result(stiction=False, S=0.0, J=0.0, **{"class": "none"})
    assert "tuning" in tune["action"] and tune["verdict"].startswith("No stiction")


def test_explanation_section_slots_in_when_present():
    res = _result(explanation={"missing_physics": "actuator_lag", "baseline_rmse": 0.2, "improved_rmse": 0.1,
                               "hypotheses": [{"name": "actuator_lag", "heldout_rmse": 0.1, "accepted": True}]})
    md = report.to_markdown(report.loop_blocks(res, figures=["explanation"]))
    assert "## Missing physics" in md and "actuator_lag" in md and "](explanation.png)" in md
    assert "## Missing physics" not in report.to_markdown(report.loop_blocks(_result()))


def test_pdf_from_blocks_without_figures_and_with_odd_characters(tmp_path):
    blocks = report.loop_blocks(_result(loop="T\u00f6st \u2265 1 \u03c4"))
    data = to_pdf(blocks)
    assert data[:5] == b"%PDF-" and len(data) > 1000
    assert latin1("S \u2265 2 \u00b1 0.1, \u03c4 = 3 s") == "S >= 2 +/- 0.1, tau = 3 s"


def test_report_says_where_S_and_J_came_from():
    from diagnose.service.report import loop_blocks

    def rows_of(result):
        blocks = loop_blocks(result)
        table = next(b for b in blocks if b[0] == "table" and b[1] == ["Quantity", "Value"])
        return dict((r[0], r[1]) for r in table[2])

    base = {"loop": "FIC1", "stiction": True, "class": "deadband", "S": 2.0, "J": 0.0,
            "S_interval": [1.8, 2.2], "J_interval": [0.0, 0.1], "warnings": []}
    assert "stem position" in rows_of({**base, "method": "op_mv"})["S and J from"]
    assert "Hammerstein" in rows_of({**base, "method": "op_pv"})["S and J from"]
