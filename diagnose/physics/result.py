"""What `explain` returns: typed, frozen results; `Explanation.to_dict` is the JSON object that
`stiction explain --json` prints."""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields, replace
from types import MappingProxyType
from typing import Any, Mapping

import numpy as np

from .locate import Mismatch, MismatchArrays
from .model import Structure

#: what the RMSEs of each stage measure
TARGETS = {"loop": "pv", "valve": "mv"}


def _num(v: float | None) -> float | None:
    """A float for JSON: NaN and infinities become None."""
    if v is None:
        return None
    v = float(v)
    return v if math.isfinite(v) else None


def _clean(obj: Any) -> Any:
    """Numbers of a nested JSON-ready structure made strict: NaN and infinities -> None."""
    if isinstance(obj, dict):
        return {str(k): _clean(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_clean(v) for v in obj]
    if isinstance(obj, (bool, np.bool_)):
        return bool(obj)
    if isinstance(obj, (int, np.integer)):
        return int(obj)
    if isinstance(obj, (float, np.floating)):
        return _num(obj)
    return obj


@dataclass(frozen=True)
class ExplainWarning:
    """Something the data cannot tell apart, or a data-quality finding passed through.

    ``code``: ``physics.<what>`` (indistinguishable, ambiguous, entrained, sub_sample, unexplained,
    valve_idle) or ``data_quality.<finding>``; ``message``: one or two sentences.
    """

    code: str
    message: str

    def to_dict(self) -> dict[str, str]:
        return {"code": self.code, "message": self.message}


@dataclass(frozen=True)
class HypothesisResult:
    """One tested hypothesis on one stage.

    Attributes
    ----------
    name : str
    params : mapping str -> float
        The fitted physical parameters, units in the names (read-only).
    heldout_rmse : float
        Held-out RMSE of its posterior-predictive mean, target units.
    accepted : bool
        Whether it passed every acceptance rule.
    stage : {"loop", "valve"}
    train_rmse : float
        Training RMSE of the fitted parameter set.
    reduction : float
        Held-out RMSE reduction against the reference (0.3: 30 % lower).
    delta_bic, train_delta_bic : float
        Held-out and training BIC differences against the reference (negative: better).
    n_extra : int
        Parameters added to the plain model.
    refused : str
        The first acceptance rule it failed, in words; empty when accepted.
    evidence : {"heldout", "training"}
        What it was judged on: the held-out part, or (a friction step inside the training part,
        after which the valve is the plain valve the held-out part confirms) the training part.
    """

    name: str
    params: Mapping[str, float]
    heldout_rmse: float
    accepted: bool
    stage: str
    train_rmse: float
    reduction: float
    delta_bic: float
    n_extra: int
    train_delta_bic: float = float("nan")
    refused: str = ""
    evidence: str = "heldout"

    def __post_init__(self) -> None:
        object.__setattr__(self, "params", MappingProxyType({str(k): float(v) for k, v in self.params.items()}))

    @property
    def target(self) -> str:
        """``pv`` (loop stage) or ``mv`` (valve stage): what the RMSEs measure."""
        return TARGETS[self.stage]

    def to_dict(self) -> dict[str, Any]:
        return {"name": self.name, "params": {k: _num(v) for k, v in self.params.items()},
                "heldout_rmse": _num(self.heldout_rmse), "accepted": bool(self.accepted),
                "stage": self.stage, "target": self.target, "train_rmse": _num(self.train_rmse),
                "heldout_reduction": _num(self.reduction), "delta_bic": _num(self.delta_bic),
                "train_delta_bic": _num(self.train_delta_bic),
                "n_extra_params": int(self.n_extra), "refused": self.refused, "evidence": self.evidence}


@dataclass(frozen=True)
class OtherStage:
    """A stage that was run but not reported: its baseline's and reference's held-out RMSE (its
    target's units) and the hints of its localisation."""

    stage: str
    baseline_rmse: float
    reference_rmse: float
    hints: tuple[str, ...]

    def to_dict(self) -> dict[str, Any]:
        return {"baseline_rmse": self.baseline_rmse, "reference_rmse": self.reference_rmse,
                "hints": list(self.hints)}


@dataclass(frozen=True, eq=False)
class StageMismatch(Mismatch):
    """Where the plain model misses on the reported stage: the localisation (`locate.Mismatch`) of
    the better-trained plain model's residual (``located_on``: ``reference`` or ``baseline``), and
    the stage's split and reference error."""

    located_on: str = ""
    stage: str = ""
    train_fraction: float = float("nan")
    heldout_start_s: float = float("nan")
    reference_rmse: float = float("nan")
    other_stages: tuple[OtherStage, ...] = ()

    @classmethod
    def of(cls, m: Mismatch, **kw) -> "StageMismatch":
        return cls(**{f.name: getattr(m, f.name) for f in fields(Mismatch)}, **kw)

    def to_dict(self) -> dict[str, Any]:
        d = super().to_dict()
        d.update({"located_on": self.located_on, "stage": self.stage, "train_fraction": self.train_fraction,
                  "heldout_start_s": self.heldout_start_s, "reference_rmse": self.reference_rmse})
        if self.other_stages:
            d["other_stages"] = {o.stage: o.to_dict() for o in self.other_stages}
        return d


@dataclass(frozen=True, eq=False)
class StageModels:
    """The plain models of one stage: the baseline (``baseline_source`` says where it came from)
    and the reference (the plain model refit by explain's searches; on the loop stage their grid
    may choose another process family)."""

    stage: str
    baseline: Structure
    reference: Structure
    baseline_source: str


@dataclass(frozen=True, eq=False)
class FigureData:
    """Arrays of the reported stage for the figure (`diagnose.physics.figures`): times (s), the
    recorded target and the baseline's, reference's and improved model's simulations, their
    residuals (``residual_located``: of the model the localisation ran on), OP and the simulated
    stem (%), the training part's start and end (s), the located windows, the localisation's own
    arrays (``mismatch``: window RMS, the profile after slips, RMS by OP bin, the residual's
    spectrum), the RMS by direction, the limit cycle's period and the slip times (s)."""

    t_s: np.ndarray
    observed: np.ndarray
    baseline: np.ndarray
    reference: np.ndarray
    improved: np.ndarray
    residual_baseline: np.ndarray
    residual_located: np.ndarray
    residual_improved: np.ndarray
    located_on: str
    op_pct: np.ndarray
    stem_hat_pct: np.ndarray
    train_start_s: float
    train_end_s: float
    windows: tuple[tuple[float, float], ...]
    mismatch: MismatchArrays
    direction_rms: tuple[float, float]
    limit_cycle_period_s: float | None
    slip_t_s: np.ndarray
    units: str


@dataclass(frozen=True, eq=False)
class Explanation:
    """Result of `explain`.

    Attributes
    ----------
    missing_physics : str or None
        Name of the accepted hypothesis, None when the baseline is good enough or nothing helps.
    baseline_rmse, improved_rmse : float
        Held-out RMSE of the baseline and of the named model (equal when None), in the target's
        units (PV units on the loop stage, % of span on the valve stage).
    hypotheses : tuple of HypothesisResult
        Every tested hypothesis, in registry order.
    mismatch : StageMismatch
        Where the plain model misses on the reported stage.
    explanation : str
        A few sentences for an engineer.
    warnings : tuple of ExplainWarning
    target : {"pv", "mv"}
        What the reported RMSEs measure.
    loop : str
        The record's name.
    baseline_source : str
        Where the reported stage's baseline came from (`diagnose.physics.baseline.SOURCES`).
    arrays : FigureData
        Figure data (`figure_data` returns it as a dict for the drawing code).
    stages : tuple of StageModels
        The plain models of every stage that was run.
    """

    missing_physics: str | None
    baseline_rmse: float
    improved_rmse: float
    hypotheses: tuple[HypothesisResult, ...]
    mismatch: StageMismatch
    explanation: str
    warnings: tuple[ExplainWarning, ...]
    target: str
    loop: str
    baseline_source: str
    arrays: FigureData = field(repr=False)
    stages: tuple[StageModels, ...] = field(default=(), repr=False)

    def to_dict(self) -> dict[str, Any]:
        """The JSON object of `stiction explain --json` (strict JSON: no NaN)."""
        return _clean({
            "loop": self.loop,
            "missing_physics": self.missing_physics,
            "baseline_rmse": self.baseline_rmse,
            "improved_rmse": self.improved_rmse,
            "target": self.target,
            "baseline_source": self.baseline_source,
            "hypotheses": [h.to_dict() for h in self.hypotheses],
            "mismatch": self.mismatch.to_dict(),
            "explanation": self.explanation,
            "warnings": [w.to_dict() for w in self.warnings],
        })

    def with_warnings(self, first: tuple[ExplainWarning, ...]) -> "Explanation":
        """The same explanation with ``first`` before its own warnings (e.g. how the file was read)."""
        return replace(self, warnings=tuple(first) + self.warnings)

    def __repr__(self) -> str:
        return (f"Explanation(loop={self.loop!r}, missing_physics={self.missing_physics!r}, "
                f"target={self.target!r}, baseline_rmse={self.baseline_rmse:.4g}, "
                f"improved_rmse={self.improved_rmse:.4g}, hypotheses={len(self.hypotheses)}, "
                f"warnings={len(self.warnings)})")

    def _repr_html_(self) -> str:
        import html

        e = html.escape
        change = (1.0 - self.improved_rmse / self.baseline_rmse) if self.baseline_rmse > 0 else 0.0
        rows = [("Missing physics", self.missing_physics or "none named"),
                ("Held-out RMSE", f"{self.baseline_rmse:.4g} plain model, {self.improved_rmse:.4g} named "
                                  f"model ({change:.0%} lower), in "
                                  + ("PV units" if self.target == "pv" else "% of span")),
                ("Explanation", self.explanation)]
        for h in self.hypotheses:
            verdict = "accepted" if h.accepted else (f"refused: {h.refused}" if h.refused else "not accepted")
            rows.append((f"{h.name} ({h.stage})", f"held-out RMSE {h.heldout_rmse:.4g}, {verdict}"))
        body = "".join(f"<tr><th style='text-align:left'>{e(k)}</th><td style='text-align:left'>{e(v)}</td></tr>"
                       for k, v in rows)
        warn = "".join(f"<li><code>{e(w.code)}</code> {e(w.message)}</li>" for w in self.warnings)
        return (f"<div><strong>Missing physics in {e(self.loop)}</strong><table>{body}</table>"
                + (f"<p>Warnings:</p><ul>{warn}</ul>" if warn else "") + "</div>")

    def plot(self):
        """The report's missing-physics figure as a new matplotlib `Figure`."""
        from .figures import draw_explanation

        title = f"{self.loop}: missing physics: {self.missing_physics or 'none named'}"
        return draw_explanation(self.figure_data(), title=title, figsize=(8.0, 6.5))

    def figure_data(self) -> dict[str, Any]:
        """The figure's arrays as a dict: the fields of `FigureData`, those of its `MismatchArrays`
        in place of ``mismatch``, ``target`` and ``missing_physics``."""
        a = {f: getattr(self.arrays, f) for f in self.arrays.__dataclass_fields__ if f != "mismatch"}
        m = self.arrays.mismatch
        a.update({f: getattr(m, f) for f in m.__dataclass_fields__})
        a["target"] = self.target
        a["missing_physics"] = self.missing_physics
        return a
