"""How close Mitsuba's own ``roughplastic`` tables are to the integrals they approximate.

Mitsuba 3's ``roughplastic`` tabulates, per material, two properties of its rough dielectric
coating (``brdf_fit.models.mitsuba``, which transcribes them exactly as the plugin computes
them, to float32 rounding):

* ``T(mu)``, the directional transmittance ``Int G1(w_t) (1 - F(wi.m)) D_wi(m) dm`` over the
  visible normals (Heitz & d'Eon 2014, eq. 2), at 64 cosines, by a 32 x 32 tensor
  Gauss-Legendre rule over the unit square of its visible-normal sampler;
* ``Fdr_int = 2 mean_j(mu_j R(mu_j; 1/eta))``, the internal diffuse reflectance, where
  ``R(mu; 1/eta)`` is the directional albedo of the reflection lobe seen from inside (total
  internal reflection included), by a 128 x 128 rule, and the cosine-weighted hemispherical
  average ``2 Int_0^1 R(mu) mu dmu`` is replaced by the mean over the 64 equispaced cosines
  (endpoints included).

This module computes the same quantities with the package's own quadrature, converged:

* ``R(mu)`` by :func:`brdf_fit.verify.albedo.directional_albedo` (the lobe-adapted
  half-vector rule) of the model whose albedo it is: the specular lobe ``F D G1 G1 /
  (4 cos cos)`` with Mitsuba's D and G1 and the exact dielectric Fresnel of ``1/eta``;
* ``2 Int_0^1 R(mu) mu dmu`` by Gauss-Legendre in ``mu``, one panel of :data:`FDR_MU_ORDER`
  nodes on each side of the critical cosine ``sqrt(1 - 1/eta^2)`` (where ``R`` has a kink);
* ``T(mu)`` over the visible normals drawn by the package's own sampler (Dupuy & Benyoub 2023,
  a different map of the unit square with the same density), on a :data:`T_ORDER`-point
  tensor rule: its integrand is smooth for ``eta > 1`` (no total internal reflection).

and reports the differences (:func:`compare`). ``benchmarks/bench_mitsuba_tables.py`` runs it
over widths and indices of refraction (``benchmarks/results/mitsuba_tables.md``).
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np

from brdf_fit.core.fresnel import DielectricFresnel
from brdf_fit.core.microfacet import SmithSeparable
from brdf_fit.models import mitsuba as mm
from brdf_fit.models.microfacet_brdf import MicrofacetBRDF
from brdf_fit.verify.albedo import directional_albedo

__all__ = ["FDR_MU_ORDER", "T_ORDER", "converged_tables", "compare"]

#: Gauss-Legendre nodes in mu for ``2 Int R(mu) mu dmu``, per panel (two panels, split at the
#: critical cosine)
FDR_MU_ORDER = 64
#: tensor Gauss-Legendre order of the converged transmittance (per axis of the unit square)
T_ORDER = 256


def _transmittance(distribution: str, alpha, eta, mu, order: int):
    """``T(mu)`` over the package's own visible-normal sampler, ``order x order`` nodes."""
    x, w = np.polynomial.legendre.leggauss(order)
    u1, u2 = np.meshgrid(0.5 * x + 0.5, 0.5 * x + 0.5, indexing="ij")
    ww = jnp.asarray(0.25 * np.outer(w, w))
    dist = mm._distribution(distribution, alpha)

    def row(m):
        wz = jnp.full(u1.shape, m)  # per node: the Beckmann sampler carries a per-lane bracket
        wx = jnp.sqrt(1.0 - wz * wz)
        mx, my, mz = dist.sample_visible(wx, jnp.zeros_like(wx), wz, jnp.asarray(u1),
                                         jnp.asarray(u2))
        wm = wx * mx + wz * mz
        F, ct, eti = mm._fresnel_dielectric(wm, eta)
        s = wm * eti + ct
        ox, oy, oz = mx * s - wx * eti, my * s, mz * s - wz * eti
        g = mm._smith_g1(distribution, alpha, ox, oy, oz, mx, my, mz)
        return jnp.sum(jnp.where(oz * wz >= 0, 0.0, g * (1.0 - F)) * ww)

    return jax.lax.map(row, jnp.asarray(mu))


