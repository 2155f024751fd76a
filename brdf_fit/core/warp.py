"""Warps from the unit square to directions, as triples: ``sample_X(u)``, ``X_pdf(w)``,
``invert_X(w)`` (the inverse map, for stratification and tests).

``u`` has shape ``(..., 2)`` with values in [0, 1). Densities are per unit solid angle.
"""

from __future__ import annotations

import math

import jax.numpy as jnp

from brdf_fit.core.frame import join
from brdf_fit.core.numerics import safe_pow, safe_sqrt

INV_PI = 1.0 / math.pi
TWO_PI = 2.0 * math.pi


def sample_cosine_hemisphere(u):
    """Cosine-weighted hemisphere by the polar map (Malley's method with a polar disk map:
    smooth in ``u``, unlike the concentric map). ``p(w) = cos(theta)/pi``."""
    r = jnp.sqrt(u[..., 0])
    phi = TWO_PI * u[..., 1]
    z = safe_sqrt(1.0 - u[..., 0])
    return join(r * jnp.cos(phi), r * jnp.sin(phi), z)


def cosine_hemisphere_pdf(w):
    return jnp.maximum(w[..., 2], 0.0) * INV_PI


def invert_cosine_hemisphere(w):
    u0 = 1.0 - w[..., 2] ** 2
    u1 = jnp.mod(jnp.arctan2(w[..., 1], w[..., 0]), TWO_PI) / TWO_PI
    return jnp.stack([u0, u1], axis=-1)


def sample_uniform_hemisphere(u):
    """Uniform on the upper hemisphere, ``p = 1/(2 pi)``."""
    z = u[..., 0]
    r = safe_sqrt(1.0 - z * z)
    phi = TWO_PI * u[..., 1]
    return join(r * jnp.cos(phi), r * jnp.sin(phi), z)


def uniform_hemisphere_pdf(w):
    return jnp.where(w[..., 2] > 0, 0.5 * INV_PI, 0.0)


def sample_uniform_sphere(u):
    """Uniform on the sphere, ``p = 1/(4 pi)``."""
    z = 1.0 - 2.0 * u[..., 0]
    r = safe_sqrt(1.0 - z * z)
    phi = TWO_PI * u[..., 1]
    return join(r * jnp.cos(phi), r * jnp.sin(phi), z)


def uniform_sphere_pdf(w):
    return jnp.full(w.shape[:-1], 0.25 * INV_PI, dtype=w.dtype)


def sample_power_cosine(u, exponent):
    """Power-cosine lobe about +z: ``cos = u0^(1/(n+1))``, ``p(w) = (n+1)/(2 pi) max(0, z)^n``
    (Lafortune & Willems 1994, section 3). Returned in the lobe's own frame."""
    z = safe_pow(u[..., 0], 1.0 / (exponent + 1.0))
    r = safe_sqrt(1.0 - z * z)
    phi = TWO_PI * u[..., 1]
    return join(r * jnp.cos(phi), r * jnp.sin(phi), z)


def power_cosine_pdf(w, exponent):
    return (exponent + 1.0) * 0.5 * INV_PI * safe_pow(w[..., 2], exponent)
