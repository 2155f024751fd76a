"""Guarded elementary functions and the library's named epsilons.

Every function here keeps both the value *and* the gradient finite at its singular point with the
"double where" idiom: the unsafe input is replaced by a harmless one *before* the singular function
sees it, and the result is masked afterwards. A single ``jnp.where(mask, f(x), 0)`` is not enough:
JAX still differentiates ``f`` on the masked lanes, and ``0 * inf`` gives NaN in the gradient.

Epsilons (each named, each with its reason):

``SQRT_EPS``
    Below this the argument of :func:`safe_sqrt` is treated as 0 (value 0, gradient 0). 1e-30 is
    far below any squared length or cosine that matters in float32 (smallest normal 1.2e-38), yet
    large enough that ``1/sqrt(SQRT_EPS)`` = 1e15 stays finite in float32 gradients.
``NORM_EPS``
    Squared length below which a vector is considered to vanish in :func:`safe_normalize`. The half
    vector ``wi + wo`` vanishes only when ``wi == -wo``, i.e. both directions on the horizon at
    opposite azimuths; 1e-24 (length 1e-12) is far below any length produced by unit vectors with
    at least one cosine above ``COS_EPS``.
``COS_EPS``
    Cosines at or below 0 are below the horizon. Exactly-zero cosines are excluded (the BRDF is 0
    there by convention); no positive epsilon is added, so cos(theta) = 1e-7 is evaluated exactly.
``ALPHA_MIN``
    Microfacet roughness is clamped below at 1e-4 (the clamp of pbrt-v4's
    ``TrowbridgeReitzDistribution`` and Mitsuba 3's ``MicrofacetDistribution``): below it
    ``1/alpha^2`` exceeds 1e8 and D(n) overflows float32 products. The gradient is 0 below the
    clamp.
"""

from __future__ import annotations

import functools
import math

import jax
import jax.numpy as jnp

SQRT_EPS = 1e-30
NORM_EPS = 1e-24
COS_EPS = 0.0
ALPHA_MIN = 1e-4

#: ``1/pi``: Lambert's ``rho/pi`` and the cosine-hemisphere density ``cos/pi`` (defined once here).
INV_PI = 1.0 / math.pi
#: ``1/(2 pi)``: the power-cosine density ``(n+1)/(2 pi) cos^n``.
INV_TWO_PI = 0.5 / math.pi
TWO_PI = 2.0 * math.pi


def safe_sqrt(x, eps: float = SQRT_EPS):
    """``sqrt(max(x, 0))`` with a finite (zero) gradient where ``x <= eps``."""
    ok = x > eps
    xs = jnp.where(ok, x, 1.0)
    return jnp.where(ok, jnp.sqrt(xs), 0.0)


@jax.custom_jvp
def safe_hypot(x, y):
    """``sqrt(x^2 + y^2)`` without overflow/underflow of the squares (``jnp.hypot``), with a finite
    gradient (bounded by 1 in each argument; 0 at the origin).

    The derivative is defined directly as ``(x/h, y/h)``: JAX's own ``hypot`` differentiates
    through ``min/max`` ratios and forms ``y/x^2``, which overflows float32 for components below
    ~1e-19 and gave NaN at (1e-30, 0) (found by the Oren-Nayar hard cases)."""
    ok = (x != 0) | (y != 0)
    xs = jnp.where(ok, x, 1.0)
    return jnp.where(ok, jnp.hypot(xs, y), 0.0)


@safe_hypot.defjvp
def _safe_hypot_jvp(primals, tangents):
    x, y = primals
    dx, dy = tangents
    h = safe_hypot(x, y)
    ok = h > 0
    hs = jnp.where(ok, h, 1.0)
    # x/h and y/h are ratios of numbers of the same magnitude: no under/overflow
    cx = jnp.where(ok, x / hs, 0.0)
    cy = jnp.where(ok, y / hs, 0.0)
    return h, cx * dx + cy * dy


def safe_rsqrt(x, eps: float = SQRT_EPS):
    """``1/sqrt(x)`` where ``x > eps``; 0 elsewhere (value and gradient)."""
    ok = x > eps
    xs = jnp.where(ok, x, 1.0)
    return jnp.where(ok, 1.0 / jnp.sqrt(xs), 0.0)


def safe_div(a, b, eps: float = 0.0):
    """``a / b`` where ``|b| > eps``; 0 elsewhere (value and gradient).

    Written as ``a * (1/b)``: in reverse mode the cotangent of ``1/b`` is then ``ct * a`` before
    it meets ``-1/b^2``. With ``a / b`` JAX forms ``ct / b^2`` first, which overflows float32 for a
    large cotangent and a small ``b`` and turns ``inf * 0`` into NaN where ``a = 0`` (seen in the
    conductor Fresnel at eta = 1, cos = 1e-7 under a grazing GGX lobe of alpha = 1e-4).
    """
    ok = jnp.abs(b) > eps
    bs = jnp.where(ok, b, 1.0)
    return jnp.where(ok, a * (1.0 / bs), 0.0)


