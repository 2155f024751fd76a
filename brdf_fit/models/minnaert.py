"""Minnaert's limb-darkening law as a BRDF (Minnaert 1941), in its normalised form.

M. Minnaert, "The reciprocity principle in lunar photometry", Astrophysical Journal 93:403-410,
1941: the radiance of a surface lit from ``l`` and seen from ``v`` is ``L ~ cl^k cv^(k-1)``
(``cl = n.l``, ``cv = n.v``), reciprocal because the BRDF ``L/(E cl) ~ (cl cv)^(k-1)`` is symmetric.
Normalised form (models.md 4.3, as in the Disney BRDF explorer, ``wdas/brdf``
``src/brdfs/minnaert.brdf``)::

    f = rho (k + 1)/(2 pi) (cl cv)^(k - 1)

``k = 1`` is Lambert (``rho/pi``); ``k < 1`` brightens towards the limb (lunar regolith,
velvet-like), ``k > 1`` darkens it. Public shaders also use the un-normalised
``rho/pi (cl cv)^(k-1)`` (e.g. ``Kdiff pow(NdL NdV, k - 1)``, Glass-Engine's
``cos_l pow(cos_l cos_v, k - 1)``); the ``(k + 1)/2`` makes ``rho`` the albedo at normal view.

Directional albedo (exact): ``a(v) = Int f cl dw_l = rho (k+1)/(2 pi) cv^(k-1) 2 pi/(k+1) =
rho cv^(k-1)``. Energy constraint (models.md 4.3): conserving iff ``k >= 1`` and ``rho <= 1``
(then ``a(v) <= rho``); for ``k < 1`` the albedo diverges like ``cv^(k-1)`` at grazing views
for any ``rho > 0`` (``a = rho 1e-3^(k-1)`` at ``cv = 1e-3``), so the ``energy`` check fails:
declared, with the measured value, for the registry default ``k = 0.75``.

Sampler (exact, zero variance in ``l``): ``f cl ~ cl^k``, so ``l`` is drawn from the power-cosine
lobe about the normal, ``cos(theta_l) = u^(1/(k+1))`` (Lafortune & Willems 1994, sec. 3; models.md
2.5.2), with density ``p(l) = (k+1)/(2 pi) cl^k``; every sample's weight is the albedo
``rho cv^(k-1)``.

Numerics. ``(cl cv)^(k-1)`` is written ``exp((k-1)(log cl + log cv))``: the product ``cl cv`` is
never formed (it underflows float32 for cosines of 1e-20), ``d/dk`` is finite, and invalid lanes
(either cosine <= 0) are sanitised to 1 before the logarithm and masked afterwards (double where).
No cosine clamp is applied: for ``k < 1`` the value at ``cl = cv = 1e-7`` is the model's own
``1e-14^(k-1)`` (1.6e13 at ``k = 0``), finite in float32, as is its gradient.
"""

from __future__ import annotations

import jax.numpy as jnp

from brdf_fit.core.numerics import INV_TWO_PI, safe_pow
from brdf_fit.core.params import Channels, Entry, Param, Scalar, bounded
from brdf_fit.core.validate import check_param, check_scalar
from brdf_fit.models._base import AbstractBRDF, expand_channels
from brdf_fit.models._lobes import (
    finish_sample,
    max_over_channels,
    power_cosine_local,
    scaled_where,
    upper,
)

__all__ = ["Minnaert", "registry_entries"]

_MINNAERT_1941 = (
    "M. Minnaert, The reciprocity principle in lunar photometry, Astrophysical Journal "
    "93:403-410, 1941"
)


