"""Loop reports: the first page, Markdown sections and figures, PDF that a reader opens (pdftoppm),
pure content from the typed diagnosis."""

from __future__ import annotations

import functools
import shutil
import subprocess
from dataclasses import replace
from types import SimpleNamespace

import numpy as np
import pytest

from diagnose import figures as draw
from diagnose.identification import Identification
from diagnose.notes import Note
from diagnose.oscillation import Oscillation
from diagnose.process_model import ProcessModel
from diagnose.record import LoopRecord
from diagnose.service import figures, pipeline, report
from diagnose.service.batch import BatchConfig, rank, write_loop_outputs
from diagnose.service.pdf import latin1, to_pdf
from diagnose.simulate import sticky_loop
from diagnose.verdict import Verdict

SECTIONS = ["## Verdict", "## Why we believe it", "## Recommended action", "## Warnings", "## Trends",
            "## Phase plots", "## Error surface", "## NARX-SP free run", "## Spectrum", "## Evidence in numbers"]


@pytest.fixture(scope="module")
def sticky_diag():
    rec = sticky_loop(4.0, 1.0, n=2000, noise_std=0.03, load_walk_std=0.02, seed=3, name="FIC7")
    return pipeline.diagnose(rec)


@pytest.fixture(scope="module")
def written(sticky_diag, tmp_path_factory):
    out = tmp_path_factory.mktemp("rep")
    cfg = BatchConfig(out_dir=str(out))
    rel, _ = write_loop_outputs(cfg, sticky_diag, "FIC7")
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
    ident = sticky_diag.identification
    assert f"{ident.S_pct:.2f} % of span" in md and f"{ident.J_pct:.2f} % of span" in md
    assert ident.cls in md and sticky_diag.action in md and sticky_diag.verdict_text in md
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
    assert data["S"] == pytest.approx(sticky_diag.identification.S_pct)
    assert data["schema"] == pipeline.SCHEMA and data["tool_version"] == pipeline.tool_version()
    assert data["summary"]["loop"] == "FIC7" and data["summary"]["verdict"] == sticky_diag.verdict_text
    assert data["summary"]["report"] == "loops/FIC7/FIC7.md" and data["timings_s"]["report"] > 0
    assert [w["code"] for w in data["warnings"]] == [w.code for w in sticky_diag.warnings]


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


def test_the_first_page_is_what_a_planner_acts_on(written, sticky_diag):
    _, md_path = written
    pdf_path = md_path.with_suffix(".pdf")
    assert shutil.which("pdftotext"), "pdftotext (poppler-utils) is needed to read the PDF"
    first = subprocess.run(["pdftotext", "-f", "1", "-l", "1", "-layout", str(pdf_path), "-"], check=True,
                           capture_output=True, text=True).stdout
    for text in ("Verdict", "deadband + stickband", "slip jump", "Why we believe it", "Recommended action",
                 "Have the valve inspected", "Probability of stiction"):
        assert text in first, text
    for later in ("Trends", "Phase plots", "Error surface", "Evidence in numbers"):
        assert later not in first, later
    ev = sticky_diag.identification.evidence
    agree = sum(1 for e in ev if e.decision == "stiction")
    assert f"{agree} say stiction" in " ".join(first.split())


def test_phase_plot_gets_an_op_mv_panel_only_with_mv(sticky_diag):
    from PIL import Image
    import io

    with_mv = figures.phase(sticky_diag)
    no_mv = replace(sticky_diag, record=sticky_diag.record.replace(mv=None))
    w1 = Image.open(io.BytesIO(with_mv)).size[0]
    w2 = Image.open(io.BytesIO(figures.phase(no_mv))).size[0]
    assert sticky_diag.record.mv is not None and w1 > 1.5 * w2


def test_the_fit_row_names_the_signal_the_fit_reproduced(sticky_diag):
    from diagnose.service.commands.identify import summary

    # a stem that moved: the OP -> MV fit; one that never moved: the OP -> PV fit, though the method
    # is op_mv (the report called PV's RMSE the stem's, in % of span)
    rec = sticky_diag.record
    stuck = pipeline.diagnose(rec.replace(mv=np.full(rec.n, 50.0)), narx=False)
    assert sticky_diag.identification.method == stuck.identification.method == "op_mv"
    assert stuck.identification.valve_not_moving and stuck.identification.valve_fit is None
    for diag, row, line in ((sticky_diag, "stem position (MV): RMSE", "of MV from OP, % of span"),
                            (stuck, "PV: RMSE", "of PV from OP")):
        fit = dict(report._detail_rows(diag))["Fit of the model (free-run simulation)"]
        assert fit.startswith(row)
        assert f"(free-run simulation {line})" in summary(diag.identification)


def test_error_surface_needs_a_fit(sticky_diag):
    assert figures.surface(sticky_diag) is not None
    ident = sticky_diag.identification
    bare = replace(sticky_diag, identification=replace(ident, fit=None, valve_fit=None))
    assert figures.surface(bare) is None
    blocks = report.loop_blocks(sticky_diag, figures=["trends"])
    md = report.to_markdown(blocks)
    assert "No error surface" in md and "](surface.png)" not in md and "## Spectrum" not in md
    bare_md = report.to_markdown(report.loop_blocks(sticky_diag))  # a monitor window: no figures
    assert "## Trends" not in bare_md and "## Verdict" in bare_md and "## NARX-SP free run" in bare_md


