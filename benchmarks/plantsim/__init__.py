"""plantsim: an independent closed-loop plant simulator for validating stiction diagnostics.

It shares no code with `diagnose/` (the project's own simulator and valve model): its friction
laws, process discretisation, controllers, noise and historian artifacts are written apart, so a
method tuned on the project's simulator can be checked against plants it has not seen.

Public API
----------
`corpus(seed, n_per_kind, ...)` -> iterator of `SimLoop`: a labelled corpus (sticky valves under
three friction laws, healthy loops and the classic false alarms; ``definition="identifiable"``
redraws records a plant would not produce or whose stiction cannot show). `concealed(effect, seed, ...)`
and `concealed_set(seed, n_per_effect, ...)`: sticky loops with one piece of missing physics
hidden in them. `write_loops(loops, out_dir)` writes wide CSV files and ``labels.csv``.
Command line: ``python -m benchmarks.plantsim --out DIR --seed S --n-per-kind N``.
See docs/plantsim.md.
"""

from .concealed import EFFECTS, concealed, concealed_set
from .export import write_loops
from .record import CLASSES, SimLoop, stiction_class
from .scenarios import DEFINITIONS, SCENARIOS, STICKY_SCENARIOS, corpus, make_loop

__all__ = ["SimLoop", "corpus", "make_loop", "concealed", "concealed_set", "write_loops", "SCENARIOS",
           "STICKY_SCENARIOS", "DEFINITIONS", "CLASSES", "EFFECTS", "stiction_class"]
