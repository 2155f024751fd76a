"""Hanrahan-Krueger single-scattering BRDF of a scattering layer under a smooth dielectric boundary
(P. Hanrahan, W. Krueger, "Reflection from layered surfaces due to subsurface scattering",
SIGGRAPH 1993, Computer Graphics Proceedings pp. 165-174, section 4: the first-order (single
scattering) reflection term ``f_r,v^(1)``; models.md 4.17).

The model (dot-product form, local frame ``n = z``)
-------------------------------------------------

A slab of optical depth ``tau = sigma_t d`` and single-scattering albedo ``W = sigma_s/sigma_t``
lies under a smooth boundary of relative index ``eta = eta_layer/eta_outside``. Light enters along
``wi``, is refracted, scattered once by the Henyey-Greenstein phase function at some depth, and
leaves along the refracted ``wo``::

    mu_i = sqrt(1 - (1 - (n.wi)^2)/eta^2)                refracted cosines (Snell), mu_o alike
    cos psi = -((wi.t)(wo.t) + (wi.b)(wo.b))/eta^2 - mu_i mu_o
                                                         angle between the refracted propagation
                                                         directions (in: down, out: up)
    p(psi) = (1 - g^2) / (4 pi (1 + g^2 - 2 g cos psi)^(3/2))     HG, Int p dw = 1
    f = W T(n.wi) T(n.wo) p(psi) [1 - exp(-tau (1/mu_i + 1/mu_o))] / (mu_i + mu_o) / eta^2

with ``T = 1 - F`` the exact dielectric Fresnel transmittance (:func:`brdf_fit.fresnel.dielectric`;
``T21`` at the internal angle equals ``T12`` at the external one, so both are evaluated outside).
The bracket is written ``-expm1(-tau (mu_i + mu_o)/(mu_i mu_o))`` (no cancellation for thin
layers, models.md 4.17 hazard 7). ``g > 0`` is forward scattering (into the layer), so it
*reduces* this reflection; ``g < 0`` strengthens it, most of all about the retro direction
``wi = wo`` (``cos psi = -1``).

Derivation, and the ``1/eta^2`` (where sources disagree)
--------------------------------------------------------

The incident irradiance ``E = L_i (n.wi) dw_i`` is transmitted as the flux ``T(n.wi) E`` of a
collimated beam of cosine ``mu_i``; at optical depth ``t`` it scatters ``W p T E / mu_i
e^(-t/mu_i) dt`` per steradian, attenuated by ``e^(-t/mu_o)`` on the way up along a path
``dt/mu_o``. The integral over ``t in [0, tau]`` gives the internal radiance
``L' = W p T E [1 - e^(-tau (1/mu_i + 1/mu_o))]/(mu_i + mu_o)`` (van de Hulst's single-scattering
reflection function of a finite slab; S. Prahl, thesis 1988, eq. 3.30). Leaving the layer the
radiance is ``T(n.wo) L'/eta^2`` (the ``n^2`` law: ``L/n^2`` is invariant across a smooth interface,
because ``cos dw`` is compressed by ``eta^2`` inside), hence the ``1/eta^2`` above.

Hanrahan & Krueger, and the public single-scattering codes, write ``f_r,v^(1)`` with ``T12 T21``
and no ``1/eta^2`` (models.md 4.17; M. Pharr's ``skin.sl`` from the SIGGRAPH 2001 "Advanced
RenderMan 3" course; Mitsuba 0.5 ``src/bsdfs/hk.cpp`` is the index-matched layer, eta = 1, where the
two forms agree). That form violates energy conservation: for a dense, strongly back-scattering
layer (W = 1, g = -0.9, tau = 100, eta = 2) its albedo at normal view is 1.308 (the
consistent form: 0.327; at eta = 1.5: 0.913 and 0.406; measured in
tests/test_hanrahan_krueger.py), because the flux leaving through the critical cone is counted
``eta^2`` times. We therefore implement the radiometrically
consistent form by default and keep the other as ``solid_angle_factor=False`` for comparison with
those codes. (The HK93 paper itself was not available to re-read; models.md marks its equation
numbering UNVERIFIED.) Mitsuba 0.5's ``hk.cpp``, as we read it, also multiplies its
single-scattering value by the cosine of its ``wi`` (the camera side) in addition to the cosine
foreshortening of the light side, i.e. returns ``f cos(theta_view)`` where we return ``f``: not
reciprocal; we follow the derivation above (reciprocal, checked).

Properties: reciprocal (``cos psi``, ``mu_i + mu_o``, ``mu_i mu_o`` and ``T T`` are symmetric);
for ``tau -> inf``, ``eta = 1`` and ``g = 0`` it is the Lommel-Seeliger (Chandrasekhar
single-scattering) law ``W/(4 pi (n.wi + n.wo))`` whose albedo is
``W/2 (1 - mu ln((1 + mu)/mu))``. Multiple scattering is not included (HK93 compute it by Monte
Carlo), so the albedo is below the layer's true reflectance. For ``eta < 1`` directions beyond the
critical angle ``sin theta >= eta`` are totally reflected at the boundary and ``f = 0`` there.

Sampler: cosine-weighted hemisphere (``pdf = n.wi/pi``, exact); ``weight = pi f``, bounded by
``W max p / (mu_i + mu_o)``. The phase-function lobe is broad for the registry's ``|g| <= 0.99``
after refraction and the Fresnel factors, so a lobe-matched mixture was not needed for the checks.

Quadrature: no ``quadrature_lobe()`` hint (neither the mirror nor the half-vector rule fits a
retro-reflection lobe), so :func:`brdf_fit.verify.albedo.directional_albedo` uses the generic
64 x 128 rule: accurate to ~1e-11 for ``g >= -0.9`` (W = 1, tau = 100, eta = 1.5: 0.9128479733
vs 256 x 512), but it under-resolves the narrow retro lobe of ``g -> -0.99`` (0.813 vs 1.025 at
normal view, published form): use a finer ``generic`` rule there.

Numerics: invalid lanes (either direction at or below the horizon, or beyond the critical angle
when ``eta < 1``) are replaced by the normal before any formula sees them and masked afterwards
(double where). No epsilon is needed: ``mu_i mu_o > 0`` on valid lanes, and at grazing with
``eta = 1`` (``mu = 1e-7``) ``exp(-tau/mu)`` underflows to exactly 0 with a finite gradient.
"""