def test_envelope_keeps_extremes_of_a_long_series():
    t = np.arange(100_000, dtype=float)
    y = np.sin(2 * np.pi * t / 977.0) + 0.01 * np.random.default_rng(0).standard_normal(t.size)
    tt, yy = draw.envelope(t, y, max_points=500)
    assert yy.size <= 2 * 500 + 2
    assert yy.max() == y.max() and yy.min() == y.min()
    assert np.all(np.diff(tt) >= 0)


@pytest.mark.parametrize("n", [3000, 3599, 100_001])
def test_envelope_covers_the_whole_record(n):
    t = np.arange(n, dtype=float)
    y = np.sin(t / 40.0)
    y[-5] = 9.0   # an event in the newest samples must be drawn
    tt, yy = draw.envelope(t, y, max_points=1200)
    assert tt[0] == t[0] and tt[-1] == t[-1]
    assert yy.max() == 9.0 and yy.min() == y.min()
    assert np.all(np.diff(tt) >= 0) and yy.size <= 2 * 1200 + 2


def _lines(fig_key, axis):
    return figures._FIGS[fig_key].axes[axis].get_lines()


def test_trends_show_the_whole_record_and_the_record_sets_the_scale(sticky_diag):
    rec = sticky_diag.record.replace(mv=None)
    n = 3599   # 33 % of the record was lost at this length
    rec = rec.replace(op=np.resize(rec.op, n), pv=np.resize(rec.pv, n), sp=np.resize(rec.sp, n))
    diag = replace(sticky_diag, record=rec)
    pv_hat = rec.pv.copy()
    pv_hat[:20] = 1e4   # a model start-up transient
    figures.trends(diag, mv_hat=rec.op, pv_hat=pv_hat)
    fig = figures._FIGS[(8.0, 4.6)]
    t_end = rec.t_s[-1] / 60.0   # the axis is in minutes for this record
    for ax in fig.axes[:2]:
        assert max(float(np.max(ln.get_xdata())) for ln in ax.get_lines()) == pytest.approx(t_end)
    lo, hi = fig.axes[0].get_ylim()
    assert hi < rec.pv.max() + 0.2 * np.ptp(rec.pv) and lo > rec.pv.min() - 0.2 * np.ptp(rec.pv)
    # ... but a model that runs off the record for most of it stays in view
    off = rec.pv - 3.0 * np.ptp(rec.pv)
    figures.trends(diag, mv_hat=rec.op, pv_hat=off)
    lo, hi = figures._FIGS[(8.0, 4.6)].axes[0].get_ylim()
    assert lo <= np.percentile(off, 5) and hi >= rec.pv.max()


def _healthy(diag):
    return replace(diag, identification=replace(diag.identification, stiction=False, cls="none"))


def test_no_sticky_valve_path_on_a_no_stiction_verdict(sticky_diag):
    diag = _healthy(sticky_diag)
    mv_hat, pv_hat = figures._model_path(diag)
    assert mv_hat is None and pv_hat is not None
    np.testing.assert_allclose(pv_hat, sticky_diag.identification.linear_fit.simulate(diag.record.op)[1])
    figures.phase(diag, mv_hat, pv_hat)
    labels = [ln.get_label() for ln in _lines((8.0, 3.8), 1)]
    assert "fitted valve" not in labels and "record" in labels
    assert figures._model_path(sticky_diag)[0] is not None   # a sticky verdict keeps its valve path


def test_recorded_op_mv_is_drawn_over_the_fitted_valve(sticky_diag):
    mv_hat, pv_hat = figures._model_path(sticky_diag)
    figures.phase(sticky_diag, mv_hat, pv_hat)
    for axis in (0, 1):
        lines = {ln.get_label(): ln for ln in _lines((8.0, 3.8), axis)}
        model = lines.get("fitted valve", lines.get("fitted model"))
        assert lines["record"].get_zorder() > model.get_zorder()
        assert model.get_linestyle() == "--"


def test_error_surface_is_the_one_of_the_fit_that_gave_S_and_J(sticky_diag):
    ident = sticky_diag.identification
    assert ident.method == "op_mv"
    surf, source = figures._surface_source(sticky_diag)
    assert surf is ident.valve_fit.surface and "OP-MV" in source
    figures.surface(sticky_diag)
    assert "OP-MV valve fit" in figures._FIGS[(4.6, 3.8)].axes[0].get_title()
    op_pv = replace(sticky_diag, identification=replace(ident, method="op_pv"))
    assert figures._surface_source(op_pv)[0] is ident.fit.surface


def _osc(oscillating, period_s, regularity):
    return Oscillation(oscillating, period_s, regularity, 10.0, 1.0, 1.0)


def test_spectrum_marks_only_an_oscillation_the_result_reports(sticky_diag):
    for osc, marked in ((_osc(False, 120.0, 0.3), False), (_osc(True, 120.0, 2.0), True),
                        (_osc(True, 86604.0, 1.5), False)):  # daily
        diag = replace(sticky_diag, identification=replace(sticky_diag.identification, oscillation=osc))
        figures.spectrum(diag)
        ax = figures._FIGS[(4.6, 3.0)].axes[0]
        assert (len(ax.get_lines()) == 2) is marked, osc
        labels = [t.get_text() for t in ax.get_xticklabels()]
        assert labels and not any("e+" in x or "^" in x for x in labels)


