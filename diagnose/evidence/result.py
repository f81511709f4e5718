"""The result every evidence test returns."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Mapping

STICTION = "stiction"
NO_STICTION = "no_stiction"
UNDETERMINED = "undetermined"
CANNOT_JUDGE = "cannot_judge"
DECISIONS = (STICTION, NO_STICTION, UNDETERMINED, CANNOT_JUDGE)


def _num(x: Any) -> float | None:
    """A plain finite float, or None (JSON has no NaN)."""
    if x is None:
        return None
    v = float(x)
    return v if math.isfinite(v) else None


@dataclass(frozen=True)
class Evidence:
    """What one non-invasive stiction test says about one record.

    Attributes
    ----------
    test : str
        Stable machine name of the test (``"horch_xcorr"``, ``"he_curve_fit"``, ...).
    value : float or None
        The test's index; None when the test cannot judge.
    threshold : float or None
        The value at (or beyond) which the test says ``stiction``. Tests with a grey zone also give
        ``extras["threshold_low"]``, at or below which they say ``no_stiction``.
    decision : str
        ``"stiction"``, ``"no_stiction"``, ``"undetermined"`` (the value lies in the test's grey
        zone, or the test's parts disagree) or ``"cannot_judge"`` (the test could not run on this
        record; ``reason`` says why).
    note : str
        One plain sentence for a control engineer: what the value means here, or why the test
        cannot judge.
    reason : str
        Machine-readable cause when ``decision == "cannot_judge"`` (``"too_short"``,
        ``"no_oscillation"``, ``"pv_unusable"``, ``"process_type_unknown"``, ...); empty otherwise.
    extras : mapping of str to float
        Secondary numbers (for example NGI and NLI, the apparent stiction in % of span). Read-only
        by convention.
    """

    test: str
    value: float | None
    threshold: float | None
    decision: str
    note: str
    reason: str = ""
    extras: Mapping[str, float] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.decision not in DECISIONS:
            raise ValueError(f"decision must be one of {DECISIONS}, got {self.decision!r}")
        object.__setattr__(self, "value", _num(self.value))
        object.__setattr__(self, "threshold", _num(self.threshold))
        clean = {str(k): _num(v) for k, v in dict(self.extras).items()}
        object.__setattr__(self, "extras", {k: v for k, v in clean.items() if v is not None})

    @property
    def judged(self) -> bool:
        """The test ran and gave stiction, no_stiction or undetermined."""
        return self.decision != CANNOT_JUDGE

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict: test, value, threshold, decision, note, reason and extras."""
        return {"test": self.test, "value": self.value, "threshold": self.threshold,
                "decision": self.decision, "note": self.note, "reason": self.reason,
                "extras": dict(self.extras)}


def graded(test: str, value: float, high: float, low: float, notes: Mapping[str, str],
           extras: Mapping[str, float] | None = None) -> Evidence:
    """The `Evidence` of a test with a grey zone: stiction at or above ``high``, no stiction at or
    below ``low``, undetermined between; ``notes`` gives the sentence for each of the three."""
    decision = STICTION if value >= high else NO_STICTION if value <= low else UNDETERMINED
    return Evidence(test, value, high, decision, notes[decision], extras=dict(extras or {}))


def cannot_judge(test: str, reason: str, note: str, threshold: float | None = None,
                 **extras: float) -> Evidence:
    """An `Evidence` that says the test could not run, and why."""
    return Evidence(test, None, threshold, CANNOT_JUDGE, note, reason, extras)