from __future__ import annotations

import math

import equinox as eqx
import jax.numpy as jnp

from brdf_fit.core.frame import split
from brdf_fit.core.numerics import safe_sqrt
from brdf_fit.core.params import Channels, Entry, Param, Scalar, bounded
from brdf_fit.core.validate import check_param, check_scalar
from brdf_fit.models._base import AbstractBRDF, expand_channels
from brdf_fit.models._lobes import cosine_pdf, max_over_channels, sample_cosine

__all__ = ["HanrahanKrueger", "henyey_greenstein", "registry_entries"]

INV_FOUR_PI = 0.25 / math.pi

_HK_1993 = (
    "P. Hanrahan, W. Krueger, Reflection from layered surfaces due to subsurface scattering, "
    "SIGGRAPH 1993, pp. 165-174 (section 4, first-order scattering f_r,v^(1))"
)
_HG_1941 = (
    "L. G. Henyey, J. L. Greenstein, Diffuse radiation in the galaxy, Astrophysical Journal 93, "
    "70-83, 1941"
)


def henyey_greenstein(cos_psi, g, one_plus=None, one_minus=None):
    """Henyey & Greenstein (1941) phase function ``(1 - g^2)/(4 pi (1 + g^2 - 2 g cos psi)^1.5)``,
    normalised over the sphere; ``psi`` is the angle between the propagation directions before and
    after scattering (``g > 0``: forward). Finite for ``|g| < 1`` (the base is ``>= (1 - |g|)^2``).

    ``one_plus``/``one_minus``: ``1 + cos psi`` and ``1 - cos psi`` computed without cancellation
    (optional); the base is then ``(1 + g)^2 - 2 g (1 + cos psi)`` for ``g < 0`` and
    ``(1 - g)^2 + 2 g (1 - cos psi)`` for ``g >= 0``, two non-negative terms. The direct form
    cancels near the peak: at ``g = -0.99``, ``cos psi = -1`` it subtracts 3.96 from 3.9601, and
    float32 lost 2.7e-3 of the value there.
    """
    if one_plus is None:
        base = 1.0 + g * g - 2.0 * g * cos_psi
    else:
        base = jnp.where(g < 0.0, (1.0 + g) ** 2 - 2.0 * g * one_plus,
                         (1.0 - g) ** 2 + 2.0 * g * one_minus)
    return (1.0 - g * g) * INV_FOUR_PI / (base * jnp.sqrt(base))