def converged_tables(alpha: float, eta: float, distribution: str = "ggx",
                     t_order: int = T_ORDER, mu_order: int = FDR_MU_ORDER,
                     n_theta: int | None = None) -> dict:
    """The converged counterparts of the plugin's tables (module docstring), in float64:
    ``T`` at the plugin's 64 cosines, ``Fdr_int`` (the integral), and the plugin's own
    estimator ``Fdr_mean`` (the mean over the 64 cosines) applied to converged ``R``."""
    with jax.enable_x64(True):
        mu64 = np.asarray(mm.table_cosines(jnp.float64))
        t = np.asarray(_transmittance(distribution, jnp.float64(alpha), jnp.float64(eta),
                                      mu64, t_order))
        lobe = MicrofacetBRDF(distribution=mm._distribution(distribution, jnp.float64(alpha)),
                              masking=SmithSeparable(),
                              fresnel=DielectricFresnel(jnp.float64(1.0 / eta)))
        # R(mu) has a kink where the smooth interface's critical angle lies (total internal
        # reflection from inside: mu_c = sqrt(1 - 1/eta^2)): one Gauss-Legendre panel on each
        # side of it
        mu_c = math.sqrt(1.0 - 1.0 / (eta * eta))
        x, w = np.polynomial.legendre.leggauss(mu_order)
        mu = np.concatenate([0.5 * mu_c * (x + 1.0), mu_c + 0.5 * (1.0 - mu_c) * (x + 1.0)])
        wmu = np.concatenate([0.5 * mu_c * w, 0.5 * (1.0 - mu_c) * w])

        def albedo(m):
            m = np.asarray(m, float)
            wo = np.stack([np.sqrt(1 - m * m), np.zeros_like(m), m], -1)
            return np.asarray(directional_albedo(lobe, jnp.asarray(wo), n_theta=n_theta))

        fdr = float(2.0 * np.sum(wmu * mu * albedo(mu)))
        fdr_mean = float(2.0 * np.mean(mu64 * albedo(mu64)))
    return {"mu": mu64, "T": t, "Fdr_int": fdr, "Fdr_mean": fdr_mean}


def compare(alpha: float, eta: float, distribution: str = "ggx") -> dict:
    """Mitsuba's tables (as :mod:`brdf_fit.models.mitsuba` computes them) against
    :func:`converged_tables`: the largest absolute difference of ``T``, both ``Fdr_int``, and
    what the ``Fdr_int`` difference does to the diffuse term, whose factor is
    ``1/(1 - Fdr_int)`` (relative change ``(F_m - F_c)/(1 - F_m)``)."""
    with jax.enable_x64(True):
        t_m, fdr_m = (np.asarray(a) for a in mm.rough_dielectric_tables(
            jnp.float64(alpha), jnp.float64(eta), distribution))
    ref = converged_tables(alpha, eta, distribution)
    fdr_m = float(fdr_m)
    return {
        "alpha": float(alpha), "eta": float(eta), "distribution": distribution,
        "T_max_abs_diff": float(np.max(np.abs(t_m - ref["T"]))),
        "Fdr_mitsuba": fdr_m, "Fdr_converged": ref["Fdr_int"],
        "Fdr_mean_of_converged_R": ref["Fdr_mean"],
        "diffuse_rel_change": (fdr_m - ref["Fdr_int"]) / (1.0 - fdr_m),
        "diffuse_rel_change_quadrature_only": (fdr_m - ref["Fdr_mean"]) / (1.0 - fdr_m),
        "note": ("positive: Mitsuba's diffuse term is brighter than the converged integrals "
                 "give" if fdr_m > ref["Fdr_int"] else "negative: Mitsuba's diffuse term is "
                 "darker than the converged integrals give"),
        "T_order": T_ORDER, "Fdr_mu_order": FDR_MU_ORDER,
    }