def test_spectrum_peak_is_at_the_oscillation_period():
    ts = 1.0
    t = np.arange(4000) * ts
    pv = np.sin(2 * np.pi * t / 125.0) + 0.1 * np.random.default_rng(1).standard_normal(t.size)
    period, power = draw.pv_spectrum(pv, ts)
    assert period[np.argmax(power)] == pytest.approx(125.0, rel=0.05)


def _record(n=2000, ts_s=1.0, name="X1"):
    k = np.arange(n)
    return LoopRecord(name=name, ts_s=ts_s, op=50 + np.sin(k / 30), pv=np.cos(k / 30), start="2026-01-01T00:00:00Z")


def _diag(*, warnings=(), notes=(), p=None, record=None, explanation=None, oscillation=(True, 100.0, 2.5), **kw):
    """A diagnosis of a made-up identification (the report's wording under test, not the fit)."""
    base = dict(loop="X1", stiction=True, cls="undershoot", S_pct=3.0, J_pct=1.0, S_interval_pct=(2.8, 3.2),
                J_interval_pct=(0.8, 1.2), process=ProcessModel("foptd", 1.0, 20.0, 3.0, 0.0), rmse=0.1, r2=0.9,
                oscillation=_osc(*oscillation), confidence=0.9, n=2000)
    base.update(kw)
    if p is not None:
        base["verdict"] = Verdict(stiction_probability=p, stiction=p >= 0.5, threshold=0.5,
                                  confidence=max(p, 1 - p))
    ident = Identification(warnings=tuple(warnings), **base)
    rec = record if record is not None else _record(name=ident.loop)
    return pipeline.assemble(rec, ident, notes=notes, explanation=explanation)


def test_the_report_says_when_the_fit_rule_settled_the_verdict():
    by_rule = Verdict(stiction_probability=0.58, stiction=True, threshold=0.635, confidence=0.58,
                      by_fit_rule=True)
    plain = replace(by_rule, stiction_probability=0.8, by_fit_rule=False)
    for v, said in ((by_rule, True), (plain, False)):
        md = report.to_markdown(report.loop_blocks(_diag(verdict=v)))
        assert "stiction at 64 % and above" in md
        assert ("the model fit's own evidence decides, and here it does" in md) is said


def test_severity_ranks_by_the_probability_of_stiction_then_its_size():
    big = _diag(S_pct=5.0, p=0.9).severity.score
    small = _diag(S_pct=0.5, p=0.9).severity.score
    unsure = _diag(S_pct=5.0, p=0.55).severity.score
    quiet = (False, None, 0.0)
    watch = _diag(stiction=False, S_pct=0.0, J_pct=0.0, p=0.4, cls="none", oscillation=quiet).severity.score
    healthy = _diag(stiction=False, S_pct=0.0, J_pct=0.0, p=0.0, cls="none", oscillation=quiet).severity.score
    dq = _diag(S_pct=0.5, p=0.9, warnings=[Note("data_quality.gap", "g")]).severity.score
    assert big > small > unsure > watch > healthy == 0
    assert dq == pytest.approx(small + 5.0)
    # an ambiguous date order dates the record but leaves its samples as they are
    dated = _diag(S_pct=0.5, p=0.9, warnings=[Note("data_quality.date_order", "d")]).severity.score
    assert dated == pytest.approx(small)
    # without a probability (an older result) a sticky verdict's confidence stands in for it
    assert _diag(S_pct=5.0, confidence=0.9).severity.score == pytest.approx(big)


def test_severity_is_the_documented_sum_and_the_model_bank_adds_nothing():
    d = _diag(S_pct=2.0, p=0.87, oscillation=(True, 100.0, 1.5), warnings=[Note("data_quality.gap", "g")])
    # docs/service.md, "Ranking": stiction + oscillation + data quality, to 0.1
    want = 50 * 0.87 * (0.75 + 0.25 * 2.0 / 5.0) + 25 * min(max(1.5 / 2, 0.5), 1) + 5
    assert d.severity.score == round(want, 1) == 60.7
    # a NARX-SP model outside its robustness margin is a gap in the tool's bank, not a worse valve
    outside = SimpleNamespace(robust=False, model="narx", to_dict=lambda: {"robust": False})
    far = _diag(S_pct=2.0, p=0.87, oscillation=(True, 100.0, 1.5), warnings=[Note("data_quality.gap", "g")],
                narx=outside)
    assert far.severity == d.severity and set(far.severity.to_dict()) == {"score", "size", "oscillation",
                                                                          "data_quality"}


def test_the_summary_shows_severity_to_the_precision_it_ranks_by():
    rows = rank([{"status": "ok", "loop": "TIC105", "severity": 75.3, "S_pct": 2.0},
                   {"status": "ok", "loop": "FIC103", "severity": 74.9, "S_pct": 5.0},
                   {"status": "ok", "loop": "FIC102", "severity": 74.9, "S_pct": 4.0}])
    assert [r["loop"] for r in rows] == ["TIC105", "FIC103", "FIC102"]   # equal severities: larger S first
    md = report.to_markdown(report.summary_blocks(rows))
    assert "| TIC105 | 75.3 |" in md and "| FIC103 | 74.9 |" in md and "| FIC102 | 74.9 |" in md


