"""Lambertian (ideal diffuse) reflection.

J. H. Lambert, "Photometria, sive de mensura et gradibus luminis, colorum et umbrae", 1760.
``f = rho / pi``; directional albedo ``rho`` for every view direction; reciprocal; energy
conserving iff ``rho <= 1``. Sampled with the cosine-weighted hemisphere, so every sample's weight
is exactly ``rho``.
"""

from __future__ import annotations

import math

import jax.numpy as jnp

from brdf_fit.core.validate import check_param
from brdf_fit.core.warp import cosine_hemisphere_pdf, sample_cosine_hemisphere
from brdf_fit.models._base import AbstractBRDF, BRDFSample, sample_weight, expand_channels

INV_PI = 1.0 / math.pi


class Lambert(AbstractBRDF):
    """Ideal diffuse BRDF ``rho/pi`` (Lambert 1760). ``rho`` may be RGB."""

    rho: object = 0.8

    def __check_init__(self):
        check_param("rho", self.rho, lo=0.0, owner="Lambert")

    def eval(self, wi, wo):
        ok = (wi[..., 2] > 0) & (wo[..., 2] > 0)
        ch = self.channels()
        return jnp.where(expand_channels(ok, ch), self.rho * INV_PI, 0.0)

    def pdf(self, wi, wo):
        return jnp.where(wo[..., 2] > 0, cosine_hemisphere_pdf(wi), 0.0)

    def sample(self, wo, uc, u):
        wi = sample_cosine_hemisphere(u)
        pdf = self.pdf(wi, wo)
        return BRDFSample(wi=wi, pdf=pdf, weight=sample_weight(self, wi, wo, pdf))

    def selection_hint(self):
        return jnp.max(jnp.asarray(self.rho))
