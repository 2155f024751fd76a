"""Energy-normalised modified Phong: directional albedo exactly ``rho_s`` for every view.

    f(wi, wo) = rho_s max(0, r.wi)^n / N(cos_o, n),   r = (-wo_x, -wo_y, wo_z),

with ``N(cos_o, n) = Int_{H+} max(0, r.wi)^n cos_i dwi`` from
:func:`brdf_fit.phong_norm.normaliser`:
J. Arvo, "Applications of irradiance tensors to the simulation of non-Lambertian phenomena",
SIGGRAPH 1995 (integer n, O(n) recurrence) or I. Mallett and C. Yuksel, "Constant-time
energy-normalization for the Phong specular BRDFs", The Visual Computer 36, 2020 (real n, O(1)
via the incomplete beta function). The normaliser depends on ``wo`` only, so the BRDF is not
reciprocal (``f(wi, wo) != f(wo, wi)`` unless ``cos_i = cos_o``).

Sampling: the power-cosine lobe about ``r`` (Lafortune & Willems 1994), ``p(wi) = (n + 1)/(2 pi)
max(0, r.wi)^n``; directions drawn below the horizon fail (pdf 0, weight 0), so the pdf integrates
over the upper hemisphere to ``1 - P(fail)`` (``= (n + 1) Int_{H+} max(0, r.wi)^n dwi/(2 pi)``).
The weight of a successful sample is ``rho_s cos_i 2 pi / ((n + 1) N)``.

``exponent`` is a scalar (geometric parameter); ``rho_s`` may carry a trailing channel axis.
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp

from brdf_fit.core.frame import frame_from_normal, mirror, to_world
from brdf_fit.core.numerics import INV_TWO_PI
from brdf_fit.core.params import Channels, Entry, Param, Scalar, bounded
from brdf_fit.core.phong_normaliser import ARVO_MAX_N, METHODS, normaliser
from brdf_fit.core.validate import check_param
from brdf_fit.core.warp import sample_power_cosine
from brdf_fit.models._base import AbstractBRDF, QuadratureLobe, expand_channels
from brdf_fit.models._lobes import (
    EXPONENT_MAX,
    cos_alpha_r_pow,
    finish_sample,
    max_over_channels,
    upper,
)

__all__ = ["EnergyNormalizedPhong", "registry_entries"]


class EnergyNormalizedPhong(AbstractBRDF):
    """``rho_s max(0, r.wi)^n / N(cos_o, n)`` (Arvo 1995; Mallett & Yuksel 2020).

    ``method``: ``"mallett-yuksel"`` (real exponent, differentiable in it) or ``"arvo"`` (integer
    exponent up to ``max_n``, rounded; not differentiable in it).
    """

    rho_s: Channels = bounded(0.8, lo=0.0, hi=1.0, channels=True)
    exponent: Scalar = bounded(50.0, lo=0.0, hi=EXPONENT_MAX)
    method: str = eqx.field(static=True, default="mallett-yuksel")
    max_n: int = eqx.field(static=True, default=ARVO_MAX_N)

    def __check_init__(self):
        check_param("rho_s", self.rho_s, lo=0.0, owner="EnergyNormalizedPhong")
        check_param("exponent", self.exponent, lo=0.0, owner="EnergyNormalizedPhong")
        if self.method not in METHODS:
            raise ValueError(
                f"EnergyNormalizedPhong: unknown method {self.method!r}; valid: {METHODS}"
            )

    def _n(self):
        """The exponent used by eval/pdf/sample: rounded for the integer-only Arvo path, so that
        lobe and normaliser agree."""
        n = jnp.asarray(self.exponent)
        return jnp.round(n) if self.method == "arvo" else n

    def _cos_lobe(self, wi, wo):
        r = mirror(wo)
        return jnp.sum(r * wi, axis=-1)

    def normaliser(self, wo):
        """``N(cos_o, n)`` for each ``wo`` (1 where ``wo`` is at or below the horizon)."""
        co = wo[..., 2]
        ok = co > 0
        return normaliser(jnp.where(ok, co, 1.0), self.exponent, self.method, self.max_n)

    def eval(self, wi, wo):
        ok = upper(wi, wo)
        n = self._n()
        lobe = cos_alpha_r_pow(wi, wo, n) / self.normaliser(wo)
        lobe = jnp.where(ok, lobe, 0.0)
        return expand_channels(lobe, self.channels()) * self.rho_s

    def pdf(self, wi, wo):
        ok = upper(wi, wo)
        n = self._n()
        p = (n + 1.0) * INV_TWO_PI * cos_alpha_r_pow(wi, wo, n)
        return jnp.where(ok, p, 0.0)

    def sample(self, wo, uc, u):
        local = sample_power_cosine(u, self._n())
        t, b, r = frame_from_normal(mirror(wo))
        return finish_sample(self, to_world(local, t, b, r), wo)

    def quadrature_lobe(self) -> QuadratureLobe:
        """Quadrature hint (:func:`brdf_fit.verify.albedo.lobe_rule`): a power-cosine lobe about the
        mirror direction."""
        return QuadratureLobe("mirror", self._n())

    def selection_hint(self):
        return max_over_channels(self.rho_s)


def registry_entries():
    """Registry entries (not registered here): ``phong-energy-normalized`` (Mallett-Yuksel, real
    exponent) and ``phong-energy-normalized-arvo`` (Arvo recurrence, integer exponent)."""
    reason = {
        "reciprocity": (
            "normalised per view direction (Arvo 1995; Mallett & Yuksel 2020): not reciprocal"
        )
    }
    rho = Param("rho_s", (0.8, 0.8, 0.8), lo=0.0, hi=1.0, channels=True,
                doc="specular albedo (exact directional albedo for every view)")
    my_ref = (
        "I. Mallett, C. Yuksel, Constant-time energy-normalization for the Phong specular BRDFs, "
        "The Visual Computer 36, 2020 (CGI 2020)"
    )
    arvo_ref = (
        "J. Arvo, Applications of irradiance tensors to the simulation of non-Lambertian "
        "phenomena, SIGGRAPH 1995"
    )
    return [
        Entry(
            name="phong-energy-normalized",
            year=2020,
            catalogue="Phong",
            sampler="power-cosine lobe (exact pdf)",
            builder=lambda rho_s, exponent: EnergyNormalizedPhong(rho_s=rho_s, exponent=exponent),
            params=(rho, Param("exponent", 50.0, lo=0.0, hi=1e6,
                               doc="Phong exponent n (real)")),
            reference=f"{my_ref}; {arvo_ref}",
            description=(
                "modified Phong lobe about the mirror direction, normalised per view so that "
                "its albedo is exactly rho_s (O(1) incomplete-beta normaliser)"
            ),
            expected_failures=dict(reason),
        ),
        Entry(
            name="phong-energy-normalized-arvo",
            year=1995,
            catalogue="Phong",
            sampler="power-cosine lobe (exact pdf)",
            builder=lambda rho_s, exponent: EnergyNormalizedPhong(
                rho_s=rho_s, exponent=exponent, method="arvo"),
            params=(rho, Param("exponent", 50.0, lo=0.0, hi=float(ARVO_MAX_N),
                               doc="Phong exponent n (rounded to an integer)")),
            reference=arvo_ref,
            description=(
                "energy-normalised modified Phong with Arvo's O(n) integer-exponent recurrence "
                f"for the normaliser (exponent rounded, at most {ARVO_MAX_N})"
            ),
            expected_failures=dict(reason),
        ),
    ]
