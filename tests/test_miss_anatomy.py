"""The miss anatomy of the simulated benchmark (benchmarks/miss_anatomy.py) sorts misses by cause."""

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
try:
    import miss_anatomy as MA
finally:
    sys.path.pop(0)


def _row(true_class, cls, c_lin, c_fit, c_truth, n_eff=1000.0):
    return {"true_class": true_class, "class": cls, "c_lin": c_lin, "c_fit": c_fit, "c_truth": c_truth,
            "n_eff": n_eff}


def test_misses_are_sorted_by_what_the_costs_say():
    # the healthy loops set the floor: fit improvements 0.1 % .. 2.0 % and the flagged one's 3 %
    healthy = [_row("none", "none", 100.0, 100.0 - 0.1 * (k + 1), 100.0) for k in range(20)]
    flagged = _row("none", "deadband", 100.0, 97.0, 100.0)
    faint = _row("deadband", "none", 100.0, 99.5, 99.0)              # truth 1.0 % < floor
    visible = _row("deadband", "none", 100.0, 99.5, 95.0)            # truth 5 % > floor
    missed_valley = _row("undershoot", "deadband", 100.0, 90.0, 80.0)
    tie = _row("overshoot", "no_offset", 100.0, 90.0, 90.0005)       # 1000 ln(ratio) = 0.006
    wrong_shape = _row("deadband", "undershoot", 100.0, 90.0, 91.0)  # 1000 ln(ratio) = 11
    right = _row("no_offset", "no_offset", 100.0, 90.0, 90.0)
    rows = healthy + [flagged, faint, visible, missed_valley, tie, wrong_shape, right]
    summary = MA.classify(rows)
    assert summary["floor_pct"] == pytest.approx(np.percentile([0.1 * (k + 1) for k in range(20)] + [3.0], 95),
                                                 rel=1e-9)
    assert [r["why"] for r in rows[20:]] == ["false_alarm", "below_floor", "detectable", "search", "tie",
                                              "data_prefer_wrong", None]
    assert summary["misses"] == 6
    assert summary["by_cause_and_confusion"]["search"] == {"undershoot->deadband": 1}
