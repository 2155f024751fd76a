"""How a bounded parameter maps to the solver's unconstrained real line (:class:`Transform`:
a scaled logistic, a softplus, or the identity) and when a fitted value counts as sitting at
an end of its interval (:func:`at_bound`). Part of the fitting problem
(:mod:`brdf_fit.fitting.problem`, which re-exports these names).
"""

from __future__ import annotations

import dataclasses

import jax
import numpy as np

__all__ = ["Transform", "at_bound", "EDGE", "AT_BOUND_REL"]

#: Logistic/softplus inverses clip the normalised value to [EDGE, 1 - EDGE]: a start exactly on a
#: bound would map to +-inf.
EDGE = 1e-9
#: A fitted value this close to an interval end (relative to max(1, |bound|), or to the
#: interval's width where that is smaller) is reported as at its bound: there the
#: unconstrained solver has (almost) no gradient left, so the value is a limit, not an optimum
#: of the model, and its standard error describes nothing (e.g. an f0 channel pushed to 1).
#: 1e-4: a logistic parameter creeps towards its end ever more slowly (its slope t (1 - t)
#: vanishes); optimistix's LM stopped an f0 that wanted to exceed 1 at 1 - 1.4e-6 after 256
#: steps, batch-lm at 1 - 1e-16 (measured). Near an end the logistic's slope is about the
#: distance to it, whatever the width, so a wide interval does not widen the tolerance: relative
#: to the width alone, a Phong exponent of 6.3 in [0, 1e6] (the demo's fit) counted as at its
#: bound (tolerance 100) and, since issue 16, lost its standard error.
AT_BOUND_REL = 1e-4


@dataclasses.dataclass(frozen=True)
class Transform:
    """Map between a parameter's interval and the real line: ``[lo, hi]`` a scaled logistic,
    ``[lo, inf)`` ``lo + softplus``, ``(-inf, hi]`` ``hi - softplus(-u)``, unbounded the
    identity. Open and closed ends map alike (the solver never reaches an end)."""

    lo: float | None
    hi: float | None

    @classmethod
    def of(cls, interval) -> Transform:
        """The transform of anything with ``lo`` and ``hi`` (a registry ``Param``, an
        :class:`~brdf_fit.core.params.Interval`; None: unbounded)."""
        if interval is None:
            return cls(None, None)
        lo, hi = interval.lo, interval.hi
        return cls(None if lo is None else float(lo), None if hi is None else float(hi))

    def forward(self, u):
        if self.lo is not None and self.hi is not None:
            return self.lo + (self.hi - self.lo) * jax.nn.sigmoid(u)
        if self.lo is not None:
            return self.lo + jax.nn.softplus(u)
        if self.hi is not None:
            return self.hi - jax.nn.softplus(-u)
        return u

    def inverse(self, x):
        """NumPy inverse (start values); ``log(-expm1(-y)) + y`` is the stable inverse
        softplus."""
        x = np.asarray(x, float)
        if self.lo is not None and self.hi is not None:
            t = np.clip((x - self.lo) / (self.hi - self.lo), EDGE, 1 - EDGE)
            return np.log(t) - np.log1p(-t)
        if self.lo is not None:
            y = np.maximum(x - self.lo, EDGE)
            return y + np.log(-np.expm1(-y))
        if self.hi is not None:
            y = np.maximum(self.hi - x, EDGE)
            return -(y + np.log(-np.expm1(-y)))
        return x


def at_bound(param, value) -> np.ndarray:
    """Boolean array (shape of ``value``): which entries of a fitted value sit at an end of the
    interval of ``param`` (anything with ``lo`` and ``hi``: a :class:`Transform`, a registry
    ``Param``; see :data:`AT_BOUND_REL`)."""
    x = np.asarray(value, float)
    out = np.zeros(x.shape, bool)
    lo, hi = param.lo, param.hi
    scale = (hi - lo) if (lo is not None and hi is not None) else None
    for b in (lo, hi):
        if b is not None:
            near = max(1.0, abs(b))
            tol = AT_BOUND_REL * (min(scale, near) if scale is not None else near)
            out |= np.abs(x - b) <= tol
    return out
