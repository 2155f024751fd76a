"""The hard-case grid every entry's ``finite`` check (:func:`brdf_fit.verify.checks.check_finite`)
and the tests' hard cases run on: direction pairs at extreme cosines (grazing to normal, in
generic position, along one azimuth, opposite azimuths where the half vector vanishes, wi ==
wo, the mirror pair, exactly on the horizon) and parameter sets at the hard values of the named
parameters (alpha to 1e-4, k to 100, exponents to 1e6) and at the interval ends of every other.
"""

from __future__ import annotations

import itertools
import math

import numpy as np

__all__ = ["HARD_COS", "HARD_PARAMS", "EDGE_OPEN_REL", "EDGE_UNBOUNDED_FACTOR", "unit_direction",
           "hard_case_directions", "hard_values", "edge_values", "hard_case_params"]


def unit_direction(cos, phi=0.3):
    """The unit vector of cosine ``cos`` to the normal (z) at azimuth ``phi``."""
    s = math.sqrt(max(0.0, 1.0 - cos * cos))
    return np.array([s * math.cos(phi), s * math.sin(phi), cos])


HARD_COS = (1e-7, 1e-4, 1e-2, 0.5, 1.0)
HARD_PARAMS = {
    "alpha": (1e-4, 1e-3, 0.05, 0.5, 1.0),
    "alpha_x": (1e-4, 1e-3, 0.05, 0.5, 1.0),
    "alpha_y": (1e-4, 0.05, 1.0),
    "eta": (1.0, 1.5, 1 / 1.5),
    "k": (0.0, 1.0, 100.0),
    "exponent": (0.0, 1.0, 100.0, 1e4, 1e6),
}


def hard_case_directions() -> tuple[np.ndarray, np.ndarray]:
    """Pairs: all cosine combinations in generic position, same azimuth, opposite azimuths
    (grazing pairs make the half vector vanish in the limit), wi == wo, wi == mirror(wo), and two
    exactly-on-horizon pairs (one with wi == -wo)."""
    wi, wo = [], []
    for ci, co in itertools.product(HARD_COS, HARD_COS):
        for pi_, po in ((0.3, 2.1), (1.0, 1.0), (0.0, math.pi)):
            wi.append(unit_direction(ci, pi_))
            wo.append(unit_direction(co, po))
    for c in HARD_COS:
        w = unit_direction(c, 0.7)
        wi += [w, w * np.array([-1.0, -1.0, 1.0])]
        wo += [w, w]
    wi += [np.array([1.0, 0.0, 0.0]), np.array([0.0, 0.0, 1.0])]
    wo += [np.array([-1.0, 0.0, 0.0]), np.array([1.0, 0.0, 0.0])]
    return np.asarray(wi), np.asarray(wo)


def hard_values(param, hard=None) -> tuple[float, ...]:
    """The hard values (``hard``, default ``HARD_PARAMS[param.name]``) of a registry parameter
    that lie in its valid interval, plus its finite upper bound when that is below the largest
    hard value (an exponent capped at 2048 is tested at 2048, not at 1e6)."""
    def inside(v):
        lo_ok = param.lo is None or (v > param.lo if param.lo_open else v >= param.lo)
        hi_ok = param.hi is None or (v < param.hi if param.hi_open else v <= param.hi)
        return lo_ok and hi_ok

    hard = HARD_PARAMS[param.name] if hard is None else hard
    vals = [v for v in hard if inside(v)]
    if param.hi is not None and not param.hi_open and param.hi < max(hard) and param.hi not in vals:
        vals.append(float(param.hi))
    return tuple(vals)


#: How close to an open interval end (relative to the interval's scale) the edge values go.
EDGE_OPEN_REL = 1e-4
#: An unbounded parameter is tested at ``EDGE_UNBOUNDED_FACTOR`` times its default (or at that
#: value when the default is 0).
EDGE_UNBOUNDED_FACTOR = 1e3


def edge_values(param) -> tuple[float, ...]:
    """The ends of a parameter's valid interval: closed finite ends as they are, open ends
    approached to :data:`EDGE_OPEN_REL` of the scale, unbounded ends at
    :data:`EDGE_UNBOUNDED_FACTOR` times the default. For parameters :data:`HARD_PARAMS` does not
    name (the catalogue's ``sigma``, ``nu``, ``tau``, lobe coefficients, ...)."""
    d = np.asarray(param.default_value(), float)
    dmax = float(np.max(np.abs(d))) if d.size else 1.0
    scale = (param.hi - param.lo) if (param.lo is not None and param.hi is not None) else \
        max(dmax, 1.0)
    vals = []
    if param.lo is not None:
        vals.append(param.lo + EDGE_OPEN_REL * scale if param.lo_open else param.lo)
    else:
        vals.append(-EDGE_UNBOUNDED_FACTOR * max(dmax, 1.0))
    if param.hi is not None:
        vals.append(param.hi - EDGE_OPEN_REL * scale if param.hi_open else param.hi)
    else:
        vals.append(EDGE_UNBOUNDED_FACTOR * (dmax if dmax > 0 else 1.0))
    return tuple(dict.fromkeys(float(v) for v in vals))


def hard_case_params(entry, hard=None) -> dict[str, np.ndarray]:
    """Parameter sets of the hard-case grid, stacked: the product of the hard values of the
    parameters :data:`HARD_PARAMS` (or ``hard``) names, then each other parameter at each of its
    :func:`edge_values` with the rest at their defaults (one at a time: a product over every
    parameter of a nine-parameter model would be thousands of sets)."""
    hard = HARD_PARAMS if hard is None else hard
    d = entry.defaults()
    names = [n for n in entry.param_names if n in hard]
    combos = list(itertools.product(*[hard_values(entry.param(n), hard[n]) for n in names])) or [()]
    sets = [{n: c[names.index(n)] if n in names else d[n] for n in entry.param_names}
            for c in combos]
    for n in entry.param_names:
        if n in names:
            continue
        for v in edge_values(entry.param(n)):
            sets.append({**{m: d[m] for m in entry.param_names}, n: v})
    grid = {}
    for name in entry.param_names:
        rows = [np.broadcast_to(np.asarray(s[name], float), d[name].shape) for s in sets]
        grid[name] = np.stack(rows) if rows else np.zeros((0, *d[name].shape))
    return grid
