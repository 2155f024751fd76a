"""Closed-form conversions between Phong / Blinn-Phong exponents and microfacet widths.

Every function is named after what it converts, states what it matches and where it comes from,
and is never applied silently by a model. Exponents ``n`` are the Blinn-Phong exponent of
``cos^n(theta_h)`` unless the name says ``phong`` (the ``cos^n(alpha_r)`` lobe about the mirror
direction). Widths ``alpha`` are the microfacet ``alpha`` (not perceptual roughness; see
:func:`brdf_fit.roughness_to_alpha`).

Facts used below (each verified numerically in tests/test_phong.py):

* The normalised Blinn-Phong NDF ``D_p(m) = (n+2)/(2 pi) cos^n(theta_m)`` has its peak
  ``D_p(n) = (n+2)/(2 pi)``; Beckmann and GGX (isotropic) both have ``D(n) = 1/(pi alpha^2)``.
  The peaks are equal iff ``alpha^2 = 2/(n+2)``.
* Mean-square slope ``E[tan^2(theta_m)]`` under ``D(m)(n.m)``: Beckmann ``alpha^2``,
  Blinn-Phong ``2/n`` (``(n+2) Int_0^1 (1 - c^2) c^(n-1) dc``); GGX's is infinite (its slope
  distribution has heavy tails), so no GGX conversion can match it.
"""

from __future__ import annotations

import jax.numpy as jnp

__all__ = [
    "blinn_phong_to_beckmann_alpha",
    "beckmann_alpha_to_blinn_phong",
    "blinn_phong_to_beckmann_alpha_slope_moment",
    "beckmann_alpha_to_blinn_phong_slope_moment",
    "blinn_phong_to_ggx_alpha",
    "ggx_alpha_to_blinn_phong",
    "blinn_phong_to_ggx_roughness",
    "ggx_roughness_to_blinn_phong",
    "blinn_phong_to_phong_exponent",
    "phong_to_blinn_phong_exponent",
]


def blinn_phong_to_beckmann_alpha(n):
    """Beckmann width of a Blinn-Phong exponent: ``alpha_b = sqrt(2/(n+2))``.

    Source: B. Walter, S. Marschner, H. Li, K. Torrance, "Microfacet models for refraction through
    rough surfaces", EGSR 2007, section 5.2 ("alpha_p = 2 alpha_b^-2 - 2"). Matches ``D`` at
    normal incidence (``D(n)``, the peak) exactly, and the Gaussian small-angle limit
    ``cos^n(theta) ~ exp(-n theta^2/2)`` as ``n -> inf``. Also the mapping Mitsuba 0.6 uses for
    its Phong lobe (models.md 4.7).
    """
    return jnp.sqrt(2.0 / (jnp.asarray(n) + 2.0))


def beckmann_alpha_to_blinn_phong(alpha):
    """Inverse of :func:`blinn_phong_to_beckmann_alpha`: ``n = 2/alpha^2 - 2`` (Walter et al.
    2007, section 5.2). Negative for ``alpha > 1`` (no Blinn-Phong lobe is that wide)."""
    a = jnp.asarray(alpha)
    return 2.0 / (a * a) - 2.0


def blinn_phong_to_beckmann_alpha_slope_moment(n):
    """Beckmann width with the same mean-square microfacet slope: ``alpha = sqrt(2/n)``.

    Matches ``E[tan^2(theta_m)]`` under ``D(m)(n.m)`` (Beckmann ``alpha^2``, Blinn-Phong ``2/n``;
    derived here, verified by quadrature in the tests). Differs from Walter's mapping by
    ``O(1/n)``; infinite at ``n = 0``."""
    return jnp.sqrt(2.0 / jnp.asarray(n))


def beckmann_alpha_to_blinn_phong_slope_moment(alpha):
    """Inverse of :func:`blinn_phong_to_beckmann_alpha_slope_moment`: ``n = 2/alpha^2``."""
    a = jnp.asarray(alpha)
    return 2.0 / (a * a)


def blinn_phong_to_ggx_alpha(n):
    """GGX width with the same peak ``D(n)`` as the normalised Blinn-Phong NDF:
    ``alpha_g = sqrt(2/(n+2))`` (GGX also has ``D(n) = 1/(pi alpha^2)``).

    The same formula as Walter's Beckmann mapping, applied to GGX as commonly done in real-time
    engines (e.g. B. Karis, "Specular BRDF reference" blog post, 2013, which writes the
    Blinn-Phong D with ``n = 2/alpha^2 - 2`` next to GGX; UNVERIFIED: quoted from memory, the
    source text was not checked). Matches ``D`` at normal incidence only: GGX's tails are far
    heavier, so the lobes differ away from the peak."""
    return jnp.sqrt(2.0 / (jnp.asarray(n) + 2.0))


def ggx_alpha_to_blinn_phong(alpha):
    """Inverse of :func:`blinn_phong_to_ggx_alpha`: ``n = 2/alpha^2 - 2``."""
    a = jnp.asarray(alpha)
    return 2.0 / (a * a) - 2.0


def blinn_phong_to_ggx_roughness(n):
    """Perceptual GGX roughness ``r`` (``alpha = r^2``, Burley 2012) with the peak match of
    :func:`blinn_phong_to_ggx_alpha`: ``r = (2/(n+2))^(1/4)``.

    This is the "specular power to roughness" conversion quoted for engines using the Disney /
    UE4 ``alpha = roughness^2`` convention (B. Burley, SIGGRAPH 2012 course notes; B. Karis,
    SIGGRAPH 2013 course notes). UNVERIFIED as a quotation: derived here from the two cited
    definitions."""
    return (2.0 / (jnp.asarray(n) + 2.0)) ** 0.25


def ggx_roughness_to_blinn_phong(r):
    """Inverse of :func:`blinn_phong_to_ggx_roughness`: ``n = 2/r^4 - 2``."""
    r = jnp.asarray(r)
    r2 = r * r
    return 2.0 / (r2 * r2) - 2.0


def blinn_phong_to_phong_exponent(n_blinn):
    """Phong exponent (``cos^n(alpha_r)`` about the mirror direction) with about the same lobe as
    the Blinn-Phong ``cos^n(theta_h)``: ``n_phong = n_blinn/4``.

    Matches the lobes' Gaussian small-angle widths **at normal view**, where ``alpha_r = 2
    theta_h`` to first order, so ``cos^nb(theta_h) ~ exp(-nb theta_h^2/2) = exp(-(nb/4)
    alpha_r^2/2)``. A common rule of thumb (e.g. F. Giesen, "Phong and Blinn-Phong normalization
    factors", 2009, and Real-Time Rendering); UNVERIFIED as a quotation. Away from normal view the
    Blinn-Phong lobe is anisotropic and wider in the plane of incidence, so no single exponent
    matches it."""
    return jnp.asarray(n_blinn) / 4.0


def phong_to_blinn_phong_exponent(n_phong):
    """Inverse of :func:`blinn_phong_to_phong_exponent`: ``n_blinn = 4 n_phong``."""
    return 4.0 * jnp.asarray(n_phong)
