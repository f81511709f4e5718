"""Established non-invasive stiction tests, each a plain function on OP/PV(/SP) arrays.

Every test returns an `Evidence` (index, threshold, decision, a sentence for the engineer, or
"cannot judge" and why); `run_all` runs them all on one record and never raises; `pv_usable` says
whether PV can be used or only OP (`op_shape`) can judge. Pure computation: no I/O.

Tests (see docs/evidence.md for formulas, thresholds and references):

* `horch_xcorr` - OP-PV cross-correlation, self-regulating loops (Horch 1999)
* `horch_integrating` - distribution of PV's second derivative, integrating loops (Horch 2000)
* `he_curve_fit` - triangle versus sinusoid fit of half-cycles (He et al. 2007)
* `choudhury_bicoherence` - NGI/NLI and apparent stiction (Choudhury et al. 2004, 2006, 2008)
* `kano_stuck` - stuck stretches ended by slips in the PV-OP path (after Kano et al. 2004)
* `yamashita_qsa` - qualitative shape share IS/DS (Yamashita 2006)
* `singhal_area` - area-peak ratio of the control error (Singhal and Salsbury 2005)
* `op_shape` - OP-only saw-tooth judgement, for when PV is unusable
"""

from .area_peak import singhal_area
from .bicoherence import choudhury_bicoherence
from .curve_fit import he_curve_fit
from .d2pdf import horch_integrating
from .op_shape import op_shape
from .qsa import yamashita_qsa
from .result import CANNOT_JUDGE, DECISIONS, NO_STICTION, STICTION, UNDETERMINED, Evidence
from .run import TESTS, pv_usable, run_all
from .stuck import kano_stuck
from .xcorr import horch_xcorr

__all__ = [
    "Evidence", "run_all", "pv_usable", "TESTS", "DECISIONS",
    "STICTION", "NO_STICTION", "UNDETERMINED", "CANNOT_JUDGE",
    "horch_xcorr", "horch_integrating", "he_curve_fit", "choudhury_bicoherence",
    "kano_stuck", "yamashita_qsa", "singhal_area", "op_shape",
]
