"""Named, documented conversions between parameterisations (never applied silently)."""

from __future__ import annotations

import jax.numpy as jnp


def roughness_to_alpha(r):
    """Perceptual roughness ``r`` to the microfacet width ``alpha = r^2`` (B. Burley, "Physically
    based shading at Disney", SIGGRAPH 2012 course notes, section 5.4; the glTF 2.0
    metallic-roughness convention). Note pbrt-v4's ``RoughnessToAlpha`` uses ``sqrt(r)``."""
    return jnp.asarray(r) ** 2


def alpha_to_roughness(alpha):
    """Inverse of :func:`roughness_to_alpha`: ``r = sqrt(alpha)``."""
    return jnp.sqrt(jnp.asarray(alpha))
