"""The NARX-SP model bank: one gated NARX-SP network per (S, J) case, selection of the closest case,
and a measured robustness map per model.

Files (package data, read by `load_bank`): ``bank/manifest.json`` (cases, protocol, metrics, maps)
and one torch state file per model (``bank/<name>.pt``). Selection and the robustness verdict need
only the manifest; torch is imported only when a model is run (`Bank.free_run`, `Bank.network`).

Distance: Euclidean in the (S, J) plane, % of span: sqrt((S - S_b)^2 + (J - J_b)^2).
Robust region of a bank model: the (S, J) where its free-run RMSE against the stiction model on the
bank test signal is at most `ROBUST_RMSE_PCT` (0.5 % of span), measured on a 0.5 %-spaced grid
S = 0..12, J = 0..14 and interpolated bilinearly between grid points.
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import dataclass, field
from importlib import resources

import numpy as np

from ..errors import DataError
from ..notes import Note
from ..plain import number
from ..stiction_model import stiction_class
from .experiments import ROBUST_RMSE_PCT
from .metrics import cdc_pct, rmse_pct
from .protocol import SCORE_FROM, make_dataset, signal_scale, test_signal

BANK_VERSION = 1
MAP_S = tuple(np.round(np.arange(0.0, 12.0 + 1e-9, 0.5), 3))
MAP_J = tuple(np.round(np.arange(0.0, 14.0 + 1e-9, 0.5), 3))


def bank_grid() -> list[tuple[float, float]]:
    """The (S, J) cases of the shipped bank, % of span: S in {0.5, 1, 2, 3, 5, 7, 10} and for each
    J in {0 (deadband), S/3 (undershoot), S (no offset), min(3S, S+3) (overshoot)}."""
    cases = []
    for S in (0.5, 1.0, 2.0, 3.0, 5.0, 7.0, 10.0):
        for J in (0.0, round(S / 3.0, 3), S, min(3.0 * S, S + 3.0)):
            cases.append((S, float(J)))
    return cases


def model_name(S_pct: float, J_pct: float) -> str:
    return f"narxsp_S{S_pct:g}_J{J_pct:g}"


@dataclass(frozen=True)
class BankModel:
    """One manifest entry."""

    name: str
    S_pct: float
    J_pct: float
    cls: str
    file: str
    scale: float
    metrics: dict
    robust_map: np.ndarray = field(repr=False)      # (len(MAP_S), len(MAP_J)) free-run RMSE, %
    robust_radius_pct: float = 0.0

    def map_rmse(self, S_pct: float, J_pct: float) -> tuple[float, bool]:
        """Interpolated free-run RMSE at (S, J) and whether (S, J) lies on the measured grid."""
        s_grid, j_grid = np.asarray(MAP_S), np.asarray(MAP_J)
        inside = bool(s_grid[0] <= S_pct <= s_grid[-1] and j_grid[0] <= J_pct <= j_grid[-1])
        s = float(np.clip(S_pct, s_grid[0], s_grid[-1]))
        j = float(np.clip(J_pct, j_grid[0], j_grid[-1]))
        i = min(int(np.searchsorted(s_grid, s, side="right")) - 1, len(s_grid) - 2)
        k = min(int(np.searchsorted(j_grid, j, side="right")) - 1, len(j_grid) - 2)
        u = (s - s_grid[i]) / (s_grid[i + 1] - s_grid[i])
        v = (j - j_grid[k]) / (j_grid[k + 1] - j_grid[k])
        m = self.robust_map
        val = ((1 - u) * (1 - v) * m[i, k] + u * (1 - v) * m[i + 1, k]
               + (1 - u) * v * m[i, k + 1] + u * v * m[i + 1, k + 1])
        return float(val), inside


@dataclass(frozen=True)
class Selection:
    """The bank model chosen for an identified (S, J).

    Attributes
    ----------
    model : str
        The bank model's name (``narxsp_S3_J1``).
    S, J : float
        The selected model's training case, % of span.
    distance : float
        Euclidean distance from the identified (S, J) to the model's case, % of span.
    robust : bool
        Whether the model's measured free-run RMSE at the identified (S, J) is within
        ``threshold_pct``.
    free_run_rmse : float
        The model's measured (interpolated) free-run RMSE, % of span, for a plant at the
        identified (S, J).
    S_query, J_query : float
        The identified values, % of span.
    threshold_pct : float
        The robustness threshold, % of span (`ROBUST_RMSE_PCT`).
    """

    model: str
    S: float
    J: float
    distance: float
    robust: bool
    free_run_rmse: float
    S_query: float
    J_query: float
    threshold_pct: float = ROBUST_RMSE_PCT

    def to_dict(self) -> dict[str, str | float | bool]:
        """The ``"narx"`` object of `stiction identify`'s JSON."""
        return {"model": self.model, "S": self.S, "J": self.J, "distance": round(self.distance, 4),
                "robust": self.robust, "free_run_rmse": round(self.free_run_rmse, 4)}

    def warning(self) -> Note | None:
        """A ``robustness.outside_region`` note when the identified (S, J) is outside the model's
        robust region, else None."""
        if self.robust:
            return None
        if not (MAP_S[0] <= self.S_query <= MAP_S[-1] and MAP_J[0] <= self.J_query <= MAP_J[-1]):
            # beyond the map nothing was measured: its edge's value is no value "there"
            return Note("robustness.outside_region",
                        f"identified S={self.S_query:.2f} %, J={self.J_query:.2f} % lies outside the bank's "
                        f"robustness map (S {MAP_S[0]:g}-{MAP_S[-1]:g} %, J {MAP_J[0]:g}-{MAP_J[-1]:g} % of span), "
                        f"where no free-run RMSE of NARX-SP model {self.model} (trained for S={self.S:g} %, "
                        f"J={self.J:g} %) was measured; at the map's nearest edge it is "
                        f"{number(self.free_run_rmse)} % of span; treat its predictions as indicative only")
        return Note("robustness.outside_region",
                    f"identified S={self.S_query:.2f} %, J={self.J_query:.2f} % lies outside "
                    f"the robust region of NARX-SP model {self.model} (trained for "
                    f"S={self.S:g} %, J={self.J:g} %): its free-run RMSE there is about "
                    f"{number(self.free_run_rmse)} % of span, above {self.threshold_pct:g} %; "
                    f"treat its predictions as indicative only")