def test_plain_words_follow_the_evidence():
    assert "inspected" in _diag().action
    comp = _diag(warnings=[Note("data_quality.compression", "c")])
    assert "compress" in comp.action and comp.verdict_text.startswith("Possible stiction")
    tune = _diag(stiction=False, S_pct=0.0, J_pct=0.0, cls="none")
    assert "tuning" in tune.action and tune.verdict_text.startswith("No stiction")


@functools.lru_cache(maxsize=1)
def _real_explanation():
    """One real `explain` result on a short sticky loop: the report tests vary its named physics."""
    from diagnose.physics import explain

    rec = sticky_loop(3.0, 1.0, n=1200, noise_std=0.1, seed=1)
    return explain(rec.replace(mv=None, name="X1"))


def _explanation(name, accepted, **params):
    from diagnose.physics import HypothesisResult

    hyp = HypothesisResult(name=name, params=params, heldout_rmse=4.33, accepted=accepted, stage="loop",
                           train_rmse=0.63, reduction=0.05, delta_bic=-3.0, n_extra=2)
    return replace(
        _real_explanation(), missing_physics=name if accepted else None, baseline_rmse=4.66,
        improved_rmse=4.33 if accepted else 4.66, hypotheses=(hyp,),
        explanation="No missing physics named." if not accepted else f"{name} explains it.")


def test_explanation_section_slots_in_when_present():
    diag = _diag(explanation=_explanation("actuator_lag", True, tau_s=12.0))
    md = report.to_markdown(report.loop_blocks(diag, figures=["explanation"]))
    assert "## Missing physics" in md and "actuator_lag" in md and "](explanation.png)" in md
    assert "## Missing physics" not in report.to_markdown(report.loop_blocks(_diag()))
    assert diag.to_dict()["explanation"]["missing_physics"] == "actuator_lag"


def test_explanation_table_gives_each_hypothesis_its_own_stages_unit():
    from diagnose.physics import HypothesisResult

    hyps = (HypothesisResult(name="asymmetric_stiction", params={}, heldout_rmse=1.7e-5, accepted=False,
                             stage="valve", train_rmse=1e-5, reduction=0.39, delta_bic=-3.0, n_extra=2),
            HypothesisResult(name="external_disturbance", params={}, heldout_rmse=0.1067, accepted=False,
                             stage="loop", train_rmse=0.1, reduction=0.0, delta_bic=3.0, n_extra=3))
    diag = _diag(explanation=replace(_real_explanation(), missing_physics=None, hypotheses=hyps))
    table = next(b for b in report.loop_blocks(diag) if b[0] == "table" and b[1][0] == "Hypothesis")
    rows = {r[0]: r for r in table[2]}
    assert rows["asymmetric_stiction"][2] == "MV" and rows["asymmetric_stiction"][3].endswith("% of span")
    assert rows["external_disturbance"][2] == "PV" and rows["external_disturbance"][3].endswith("PV units")


def test_pdf_from_blocks_without_figures_and_with_odd_characters(tmp_path):
    blocks = report.loop_blocks(_diag(loop="T\u00f6st \u2265 1 \u03c4"))
    data = to_pdf(blocks)
    assert data[:5] == b"%PDF-" and len(data) > 1000
    assert latin1("S \u2265 2 \u00b1 0.1, \u03c4 = 3 s") == "S >= 2 +/- 0.1, tau = 3 s"


def test_a_pdf_table_over_two_pages_repeats_its_header_and_keeps_each_cell_whole(tmp_path):
    """A plant's summary runs over pages: each page's part of the table starts with the header, and
    a cell's words stay in order, wrapped between words (a path after a '/')."""
    notes = ["valve sticks " * (i % 6 + 1) for i in range(90)]
    rows = [[str(i), f"FIC{i:03d}", notes[i], f"/plant/north/unit_400/exports/area_51/FIC{i:03d}_2026-11-26.csv"]
            for i in range(90)]
    pdf = tmp_path / "t.pdf"
    pdf.write_bytes(to_pdf([("title", "Loops"), ("table", ["#", "Loop", "Notes", "File"], rows)]))
    pages = int(next(ln for ln in subprocess.run(["pdfinfo", str(pdf)], capture_output=True, text=True,
                                                 check=True).stdout.splitlines() if ln.startswith("Pages:")).split()[1])
    assert pages >= 2
    text = []
    for page in range(1, pages + 1):
        lines = subprocess.run(["pdftotext", "-raw", "-f", str(page), "-l", str(page), str(pdf), "-"],
                               capture_output=True, text=True, check=True).stdout.split()
        head = lines[:4] if page > 1 else lines[1:5]
        assert head == ["#", "Loop", "Notes", "File"], (page, lines[:6])
        text += lines
    words = " ".join(text)
    for i in (0, 45, 89):      # every row's cells whole and in order
        assert f"{i} FIC{i:03d} {notes[i].strip()} /plant/north/unit_400/exports/area_51/FIC{i:03d}_2026-11-26.csv" \
            in words.replace("/ ", "/")


