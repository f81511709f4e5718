"""NARX networks, the NARX-SP bank and the reproduction commands (issue 4).

Budgets are tiny so the file runs in well under a minute on two cores; the full-budget numbers are
in docs/narx.md and docs/_bench_narx.md.
"""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest
import torch

from diagnose.errors import DataError, NotFittedError
from diagnose.narx.bank import (MAP_J, MAP_S, bank_from_manifest, bank_grid, load_bank,
                                train_bank)
from diagnose.narx.metrics import cdc_pct, direction_agreement_pct, rmse_pct
from diagnose.narx.networks import NETWORKS, PAPER_NETWORKS, NarxNetwork, NarxSP, make_network
from diagnose.narx import protocol
from diagnose.narx.protocol import CASES, long_signal, make_dataset
from diagnose.service.cli import main
from diagnose.stiction_model import simulate_valve

torch.set_num_threads(1)

SMALL_SP = dict(epochs=150, restarts=4)


# --- metrics ---------------------------------------------------------------------------------
def test_rmse_and_cdc_by_hand():
    y = np.array([0.0, 0, 0, 1, 2, 2, 1, 1, 0, 0, 0, 0])
    yh = y.copy()
    yh[3] = 0.0           # missed a rise
    yh[6] = 3.0           # wrong direction (rise where it fell)
    assert rmse_pct(y, yh, start=0) == pytest.approx(np.sqrt((1 + 4) / 12))
    # true y changes at t = 3, 4, 6, 8; yhat-from-true-previous agrees at 4 and 8 only
    assert cdc_pct(y, yh, start=1) == pytest.approx(50.0)
    # three-way agreement over all 11 steps: wrong at t = 3 and 6
    assert direction_agreement_pct(y, yh, start=1) == pytest.approx(100 * 9 / 11)


def test_cdc_ignores_stuck_samples():
    y = np.array([0.0, 0, 0, 0, 1, 1, 1])
    yh = np.array([0.0, 5, -5, 5, 2, 9, 9])   # wild while stuck, right direction at the move
    assert cdc_pct(y, yh, start=1) == 100.0


# --- NARX-SP on the protocol -----------------------------------------------------------------
@pytest.mark.parametrize("case", ["undershoot", "overshoot"])
def test_narxsp_meets_protocol_targets_small_budget(case):
    ds = make_dataset(*CASES[case])
    net = NarxSP(seed=0, **SMALL_SP).fit(ds.x_train, ds.y_train, ds.x_val, ds.y_val)
    free = net.to_model_mode().free_run(ds.x_test, ds.y_test[:2])
    one = net.predict_one_step(ds.x_test, ds.y_test)
    assert rmse_pct(ds.y_test, free) <= 0.05
    assert rmse_pct(ds.y_test, one) <= 0.02
    assert cdc_pct(ds.y_test, free) >= 99.0


def test_narxsp_is_deterministic_and_roundtrips_its_state():
    ds = make_dataset(3.0, 3.0)
    a = NarxSP(seed=1, **SMALL_SP).fit(ds.x_train, ds.y_train, ds.x_val, ds.y_val)
    b = NarxSP(seed=1, **SMALL_SP).fit(ds.x_train, ds.y_train, ds.x_val, ds.y_val)
    np.testing.assert_array_equal(a.params_, b.params_)
    c = NarxNetwork.from_state(a.state())
    x = long_signal(3000)
    np.testing.assert_array_equal(a.free_run(x), c.free_run(x))


def test_model_mode_kernel_agrees_with_the_torch_network():
    # feeding the free run back in as "measured" outputs, predictor mode (torch, hard gates) must
    # reproduce it sample for sample: the compiled loop is the same network
    ds = make_dataset(3.0, 1.0)
    net = NarxSP(seed=0, **SMALL_SP).fit(ds.x_train, ds.y_train, ds.x_val, ds.y_val)
    x = long_signal(2000)
    free = net.free_run(x, (x[0], x[0]))
    np.testing.assert_allclose(net.predict_one_step(x, free), free, atol=1e-9)


def test_model_mode_long_run_on_unseen_input():
    ds = make_dataset(3.0, 1.0)
    net = NarxSP(seed=0, **SMALL_SP).fit(ds.x_train, ds.y_train, ds.x_val, ds.y_val)
    x = long_signal(10_000)
    y = simulate_valve(x, 3.0, 1.0, 1)
    assert rmse_pct(y, net.free_run(x, y[:2])) <= 0.1


