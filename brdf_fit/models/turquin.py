"""Multiple-scattering compensation by scaling the single-scattering lobe (Turquin 2019).

    f(wi, wo) = (1 + F0 (1 - E(mu_o)) / E(mu_o)) f_ss(wi, wo)

with ``E(mu_o)`` the directional albedo of the single-scattering lobe with ``F = 1``, evaluated
at the **view** cosine ``mu_o`` (the tabulated ``E`` of :mod:`brdf_fit.models.kulla_conty`,
same table, same clamp ``alpha >= ALPHA_MIN``), and ``F0`` the normal-incidence reflectance. With
``F = 1`` (``F0 = 1``) the albedo is ``E_ss(mu_o) / E(mu_o) = 1`` up to the table's
interpolation error; with ``F0 < 1`` the added energy is tinted by ``F0`` (Turquin's
approximation of the multiply scattered Fresnel factor). The lobe shape is the single-scattering
one (no cosine-like lobe is added), so it is sampled exactly like it (the same ``wi`` and pdf,
the weight times the factor). The factor depends on ``mu_o`` only, so the model is **not
reciprocal** (Turquin 2019, section 4, says so); the registry entry declares the measured
asymmetry.

References
----------
- E. Turquin, "Practical multiple scattering compensation for microfacet models", Industrial
  Light & Magic technical report, 2019 (eq. 16-18: ``f_ms = F0 (1 - E)/E f_ss``).
"""

from __future__ import annotations

import jax.numpy as jnp

from brdf_fit.core.numerics import safe_div
from brdf_fit.core.params import Channels, bounded
from brdf_fit.models._base import AbstractBRDF, BRDFSample, QuadratureLobe, expand_channels
from brdf_fit.models.kulla_conty import ms_loss
from brdf_fit.models.microfacet_brdf import MicrofacetBRDF

__all__ = ["TurquinCompensated"]


class TurquinCompensated(AbstractBRDF):
    """``(1 + F0 (1 - E(mu_o))/E(mu_o)) lobe`` (see the module docstring); ``lobe`` is an
    isotropic GGX :class:`~brdf_fit.models.MicrofacetBRDF` with height-correlated Smith masking
    (the lobe the table was computed for)."""

    lobe: MicrofacetBRDF
    f0: Channels = bounded(0.04, lo=0.0, hi=1.0, channels=True)

    def factor(self, wo):
        """``1 + F0 (1 - E(mu_o))/E(mu_o)``, shape ``batch`` or ``batch + (C,)``."""
        mu_o = jnp.clip(wo[..., 2], 0.0, 1.0)
        alpha = self.lobe.distribution.widths()[0]
        loss = ms_loss(mu_o, jnp.asarray(alpha, mu_o.dtype))
        ratio = safe_div(loss, 1.0 - loss)  # E >= 0.3 on the table: never near 0
        return 1.0 + self.f0 * expand_channels(ratio, self.channels())

    def eval(self, wi, wo):
        return self.factor(wo) * self.lobe.eval(wi, wo)

    def pdf(self, wi, wo):
        return self.lobe.pdf(wi, wo)

    def sample(self, wo, uc, u):
        s = self.lobe.sample(wo, uc, u)
        return BRDFSample(wi=s.wi, pdf=s.pdf, weight=self.factor(wo) * s.weight)

    def selection_hint(self):
        return self.lobe.selection_hint()

    def quadrature_lobe(self) -> QuadratureLobe:
        """The half-vector rule at the lobe's width (the factor is constant in ``wi``)."""
        return QuadratureLobe("half", self.lobe.distribution.widths()[0])

    def is_anisotropic(self) -> bool:
        return self.lobe.is_anisotropic()