def test_a_pdf_cell_with_a_word_wider_than_the_page_breaks_it_and_loses_nothing(tmp_path):
    from diagnose.service.pdf import _lines

    word = "".join(chr(65 + i % 26) for i in range(400))      # a tag dump with no space or '/'
    pdf = tmp_path / "w.pdf"
    pdf.write_bytes(to_pdf([("table", ["Tag", "Note"], [[word, ""], ["", "x"]])]))
    text = subprocess.run(["pdftotext", "-raw", str(pdf), "-"], capture_output=True, text=True,
                          check=True).stdout
    assert word in "".join(text.split())

    class Fixed:        # 1 mm per character: the breaking is easy to check
        @staticmethod
        def get_string_width(s):
            return float(len(s))

    assert _lines(Fixed, "", 10.0, {}) == [""]
    assert _lines(Fixed, "ab cd efghijklmnopq r", 6.0, {}) == ["ab cd", "efghij", "klmnop", "q r"]
    assert _lines(Fixed, "one\ntwo", 50.0, {}) == ["one", "two"]


def _quantity_rows(diag):
    rows = {}
    for b in report.loop_blocks(diag):
        if b[0] == "table" and b[1] == ["Quantity", "Value"]:
            rows.update({r[0].split(":")[0]: r[1] for r in b[2]})
    return rows


def test_report_says_where_S_and_J_came_from():
    base = dict(cls="deadband", S_pct=2.0, J_pct=0.0, S_interval_pct=(1.8, 2.2), J_interval_pct=(0.0, 0.1))
    assert "stem position" in _quantity_rows(_diag(method="op_mv", **base))["S and J from"]
    assert "Hammerstein" in _quantity_rows(_diag(method="op_pv", **base))["S and J from"]


def test_numbers_are_plain_minutes_and_hours():
    from diagnose.controller import ControllerAction

    rec = _record(n=6585, ts_s=60.0)
    diag = _diag(process=ProcessModel("foptd", -2.33, 60.1, 3480.0, 0.0),
                 controller=ControllerAction(1, 0.21, 1.9797e6, 0.8, 0), oscillation=(True, 1500.0, 1.5),
                 record=rec, n=rec.n, ts_s=rec.ts_s)
    md = report.to_markdown(report.loop_blocks(diag))
    assert "e+0" not in md and "3480" not in md and "1500 s" not in md
    assert "dead time 58 min" in md and "22.9 days" in md and "25 min" in md and "4.57 days" in md
    summary = report.to_markdown(report.summary_blocks([{"status": "ok", "loop": "X", "rank": 1, "severity": 20,
                                                         "oscillation_period_s": 1500.0}]))
    assert "| 25 min |" in summary


def test_a_daily_cycle_is_a_slow_cycle_ranked_below_a_sticky_valve():
    daily = _diag(stiction=False, S_pct=0.0, J_pct=0.0, confidence=0.68, cls="none",
                  oscillation=(True, 86604.0, 1.49), warnings=[Note("data_quality.segment", "s")])
    sticky = _diag(S_pct=2.24, J_pct=0.0, confidence=0.97, cls="deadband", oscillation=(False, None, 0.0))
    assert sticky.severity.score > daily.severity.score
    rows = _quantity_rows(daily)
    assert "slow cycle" in rows["Oscillation"] and "24.1 h" in rows["Oscillation"]
    assert "tuning" not in daily.action and "slow cycle" in daily.action
    from diagnose.service.batch import loop_row, rank

    ranked = rank([{**loop_row(daily, None), "loop": "FIC211"}, {**loop_row(sticky, None), "loop": "FIC20102"}])
    assert [r["loop"] for r in ranked] == ["FIC20102", "FIC211"]
    md = report.to_markdown(report.summary_blocks(ranked))
    assert "| slow cycle 24.1 h |" in md


def test_classes_and_S_J_are_explained_in_words():
    md = report.to_markdown(report.loop_blocks(_diag()))   # undershoot
    assert "stops short" in md and "how far OP must travel back" in md and "jumps when it breaks free" in md
    md = report.to_markdown(report.loop_blocks(_diag(cls="overshoot", S_pct=2.0, J_pct=4.0)))
    assert "jumps past" in md
    md = report.to_markdown(report.loop_blocks(_diag(cls="no_offset", S_pct=3.0, J_pct=3.0)))
    assert "jumps to where the controller output asks" in md and "within 15 % of S" in md


def test_S_and_J_units_follow_OP_when_OP_is_not_in_percent():
    res = _diag(S_pct=0.42, J_pct=0.1, warnings=[Note("op_not_percent", "OP spans -3..4, outside 0..100 %")])
    rows = _quantity_rows(res)
    assert "OP's own units" in rows["S"] and not rows["S"].startswith("0.42 %")
    assert "OP's own units" in res.verdict_text and "% of valve span" not in res.verdict_text
    assert "% of its span" not in res.action
    from diagnose.service.batch import loop_row

    md = report.to_markdown(report.summary_blocks([{**loop_row(res, None), "rank": 1}]))
    assert "| 0.42 (OP units) |" in md


def test_no_narx_model_is_explained_where_there_are_no_warnings():
    healthy = _diag(stiction=False, S_pct=0.0, J_pct=0.0, cls="none", oscillation=(False, None, 0.0))
    md = report.to_markdown(report.loop_blocks(healthy))
    assert "see warnings" not in md.lower() and "shows no stiction" in md
    broken = _diag(notes=[Note("service.narx_unavailable", "no bank")])
    assert "see the warnings" in report.to_markdown(report.loop_blocks(broken))


