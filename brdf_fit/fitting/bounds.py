"""Optima on a parameter's bound, for the dense fit (:mod:`brdf_fit.fitting.single`).

A parameter whose best value is an end of its interval (a dielectric's metallic = 0, an albedo
the data push past 1) approaches it along the plateau of its logistic or softplus transform,
by a roughly constant step in the unconstrained variable each iteration: optimistix's step test
never passes, and such fits ran their 256 steps and said "did not converge". When a solve stops
with entries at a bound (:func:`brdf_fit.fitting.problem.at_bound`), :func:`onto_plateau` moves
them far onto their plateau (their Jacobian column then vanishes and the solver's step in them is
~0) and the same compiled solver goes on; the result counts as converged only where the
Karush-Kuhn-Tucker sign condition holds (:func:`inward_gradient_free`), or, failing the solver's
own test, where :func:`converged_at_bounds` finds the other entries converged with the bound
ones held. Whether or not the solver converged, an entry at a bound that the loss pulls inward
(a start on a bound stalls there as well: the solver's step test passes in it at once) is
released just inside (:func:`release_inward`) and the solver goes on. The chunked path has its
own counterpart (:func:`brdf_fit.fitting.chunked.converged_at_bounds`; it releases nothing).
"""

from __future__ import annotations

import numpy as np

from brdf_fit.fitting import _lm

__all__ = ["EXACT_RMS_EPS", "PLATEAU_U", "RELEASE_T", "converged_at_bounds", "flat_bounds",
           "inward_gradient_free", "onto_plateau", "release_inward"]


#: where :func:`onto_plateau` puts an entry at its bound, in the unconstrained variable: the
#: logistic's or softplus's slope there is ~4e-18, so its Jacobian column vanishes and the
#: damped step in it is ~0 (optimistix's step test then passes for it)
PLATEAU_U = 40.0
#: a fit whose residual rms is at most this many float eps reproduces its data to rounding
#: (the model's own noise-free values: rms 1e-13 of a log residual, 2.2e-16 eps): a global
#: minimum, whatever the signs of a gradient made of rounding errors say
EXACT_RMS_EPS = 1e4
#: where :func:`release_inward` puts an entry the loss pulls off its bound: this fraction of its
#: interval inside it (logistic u = +-13.8, slope 1e-6): inside :data:`AT_BOUND_REL`'s band (1e-4),
#: so an optimum that near the bound is still reported at it, yet the Jacobian column is 1e12
#: times larger than on the plateau, so the solver moves it
RELEASE_T = 1e-6


def flat_bounds(layout, n: int):
    """Per flat entry: the interval ends (+-inf where open)."""
    lo, hi = np.full(n, -np.inf), np.full(n, np.inf)
    for tr, sl in zip(layout.transforms, layout.slices, strict=True):
        lo[sl] = -np.inf if tr.lo is None else tr.lo
        hi[sl] = np.inf if tr.hi is None else tr.hi
    return lo, hi


def onto_plateau(layout, u, flat_phys):
    """``u`` with each entry at an end of its interval moved to ``-+PLATEAU_U`` (the end it is
    at)."""
    x = np.asarray(flat_phys, float)
    lo, hi = flat_bounds(layout, x.size)
    bound = layout.at_bound(layout.split(x))
    at_lo = np.abs(x - lo) <= np.abs(x - hi)
    return np.where(bound, np.where(at_lo, -PLATEAU_U, PLATEAU_U), u)


def _pulled_inward(layout, x, J, r):
    """Per flat entry: whether it sits at an end of its interval and the loss falls by moving it
    inward (its physical gradient ``J^T r`` points inward beyond MINPACK's gtol test of
    orthogonality to the residual); None where ``J`` or ``r`` is not finite."""
    if not (np.all(np.isfinite(J)) and np.all(np.isfinite(r))):
        return None
    lo, hi = flat_bounds(layout, x.size)
    g = J.T @ r
    gtol = _lm.GTOL_SQRT_EPS * np.sqrt(np.finfo(J.dtype).eps) * np.sqrt(
        float(r @ r) * np.sum(J * J, axis=0))
    at_lo = np.abs(x - lo) <= np.abs(x - hi)
    inward_helps = np.where(at_lo, g < -gtol, g > gtol)  # d loss / dx < 0 going up from lo
    return layout.at_bound(layout.split(x)) & inward_helps


