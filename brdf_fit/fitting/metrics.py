"""The residual metrics of a fit, per sample and channel (``f`` measured, ``m`` model,
``c = cos(theta_i)``); :mod:`brdf_fit.fitting.problem` re-exports these names.

**Residual metrics** (per sample and channel; ``f`` measured, ``m`` model, ``c = cos(theta_i)``):

``log``       ``ln(1 + m c) - ln(1 + f c)``  (J. Low, J. Kronander, A. Ynnerman, J. Unger, "BRDF
              models for accurate and efficient rendering of glossy surfaces", ACM TOG 31(1),
              2012, section 5: compresses the specular peak so the lobe shape counts)
``cuberoot``  ``cbrt(m) - cbrt(f)``  (a cube-root compression of the dynamic range)
``relative``  ``(m - f)/max(f, floor)``
``absolute``  ``m - f``

With per-sample ``sigma`` the residual is divided by the metric's first-order standard deviation
``g'(f) sigma`` (the delta method); otherwise it is multiplied by ``sqrt(weight)``.
``cos_weight`` multiplies by ``cos(theta_i)``.

**Robust metrics** (for data with outliers): the (weighted) ``log`` residual ``r``, then a
robust loss ``rho`` of scale ``s`` = :data:`ROBUST_SCALE` (in log units), written as the
residual ``sign(r) s sqrt(2 rho(r / s))`` so that least squares minimises ``sum s^2 rho(r/s)``
(the square-rooted robust residual of B. Triggs, P. McLauchlan, R. Hartley, A. Fitzgibbon,
"Bundle adjustment - a modern synthesis", Vision Algorithms 1999, LNCS 1883, section 4.3):

``huber``     ``rho(x) = x^2/2`` for ``|x| <= 1``, ``|x| - 1/2`` beyond (P. J. Huber, "Robust
              estimation of a location parameter", Ann. Math. Statist. 35(1), 1964): quadratic
              for the noise, linear for outliers
``cauchy``    ``rho(x) = log(1 + x^2)/2`` (the Cauchy or Lorentzian loss; Triggs et al., and
              M. J. Black & P. Anandan, CVIU 63(1), 1996): an outlier's pull vanishes as it grows

Their loss, rms and standard errors are those of the transformed residuals (the standard errors
the Gauss-Newton approximation of the robust loss, not a robust covariance). Not with
``sigma`` (the scale is in log units, a sigma-weighted residual is in standard deviations).
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from brdf_fit.core.validate import FitError

__all__ = [
    "METRICS", "METRIC_H", "ROBUST", "ROBUST_SCALE", "RELATIVE_FLOOR", "DATA_SCALE_FLOOR",
    "SIGMA_FLOOR", "metric_parts", "robust_residual",
]

METRICS = ("log", "cuberoot", "relative", "absolute", "huber", "cauchy")
#: robust metrics: name -> the metric whose residual the robust loss is applied to
ROBUST = {"huber": "log", "cauchy": "log"}
#: Scale ``s`` of the robust metrics in units of the (weighted) log residual
#: ``ln(1 + m c) - ln(1 + f c)``: 0.05, a 5% deviation of ``1 + f c``, is 5x the largest log
#: residual of 1% noise (the benchmarks' and the synthetic recipes' level) and far below a
#: corrupt sample (a value 1e6 where the model gives ~1: ~14).
ROBUST_SCALE = 0.05
#: Floor of the denominator of the relative metric, as a fraction of the data's largest value:
#: keeps near-zero measurements (dark tails) from dominating.
RELATIVE_FLOOR = 1e-3
#: Smallest data scale the relative floor is taken of (all-zero data would give a zero floor).
DATA_SCALE_FLOOR = 1e-300
#: Smallest ``g'(f) sigma`` a sigma-weighted residual is divided by (a sample with sigma = 0 and
#: positive weight would otherwise divide by zero); far below any measured standard deviation.
SIGMA_FLOOR = 1e-300


#: The metrics as ``g(m) = h(m * mul) - g(f)`` (see :func:`metric_parts`).
METRIC_H = {"log": jnp.log1p, "cuberoot": jnp.cbrt, "relative": lambda x: x,
            "absolute": lambda x: x, "huber": jnp.log1p, "cauchy": jnp.log1p}


def robust_residual(name, r, s=ROBUST_SCALE):
    """``sign(r) s sqrt(2 rho(r/s))`` for the robust metric ``name`` (module docstring):
    ``r`` itself for ``|r| <= s`` (huber) or to first order (cauchy); differentiable
    everywhere (the branches are guarded so no NaN reaches a derivative)."""
    x = r / s
    if name == "huber":
        big = jnp.abs(x) > 1.0
        a = jnp.where(big, jnp.abs(x), 1.0)
        return s * jnp.where(big, jnp.sign(x) * jnp.sqrt(2.0 * a - 1.0), x)
    if name == "cauchy":
        x2 = x * x
        small = x2 < 1e-8
        y = jnp.where(small, 1.0, x2)
        return s * x * jnp.where(small, 1.0 - 0.25 * x2, jnp.sqrt(jnp.log1p(y) / y))
    raise FitError(name)  # pragma: no cover - validated earlier


def metric_parts(name, f, c, sigma, w, floor, cos_weight, xp=np):
    """The residual metrics, data side: ``(mul, gf, scale)`` such that the residual of model
    values ``m`` is ``(h(m * mul) - gf) * scale`` with ``h`` = :data:`METRIC_H` [name] (log:
    ``h = log1p``, ``mul = cos``; cube root: ``h = cbrt``; relative: ``mul = 1/den``; absolute:
    identity), ``gf = h(f * mul)``, and ``scale`` the weight (``sqrt(w)``, or
    ``1/(g'(f) sigma)`` where ``w > 0``) times ``cos`` with ``cos_weight``; relative is
    evaluated as ``m/den - f/den``. fit() computes it inside its residual (differentiable with
    respect to the data); the batch solver once per call, so the data terms (for ``log``, half
    of the transcendental calls) are not recomputed at every iteration. ``f``, ``w`` (None:
    all 1), ``sigma`` (or None): (..., M, C); ``c``: (..., M, 1); ``floor``: (...,). ``mul``
    is (..., M, 1) except for ``relative`` (..., M, C); ``scale`` is None without weights,
    sigma and ``cos_weight``. ``xp``: numpy or jax.numpy."""
    if name in ROBUST:
        if sigma is not None:
            raise FitError(f"metric {name!r} is not for data with sigma (its scale "
                           f"{ROBUST_SCALE:g} is in log units); use 'log'")
        name = ROBUST[name]
    floor = xp.asarray(floor)[..., None, None]
    ones_c = xp.ones_like(c)
    if name == "log":
        mul = c
        gf = xp.log1p(f * c)
        dg = c / (1.0 + f * c)
    elif name == "cuberoot":
        mul, gf = ones_c, xp.cbrt(f)
        dg = 1.0 / (3.0 * xp.cbrt(xp.maximum(f, floor)) ** 2)
    elif name == "relative":
        den = xp.maximum(f, floor)
        mul = 1.0 / den
        gf, dg = f * mul, mul
    elif name == "absolute":
        mul, gf, dg = ones_c, f, xp.ones_like(f)
    else:  # pragma: no cover - validated earlier
        raise FitError(name)
    if sigma is not None:
        pos = xp.ones_like(f, dtype=bool) if w is None else w > 0
        scale = xp.where(pos, 1.0 / xp.maximum(dg * sigma, SIGMA_FLOOR), 0.0)
    elif w is not None:
        scale = xp.sqrt(w)
    else:  # no weights: no scale array (None), nothing to multiply at every iteration
        scale = c * xp.ones_like(f) if cos_weight else None
        return mul, gf, scale
    if cos_weight:
        scale = scale * c
    return mul, gf, scale
