"""The direct valve fit: the stiction model fitted on recorded OP -> stem position MV.

When the stem position is recorded, the valve can be fitted on its own: ``MV ~ offset + gain *
lag(valve(OP))``, with a small actuator lag and dead time (a positioner's response).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from .fit import ErrorSurface, HammersteinFit, SearchConfig, fit_hammerstein
from .search import GridConfig, ModelSpace


@dataclass(frozen=True)
class ValveFit:
    """Result of `fit_valve`: the stiction model fitted on recorded OP -> stem position MV.

    ``MV ~ offset_pct + gain * lag(valve(OP))`` with an actuator lag ``lag_s`` and dead time
    ``delay_s`` (a positioner's response), both small.
    """

    S_pct: float
    J_pct: float
    f0: int
    lag_s: float
    delay_s: float
    gain: float
    offset_pct: float
    ts_s: float
    rmse: float
    r2: float
    S_interval_pct: tuple[float, float]
    J_interval_pct: tuple[float, float]
    surface: ErrorSurface
    hammerstein: HammersteinFit

    def simulate(self, op_pct) -> np.ndarray:
        """Modelled stem position (% of span) for any OP series."""
        return self.hammerstein.simulate(op_pct)[1]

    @property
    def stiction_class(self) -> str:
        from .stiction_model import stiction_class
        return stiction_class(self.S_pct, self.J_pct)

    def to_dict(self) -> dict[str, Any]:
        return {"S_pct": self.S_pct, "J_pct": self.J_pct, "f0": self.f0, "lag_s": self.lag_s,
                "delay_s": self.delay_s, "gain": self.gain, "offset_pct": self.offset_pct,
                "rmse": self.rmse, "r2": self.r2, "S_interval_pct": list(self.S_interval_pct),
                "J_interval_pct": list(self.J_interval_pct)}


def fit_valve(op_pct, mv_pct, ts_s: float = 1.0, *, train=None, stiction: bool = True,
              max_lag_s: float | None = None, max_delay_s: float | None = None,
              free_gain: bool = False, surface: bool = True) -> ValveFit:
    """Fit the two-parameter valve model directly on OP -> recorded stem position MV.

    Parameters
    ----------
    op_pct, mv_pct : array (n,)
        Controller output and stem position, % of span.
    ts_s : float
        Sample period, seconds.
    train : slice or mask, optional
        Samples the fit may score.
    max_lag_s, max_delay_s : float, optional
        Largest actuator lag and dead time searched (default 5 and 3 samples).
    free_gain : bool
        Fit the stem's gain too (default: 1, OP and MV both in % of span; only an offset is
        fitted). A free gain lets a wrong (S, J) hide behind a smaller travel.
    surface : bool
        Compute the error surface and the intervals (False: point estimates only).
    """
    lag_hi = max_lag_s if max_lag_s is not None else 5.0 * ts_s
    space = ModelSpace(kinds=("foptd",), max_delay_s=max_delay_s if max_delay_s is not None else 3.0 * ts_s,
                       tau_range_s=(0.05 * ts_s, lag_hi), min_delay_s=0.0)
    # The stem position shows the valve itself: a dense global grid is affordable (the linear part
    # is only a small actuator lag) and needed (on clean data the optimum is a narrow valley).
    search = SearchConfig(grid=GridConfig(n_S=40, J_ratios=tuple(np.linspace(0.0, 2.0, 13)), both_f0=not free_gain))
    h = fit_hammerstein(op_pct, mv_pct, ts_s, train=train, stiction=stiction, hp_tau_s=None, load_order=0,
                        gain_fixed=None if free_gain else 1.0, surface=surface, space=space,
                        search=search)
    p = h.process
    return ValveFit(S_pct=h.S_pct, J_pct=h.J_pct, f0=h.f0, lag_s=p.tau_s, delay_s=p.delay_s,
                    gain=p.gain, offset_pct=p.bias, ts_s=h.ts_s, rmse=h.rmse, r2=h.r2,
                    S_interval_pct=h.S_interval_pct, J_interval_pct=h.J_interval_pct,
                    surface=h.surface, hammerstein=h)