def _transmittance(c, mu, eta):
    """Fresnel transmittance ``T = 1 - F`` (:func:`brdf_fit.fresnel.dielectric`) of the smooth
    boundary for the outside cosine ``c > 0`` and the refracted cosine ``mu > 0`` (no total
    internal reflection), written without the cancellation of ``1 - F`` (F -> 1 for eta -> 0 or
    eta -> inf; float32 at eta = 1e6 had 1.3% error, at eta = 1e-6 a factor 120):
    ``1 - r_par^2 = 4 eta c mu/(eta c + mu)^2``, ``1 - r_perp^2 = 4 eta c mu/(c + eta mu)^2``
    (Born & Wolf section 1.5.2), so ``T = 2 eta c mu (1/(eta c + mu)^2 + 1/(c + eta mu)^2)``."""
    a = eta * c + mu
    b = c + eta * mu
    return 2.0 * eta * c * mu * (1.0 / (a * a) + 1.0 / (b * b))


class HanrahanKrueger(AbstractBRDF):
    """Single-scattering BRDF of a Henyey-Greenstein layer under a smooth dielectric boundary
    (Hanrahan & Krueger 1993, section 4; see the module docstring for the formula, the
    derivation and the ``1/eta^2`` factor).

    Parameters: ``albedo`` ``W = sigma_s/sigma_t`` in [0, 1] and ``tau`` ``= sigma_t d >= 0`` may
    carry channels; ``g`` in (-1, 1) and ``eta > 0`` are scalars (they bend and weight the
    directions). ``solid_angle_factor=False`` drops the ``1/eta^2`` (the published form; not
    energy conserving for ``eta > 1``).
    """

    albedo: Channels = bounded(0.8, lo=0.0, hi=1.0, channels=True)
    tau: Channels = bounded(1.0, lo=0.0, channels=True)
    g: Scalar = bounded(0.3, lo=-0.99, hi=0.99)
    eta: Scalar = bounded(1.4, lo=0.0, lo_open=True)
    solid_angle_factor: bool = eqx.field(static=True, default=True)

    def __check_init__(self):
        owner = "HanrahanKrueger"
        check_param("albedo", self.albedo, lo=0.0, hi=1.0, owner=owner)
        check_param("tau", self.tau, lo=0.0, owner=owner)
        check_param("g", self.g, lo=-1.0, hi=1.0, lo_open=True, hi_open=True, owner=owner)
        check_param("eta", self.eta, lo=0.0, lo_open=True, owner=owner)
        check_scalar("g", self.g, owner)
        check_scalar("eta", self.eta, owner)

    def _geometry(self, wi, wo):
        """Validity mask, refracted cosines, Fresnel transmittances and ``cos psi`` (sanitised)."""
        ix, iy, iz = split(wi)
        ox, oy, oz = split(wo)
        eta = self.eta
        inv_e2 = 1.0 / (eta * eta)
        em1 = (eta - 1.0) * (eta + 1.0)  # eta^2 - 1 without cancellation near eta = 1
        # cos^2 of the refracted angles: 1 - (1 - z^2)/eta^2 = (eta^2 - 1 + z^2)/eta^2, a sum of
        # non-negative terms for eta >= 1; for eta < 1 written 1 - (x^2 + y^2)/eta^2, whose
        # round-off is ~eps in c2 itself, not eps/eta^2 (float32 at eta = 1e-4 lost every
        # direction to a spurious total internal reflection: 0 instead of 0.18 at the normal)
        above = eta >= 1.0
        c2i = jnp.where(above, (em1 + iz * iz) * inv_e2, 1.0 - (ix * ix + iy * iy) * inv_e2)
        c2o = jnp.where(above, (em1 + oz * oz) * inv_e2, 1.0 - (ox * ox + oy * oy) * inv_e2)
        ok = (iz > 0) & (oz > 0) & (c2i > 0) & (c2o > 0)
        # sanitise: invalid lanes see the normal (mu = 1, T finite, cos psi = -1)
        ixs, iys, izs = (jnp.where(ok, ix, 0.0), jnp.where(ok, iy, 0.0), jnp.where(ok, iz, 1.0))
        oxs, oys, ozs = (jnp.where(ok, ox, 0.0), jnp.where(ok, oy, 0.0), jnp.where(ok, oz, 1.0))
        mu_i = safe_sqrt(jnp.where(ok, c2i, 1.0))
        mu_o = safe_sqrt(jnp.where(ok, c2o, 1.0))
        cos_psi = -(ixs * oxs + iys * oys) * inv_e2 - mu_i * mu_o
        # 1 -+ cos psi = |k_i' -+ k_o'|^2/2 for the refracted unit directions
        # k_i' = (-x_i/eta, -y_i/eta, -mu_i), k_o' = (x_o/eta, y_o/eta, mu_o): no cancellation
        # near psi = 0 or pi; mu_o - mu_i = (z_o - z_i)(z_o + z_i)/(eta^2 (mu_o + mu_i))
        dmu = (ozs - izs) * (ozs + izs) * inv_e2 / (mu_o + mu_i)
        one_plus = 0.5 * (((oxs - ixs) ** 2 + (oys - iys) ** 2) * inv_e2 + dmu * dmu)
        one_minus = 0.5 * (((oxs + ixs) ** 2 + (oys + iys) ** 2) * inv_e2 + (mu_i + mu_o) ** 2)
        return ok, izs, ozs, mu_i, mu_o, cos_psi, one_plus, one_minus, inv_e2

    def eval(self, wi, wo):
        ok, izs, ozs, mu_i, mu_o, cos_psi, one_plus, one_minus, inv_e2 = self._geometry(wi, wo)
        ch = self.channels()
        t_i = _transmittance(izs, mu_i, self.eta)
        t_o = _transmittance(ozs, mu_o, self.eta)
        phase = henyey_greenstein(cos_psi, self.g, one_plus, one_minus)
        s = mu_i + mu_o
        rate = s / (mu_i * mu_o)  # 1/mu_i + 1/mu_o
        geo = t_i * t_o * phase / s
        if self.solid_angle_factor:
            geo = geo * inv_e2
        atten = -jnp.expm1(-self.tau * expand_channels(rate, ch))
        val = self.albedo * atten * expand_channels(geo, ch)
        return jnp.where(expand_channels(ok, ch), val, 0.0)

    def pdf(self, wi, wo):
        return cosine_pdf(wi, wo)

    def sample(self, wo, uc, u):
        return sample_cosine(self, wo, u)

    def selection_hint(self):
        return max_over_channels(self.albedo)