class Bank:
    """The NARX-SP model bank (see module docstring)."""

    def __init__(self, manifest: dict, models: list[BankModel], weights: dict | None = None):
        self.manifest = manifest
        self.models = models
        self._weights = weights or {}       # name -> state dict (in-memory banks)
        self._nets: dict = {}

    def __len__(self) -> int:
        return len(self.models)

    def select(self, S_pct: float, J_pct: float) -> Selection:
        """The model trained for the closest (S, J) (Euclidean, % of span); ties -> smaller S."""
        if not (math.isfinite(S_pct) and math.isfinite(J_pct)) or S_pct < 0 or J_pct < 0:
            raise DataError(f"S and J must be finite and >= 0 % of span, got S={S_pct}, J={J_pct}")
        if not self.models:
            raise DataError("the NARX bank is empty; rebuild it with `stiction bank train`")
        dist = [math.hypot(S_pct - m.S_pct, J_pct - m.J_pct) for m in self.models]
        i = int(np.argmin(dist))
        m = self.models[i]
        rmse, inside = m.map_rmse(S_pct, J_pct)
        robust = bool(inside and rmse <= ROBUST_RMSE_PCT + 1e-6)
        return Selection(m.name, m.S_pct, m.J_pct, float(dist[i]), robust, rmse,
                         float(S_pct), float(J_pct))

    def get(self, name: str) -> BankModel:
        for m in self.models:
            if m.name == name:
                return m
        raise DataError(f"no model {name!r} in the NARX bank; `stiction bank show` lists them")

    def network(self, name: str):
        """The fitted `NarxSP` network of one bank model (loads its weights; imports torch)."""
        if name not in self._nets:
            from .networks import NarxNetwork
            entry = self.get(name)
            state = self._weights.get(name)
            if state is None:
                import torch
                ref = resources.files("diagnose.narx").joinpath("bank", entry.file)
                with resources.as_file(ref) as path:
                    state = torch.load(path, weights_only=True)
            self._nets[name] = NarxNetwork.from_state(state)
        return self._nets[name]

    def free_run(self, selection: Selection | str, op_pct, mv0_pct=None) -> np.ndarray:
        """Model-mode prediction of the stem position (MV, % of span) for an OP series.

        ``mv0_pct``: the first two stem positions if known (default: the valve at rest at op[0]).
        """
        name = selection.model if isinstance(selection, Selection) else str(selection)
        op = np.asarray(op_pct, dtype=float)
        y_init = None if mv0_pct is None else np.asarray(mv0_pct, dtype=float)
        return self.network(name).free_run(op, y_init)


def _model_from_entry(e: dict) -> BankModel:
    return BankModel(e["name"], float(e["S"]), float(e["J"]), e["class"], e["file"],
                     float(e["scale"]), dict(e["metrics"]), np.asarray(e["robust_map"], dtype=float),
                     float(e.get("robust_radius_pct", 0.0)))


def bank_from_manifest(manifest: dict, weights: dict | None = None) -> Bank:
    if manifest.get("version") != BANK_VERSION:
        raise DataError(f"NARX bank manifest version {manifest.get('version')!r} is not "
                        f"{BANK_VERSION}; rebuild it with `stiction bank train`")
    return Bank(manifest, [_model_from_entry(e) for e in manifest["models"]], weights)


