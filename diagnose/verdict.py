"""The combined stiction verdict: every piece of evidence into one calibrated probability.

A record's evidence is a list of `diagnose.evidence.Evidence` rows: the established non-invasive
tests (cross-correlation, curve fitting, bicoherence, stuck segments, area-peak ratio, ...) and the
Hammerstein fit's own evidence (its improvement over a linear loop, the valve band against OP's
noise, the oscillation's regularity). Each row gives one number, its index. The combiner is a
logistic regression over those numbers:

    z_k = (clip(g_k(value_k), lo_k, hi_k) - center_k) / scale_k     (0 when the test cannot judge)
    p   = 1 / (1 + exp(-(intercept + sum_k coef_k z_k)))

with ``g_k`` the identity or ``log(1 + v)`` for ratios that span decades, so a test that cannot
judge contributes nothing and the verdict rests on what remains. Each test's weight is bounded to
its own direction (an index that says stiction can only push towards stiction), which keeps one
test's quirks on the training corpus from turning its evidence around. The
coefficients, the clipping range and the decision threshold are fitted on a labelled simulated
corpus of several friction laws and the classic false alarms (``benchmarks/train_verdict.py``)
and stored in ``verdict_model.json`` beside this module; docs/verdict.md lists them.

Three models are stored: ``full`` (OP and PV), ``op_mv`` (the stem position recorded too) and
``op_only`` (PV unusable: OP's shape alone), each with its own features and threshold. Between
0.5 and the threshold the fit's own decisive evidence settles the verdict (`fit_rule`). Nothing
here reads files except `load_model`, which reads the packaged JSON once.
"""

from __future__ import annotations

import functools
import json
import math
from dataclasses import dataclass, field
from importlib import resources
from typing import Any, Iterable, Mapping, Sequence

MODEL_FILE = "verdict_model.json"


@dataclass(frozen=True)
class Feature:
    """One input of the combiner: which evidence row and number it reads and how it is scaled.

    Attributes
    ----------
    name : str
        ``"<test>"`` for the row's index, ``"<test>.<extra>"`` for one of its extras.
    lo, hi : float
        The value is clipped to this range first (robust to one extreme index).
    center, scale : float
        Standardisation after clipping.
    coef : float
        Weight of the standardised value in the log-odds.
    log : bool
        Take ``log(1 + max(value, 0))`` before clipping (ratios that span decades).
    """

    name: str
    lo: float
    hi: float
    center: float
    scale: float
    coef: float
    log: bool = False

    def transform(self, value: float) -> float:
        return math.log1p(max(float(value), 0.0)) if self.log else float(value)

    def z(self, value: float | None) -> float:
        """The standardised input (0 when the value is missing: no evidence either way)."""
        if value is None or not math.isfinite(value):
            return 0.0
        v = min(max(self.transform(value), self.lo), self.hi)
        return (v - self.center) / self.scale if self.scale > 0 else 0.0


@dataclass(frozen=True)
class CombinerModel:
    """A fitted combiner (logistic regression over evidence values).

    Attributes
    ----------
    kind : str
        ``"full"``, ``"op_mv"`` or ``"op_only"``.
    features : tuple of Feature
    intercept : float
    threshold : float
        Probability at and above which the verdict is stiction.
    trained_on : str
        One line: the corpus the model was fitted on.
    fit_rule_floor : float or None
        Between this probability and ``threshold`` the fit's own decisive evidence breaks the tie
        (`fit_rule`): stiction when it holds. None: the threshold alone decides.
    """

    kind: str
    features: tuple[Feature, ...]
    intercept: float
    threshold: float
    trained_on: str = ""
    fit_rule_floor: float | None = None

    def contributions(self, values: Mapping[str, float | None]) -> dict[str, float]:
        """Each feature's term in the log-odds, ``coef * z``."""
        return {f.name: f.coef * f.z(values.get(f.name)) for f in self.features}

    def probability(self, values: Mapping[str, float | None]) -> float:
        """Probability of stiction for these feature values."""
        s = self.intercept + sum(self.contributions(values).values())
        return 1.0 / (1.0 + math.exp(-s)) if s > -700 else 0.0

    def to_dict(self) -> dict[str, Any]:
        return {"kind": self.kind, "intercept": self.intercept, "threshold": self.threshold,
                "trained_on": self.trained_on, "fit_rule_floor": self.fit_rule_floor,
                "features": [{"name": f.name, "lo": f.lo, "hi": f.hi, "center": f.center,
                              "scale": f.scale, "coef": f.coef, "log": f.log} for f in self.features]}

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> "CombinerModel":
        feats = tuple(Feature(str(f["name"]), float(f["lo"]), float(f["hi"]), float(f["center"]),
                              float(f["scale"]), float(f["coef"]), bool(f.get("log", False)))
                      for f in d["features"])
        floor = d.get("fit_rule_floor")
        return cls(str(d["kind"]), feats, float(d["intercept"]), float(d["threshold"]),
                   str(d.get("trained_on", "")), None if floor is None else float(floor))


