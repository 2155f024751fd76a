"""The least-squares solvers of :func:`brdf_fit.fitting.single.fit` and the estimators every
fitting path shares: the optimistix solver classes by name (:data:`SOLVERS`, :func:`solve`),
the parameter covariance from a Jacobian or from normal equations (:func:`covariance`,
:func:`covariance_normal`; the estimators are described in :mod:`brdf_fit.fitting.single`),
and the sample-count buckets that let fits of nearby sizes share a compiled program
(:func:`bucket`).

Kept apart from :mod:`brdf_fit.fitting.single` so that the solvers built on these pieces
(:mod:`brdf_fit.fitting._lm`, :mod:`brdf_fit.fitting.chunked`) sit below ``fit()``, which
uses them.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping

import jax
import jax.numpy as jnp
import numpy as np

from brdf_fit.fitting.problem import FitProblem

__all__ = ["SOLVERS", "solve", "covariance", "covariance_normal", "bucket", "dense_bucket",
           "BUCKETS_PER_OCTAVE", "MIN_BUCKET", "SANDWICH", "LEVERAGE_FLOOR", "hc3_weights",
           "pinv_or_stand_in"]


def _quiet(*args, **kwargs):
    return None


_SOLVER_CLASSES: dict = {}


def _solver_classes() -> dict:
    """The solver classes, made on first use: optimistix (with lineax) is imported only when a
    solver is traced, not by a process that runs exported programs only
    (:mod:`brdf_fit.fitting._export`; 0.1-0.2 s of a warm ``brdf-fit fit``)."""
    if not _SOLVER_CLASSES:
        import optimistix as optx

        class LineSearchGaussNewton(optx.AbstractGaussNewton):
            """Gauss-Newton steps (``optx.NewtonDescent`` on the normal equations) globalised by
            a backtracking Armijo line search (Nocedal & Wright, *Numerical Optimization*, 2nd
            ed. 2006, algorithm 3.1 and section 10.3). Plain Gauss-Newton
            (``optx.GaussNewton``, step length 1) diverges from a start as far as alpha = 0.4
            for a truth of 0.23 in GGX fits (measured: it ran to the alpha = 1 bound); the line
            search keeps each step a descent step."""

            rtol: float
            atol: float
            norm: Callable = optx.max_norm
            descent: optx.NewtonDescent = optx.NewtonDescent()
            search: optx.BacktrackingArmijo = optx.BacktrackingArmijo()
            verbose: Callable = _quiet

        LineSearchGaussNewton.__module__ = __name__
        LineSearchGaussNewton.__qualname__ = "LineSearchGaussNewton"
        _SOLVER_CLASSES.update({
            "lm": optx.LevenbergMarquardt,
            "levenberg-marquardt": optx.LevenbergMarquardt,
            "gauss-newton": LineSearchGaussNewton,
            "gauss-newton-plain": optx.GaussNewton,
            "dogleg": optx.Dogleg,
        })
    return _SOLVER_CLASSES


class _Solvers(Mapping):
    """Solver name -> optimistix solver class; the names without importing optimistix."""

    _NAMES = ("lm", "levenberg-marquardt", "gauss-newton", "gauss-newton-plain", "dogleg")

    def __getitem__(self, name):
        if name not in self._NAMES:
            raise KeyError(name)
        return _solver_classes()[name]

    def __iter__(self):
        return iter(self._NAMES)

    def __len__(self):
        return len(self._NAMES)

    def __contains__(self, name):
        return name in self._NAMES


SOLVERS = _Solvers()


def __getattr__(name: str):
    if name == "LineSearchGaussNewton":
        return _solver_classes()["gauss-newton"]
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def solve(problem: FitProblem, u0, arrays, solver="lm", rtol=1e-10, atol=1e-10, max_steps=256,
          residuals=None):
    """Pure-JAX least-squares solve from ``u0``; returns ``(u, converged, steps)`` (``u`` is
    differentiable with respect to ``arrays`` by optimistix's implicit adjoint).
    ``residuals(u, arrays)``: the flat residual (default :meth:`FitProblem.residuals`)."""
    import optimistix as optx

    cls = SOLVERS[solver]
    res = problem.residuals if residuals is None else residuals
    sol = optx.least_squares(
        lambda u, a: res(u, a), cls(rtol=rtol, atol=atol), u0, args=arrays,
        max_steps=max_steps, throw=False,
    )
    return sol.value, sol.result == optx.RESULTS.successful, sol.stats["num_steps"]


#: The sandwich estimator of the standard errors of a fit without sigma (the residuals'
#: variance unknown and not constant): "HC3", ``(J^T J)^+ J^T diag(r_i^2 / (1 - h_i)^2) J
#: (J^T J)^+`` with the leverages ``h_i = J_i (J^T J)^+ J_i^T`` (MacKinnon and White, J.
#: Econometrics 29, 1985, their jackknife-derived estimator; named HC3 and recommended for
#: small samples by Long and Ervin, The American Statistician 54(3), 2000), or "HC1", ``m/(m - p)
#: (J^T J)^+ J^T diag(r^2) J (J^T J)^+`` (White 1980 with a degrees-of-freedom factor). A
#: residual of a sample that pulls the fit toward itself (high leverage: few samples per
#: parameter, a sample alone near the specular peak) understates that sample's noise, and HC1
#: takes it at face value: on two dozen directions with 2% noise its 95% intervals covered
#: GGX's and Beckmann's truth in 23.5-70.5% of 200 draws, HC3's in 87-98%
#: (benchmarks/results/coverage.md).
#: Only the chunked path of large data (fitting.chunked, at least 2^17 residuals: leverages
#: ~p/m, below 1e-4 on average) keeps HC1, which needs no second pass over the data.
SANDWICH = "HC3"
#: ``1 - h_i`` is held at least this far from 0 in HC3's weights: a sample with leverage 1
#: determines a direction of the parameters on its own and its residual is 0 to rounding
#: (0/0 otherwise); 1e-8 keeps such a term at rounding level (r^2 / 1e-16 with r ~ 1e-16)
LEVERAGE_FLOOR = 1e-8


def pinv_or_stand_in(A, xp=np):
    """``A^+``, or where ``A`` (p, p) is not finite the pseudo-inverse of the identity: a
    harmless stand-in, never an SVD of inf/NaN (numpy's pinv spun for 14+ minutes on one); the
    covariance made with it is NaN (:func:`covariance_normal`)."""
    finite = xp.all(xp.isfinite(A))
    return xp.linalg.pinv(xp.where(finite, A, xp.eye(A.shape[-1], dtype=A.dtype)))


def hc3_weights(r, h, xp=np):
    """HC3's per-residual factors ``r / (1 - h)`` (:data:`SANDWICH`): the meat is
    ``J^T diag(w^2) J``."""
    return r / xp.maximum(1.0 - h, LEVERAGE_FLOOR)


def covariance(J, r, m_eff, sandwich: bool):
    """Parameter covariance from the residual Jacobian ``J`` (m, p) and residuals ``r`` (m,) at
    the optimum, ``m_eff`` samples that carry weight (see the module docstring): ``sandwich=False``
    ``s^2 (J^T J)^+`` with ``s^2 = RSS/(m_eff - p)``; ``sandwich=True`` the :data:`SANDWICH`
    estimator (HC3, or HC1 ``m_eff/(m_eff - p) (J^T J)^+ (J^T diag(r^2) J) (J^T J)^+``). NumPy
    or JAX arrays (jit/vmap)."""
    xp = jnp if any(isinstance(x, jax.Array) for x in (J, r)) else np
    with np.errstate(invalid="ignore", over="ignore"):  # inf/NaN input: NaN out, as a flag
        A = J.T @ J
        if not sandwich:
            return covariance_normal(A, None, (r * r).sum(), m_eff)
        if SANDWICH == "HC1":
            Jr = J * r[:, None]
            return covariance_normal(A, Jr.T @ Jr, (r * r).sum(), m_eff)
        bread = pinv_or_stand_in(A, xp)
        h = xp.einsum("ip,pq,iq->i", J, bread, J)
        Jw = J * hc3_weights(r, h, xp)[:, None]
        return covariance_normal(A, Jw.T @ Jw, (r * r).sum(), m_eff, dof_factor=False,
                                 bread=bread)


def covariance_normal(A, meat, rss, m_eff, dof_factor: bool = True, bread=None):
    """:func:`covariance` from the normal-equation quantities: ``A = J^T J`` (p, p), the
    sandwich's ``meat = J^T diag(r^2) J`` (None: the pooled estimator) and ``rss = sum r^2``
    (what the batch solver computes without forming ``J``). ``dof_factor``: HC1's
    ``m_eff/(m_eff - p)`` on the sandwich (False: a meat already corrected, HC3's). ``bread``:
    :func:`pinv_or_stand_in` of ``A`` where the caller has it already (HC3's leverages)."""
    xp = jnp if any(isinstance(x, jax.Array) for x in (A, meat, rss)) else np
    p = A.shape[-1]
    dof = max(int(m_eff) - p, 1) if isinstance(m_eff, int) else xp.maximum(m_eff - p, 1)
    # non-finite input: NaN, never an SVD of inf/NaN (numpy's pinv spun for 14+ minutes on one)
    finite = xp.all(xp.isfinite(A)) & xp.all(xp.isfinite(rss))
    if meat is not None:
        finite = finite & xp.all(xp.isfinite(meat))
    if xp is np and not finite:
        return np.full(A.shape, np.nan)
    if xp is jnp:  # traced: the SVD runs on a harmless stand-in, the result is masked
        A = jnp.where(finite, A, jnp.eye(p, dtype=A.dtype))
        meat = None if meat is None else jnp.where(finite, meat, 0.0)
    bread = xp.linalg.pinv(A) if bread is None else bread
    factor = m_eff / dof if dof_factor else 1.0
    cov = rss / dof * bread if meat is None else factor * (bread @ meat @ bread)
    return cov if xp is np else jnp.where(finite, cov, jnp.nan)


#: sample counts are padded up to a bucket (:func:`bucket`) so that fits of data of nearby sizes
#: share one compiled solver: at most 1/BUCKETS_PER_OCTAVE (12.5%) more samples, and
#: BUCKETS_PER_OCTAVE shapes per doubling of the sample count (the chunked path of large data,
#: whose work grows with the padding: a whole MERL file)
BUCKETS_PER_OCTAVE = 8
#: the same for the dense path (data held whole: :func:`dense_bucket`), coarser: there a compile
#: (2-5 s on 2 cores) costs far more than up to 50% more samples (milliseconds), and with 8 per
#: octave a file of 90% of another's samples compiled 2 programs again (2.3 s;
#: benchmarks/bench_compiles.py, fit-again)
DENSE_BUCKETS_PER_OCTAVE = 2
#: no bucket is smaller than this
MIN_BUCKET = 64


def bucket(n: int, per_octave: int = BUCKETS_PER_OCTAVE) -> int:
    """The padded sample count of ``n`` samples (``n`` itself when it is a bucket): the next
    multiple of ``2**floor(log2 n) / per_octave`` (a power of 2)."""
    if n <= MIN_BUCKET:
        return MIN_BUCKET
    step = 2 ** max(int(math.floor(math.log2(n))) - int(math.log2(per_octave)), 0)
    return -(-n // step) * step


def dense_bucket(n: int) -> int:
    """:func:`bucket` of the dense path (:data:`DENSE_BUCKETS_PER_OCTAVE`)."""
    return bucket(n, DENSE_BUCKETS_PER_OCTAVE)
