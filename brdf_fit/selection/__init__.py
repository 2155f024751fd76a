"""Model selection (layer 6): the cheapest model that renders the data within an error budget.

:func:`select` fits every candidate in the error it is judged by, measures each candidate's
evaluation cost in the same run, and reports errors, AIC/BIC, costs, checks, the Pareto front and
the choice. It lives in :mod:`brdf_fit.selection.selector` (a module named ``select`` would be
shadowed by the function of the same name re-exported here).
"""

from brdf_fit.selection.anisotropy import AnisotropyTest, detect_anisotropy
from brdf_fit.selection.selector import (
    CEILING_ABOVE_NOISE,
    DEFAULT_CANDIDATES,
    ERROR_DEFINITION,
    FAMILIES,
    TARGETS,
    Candidate,
    Selection,
    exports_exactly,
    family_candidates,
    measure_cost,
    radiance_error,
    select,
    target_candidates,
)

__all__ = ["CEILING_ABOVE_NOISE", "DEFAULT_CANDIDATES", "ERROR_DEFINITION", "FAMILIES",
           "TARGETS", "AnisotropyTest", "Candidate", "Selection", "detect_anisotropy",
           "exports_exactly", "family_candidates", "measure_cost", "radiance_error", "select",
           "target_candidates"]