def test_explanation_tables_use_words_not_internal_keys():
    diag = _diag(explanation=_explanation("external_disturbance", False, period_s=84755.6, amplitude=1.229))
    md = report.to_markdown(report.loop_blocks(diag, figures=["explanation"]))
    for raw in ("baseline_source", "train_rmse", "heldout_rmse", "baseline_rmse", "e+0"):
        assert raw not in md
    assert "| -5 % |" in md and "period_s 23.5 h" in md   # a 5 % fall is -5 %, as explain prints it


def test_evidence_says_which_tests_agree_and_which_cannot_judge_and_why(sticky_diag):
    ident = sticky_diag.identification
    text = report.evidence_summary(ident)
    cannot = [e for e in ident.evidence if e.decision == "cannot_judge"]
    assert cannot, "the fixture should have a test that cannot judge"
    judged = len(ident.evidence) - len(cannot)
    assert f"Of the {judged} tests that could judge this record" in text
    assert f"{len(cannot)} cannot judge it: " in text
    for e in cannot:
        assert report.REASON_TEXT[e.reason] in text
    table = next(b for b in report.loop_blocks(sticky_diag) if b[0] == "table" and b[1] == ["Test", "Says", "Why"])
    why = {r[0]: r[2] for r in table[2]}
    for e in cannot:
        assert why[report.EVIDENCE_LABELS[e.test]] == e.note and e.note


def test_explain_summary_prints_a_fall_as_negative():
    from diagnose.service.commands.explain import summary

    d = {"loop": "X", "missing_physics": None, "baseline_rmse": 1.0, "improved_rmse": 1.0, "target": "pv",
         "hypotheses": [{"name": "actuator_lag", "params": {"tau_s": 3480.0}, "accepted": False,
                         "heldout_rmse": 0.95, "heldout_reduction": 0.05, "target": "pv"}],
         "mismatch": {"windows": [{"start_s": 345660.0, "end_s": 395100.0, "rms": 6.98, "ratio_to_median": 8.1}]},
         "explanation": "changes the held-out RMSE by -5 % against the refit plain model", "warnings": []}
    text = summary(d)
    assert "change -5 %" in text and "+5 %" not in text and "tau_s 58 min" in text
    assert "e+0" not in text and "4 days to 4.57 days" in text


def test_explain_summary_gives_each_hypothesis_its_own_stages_unit():
    from diagnose.service.commands.explain import summary

    d = {"loop": "X", "missing_physics": None, "baseline_rmse": 0.95, "improved_rmse": 0.95, "target": "pv",
         "hypotheses": [{"name": "asymmetric_stiction", "params": {}, "accepted": False, "heldout_rmse": 1.7e-5,
                         "heldout_reduction": 0.39, "target": "mv"},
                        {"name": "external_disturbance", "params": {}, "accepted": False, "heldout_rmse": 0.1067,
                         "heldout_reduction": 0.0, "target": "pv"}],
         "mismatch": {}, "explanation": "", "warnings": []}
    rows = {ln.split()[0]: ln for ln in summary(d).splitlines()[2:4]}
    assert "% of span" in rows["asymmetric_stiction"] and "PV units" not in rows["asymmetric_stiction"]
    assert "PV units" in rows["external_disturbance"] and "% of span" not in rows["external_disturbance"]


def test_missing_physics_figure_titles_do_not_overlap_and_ticks_are_distinct():
    from diagnose.physics.figures import _distinct_labels, draw_explanation

    assert _distinct_labels([33.6, 34.1, 34.4, 35.0, 35.6]) == ["33.6", "34.1", "34.4", "35.0", "35.6"]
    n = 6000
    t = np.arange(n) * 60.0
    rng = np.random.default_rng(0)
    y = rng.standard_normal(n)
    d = {"t_s": t, "observed": y, "baseline": y, "reference": y, "improved": y, "residual_baseline": y,
         "residual_improved": y, "train_end_s": t[3900], "train_start_s": 600.0, "windows": [(1e5, 1.5e5)],
         "window_t_s": t[::100], "window_rms": np.abs(y[::100]), "slip_t_s": t[::500],
         "profile_lag_s": np.arange(50) * 1000.0, "after_slip_profile": rng.random(50),
         "op_bin_centres_pct": [33.6, 34.1, 34.4, 35.0, 35.6], "op_bin_rms": rng.random(5),
         "direction_rms": (5.84, 1.2), "freq_hz": 1.0 / t[1:][::-1], "residual_psd": rng.random(n - 1),
         "limit_cycle_period_s": 3000.0, "target": "pv", "missing_physics": None, "units": "PV units"}
    fig = draw_explanation(d, title="FIC211: missing physics: none named", figsize=(8.0, 6.5))
    fig.canvas.draw()
    r = fig.canvas.get_renderer()
    bottom = sorted(fig.axes[2:5], key=lambda a: a.get_position().x0)
    boxes = [a.title.get_window_extent(r) for a in bottom]
    fig_box = fig.bbox
    for a, b in zip(boxes, boxes[1:]):
        assert a.x1 <= b.x0, "titles overlap"
    for b in boxes:
        assert b.x0 >= fig_box.x0 and b.x1 <= fig_box.x1, "title cut at the figure's edge"
    assert fig.axes[0].get_xlim()[1] < 200   # a 100-hour record is drawn in hours, not seconds
    import matplotlib.pyplot as plt

    plt.close(fig)