class Minnaert(AbstractBRDF):
    """Normalised Minnaert BRDF ``rho (k+1)/(2 pi) (cl cv)^(k-1)`` (Minnaert 1941; see the module
    docstring). ``rho`` (the albedo at normal view, may carry channels) in [0, 1]; ``k >= 0`` a
    scalar (``k = 1``: Lambert). Reciprocal; energy conserving iff ``k >= 1`` (and ``rho <= 1``).

    Sampling: power-cosine lobe of exponent ``k`` about the normal (exact:
    ``pdf = (k+1)/(2 pi) cl^k``, weight ``rho cv^(k-1)`` for every sample).
    """

    rho: Channels = bounded(0.8, lo=0.0, hi=1.0, channels=True)
    k: Scalar = bounded(0.75, lo=0.0, hi=4.0)

    def __check_init__(self):
        check_param("rho", self.rho, lo=0.0, hi=1.0, owner="Minnaert")
        check_param("k", self.k, lo=0.0, owner="Minnaert")
        check_scalar("k", self.k, "Minnaert")

    def eval(self, wi, wo):
        ok = upper(wi, wo)
        cl = jnp.where(ok, wi[..., 2], 1.0)
        cv = jnp.where(ok, wo[..., 2], 1.0)
        lobe = (self.k + 1.0) * INV_TWO_PI * jnp.exp((self.k - 1.0) * (jnp.log(cl) + jnp.log(cv)))
        return scaled_where(ok, self.rho, lobe, self.channels())

    def pdf(self, wi, wo):
        lobe = (self.k + 1.0) * INV_TWO_PI * safe_pow(jnp.maximum(wi[..., 2], 0.0), self.k)
        return jnp.where(upper(wi, wo), lobe, 0.0)

    def sample(self, wo, uc, u):
        # power_cosine_local uses expm1 for 1 - cos (accurate for large k); u0 = 0 lands on the
        # horizon, where pdf = 0: a failed sample
        return finish_sample(self, power_cosine_local(u, self.k), wo, wo[..., 2] > 0)

    def albedo(self, wo):
        """Closed-form directional albedo ``rho cv^(k-1)`` (0 for ``wo`` at or below the
        horizon)."""
        ok = wo[..., 2] > 0
        cv = jnp.where(ok, wo[..., 2], 1.0)
        a = jnp.where(ok, jnp.exp((self.k - 1.0) * jnp.log(cv)), 0.0)
        return self.rho * expand_channels(a, self.channels())

    def selection_hint(self):
        return max_over_channels(self.rho)


# Measured with brdf_fit.checks.run_checks("minnaert") at the defaults (float64); asserted by
# tests/test_minnaert.py::test_run_checks_declared_failures.
_MINNAERT_FAILURES: dict[str, str] = {
    "energy": (
        "k = 0.75 < 1 (limb brightening): the albedo rho cv^(k-1) diverges at grazing views; "
        "measured max albedo 4.4987 (= 0.8 x 1e-3^(-0.25)) at cos_o = 1e-3; conserving only for "
        "k >= 1 and rho <= 1 (models.md 4.3)"
    ),
}


def registry_entries():
    """:class:`brdf_fit.registry.Entry` for the normalised Minnaert model (not registered here)."""
    return [
        Entry(
            name="minnaert",
            builder=lambda rho, k: Minnaert(rho=rho, k=k),
            params=(
                Param("rho", (0.8, 0.6, 0.4), lo=0.0, hi=1.0, channels=True,
                      doc="albedo at normal view (the directional albedo is rho cos_o^(k-1))"),
                Param("k", 0.75, lo=0.0, hi=4.0,
                      doc="Minnaert darkening exponent (1: Lambert; < 1 limb brightening, "
                          "> 1 limb darkening)"),
            ),
            reference=(
                f"{_MINNAERT_1941}; normalised form rho (k+1)/(2 pi) (cl cv)^(k-1): models.md "
                "4.3 (Disney BRDF explorer minnaert.brdf)"
            ),
            description=(
                "rho (k+1)/(2 pi) (cos_i cos_o)^(k-1); reciprocal; albedo rho cos_o^(k-1) "
                "(conserving iff k >= 1, diverges at grazing for k < 1)"
            ),
            aliases=("minnaert-1941",),
            expected_failures=_MINNAERT_FAILURES,
            year=1941,
            catalogue="Minnaert",
            sampler="exact cos^k lobe about the normal",
        ),
    ]