def fit_rule(decisions: Mapping[str, str]) -> bool:
    """The Hammerstein fit's own decisive evidence, from each evidence row's decision by test name:
    a valve band clear of OP's noise, backed by a clear improvement over a linear loop, a sharply
    determined S or a deadband-shaped fit.

    On its own this rule calls a hard negative (compression, an external load) sticky too often;
    the combiner uses it only to settle records whose probability is near the threshold."""
    d = decisions
    return d.get("valve_band") == "stiction" and any(
        d.get(k) == "stiction" for k in ("model_fit", "band_sharpness", "deadband_fit"))


def feature_values(evidence: Iterable[Any]) -> dict[str, float | None]:
    """The numbers the combiner reads from evidence rows: each judged row's value and extras."""
    out: dict[str, float | None] = {}
    for ev in evidence:
        if ev.decision == "cannot_judge":
            continue
        out[ev.test] = ev.value
        for k, v in dict(ev.extras).items():
            out[f"{ev.test}.{k}"] = v
    return out


@functools.lru_cache(maxsize=1)
def _models() -> dict[str, CombinerModel]:
    text = resources.files(__package__).joinpath(MODEL_FILE).read_text(encoding="utf-8")
    return {k: CombinerModel.from_dict(v) for k, v in json.loads(text)["models"].items()}


def load_model(kind: str = "full") -> CombinerModel:
    """The packaged combiner of this kind (``"full"``, ``"op_mv"`` or ``"op_only"``)."""
    models = _models()
    if kind not in models:
        raise KeyError(f"no combiner model {kind!r} in {MODEL_FILE} (have {sorted(models)})")
    return models[kind]


@dataclass(frozen=True)
class Verdict:
    """The combined verdict on one record.

    Attributes
    ----------
    stiction_probability : float
        Calibrated probability that the valve sticks, 0..1.
    stiction : bool
        ``stiction_probability >= threshold``, or the fit's decisive evidence (`fit_rule`) with a
        probability of at least the model's ``fit_rule_floor``.
    threshold : float
    confidence : float
        Probability of the reported verdict (``p`` or ``1 - p``), lowered for weak data
        (OP-only judgement, compression, few usable tests).
    op_only : bool
        PV was unusable and only OP's shape was judged.
    contributions : mapping of str to float
        Each feature's term in the log-odds (positive: towards stiction).
    judged : tuple of str
        Tests that judged; ``cannot_judge`` lists the others.
    cannot_judge : tuple of str
    """

    stiction_probability: float
    stiction: bool
    threshold: float
    confidence: float
    op_only: bool = False
    contributions: Mapping[str, float] = field(default_factory=dict)
    judged: tuple[str, ...] = ()
    cannot_judge: tuple[str, ...] = ()
    by_fit_rule: bool = False


def combine(evidence: Sequence[Any], *, kind: str = "full", model: CombinerModel | None = None,
            confidence_cap: float = 1.0) -> Verdict:
    """Combine evidence rows into one `Verdict`.

    Parameters
    ----------
    evidence : sequence of Evidence
        Rows from `diagnose.evidence` and the fit (`fit_evidence`).
    kind : {"full", "op_mv", "op_only"}
        Which packaged model: OP and PV; OP, PV and the stem position; OP alone (PV unusable).
    model : CombinerModel, optional
        Use this model instead of the packaged one.
    confidence_cap : float
        Upper bound on the confidence (weak data: OP-only, compression).
    """
    m = model if model is not None else load_model(kind)
    op_only = m.kind == "op_only"
    values = feature_values(evidence)
    p = m.probability(values)
    stiction = p >= m.threshold
    by_rule = bool(not stiction and m.fit_rule_floor is not None and p >= m.fit_rule_floor
                   and fit_rule({ev.test: ev.decision for ev in evidence}))
    stiction = stiction or by_rule
    judged = tuple(ev.test for ev in evidence if ev.decision != "cannot_judge")
    missing = tuple(ev.test for ev in evidence if ev.decision == "cannot_judge")
    conf = p if stiction else 1.0 - p
    return Verdict(stiction_probability=p, stiction=bool(stiction), threshold=m.threshold,
                   confidence=float(min(conf, confidence_cap)), op_only=op_only,
                   contributions=m.contributions(values), judged=judged, cannot_judge=missing,
                   by_fit_rule=by_rule)
