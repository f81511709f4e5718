"""Stages working together through the CLI: identify's NARX-SP selection and robustness warning."""

import json

import pytest

from connectors.historian import write_wide
from diagnose.service.cli import main
from diagnose.simulate import sticky_loop

NARX_KEYS = {"model": str, "S": float, "J": float, "distance": float, "robust": bool, "free_run_rmse": float}


def _identify_json(tmp_path, capsys, S, J, seed):
    rec = sticky_loop(S, J, n=2500, noise_std=0.02, load_walk_std=0.01, seed=seed, name="FIC7")
    path = tmp_path / f"loop_{seed}.csv"
    write_wide(rec, path)
    capsys.readouterr()
    assert main(["identify", str(path), "--json"]) == 0
    out = capsys.readouterr().out
    return json.loads(out)


def test_identify_selects_the_closest_bank_model(tmp_path, capsys):
    d = _identify_json(tmp_path, capsys, 3.0, 1.0, seed=3)
    assert d["stiction"] is True
    narx = d["narx"]
    assert set(narx) == set(NARX_KEYS)
    for key, typ in NARX_KEYS.items():
        assert isinstance(narx[key], typ) or (typ is float and isinstance(narx[key], int)), key
    # the selected case is the nearest bank case to the identified (S, J)
    from diagnose.narx.bank import load_bank

    bank = load_bank()
    best = min(bank.models, key=lambda m: (m.S_pct - d["S"]) ** 2 + (m.J_pct - d["J"]) ** 2)
    assert narx["model"] == best.name
    assert narx["distance"] == pytest.approx(((best.S_pct - d["S"]) ** 2 + (best.J_pct - d["J"]) ** 2) ** 0.5,
                                             abs=1e-3)
    assert not any(w["code"].startswith("robustness") for w in d["warnings"]) or not narx["robust"]


def test_identify_warns_outside_the_robust_region(tmp_path, capsys):
    d = _identify_json(tmp_path, capsys, 9.0, 13.0, seed=4)
    assert d["narx"]["robust"] is False
    codes = [w["code"] for w in d["warnings"]]
    assert any(c.startswith("robustness") for c in codes)


def test_healthy_valve_has_no_bank_model(tmp_path, capsys):
    d = _identify_json(tmp_path, capsys, 0.0, 0.0, seed=5)
    assert d["stiction"] is False and d["class"] == "none"
    assert d["narx"] is None
    assert d["S"] == 0 and d["J"] == 0