def test_a_diagnosis_shows_itself_in_a_notebook(sticky_diag):
    from matplotlib.figure import Figure

    assert repr(sticky_diag).startswith("Diagnosis(loop='FIC7', verdict='Stiction: S = ")
    page = sticky_diag._repr_html_()
    import html

    assert html.escape(sticky_diag.verdict_text) in page and html.escape(sticky_diag.action) in page
    assert "<table>" in page and "> 99" not in page        # text is escaped
    fig = sticky_diag.plot("narx")
    assert isinstance(fig, Figure)
    labels = {ln.get_label() for ln in fig.axes[0].get_lines()}
    assert labels == {"recorded MV", "NARX-SP free run (MV)"}
    assert isinstance(sticky_diag.plot(), Figure)


def test_an_explanation_shows_itself_in_a_notebook_and_plots_the_report_figure():
    expl = _explanation("actuator_lag", True, tau_s=12.0)
    page = expl._repr_html_()
    assert "Missing physics in X1" in page and "actuator_lag" in page and "accepted" in page
    assert "<script" not in page
    assert repr(expl).startswith("Explanation(loop='X1', missing_physics='actuator_lag'")
    fig = expl.plot()
    assert len(fig.axes) >= 3 and any("missing physics: actuator_lag" in ax.get_title() for ax in fig.axes)


def test_a_valve_that_never_moved_is_reported_and_summarised_without_a_class(tmp_path):
    # a stuck stem showed "class deadband" with S in [OP's travel, 100] and J in [0, 100]
    from diagnose.service.batch import loop_row

    rec = sticky_loop(3.0, 1.0, n=600, noise_std=0.02, load_walk_std=0.01, seed=3, name="FV3")
    diag = pipeline.diagnose(rec.replace(mv=np.full(rec.n, 20.0)))
    assert diag.identification.cls == "unknown"
    assert "never moved" in diag.verdict_text and "class are not judged" in diag.verdict_text
    assert "deadband" not in diag.verdict_text
    assert "never moved" in diag.action and "stem position" in diag.action
    rows = _quantity_rows(diag)
    assert rows["Class"].startswith("unknown: not judged: the stem never moved")
    assert rows["S"].startswith("at least ") and "never moved" in rows["S"]
    assert rows["J"].startswith("not measurable")
    md = report.to_markdown(report.loop_blocks(diag))
    assert "[0.00, 100.00]" not in md and "100.00]" not in md
    row = {**loop_row(diag, None), "rank": 1}
    assert row["class"] == "unknown" and row["J_hi"] is None and row["S_hi"] is None
    summary = report.to_markdown(report.summary_blocks([row]))
    assert "| unknown |" in summary and "never moved" in summary and "deadband" not in summary


def test_evidence_numbers_show_the_gate_of_the_bicoherence_index():
    from diagnose.evidence.result import Evidence

    # NLI above its threshold, yet no stiction: the signal is Gaussian (NGI under its own threshold)
    ev = Evidence("choudhury_bicoherence", 0.117, 0.01, "no_stiction", "PV is Gaussian by its bicoherence",
                  extras={"NGI": -0.0455, "NLI": 0.117, "NGI_threshold": 0.001})
    (row,) = report.evidence_rows(SimpleNamespace(evidence=(ev,), verdict=None), numbers=True)
    assert row[1:] == ["no stiction", "0.117", "0.01, once NGI > 0.001 (NGI here -0.0455)"]


def test_a_tests_weight_counts_every_input_it_feeds_the_verdict():
    from diagnose.evidence.result import Evidence

    # model_fit moves the verdict through its likelihood ratio, not its own row: the row weighs
    # what both moved it by together, and a test whose inputs cancel out shows no weight
    fit = Evidence("model_fit", 0.17, 0.05, "stiction", "the valve explains 17 %")
    band = Evidence("valve_band", 80.0, 3.0, "stiction", "S is 80 times OP's noise")
    qsa = Evidence("yamashita_qsa", 0.8, 0.25, "stiction", "PV steady while OP moves")
    verdict = SimpleNamespace(contributions={"model_fit": 0.0, "model_fit.lr": 1.1373, "valve_band": 1.84,
                                             "valve_band.slips": -1.84, "yamashita_qsa": 0.146})
    rows = report.evidence_rows(SimpleNamespace(evidence=(fit, band, qsa), verdict=verdict))
    assert [r[1] for r in rows] == ["stiction, weighs +1.14", "stiction", "stiction, weighs +0.15"]


def test_summary_words_probabilities_as_the_loop_reports_do():
    row = {"loop": "FIC7", "status": "ok", "rank": 1, "severity": 74.9, "class": "undershoot", "S_pct": 5.0,
           "J_pct": 2.0, "stiction_probability": 0.9979, "confidence": 0.9979, "sticky": True,
           "data_quality_warnings": 0, "report": "loops/FIC7/FIC7.md"}
    healthy = dict(row, loop="FIC8", rank=2, severity=0.0, stiction_probability=0.0004, confidence=0.9996,
                   sticky=False, **{"class": "none"})
    table = next(b for b in report.summary_blocks([row, healthy]) if b[0] == "table")
    assert [r[6:8] for r in table[2]] == [["> 99 %", "> 99 %"], ["< 1 %", "> 99 %"]]


