"""Fallback sampler shared by models without an analytic importance sampler (HTSG,
Beard-Maxwell): with probability ``p_cos`` the cosine hemisphere, otherwise a Beckmann NDF sample
``D(h) (n.h)`` of width ``alpha`` reflected about ``h``. The pdf is the exact mixture density

    p(wi) = p_cos cos(theta_i)/pi + (1 - p_cos) D(h) (n.h) / (4 wo.h)

(half-vector Jacobian, Walter et al. 2007, eq. 14), so the chi-square test applies unchanged.
"""

from __future__ import annotations

import jax.numpy as jnp

from brdf_fit.core.frame import join, split
from brdf_fit.core.microfacet import Beckmann, reflect_about
from brdf_fit.core.numerics import INV_PI, safe_div
from brdf_fit.core.warp import sample_cosine_hemisphere
from brdf_fit.models._base import BRDFSample
from brdf_fit.models._lobes import finish_sample, half_vector, sanitize


def cosine_beckmann_pdf(wi, wo, alpha, p_cos):
    """The mixture density above (0 unless both directions are above the horizon)."""
    (_, _, iz), (ox, oy, oz), (hx, hy, hz), hok = half_vector(wi, wo)
    dvh = ox * hx + oy * hy + oz * hz
    up = (iz > 0) & (oz > 0)
    lobe_ok = up & hok & (dvh > 0)
    D = Beckmann(alpha).D(hx, hy, hz)
    lobe = jnp.where(lobe_ok, D * safe_div(hz, 4.0 * dvh), 0.0)
    return jnp.where(up, p_cos * jnp.maximum(iz, 0.0) * INV_PI + (1.0 - p_cos) * lobe, 0.0)


def cosine_beckmann_sample(model, wo, uc, u, alpha, p_cos) -> BRDFSample:
    """Draw from the mixture (``uc < p_cos``: cosine); ``model.pdf`` must be
    :func:`cosine_beckmann_pdf` with the same ``alpha`` and ``p_cos``."""
    ox, oy, oz = split(wo)
    ok = oz > 0
    ox, oy, oz = sanitize(ok, ox, oy, oz)
    mx, my, mz = Beckmann(alpha).sample_normal(u[..., 0], u[..., 1])
    w_lobe = join(*reflect_about(ox, oy, oz, mx, my, mz))
    w_cos = sample_cosine_hemisphere(u)
    use_cos = uc < p_cos
    wi = jnp.where(use_cos[..., None], w_cos, w_lobe)
    ok = ok & (use_cos | ((ox * mx + oy * my + oz * mz) > 0))
    return finish_sample(model, wi, wo, ok)