# --- the six types behind one interface -------------------------------------------------------
TINY = {"ff": dict(epochs=60), "cascade": dict(epochs=60), "elman": dict(epochs=5, hidden=4),
        "lrn": dict(epochs=5, hidden=4), "narx": dict(epochs=5, window=10, stride=20),
        "narxsp": dict(epochs=40, restarts=2), "narxsp_mlp": dict(epochs=60)}


@pytest.mark.parametrize("kind", list(NETWORKS))
def test_every_network_type_shares_the_interface(kind):
    assert set(PAPER_NETWORKS) <= set(NETWORKS)
    x = 50 + 8 * np.sin(2 * np.pi * np.arange(400) / 80)
    y = simulate_valve(x, 3.0, 1.0, 1)
    net = make_network(kind, seed=0, **TINY[kind])
    with pytest.raises(NotFittedError, match="fit"):
        net.free_run(x)
    net.fit(x, y, x[:200], y[:200])
    one = net.predict_one_step(x, y)
    free = net.free_run(x, y[:2])
    assert one.shape == free.shape == x.shape
    assert np.all(np.isfinite(free)) and np.all(np.isfinite(one))
    np.testing.assert_array_equal(free[:2], y[:2])
    again = NarxNetwork.from_state(net.state()).free_run(x, y[:2])
    np.testing.assert_allclose(again, free, atol=1e-9)


def test_bad_inputs_raise_data_errors():
    with pytest.raises(DataError, match="unknown network"):
        make_network("transformer")
    net = make_network("ff", epochs=5)
    with pytest.raises(DataError, match="differ in shape"):
        net.fit(np.zeros(50), np.zeros(40))
    with pytest.raises(DataError, match="non-finite"):
        net.fit(np.r_[np.zeros(49), np.nan], np.zeros(50))
    with pytest.raises(DataError, match="barely moves"):
        NarxSP(epochs=5).fit(np.full(100, 50.0), np.full(100, 50.0))


# --- the shipped bank -------------------------------------------------------------------------
def test_shipped_bank_covers_the_plane_and_has_maps():
    bank = load_bank()
    assert len(bank) == len(bank_grid())
    assert {m.cls for m in bank.models} >= {"deadband", "undershoot", "no_offset", "overshoot"}
    assert max(m.S_pct for m in bank.models) >= 10.0
    for m in bank.models:
        assert m.robust_map.shape == (len(MAP_S), len(MAP_J))
        # the map at the model's own case is its own test-signal free-run error
        own, inside = m.map_rmse(m.S_pct, m.J_pct)
        assert inside
        if m.S_pct in MAP_S and m.J_pct in MAP_J:
            assert own == pytest.approx(m.metrics["rmse_free_run"], abs=1e-3)
        assert m.metrics["train_s"] <= 30.0
    # the protocol's four cases are bank cases; every bank model meets the free-run target on
    # the bank test signal
    for S, J in CASES.values():
        assert bank.select(S, J).distance == 0.0
    errs = [m.metrics["rmse_free_run"] for m in bank.models]
    assert max(errs) <= 0.05


def test_selection_contract_and_robustness_warning():
    bank = load_bank()
    sel = bank.select(3.2, 1.1)
    d = sel.to_dict()
    assert set(d) == {"model", "S", "J", "distance", "robust", "free_run_rmse"}
    assert (d["S"], d["J"]) == (3.0, 1.0)
    assert d["distance"] == pytest.approx(np.hypot(0.2, 0.1), abs=1e-4)
    assert d["robust"] is True and sel.warning() is None
    json.dumps(d)
    far = bank.select(4.0, 2.0)        # between bank cases, 1 % of span from the nearest
    w = far.warning()
    assert far.robust is False and w is not None and w.code.startswith("robustness")
    assert far.free_run_rmse > 0.5
    off = bank.select(40.0, 0.0)       # beyond the measured map
    assert off.robust is False and off.warning().code.startswith("robustness")
    with pytest.raises(DataError):
        bank.select(-1.0, 0.0)


def test_bank_free_run_tracks_the_plant_on_a_new_input():
    bank = load_bank()
    sel = bank.select(3.0, 1.0)
    x = long_signal(5000)
    y = simulate_valve(x, 3.0, 1.0, 1)
    yh = bank.free_run(sel, x, y[:2])
    assert rmse_pct(y, yh) <= 0.1
    # without the measured start the valve is assumed at rest at op[0]
    assert bank.free_run(sel, x).shape == x.shape