def safe_log(x, eps: float = 0.0):
    """``log(x)`` where ``x > eps``; 0 elsewhere (value and gradient). Callers mask the result."""
    ok = x > eps
    xs = jnp.where(ok, x, 1.0)
    return jnp.where(ok, jnp.log(xs), 0.0)


def safe_pow(x, n):
    """``x**n`` for ``x >= 0`` written as ``exp(n log x)``, 0 where ``x <= 0``.

    ``d/dn`` is ``x^n log x``, finite everywhere (0 at x = 0), unlike ``jnp.power`` whose
    derivative in n at x = 0 is ``0 * (-inf) = NaN``.
    """
    ok = x > 0
    xs = jnp.where(ok, x, 1.0)
    return jnp.where(ok, jnp.exp(n * jnp.log(xs)), 0.0)


def dot3(ax, ay, az, bx, by, bz):
    """Dot product written on components (kernels unpack vectors once, see DESIGN.md section 5)."""
    return ax * bx + ay * by + az * bz


def _inv_length(x, y, z, eps):
    l2 = x * x + y * y + z * z
    ok = l2 > eps
    return jnp.where(ok, 1.0 / jnp.sqrt(jnp.where(ok, l2, 1.0)), 0.0), ok


@functools.partial(jax.custom_jvp, nondiff_argnums=(3,))
def _normalize3(x, y, z, eps):
    inv, _ = _inv_length(x, y, z, eps)
    return x * inv, y * inv, z * inv


@_normalize3.defjvp
def _normalize3_jvp(eps, primals, tangents):
    """``dn = (dv - n (n.dv)) / |v|``: only the factor ``1/|v|``. Differentiating through
    ``l2 = |v|^2`` forms ``l2^(-3/2)`` (1.25e23 at |v| = 2e-8, the half vector of a grazing
    mirror pair), whose product with a large cotangent overflowed float32 and gave NaN
    gradients where the exact one is finite (issue 16)."""
    x, y, z = primals
    dx, dy, dz = tangents
    inv, _ = _inv_length(x, y, z, eps)
    nx, ny, nz = x * inv, y * inv, z * inv
    nd = nx * dx + ny * dy + nz * dz
    return (nx, ny, nz), ((dx - nx * nd) * inv, (dy - ny * nd) * inv, (dz - nz * nd) * inv)


def safe_normalize3(x, y, z, eps: float = NORM_EPS):
    """Normalise (x, y, z); returns ``(x, y, z, ok)`` with a zero vector and ``ok = False``
    where the squared length is ``<= eps`` (value and gradient finite; the gradient is the
    projection ``(I - n n^T)/|v|``, see :func:`_normalize3_jvp`)."""
    x, y, z = jnp.broadcast_arrays(x, y, z)
    _, ok = _inv_length(x, y, z, eps)
    nx, ny, nz = _normalize3(x, y, z, eps)
    return nx, ny, nz, ok


@jax.custom_jvp
def safe_norm3(x, y, z):
    """``sqrt(x^2 + y^2 + z^2)`` (the same expression, so the same value) with the derivative
    written as ``n.dv``, ``n = v/|v|`` (bounded by 1; 0 where the length is 0).

    Differentiating ``sqrt`` of the squared length forms ``1/(2 |v|)`` times the incoming
    cotangent *before* it meets ``2 v``: at the half vector of the grazing mirror pair
    ``wi = (-1, 0, 1e-8), wo = (1, 0, 1e-8)`` (``|v| = 2e-8``) that intermediate is 6e38 for
    Kelemen's ``D/|H|^2`` at alpha = 1e-4, past float32's 3.4e38, and ``inf * 0`` gave NaN
    gradients where the exact ones are finite (-2.4e31; issue 16). ``n`` is a ratio of numbers
    of the same magnitude: no overflow."""
    return jnp.sqrt(x * x + y * y + z * z)


@safe_norm3.defjvp
def _safe_norm3_jvp(primals, tangents):
    x, y, z = primals
    dx, dy, dz = tangents
    h = safe_norm3(x, y, z)
    ok = h > 0
    inv = jnp.where(ok, 1.0 / jnp.where(ok, h, 1.0), 0.0)
    return h, (x * inv) * dx + (y * inv) * dy + (z * inv) * dz


def safe_normalize(v, eps: float = NORM_EPS):
    """Normalise ``v`` of shape (..., 3); the zero vector where it vanishes."""
    x, y, z, _ = safe_normalize3(v[..., 0], v[..., 1], v[..., 2], eps)
    return jnp.stack([x, y, z], axis=-1)


def pow5(x):
    """``x**5`` by two multiplications and a square (cheap, and smooth at 0)."""
    x2 = x * x
    return x2 * x2 * x