def load_bank() -> Bank:
    """The bank shipped in the package (diagnose/narx/bank/manifest.json + weights)."""
    ref = resources.files("diagnose.narx").joinpath("bank", "manifest.json")
    try:
        text = ref.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise DataError("the NARX bank manifest is missing from the package; rebuild it with "
                        "`stiction bank train`") from None
    return bank_from_manifest(json.loads(text))


# ------------------------------------------------------------------------------------------------
def robust_map(net, scale: float) -> np.ndarray:
    """Free-run RMSE (% of span) of a network against the stiction model at every (S, J) of the
    map grid, on the bank test signal with amplitude factor ``scale``."""
    from ..stiction_model import stiction_batch
    x = test_signal(scale=scale)
    Sg, Jg = np.meshgrid(np.asarray(MAP_S), np.asarray(MAP_J), indexing="ij")
    ys = stiction_batch(x, Sg.ravel(), Jg.ravel(), 1)
    out = np.empty(ys.shape[0])
    for i in range(ys.shape[0]):
        yh = net.free_run(x, ys[i, :2])
        out[i] = rmse_pct(ys[i], yh, SCORE_FROM)
    return out.reshape(Sg.shape)


def robust_radius(S_pct: float, J_pct: float, rmap: np.ndarray) -> float:
    """Largest r (on the grid) such that every map point within distance r of the model's case
    has free-run RMSE <= the threshold."""
    Sg, Jg = np.meshgrid(np.asarray(MAP_S), np.asarray(MAP_J), indexing="ij")
    dist = np.hypot(Sg - S_pct, Jg - J_pct)
    bad = dist[rmap > ROBUST_RMSE_PCT + 1e-6]
    return float(bad.min()) if bad.size else float(dist.max())


def train_bank_model(S_pct: float, J_pct: float, seed: int = 0, **kwargs) -> tuple[dict, dict]:
    """Train one bank model; returns (manifest entry, torch state)."""
    import torch

    from .networks import NarxSP
    torch.set_num_threads(1)
    scale = signal_scale(S_pct, J_pct)
    ds = make_dataset(S_pct, J_pct, scale=scale, bank=True)
    net = NarxSP(seed=seed, **kwargs).fit(ds.x_train, ds.y_train, ds.x_val, ds.y_val)
    one = net.predict_one_step(ds.x_test, ds.y_test)
    free = net.free_run(ds.x_test, ds.y_test[:2])
    rmap = robust_map(net, scale)
    name = model_name(S_pct, J_pct)
    entry = {"name": name, "S": S_pct, "J": J_pct, "class": stiction_class(S_pct, J_pct),
             "file": name + ".pt", "scale": scale,
             "metrics": {"rmse_one_step": rmse_pct(ds.y_test, one, SCORE_FROM),
                         "rmse_free_run": rmse_pct(ds.y_test, free, SCORE_FROM),
                         "cdc": cdc_pct(ds.y_test, free, SCORE_FROM),
                         "train_s": round(net.fit_time_s_, 3),
                         "theta_s": float(net.params_[0])},
             "robust_radius_pct": robust_radius(S_pct, J_pct, rmap),
             "robust_map": np.round(rmap, 4).tolist()}
    return entry, net.state()


def train_bank(cases=None, seed: int = 0, progress=None, **kwargs) -> tuple[dict, dict]:
    """Train every bank case; returns (manifest, {name: torch state}). No files are written."""
    cases = list(cases or bank_grid())
    entries, states = [], {}
    t0 = time.perf_counter()
    for i, (S, J) in enumerate(cases):
        entry, state = train_bank_model(float(S), float(J), seed, **kwargs)
        entries.append(entry)
        states[entry["name"]] = state
        if progress is not None:
            progress(i + 1, len(cases), entry)
    manifest = {
        "version": BANK_VERSION,
        "network": "narxsp (gated NARX-SP network, diagnose.narx.networks.NarxSP)",
        "protocol": {"plant": "two-parameter stiction model, f0=+1, at rest at x[0]",
                     "signals": "bank_train_signal (6000), bank_validation_signal (40000), "
                                "protocol test signal (2000); amplitudes x scale, "
                                "scale = max(1, (S+J)/8) (diagnose/narx/protocol.py)",
                     "score_from": SCORE_FROM, "seed": seed,
                     "training": "Adam + annealed gates, least-squares heads, slip threshold "
                                 "picked on validation free-run RMSE (docs/narx.md)"},
        "distance": "euclidean in (S, J), % of span",
        "robust_threshold_pct": ROBUST_RMSE_PCT,
        "map_S": list(MAP_S), "map_J": list(MAP_J),
        "train_total_s": round(time.perf_counter() - t0, 2),
        "models": entries,
    }
    return manifest, states