def test_summary_puts_the_degradation_beside_s_not_among_the_data_quality_warnings():
    row = {"loop": "FIC7", "status": "ok", "rank": 1, "severity": 74.9, "class": "undershoot", "S_pct": 5.0,
           "J_pct": 2.0, "stiction_probability": 0.9, "confidence": 0.9, "sticky": True,
           "data_quality_warnings": 2, "degradation": "S grew over the last 3 runs", "report": "loops/FIC7/FIC7.md"}
    (_, header, rows) = next(b for b in report.summary_blocks([row]) if b[0] == "table")
    cells = dict(zip(header, rows[0]))
    assert cells["DQ warn."] == "2" and cells["S %"] == "5.00 (degrading)"


def test_evidence_summary_agrees_in_number():
    from types import SimpleNamespace

    def ident(*decisions):
        return SimpleNamespace(evidence=[SimpleNamespace(test=f"t{i}", decision=d, reason="")
                                         for i, d in enumerate(decisions)], verdict=None)

    one_each = report.evidence_summary(ident("stiction", "no_stiction", "undetermined"))
    assert one_each.startswith("Of the 3 tests that could judge this record, 1 says stiction, 1 says no stiction "
                               "and 1 is undecided.")
    two_each = report.evidence_summary(ident("stiction", "stiction", "undetermined", "undetermined"))
    assert "Of the 4 tests" in two_each and "2 say stiction, 0 say no stiction and 2 are undecided." in two_each
    assert report.evidence_summary(ident("stiction")).startswith("Of the 1 test that could judge this record, "
                                                                 "1 says stiction")


def test_the_action_weighs_how_often_the_loops_last_runs_said_stiction():
    quiet = (False, None, 0.0)
    small = _diag(S_pct=0.5, J_pct=0.2, p=0.8, oscillation=quiet).identification
    none = _diag(stiction=False, S_pct=0.0, J_pct=0.0, p=0.2, cls="none", oscillation=(True, 100.0, 2.5)).identification
    # one window, or a loop rarely called sticky: the watch list, as before
    for runs in (None, (1, 2), (1, 4)):
        assert "watch list and compare with the next nightly run" in pipeline.recommended_action(small, (), runs)
    assert "the valve is not the cause" in pipeline.recommended_action(none, (), (1, 5))
    # a habit of at least half of three or more runs: a stroke test, and no "not the cause"
    habit = pipeline.recommended_action(small, (), (5, 7))
    assert "called sticky in 5 of its last 7 runs" in habit and "stroke-tested" in habit
    calm = pipeline.recommended_action(none, (), (3, 6))
    assert "shows no stiction, but the loop was called sticky in 3 of its last 6 runs" in calm
    assert "not the cause" not in calm


def test_a_narx_free_run_that_never_moves_is_said_to_stand_still():
    # an RMSE of a model output that stays put is the record's own swing: the report says so
    from diagnose.service.pipeline import NarxRun

    op = 50.0 + 2.0 * np.sin(np.arange(2000) / 40.0)
    sel = SimpleNamespace(model="narxsp_S2_J4", S=2.0, J=4.0, distance=0.0, robust=True, free_run_rmse=0.4)
    ident = SimpleNamespace(pct_per_op_unit=1.0, stiction=True, S_pct=2.0)
    still = SimpleNamespace(selection=sel, identification=ident, record=SimpleNamespace(op=op),
                            narx_run=NarxRun(np.full(2000, 49.9), None, 1.4, "mv"))
    blocks = report._narx_blocks(still, set(), set())
    said = [b[1] for b in blocks if b[0] == "p"]
    assert len(said) == 1 and "does not move in its free run" in said[0] and "stays at 49.9 %" in said[0]
    moving = SimpleNamespace(**{**vars(still), "narx_run": NarxRun(op - 0.5, None, 0.5, "mv")})
    assert not [b for b in report._narx_blocks(moving, set(), set()) if b[0] == "p"]


def test_the_history_figure_tells_hourly_records_apart(monkeypatch):
    from diagnose.service import figures as figs

    drawn = []
    monkeypatch.setattr(figs, "_png", lambda fig: drawn.append(fig) or b"png")
    rows = [{"data_end": f"2026-01-01T0{h}:49:59Z", "S_pct": 2.0 + 0.1 * h, "J_pct": 0.5, "stiction": 1,
             "sj_units": "% of span"} for h in (0, 1)]
    assert figs.history(rows) == b"png"
    ax = drawn[-1].axes[0]
    assert [t.get_text() for t in ax.get_xticklabels()] == ["2026-01-01 00:49", "2026-01-01 01:49"]
    assert ax.get_xlabel() == "record end (UTC)"
    days = [dict(r, data_end=f"2026-01-0{k + 1}T00:49:59Z") for k, r in enumerate(rows)]
    figs.history(days)
    assert [t.get_text() for t in drawn[-1].axes[0].get_xticklabels()] == ["2026-01-01", "2026-01-02"]