def inward_gradient_free(layout, flat_phys, J, r) -> bool:
    """Whether no entry at an end of its interval would lower the loss by moving inward: the
    physical gradient ``J^T r`` points outward there, or is orthogonal to the residual to
    rounding (MINPACK's gtol test). The Karush-Kuhn-Tucker sign condition of a bound optimum."""
    x = np.asarray(flat_phys, float)
    if not layout.at_bound(layout.split(x)).any():
        return True
    pulled = _pulled_inward(layout, x, J, r)
    return pulled is not None and not bool(pulled.any())


def release_inward(layout, u, flat_phys, J, r):
    """``u`` with each entry at an end of its interval whose loss falls inward (the test of
    :func:`inward_gradient_free` failing for it) moved off the plateau to :data:`RELEASE_T` of
    its interval inside (a bounded entry) or :data:`RELEASE_T` past a one-sided bound; ``None``
    where no entry is such. Measured need: a Cycles-rendered coat, coat weight 1 set, whose
    float32 rendering puts the optimum 1e-5 below 1; the plateau then held it where the loss
    still fell inward and the fit said "did not converge" at the right answer."""
    x = np.asarray(flat_phys, float)
    pulled = _pulled_inward(layout, x, J, r)
    if pulled is None or not pulled.any():
        return None
    lo, hi = flat_bounds(layout, x.size)
    at_lo = np.abs(x - lo) <= np.abs(x - hi)
    width = np.where(np.isfinite(hi - lo), hi - lo, 1.0)
    inside = np.where(at_lo, lo + RELEASE_T * width, hi - RELEASE_T * width)
    u_in = layout.inverse(layout.split(inside))
    return np.where(pulled, u_in, np.asarray(u, float))


def converged_at_bounds(layout, flat_phys, J, r, rtol: float, atol: float) -> bool:
    """Whether a dense solve that stopped without converging is at a constrained optimum (the
    dense counterpart of :func:`brdf_fit.fitting.chunked.converged_at_bounds`): some entries sit
    at an end of their interval (:func:`brdf_fit.fitting.problem.at_bound`), the loss does not
    decrease by moving any of them inward (the sign of its physical gradient ``J^T r``, or a
    gradient orthogonal to the residual as MINPACK's gtol test puts it), and with them held,
    the undamped Gauss-Newton step of the others passes the convergence test
    (:func:`brdf_fit.fitting._lm.newton_converged`'s test, in the physical parameters). A
    parameter whose optimum is its bound
    (a dielectric's metallic = 0) approaches it along the logistic's plateau, by a constant
    step in the unconstrained variable each iteration, so optimistix's step test never passes:
    a Principled fit of a plain plastic ran its 256 steps and said "did not converge"."""
    x = np.asarray(flat_phys, float)
    bound = layout.at_bound(layout.split(x))
    if not bound.any() or not (np.all(np.isfinite(J)) and np.all(np.isfinite(r))):
        return False
    if r.size and np.sqrt(np.mean(r * r)) <= EXACT_RMS_EPS * np.finfo(J.dtype).eps:
        return True  # the data reproduced to rounding: a global minimum (the sign test is noise)
    if not inward_gradient_free(layout, x, J, r):
        return False
    cost = 0.5 * float(r @ r)
    free = ~bound
    if not free.any():
        return True
    Jf = J[:, free]
    gf = Jf.T @ r
    try:  # newton_converged's test, in NumPy (an eager JAX call compiles its operations)
        dn = -np.linalg.solve(Jf.T @ Jf, gf)
    except np.linalg.LinAlgError:
        return False
    if not np.all(np.isfinite(dn)):
        return False
    decrement = -0.5 * float(gf @ dn)
    if (np.max(np.abs(dn) / (atol + rtol * np.abs(x[free]))) < 1.0
            and decrement < atol + rtol * cost):
        return True
    # at the rounding floor (batch-lm's ROUNDING_FLOOR): no step can lower the loss by one
    # rounding unit of it; a minimum if the residual is orthogonal to the columns (gtol)
    eps = float(np.finfo(J.dtype).eps)
    cosine = np.abs(gf) / np.maximum(np.sqrt(np.sum(Jf * Jf, axis=0) * 2.0 * cost), 1e-300)
    return bool(decrement <= _lm.ROUNDING_FLOOR * eps * cost
                and np.max(cosine) < _lm.GTOL_SQRT_EPS * np.sqrt(eps))
