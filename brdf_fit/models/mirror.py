"""Smooth mirror: a delta lobe.

``f(wi, wo) = F(n.wo) delta(wi - r(wo)) / (n.wi)`` with ``r(wo) = (-x, -y, z)`` (law of reflection;
Fresnel 1823 for F). A delta cannot be evaluated pointwise: ``eval`` and ``pdf`` return 0 for every
pair of directions, and ``is_delta`` is True so that quadrature-based checks treat it separately.
``sample`` returns the mirror direction with ``pdf = 1`` (a discrete probability, the convention
of pbrt-v4's specular BxDFs) and ``weight = F(n.wo)``, which is also the directional albedo.
Reciprocal; energy conserving iff ``F <= 1``.
"""

from __future__ import annotations

from typing import ClassVar

import jax.numpy as jnp

from brdf_fit.core.frame import mirror
from brdf_fit.core.fresnel import AbstractFresnel, SchlickFresnel
from brdf_fit.models._base import AbstractBRDF, BRDFSample, expand_channels


class Mirror(AbstractBRDF):
    """Perfectly smooth specular reflector with a Fresnel component (default: F = 1)."""

    fresnel: AbstractFresnel = SchlickFresnel(f0=1.0)
    is_delta: ClassVar[bool] = True

    def eval(self, wi, wo):
        z = jnp.zeros(jnp.broadcast_shapes(wi.shape, wo.shape)[:-1], dtype=wo.dtype)
        ch = self.channels()
        return z if ch is None else jnp.zeros(z.shape + (ch,), dtype=wo.dtype)

    def pdf(self, wi, wo):
        return jnp.zeros(jnp.broadcast_shapes(wi.shape, wo.shape)[:-1], dtype=wo.dtype)

    def albedo(self, wo):
        """Directional albedo ``F(n.wo)`` (0 below the horizon)."""
        c = wo[..., 2]
        ch = self.channels()
        cc = expand_channels(jnp.maximum(c, 0.0), ch)
        return jnp.where(expand_channels(c > 0, ch), self.fresnel(cc), 0.0)

    def delta_albedo(self, wo):
        return self.albedo(wo)

    def sample(self, wo, uc, u):
        wi = mirror(wo)
        ok = wo[..., 2] > 0
        pdf = jnp.where(ok, 1.0, 0.0).astype(wo.dtype)
        return BRDFSample(wi=wi, pdf=pdf, weight=self.albedo(wo))

    def selection_hint(self):
        return self.fresnel.reflectance_hint()
