"""Lambertian (ideal diffuse) reflection.

J. H. Lambert, "Photometria, sive de mensura et gradibus luminis, colorum et umbrae", 1760.
``f = rho / pi``; directional albedo ``rho`` for every view direction; reciprocal; energy
conserving iff ``rho <= 1``. Sampled with the cosine-weighted hemisphere, so every sample's weight
is exactly ``rho``.
"""

from __future__ import annotations

import jax.numpy as jnp

from brdf_fit.core.numerics import INV_PI
from brdf_fit.core.params import Channels, bounded
from brdf_fit.core.validate import check_param
from brdf_fit.core.warp import cosine_hemisphere_pdf
from brdf_fit.models._base import AbstractBRDF, expand_channels
from brdf_fit.models._lobes import max_over_channels, sample_cosine


class Lambert(AbstractBRDF):
    """Ideal diffuse BRDF ``rho/pi`` (Lambert 1760). ``rho`` may be RGB."""

    rho: Channels = bounded(0.8, lo=0.0, hi=1.0, channels=True)

    def __check_init__(self):
        check_param("rho", self.rho, lo=0.0, owner="Lambert")

    def eval(self, wi, wo):
        ok = (wi[..., 2] > 0) & (wo[..., 2] > 0)
        ch = self.channels()
        return jnp.where(expand_channels(ok, ch), self.rho * INV_PI, 0.0)

    def pdf(self, wi, wo):
        return jnp.where(wo[..., 2] > 0, cosine_hemisphere_pdf(wi), 0.0)

    def sample(self, wo, uc, u):
        return sample_cosine(self, wo, u)

    def selection_hint(self):
        return max_over_channels(self.rho)
