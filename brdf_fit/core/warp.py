"""Warps from the unit square to directions with their densities: ``sample_X(u)`` and ``X_pdf(w)``.

``u`` has shape ``(..., 2)`` with values in [0, 1). Densities are per unit solid angle. (The
power-cosine lobe about the mirror direction that the Phong family samples is in
:mod:`brdf_fit.models._lobes`.)
"""

from __future__ import annotations

import jax.numpy as jnp

from brdf_fit.core.frame import join
from brdf_fit.core.numerics import INV_PI, TWO_PI, safe_pow, safe_sqrt


def sample_cosine_hemisphere(u):
    """Cosine-weighted hemisphere by the polar map (Malley's method with a polar disk map:
    smooth in ``u``, unlike the concentric map). ``p(w) = cos(theta)/pi``."""
    r = jnp.sqrt(u[..., 0])
    phi = TWO_PI * u[..., 1]
    z = safe_sqrt(1.0 - u[..., 0])
    return join(r * jnp.cos(phi), r * jnp.sin(phi), z)


def cosine_hemisphere_pdf(w):
    return jnp.maximum(w[..., 2], 0.0) * INV_PI


def sample_power_cosine(u, exponent):
    """Power-cosine lobe about +z: ``cos = u0^(1/(n+1))``, ``p(w) = (n+1)/(2 pi) max(0, z)^n``
    (Lafortune & Willems 1994, section 3). Returned in the lobe's own frame."""
    z = safe_pow(u[..., 0], 1.0 / (exponent + 1.0))
    r = safe_sqrt(1.0 - z * z)
    phi = TWO_PI * u[..., 1]
    return join(r * jnp.cos(phi), r * jnp.sin(phi), z)