def test_import_is_cheap():
    code = ("import sys, diagnose.narx, diagnose.narx.bank; b = diagnose.narx.load_bank(); "
            "b.select(2.0, 1.0); sys.exit(1 if 'torch' in sys.modules else 0)")
    assert subprocess.run([sys.executable, "-c", code]).returncode == 0


# --- CLI --------------------------------------------------------------------------------------
def test_cli_bank_show_and_select(capsys):
    assert main(["bank", "show", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert len(out["models"]) == len(load_bank())
    assert main(["bank", "show"]) == 0
    assert "narxsp_S3_J1" in capsys.readouterr().out
    assert main(["bank", "select", "--S", "5", "--J", "8"]) == 0
    assert json.loads(capsys.readouterr().out)["narx"]["model"] == "narxsp_S5_J8"


def test_cli_bank_train_writes_a_loadable_bank(tmp_path, capsys):
    assert main(["bank", "train", "--cases", "3:1", "--out", str(tmp_path)]) == 0
    manifest = json.loads((tmp_path / "manifest.json").read_text())
    state = torch.load(tmp_path / "narxsp_S3_J1.pt", weights_only=True)
    bank = bank_from_manifest(manifest, {"narxsp_S3_J1": state})
    x = protocol.test_signal()
    y = simulate_valve(x, 3.0, 1.0, 1)
    assert rmse_pct(y, bank.free_run(bank.select(3, 1), x, y[:2])) <= 0.05
    assert main(["bank", "train", "--cases", "3-1", "--out", str(tmp_path)]) == 1
    assert "error: --cases" in capsys.readouterr().err


def test_cli_reproduce_model_mode_and_table1_json(tmp_path, capsys):
    assert main(["reproduce", "model-mode", "--json", "--steps", "3000", "--out", str(tmp_path)]) == 0
    res = json.loads(capsys.readouterr().out)
    assert res["model_mode"]["rmse_free_run"] <= 0.1
    assert (tmp_path / "narx_model_mode.png").stat().st_size > 1000
    assert main(["reproduce", "table1", "--json", "--seeds", "1", "--networks", "narxsp",
                 "--out", ""]) == 0
    rows = json.loads(capsys.readouterr().out)["table1"]
    assert {r["case"] for r in rows} == set(CASES)
    for r in rows:
        assert r["network"] == "narxsp"
        assert {"rmse_one_step", "rmse_free_run", "cdc"} <= set(r)
        assert r["rmse_free_run"] <= 0.05
    assert main(["reproduce", "table1", "--networks", "gpt"]) == 1
    assert "unknown network" in capsys.readouterr().err


def test_train_bank_returns_without_writing():
    manifest, states = train_bank([(1.0, 0.0)], epochs=60, restarts=2)
    assert list(states) == ["narxsp_S1_J0"]
    assert manifest["models"][0]["class"] == "deadband"
    assert manifest["robust_threshold_pct"] == 0.5


def test_conditional_network_learns_the_plane():
    from diagnose.narx.conditional import ConditionalNarxSP
    from diagnose.narx.protocol import bank_train_signal
    cases = []
    for S, J in [(1.0, 0.0), (3.0, 1.0), (2.0, 2.0), (1.0, 3.0), (5.0, 2.0)]:
        x = bank_train_signal(1500)
        cases.append((S, J, x, simulate_valve(x, S, J, 1)))
    net = ConditionalNarxSP(epochs=60).fit(cases)
    # an unseen plant between the training cases
    x = protocol.test_signal()
    y = simulate_valve(x, 2.5, 1.5, 1)
    assert rmse_pct(y, net.free_run(2.5, 1.5, x, y[:2])) <= 0.1
    with pytest.raises(NotFittedError):
        ConditionalNarxSP().free_run(1.0, 1.0, x)


def test_off_the_robustness_map_the_note_says_nothing_was_measured_there():
    sel = load_bank().select(MAP_S[-1] + 8.0, 0.0)
    note = sel.warning()
    assert not sel.robust and note is not None
    assert "outside the bank's robustness map" in note.message and "no free-run RMSE" in note.message
    assert "its free-run RMSE there is" not in note.message
    on_map = load_bank().select(6.0, 12.0)       # on the map, outside the model's robust region
    assert not on_map.robust and "its free-run RMSE there is about 2.29 % of span" in on_map.warning().message