# ----------------------------------------------------------------------------- registry entries


def registry_entries():
    """:class:`brdf_fit.registry.Entry` for the single-scattering Hanrahan-Krueger layer.

    ``run_checks("hanrahan-krueger")`` passes every check at the defaults (float64), so no
    expected failures are declared (see tests/test_hanrahan_krueger.py).
    """
    return [
        Entry(
            name="hanrahan-krueger",
            builder=lambda albedo, tau, g, eta: HanrahanKrueger(
                albedo=albedo, tau=tau, g=g, eta=eta),
            params=(
                Param("albedo", (0.8, 0.6, 0.4), lo=0.0, hi=1.0, channels=True,
                      doc="single-scattering albedo sigma_s/sigma_t of the layer"),
                Param("tau", (1.0, 1.5, 2.0), lo=0.0, channels=True,
                      doc="optical depth sigma_t d of the layer"),
                Param("g", 0.3, lo=-0.99, hi=0.99,
                      doc="Henyey-Greenstein asymmetry (> 0 forward); |g| <= 0.99 as pbrt-v4 "
                          "clamps it"),
                Param("eta", 1.4, lo=0.0, lo_open=True,
                      doc="relative index of refraction of the layer (layer/outside)"),
            ),
            reference=f"{_HK_1993}; phase function: {_HG_1941}",
            description=(
                "single scattering in a Henyey-Greenstein layer under a smooth dielectric: "
                "W T_i T_o p(psi) (1 - exp(-tau (1/mu_i + 1/mu_o)))/((mu_i + mu_o) eta^2), "
                "refracted cosines mu; no multiple scattering, no surface specular"
            ),
            aliases=("hk", "hanrahan-krueger-1993"),
            year=1993,
            catalogue="Hanrahan-Krueger",
            sampler="cosine fallback (exact pdf)",
            tags=("layered",),
        ),
    ]
