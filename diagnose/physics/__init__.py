"""Missing physics: locate where the baseline model and the recording disagree, name the effect the
model left out, fit a model that has it, and show the held-out error fall.

Public API: `explain(record, **opts) -> Explanation`, the hypothesis `REGISTRY` (`register` to add
one), `locate`, and in `diagnose.physics.plant` the simulator parts that hide each effect; the
concealed-data generator is `diagnose.physics.concealed.concealed_loop`.
"""

from .explain import explain
from .hypotheses import REGISTRY, Fitted, PhysicsHypothesis, PlainModel, register
from .locate import Mismatch, locate
from .result import ExplainWarning, Explanation, HypothesisResult, StageMismatch

__all__ = ["Explanation", "HypothesisResult", "explain", "REGISTRY", "Fitted", "PhysicsHypothesis",
           "PlainModel", "register", "Mismatch", "locate", "ExplainWarning", "StageMismatch"]
