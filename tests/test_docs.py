"""The notebook example of docs/api.md runs as written and gives what the page says."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def python_blocks(path: Path) -> list[str]:
    return re.findall(r"^```python\n(.*?)^```", path.read_text(encoding="utf-8"), flags=re.M | re.S)


def test_the_api_page_runs_as_a_notebook(tmp_path, monkeypatch):
    blocks = python_blocks(ROOT / "docs" / "api.md")
    assert len(blocks) >= 3
    (tmp_path / "sample_logs").symlink_to(ROOT / "sample_logs")
    monkeypatch.chdir(tmp_path)
    ns: dict = {}
    for i, code in enumerate(blocks):
        exec(compile(code, f"docs/api.md, python block {i + 1}", "exec"), ns)
    result, fic103 = ns["result"], ns["fic103"]
    # the values the page shows
    assert repr(result).startswith("Identification(loop='2411FIC20102', stiction=True, cls='deadband', S_pct=2.24,")
    assert (result.stiction, result.cls, round(result.S_pct, 2), result.J_pct) == (True, "deadband", 2.24, 0.0)
    assert result.narx.model == "narxsp_S2_J0" and result.narx.robust
    assert (fic103.method, fic103.cls, round(fic103.S_pct, 2), round(fic103.J_pct, 2)) == \
        ("op_mv", "undershoot", 5.0, 2.0)
    assert (tmp_path / "FIC103_trends.png").stat().st_size > 10_000
    assert [(r.name, r.n, r.ts_s) for r in ns["records"]][:2] == [("FIC101", 3000, 1.0), ("FIC102", 3000, 1.0)]
    assert ns["same"].method == "op_mv" and ns["berlin"].cls == fic103.cls
    assert ns["back"].n == ns["records"][0].n
    assert (round(ns["act"].travel_pct_per_day, -2), ns["act"].reversals_per_day) == (4400.0, 431.0)
    assert fic103.to_dict()["source"] is None and result.to_dict()["source"].endswith("dcs_2411FIC20102_stiction.txt")


def test_the_confidence_caps_the_pages_list_include_a_stem_that_never_moved():
    import numpy as np

    from diagnose.identification import identify
    from diagnose.simulate import sticky_loop

    rec = sticky_loop(3.0, 1.0, n=600, noise_std=0.02, load_walk_std=0.02, seed=2)
    stuck = identify(rec.replace(mv=np.full(rec.n, 50.0)), class_test=False)
    assert stuck.valve_not_moving and stuck.confidence == 0.7
    pages = {p: (ROOT / "docs" / p).read_text(encoding="utf-8") for p in ("verdict.md", "fitting.md", "tutorial.md")}
    for page, text in pages.items():
        caps = re.search(r"capped (?:where|when) the data (?:are weak|weaken it).*?\n\n", text, flags=re.S)
        assert caps and "valve_not_moving" in caps.group(0) and re.search(r"\b(0\.7|70 %)", caps.group(0)), page
