"""Neumann, Neumann & Szirmay-Kalos (1999): the max-cosine ("metallic") Phong model.

L. Neumann, A. Neumann, L. Szirmay-Kalos, "Compact metallic reflectance models", Computer
Graphics Forum 18(3):161-172 (Eurographics '99), 1999. The paper modifies the Phong, Blinn and
Ward models by dividing the lobe by ``max(cos(theta_i), cos(theta_o))`` so that the albedo stays
mirror-like ("metallic") up to grazing angles, the BRDF stays reciprocal, and the ideal mirror is
the limit of large exponents (paper abstract and introduction; models.md 4.22). Implemented here:
the Phong-type member,

    f(wi, wo) = rho_s (n+1)/(2 pi) cos^n(alpha_r) / max(n.wi, n.wo),
    cos(alpha_r) = max(0, r_o.wi) = max(0, 2 (n.wi)(n.wo) - wi.wo)       (symmetric)

Source of the constant: the full text of the paper (and of the companion "Reflectance models
with fast importance sampling", CGF 18(4), 1999) was not available to us, only the abstracts and
the introduction; models.md marks the constants UNVERIFIED. We take the lobe normalisation
``(n+1)/(2 pi)``, the one that makes the energy bound of models.md 4.22 hold with equality in the
mirror limit: ``f cos(theta_i) = rho_s p(wi) min(1, cos_i/cos_o)`` with ``p`` the power-cosine
density about ``r_o`` (normalised on the sphere), so

    a(wo) = rho_s Int_H p(wi) min(1, cos_i/cos_o) dwi <= rho_s,

i.e. energy conserving for ``rho_s <= 1`` (measured in tests/test_neumann.py), and
``a(wo) -> rho_s`` for every view as ``n -> inf`` (the metallic mirror limit). At normal view
``a = rho_s (n+1)/(n+2)``. The Blinn- and Ward-type members of the paper are not implemented:
their constants could not be pinned to the paper (the often-quoted Blinn normalisation
``(n+2)/(4 pi (2 - 2^(-n/2)))`` is Gotanda's 2010 one, not the paper's).

Reciprocal (``r_o.wi = r_i.wo``, max symmetric). ``max`` has a kink on ``cos_i = cos_o``
(JAX's subgradient there is 1/2 each: finite). At grazing both ``1/max`` and the lobe stay
finite: ``max(cos_i, cos_o) >= cos_i``, so ``f cos(theta_i) <= rho_s p``.

Sampling (exact): the power-cosine lobe about the mirror direction ``r_o`` (Lafortune & Willems
1994), ``pdf = (n+1)/(2 pi) cos^n(alpha_r)``; samples below the horizon fail. The weight is
``rho_s min(1, cos_i/cos_o)`` (nearly constant).
"""

from __future__ import annotations

import jax.numpy as jnp

from brdf_fit.core.numerics import safe_div
from brdf_fit.core.params import Channels, Entry, Param, Scalar, bounded
from brdf_fit.core.validate import check_param
from brdf_fit.models._base import AbstractBRDF, QuadratureLobe
from brdf_fit.models._lobes import (
    EXPONENT_MAX,
    check_exponent,
    max_over_channels,
    mirror_lobe_pdf,
    power_cosine_pdf,
    sample_mirror_lobe,
    scaled_where,
    upper,
)

__all__ = ["NeumannPhong", "registry_entries"]


class NeumannPhong(AbstractBRDF):
    """``rho_s (n+1)/(2 pi) cos^n(alpha_r) / max(cos_i, cos_o)`` (module docstring). ``rho_s`` may
    carry channels; the exponent is a scalar >= 0."""

    rho_s: Channels = bounded(0.8, lo=0.0, hi=1.0, channels=True)
    exponent: Scalar = bounded(50.0, lo=0.0, hi=EXPONENT_MAX)

    def __check_init__(self):
        check_param("rho_s", self.rho_s, lo=0.0, hi=1.0, owner="NeumannPhong")
        check_exponent(self.exponent, "NeumannPhong")

    def eval(self, wi, wo):
        ok = upper(wi, wo)
        cmax = jnp.where(ok, jnp.maximum(wi[..., 2], wo[..., 2]), 0.0)
        val = safe_div(power_cosine_pdf(wi, wo, self.exponent), cmax)
        return scaled_where(ok, self.rho_s, val, self.channels())

    def pdf(self, wi, wo):
        return mirror_lobe_pdf(wi, wo, self.exponent)

    def sample(self, wo, uc, u):
        return sample_mirror_lobe(self, wo, u, self.exponent)

    def quadrature_lobe(self) -> QuadratureLobe:
        """Quadrature hint: a power-cosine lobe about the mirror direction."""
        return QuadratureLobe("mirror", self.exponent)

    def selection_hint(self):
        return max_over_channels(self.rho_s)


_NNSK_1999 = (
    "L. Neumann, A. Neumann, L. Szirmay-Kalos, Compact metallic reflectance models, Computer "
    "Graphics Forum 18(3):161-172 (Eurographics 1999)"
)


def registry_entries():
    return [
        Entry(
            name="neumann",
            builder=lambda rho_s, exponent: NeumannPhong(rho_s=rho_s, exponent=exponent),
            params=(
                Param("rho_s", (0.9, 0.7, 0.4), lo=0.0, hi=1.0, channels=True,
                      doc="specular (metallic) reflectance; albedo <= rho_s"),
                Param("exponent", 50.0, lo=0.0, hi=1e6, doc="Phong exponent n"),
            ),
            reference=f"{_NNSK_1999}; lobe constant (n+1)/(2 pi) ours (models.md 4.22)",
            description=(
                "metallic Phong: rho_s (n+1)/(2 pi) cos^n(alpha_r)/max(cos_i, cos_o); "
                "reciprocal, albedo <= rho_s, -> rho_s (mirror) as n grows"
            ),
            aliases=("neumann-phong", "nnsk-phong"),
            year=1999,
            catalogue="Neumann-Neumann",
            sampler="exact power-cosine lobe about the mirror direction",
        ),
    ]
