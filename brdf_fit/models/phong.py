"""Phong-family BRDFs: Phong 1975 (as a BRDF), modified Phong (Lafortune & Willems 1994), modified
Phong with a Fresnel specular reflectance, and Blinn-Phong (Blinn 1977) with its common
normalisations.

Notation (dot products in the local frame, ``n = z``): ``r_o = 2 (n.wo) n - wo`` is the mirror of
``wo``; ``cos(alpha_r) = max(0, r_o.wi) = max(0, 2 (n.wi)(n.wo) - wi.wo)``, symmetric in
``(wi, wo)``; ``h = normalize(wi + wo)`` and ``cos(theta_h) = n.h``. Exponents enter through
:func:`brdf_fit._numerics.safe_pow` (``exp(n log x)``), so ``d/dn`` is finite (0 where the base
is 0) and ``n`` up to 1e6 is safe in float32 (the power underflows to 0, never to NaN).

Samplers (models.md 2.5.2, 2.5.3):

* power-cosine lobe about ``r_o``: ``cos(alpha) = u^(1/(n+1))``, ``p = (n+1)/(2 pi) cos^n(alpha)``,
  normalised over the whole sphere; samples below the horizon fail (pdf 0, weight 0), so the pdf
  integrates over the upper hemisphere to ``1 - P(fail)``;
* Blinn-Phong half vector: ``cos(theta_h) = u^(1/(n+1))``, ``p_h = (n+1)/(2 pi) cos^n(theta_h)``,
  ``p(wi) = p_h / (4 wo.h)`` (Walter et al. 2007, eq. 14).
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp

from brdf_fit.core.fresnel import dielectric, ior_from_f0, schlick
from brdf_fit.core.numerics import INV_PI, INV_TWO_PI, safe_div, safe_pow
from brdf_fit.core.params import Channels, Entry, Param, Scalar, bounded
from brdf_fit.core.validate import ParameterError, check_param, check_sum_at_most_one
from brdf_fit.models._base import AbstractBRDF, QuadratureLobe, expand_channels
from brdf_fit.models._lobes import (
    EXPONENT_MAX,
    check_exponent,
    cos_alpha_r_pow,
    diffuse_mirror_pdf,
    finish_sample,
    half_vector,
    lobe_probability,
    max_over_channels,
    mirror_lobe_pdf,
    power_cosine_local,
    power_cosine_pdf,
    reflect_about_half,
    sample_diffuse_or_mirror,
    sample_mirror_lobe,
    sanitize_wo,
    scaled_where,
    upper,
)

__all__ = [
    "PhongOriginal",
    "ModifiedPhong",
    "ModifiedPhongFresnel",
    "BlinnPhong",
    "registry_entries",
]

_PHONG_1975 = (
    "B. T. Phong, Illumination for computer generated pictures, Communications of the ACM "
    "18(6):311-317, 1975"
)
_LW_1994 = (
    "E. P. Lafortune, Y. D. Willems, Using the modified Phong reflectance model for physically "
    "based rendering, Technical Report CW197, K.U. Leuven, 1994"
)
_BLINN_1977 = (
    "J. F. Blinn, Models of light reflection for computer synthesized pictures, SIGGRAPH 1977, "
    "Computer Graphics 11(2):192-198"
)
_RTR3 = (
    "T. Akenine-Moller, E. Haines, N. Hoffman, Real-Time Rendering, 3rd ed., 2008 (section 7.6); "
    "N. Hoffman, Crafting physically motivated shading models for video games, SIGGRAPH 2010 "
    "course notes"
)


# ----------------------------------------------------------------------------- Phong 1975


class PhongOriginal(AbstractBRDF):
    """Phong's 1975 specular term read literally as a BRDF (Phong 1975, CACM 18(6), the
    ``ks cos^n`` term of eq. (1)/(2); models.md 4.6, "divide_by_NdotL" form)::

        f = rho_s (n+1)/(2 pi) cos^n(alpha_r) / cos(theta_i),    cos(alpha_r) = max(0, r_o.wi)

    Phong's shading model multiplies the specular term by the light's intensity, not by
    ``cos(theta_i)``; as a BRDF that is a division by ``cos(theta_i)``. The normaliser
    ``(n+1)/(2 pi)`` normalises the lobe ``cos^n(alpha_r)`` **over the whole sphere of wi** (it is
    the power-cosine density): ``f cos(theta_i) = rho_s p_lobe(wi)``, so the directional albedo is
    ``rho_s`` times the fraction of the lobe above the horizon (``rho_s`` at normal view, less at
    oblique views), and the sampler's weight is exactly ``rho_s``.

    Not reciprocal (the ``1/cos(theta_i)``); ``f`` diverges as ``theta_i -> 90 deg`` where the lobe
    reaches the horizon (``f cos`` stays bounded). The division is guarded (double where): 0 for
    ``cos(theta_i) <= 0`` with a finite gradient.
    """

    rho_s: Channels = bounded(0.5, lo=0.0, hi=1.0, channels=True)
    exponent: Scalar = bounded(20.0, lo=0.0, hi=EXPONENT_MAX)

    def __check_init__(self):
        check_param("rho_s", self.rho_s, lo=0.0, hi=1.0, owner="PhongOriginal")
        check_exponent(self.exponent, "PhongOriginal")

    def eval(self, wi, wo):
        ok = upper(wi, wo)
        lobe = power_cosine_pdf(wi, wo, self.exponent)
        val = safe_div(lobe, jnp.where(ok, wi[..., 2], 0.0))
        return scaled_where(ok, self.rho_s, val, self.channels())

    def pdf(self, wi, wo):
        return mirror_lobe_pdf(wi, wo, self.exponent)

    def sample(self, wo, uc, u):
        return sample_mirror_lobe(self, wo, u, self.exponent)

    def quadrature_lobe(self) -> QuadratureLobe:
        """Quadrature hint (:func:`brdf_fit.verify.albedo.lobe_rule`): a power-cosine lobe about the
        mirror direction."""
        return QuadratureLobe("mirror", self.exponent)

    def selection_hint(self):
        return max_over_channels(self.rho_s)


# ----------------------------------------------------------------------------- modified Phong


def _modified_phong_lobe(wi, wo, exponent):
    """``(n+2)/(2 pi) cos^n(alpha_r)``: the lobe normalised on the cosine-weighted hemisphere."""
    return (exponent + 2.0) * INV_TWO_PI * cos_alpha_r_pow(wi, wo, exponent)


class ModifiedPhong(AbstractBRDF):
    """Modified Phong BRDF (Lafortune & Willems 1994, eq. (3); also Lewis 1994; models.md 4.7)::

        f = rho_d / pi + rho_s (n+2)/(2 pi) cos^n(alpha_r),      cos(alpha_r) = max(0, r_o.wi)

    Reciprocal (``r_o.wi = r_i.wo``). ``(n+2)/(2 pi)`` makes the specular albedo exactly ``rho_s``
    at normal view (``Int cos^n(theta) cos(theta) dw = 2 pi/(n+2)``) and smaller elsewhere, so the
    model conserves energy iff ``rho_d + rho_s <= 1`` per channel (validated for concrete values).

    Sampling: lobe ``d`` with probability ``p_d = max rho_d/(max rho_d + max rho_s)`` (maxima over
    channels), cosine hemisphere; otherwise the power-cosine lobe about ``r_o``. ``pdf`` is the
    mixture ``p_d cos(theta_i)/pi + (1-p_d)(n+1)/(2 pi) cos^n(alpha_r)`` on the upper hemisphere;
    specular samples below the horizon fail.
    """

    rho_d: Channels = bounded(0.3, lo=0.0, hi=1.0, channels=True)
    rho_s: Channels = bounded(0.5, lo=0.0, hi=1.0, channels=True)
    exponent: Scalar = bounded(20.0, lo=0.0, hi=EXPONENT_MAX)

    def __check_init__(self):
        owner = "ModifiedPhong"
        check_param("rho_d", self.rho_d, lo=0.0, hi=1.0, owner=owner)
        check_param("rho_s", self.rho_s, lo=0.0, hi=1.0, owner=owner)
        check_exponent(self.exponent, owner)
        check_sum_at_most_one(self.rho_d, self.rho_s, "rho_d + rho_s", owner)

    def _p_d(self):
        return lobe_probability(max_over_channels(self.rho_d), max_over_channels(self.rho_s))

    def eval(self, wi, wo):
        ok = upper(wi, wo)
        lobe = _modified_phong_lobe(wi, wo, self.exponent)
        ch = self.channels()
        val = self.rho_d * INV_PI + self.rho_s * expand_channels(lobe, ch)
        return jnp.where(expand_channels(ok, ch), val, 0.0)

    def pdf(self, wi, wo):
        return diffuse_mirror_pdf(wi, wo, self.exponent, self._p_d())

    def sample(self, wo, uc, u):
        return sample_diffuse_or_mirror(self, wo, uc, u, self.exponent, self._p_d())

    def quadrature_lobe(self) -> QuadratureLobe:
        """Quadrature hint (:func:`brdf_fit.verify.albedo.lobe_rule`): a power-cosine lobe about the
        mirror direction."""
        return QuadratureLobe("mirror", self.exponent)

    def selection_hint(self):
        return max_over_channels(self.rho_d) + max_over_channels(self.rho_s)


_FRESNEL = ("schlick", "dielectric")


class ModifiedPhongFresnel(AbstractBRDF):
    """Modified Phong (Lafortune & Willems 1994, eq. (3)) with the specular reflectance replaced
    by a Fresnel term evaluated at the half-vector angle::

        f = rho_d / pi + F(wo.h) (n+2)/(2 pi) cos^n(alpha_r),     h = normalize(wi + wo)

    ``wo.h = wi.h``, so the model stays reciprocal. ``fresnel="schlick"``: Schlick 1994 eq. (24),
    ``F = f0 + (1 - f0)(1 - wo.h)^5``; ``fresnel="dielectric"``: the exact unpolarised dielectric
    Fresnel factor at the index ``eta = (1 + sqrt(f0))/(1 - sqrt(f0))`` whose normal-incidence
    reflectance is ``f0`` (:func:`brdf_fit.fresnel.ior_from_f0`; ``f0 < 1`` required). ``f0``
    may carry channels. ``F <= 1`` so the specular albedo is at most that of modified Phong with
    ``rho_s = 1``; energy conservation is not guaranteed for ``rho_d + F > 1`` (measured in
    :func:`registry_entries`).

    Sampling as :class:`ModifiedPhong`, with ``max f0`` in place of ``max rho_s``.
    """

    rho_d: Channels = bounded(0.3, lo=0.0, hi=1.0, channels=True)
    f0: Channels = bounded(0.04, lo=0.0, hi=1.0, channels=True)
    exponent: Scalar = bounded(20.0, lo=0.0, hi=EXPONENT_MAX)
    fresnel: str = eqx.field(static=True, default="schlick")

    def __check_init__(self):
        owner = "ModifiedPhongFresnel"
        if self.fresnel not in _FRESNEL:
            raise ParameterError(f"{owner}: fresnel must be one of {_FRESNEL}, got "
                                 f"{self.fresnel!r}")
        check_param("rho_d", self.rho_d, lo=0.0, hi=1.0, owner=owner)
        hi_open = self.fresnel == "dielectric"
        check_param("f0", self.f0, lo=0.0, hi=1.0, hi_open=hi_open, owner=owner)
        check_exponent(self.exponent, owner)

    def _p_d(self):
        return lobe_probability(max_over_channels(self.rho_d), max_over_channels(self.f0))

    def _F(self, cos):
        if self.fresnel == "schlick":
            return schlick(cos, self.f0)
        return dielectric(cos, ior_from_f0(self.f0))

    def eval(self, wi, wo):
        ok = upper(wi, wo)
        _, (ox, oy, oz), (hx, hy, hz), _ = half_vector(wi, wo)
        d = jnp.clip(ox * hx + oy * hy + oz * hz, 0.0, 1.0)
        lobe = _modified_phong_lobe(wi, wo, self.exponent)
        ch = self.channels()
        F = self._F(expand_channels(jnp.where(ok, d, 1.0), ch))
        val = self.rho_d * INV_PI + F * expand_channels(lobe, ch)
        return jnp.where(expand_channels(ok, ch), val, 0.0)

    def pdf(self, wi, wo):
        return diffuse_mirror_pdf(wi, wo, self.exponent, self._p_d())

    def sample(self, wo, uc, u):
        return sample_diffuse_or_mirror(self, wo, uc, u, self.exponent, self._p_d())

    def quadrature_lobe(self) -> QuadratureLobe:
        """Quadrature hint (:func:`brdf_fit.verify.albedo.lobe_rule`): a power-cosine lobe about the
        mirror direction."""
        return QuadratureLobe("mirror", self.exponent)

    def selection_hint(self):
        return max_over_channels(self.rho_d) + max_over_channels(self.f0)


# ----------------------------------------------------------------------------- Blinn-Phong

_NORMALISATIONS = ("ndf", "approx", "none")


class BlinnPhong(AbstractBRDF):
    """Blinn-Phong specular BRDF (Blinn 1977, eq. for ``cos^c`` of the half-vector angle;
    models.md 4.9)::

        f = rho_s K(n) cos^n(theta_h),        cos(theta_h) = max(0, n.h),  h = normalize(wi + wo)

    ``normalisation``:

    * ``"ndf"``: ``K = (n+2)/(2 pi)``. Normalises the *distribution of normals*
      ``D(h) = K cos^n(theta_h)``: ``Int D(h) (n.h) dh = 1`` (Walter et al. 2007, section 5.2).
      It does **not** normalise this BRDF (that needs the microfacet form ``F D G/(4 cl cv)``, see
      :class:`~brdf_fit.microfacet.BlinnPhongNDF`): the albedo at normal view is
      ``4 (2^(-n/2) + n)/(n+4)``, about 4 for large ``n``.
    * ``"approx"``: ``K = (n+8)/(8 pi)``, the approximate BRDF normalisation of Akenine-Moller,
      Haines & Hoffman (Real-Time Rendering 3rd ed. 2008; Hoffman 2010): approximates the exact
      normal-view normalisation ``(n+2)(n+4)/(8 pi (2^(-n/2) + n))`` (Giesen 2009), with which the
      albedo at normal view is 1; with ``(n+8)/(8 pi)`` it is ``(n+8)(2^(-n/2)+n)/((n+2)(n+4))``,
      up to about 1.075 (n ~ 8..10).
    * ``"none"``: ``K = 1`` (Blinn's original, un-normalised).

    Reciprocal. Sampler: ``cos(theta_h) = u^(1/(n+1))`` (density ``(n+1)/(2 pi) cos^n(theta_h)``
    over ``h``), ``wi = reflect(wo, h)``, ``pdf(wi) = (n+1)/(2 pi) cos^n(theta_h) / (4 wo.h)``;
    a sample fails (pdf 0, weight 0) when ``wi`` is below the horizon or ``wo.h <= 0``.
    """

    rho_s: Channels = bounded(0.5, lo=0.0, hi=1.0, channels=True)
    exponent: Scalar = bounded(20.0, lo=0.0, hi=EXPONENT_MAX)
    normalisation: str = eqx.field(static=True, default="ndf")

    def __check_init__(self):
        owner = "BlinnPhong"
        if self.normalisation not in _NORMALISATIONS:
            raise ParameterError(f"{owner}: normalisation must be one of {_NORMALISATIONS}, got "
                                 f"{self.normalisation!r}")
        check_param("rho_s", self.rho_s, lo=0.0, hi=1.0, owner=owner)
        check_exponent(self.exponent, owner)

    def _K(self):
        n = self.exponent
        if self.normalisation == "ndf":
            return (n + 2.0) * INV_TWO_PI
        if self.normalisation == "approx":
            return (n + 8.0) * (0.125 * INV_PI)
        return 1.0

    @staticmethod
    def _half(wi, wo):
        _, (ox, oy, oz), (hx, hy, hz), hok = half_vector(wi, wo)
        return hz, ox * hx + oy * hy + oz * hz, hok

    def eval(self, wi, wo):
        hz, _, hok = self._half(wi, wo)
        ok = upper(wi, wo) & hok
        val = self._K() * safe_pow(jnp.maximum(hz, 0.0), self.exponent)
        return scaled_where(ok, self.rho_s, val, self.channels())

    def pdf(self, wi, wo):
        hz, d, hok = self._half(wi, wo)
        ok = upper(wi, wo) & hok & (d > 0)
        ph = (self.exponent + 1.0) * INV_TWO_PI * safe_pow(jnp.maximum(hz, 0.0), self.exponent)
        return jnp.where(ok, safe_div(ph, 4.0 * d), 0.0)

    def sample(self, wo, uc, u):
        wos, ok = sanitize_wo(wo)
        wi, d = reflect_about_half(wos, power_cosine_local(u, self.exponent))
        return finish_sample(self, wi, wo, ok & (d[..., 0] > 0))

    def quadrature_lobe(self) -> QuadratureLobe:
        """Quadrature hint (:func:`brdf_fit.verify.albedo.lobe_rule`): a half-vector lobe of the
        equivalent Beckmann width ``sqrt(2/(n+2))`` (Walter et al. 2007, sec. 5.2)."""
        return QuadratureLobe("half", jnp.sqrt(2.0 / (jnp.asarray(self.exponent) + 2.0)))

    def selection_hint(self):
        return max_over_channels(self.rho_s)


# ----------------------------------------------------------------------------- registry entries


# Measured with brdf_fit.checks.run_checks on the default parameters (float64); the slow test
# tests/test_phong.py::test_registry_entries_run_checks asserts that each still fails. The checks
# integrate these lobes with brdf_fit.core.mirror_rule.mirror_lobe_rule (Phong lobes) and the
# half-vector rule at the equivalent Beckmann width (Blinn-Phong), via quadrature_lobe().
_PHONG_ORIGINAL_FAILURES: dict[str, str] = {
    "reciprocity": (
        "divides by cos(theta_i) (Phong 1975 as a BRDF): not reciprocal (measured max relative "
        "asymmetry 2.5 at n = 20; f cos(theta_i) is symmetric)"
    ),
}
_BLINN_NDF_FAILURES: dict[str, str] = {
    "energy": (
        "(n+2)/(2 pi) normalises the NDF, not this BRDF: albedo at normal view "
        "rho_s 4 (2^(-n/2) + n)/(n+4), measured 1.66675 for rho_s = 0.5, n = 20 (-> 4 rho_s as "
        "n grows)"
    ),
}


def registry_entries():
    """:class:`brdf_fit.registry.Entry` objects for the Phong family (not registered here).

    ``expected_failures`` hold the values measured with :func:`brdf_fit.checks.run_checks` at the
    default parameters (see tests/test_phong.py for the measurements that back them).
    """
    def unit(name, default, doc):
        return Param(name, default, lo=0.0, hi=1.0, channels=True, doc=doc)

    def expo(default, doc="Phong exponent n (lobe sharpness)"):
        return Param("exponent", default, lo=0.0, hi=EXPONENT_MAX, doc=doc)

    return [
        Entry(
            name="phong-original",
            year=1975,
            catalogue="Phong",
            sampler="exact power-cosine lobe",
            builder=lambda rho_s, exponent: PhongOriginal(rho_s=rho_s, exponent=exponent),
            params=(unit("rho_s", (0.5, 0.5, 0.5), "specular reflectance"), expo(20.0)),
            reference=f"{_PHONG_1975}; as a BRDF with the 1/cos(theta_i): models.md 4.6",
            description=(
                "Phong 1975 read literally as a BRDF: "
                "rho_s (n+1)/(2 pi) cos^n(alpha_r)/cos(theta_i) (lobe normalised over the "
                "sphere; albedo <= rho_s; not reciprocal)"
            ),
            aliases=("phong-1975",),
            expected_failures=_PHONG_ORIGINAL_FAILURES,
        ),
        Entry(
            name="modified-phong",
            year=1994,
            catalogue="Phong",
            sampler="cosine + power-cosine lobe (mixture)",
            builder=lambda rho_d, rho_s, exponent: ModifiedPhong(
                rho_d=rho_d, rho_s=rho_s, exponent=exponent),
            params=(unit("rho_d", (0.3, 0.2, 0.1), "diffuse albedo"),
                    unit("rho_s", (0.5, 0.5, 0.5), "specular albedo at normal view (rho_d + "
                         "rho_s <= 1)"),
                    expo(20.0)),
            reference=_LW_1994,
            description="rho_d/pi + rho_s (n+2)/(2 pi) cos^n(alpha_r); reciprocal, conserving",
            aliases=("phong", "lafortune-willems-phong"),
        ),
        Entry(
            name="modified-phong-fresnel",
            year=1994,
            catalogue="Phong",
            sampler="cosine + power-cosine lobe (mixture)",
            builder=lambda rho_d, f0, exponent: ModifiedPhongFresnel(
                rho_d=rho_d, f0=f0, exponent=exponent),
            params=(unit("rho_d", (0.3, 0.2, 0.1), "diffuse albedo"),
                    unit("f0", (0.04, 0.04, 0.04), "normal-incidence reflectance (Schlick)"),
                    expo(20.0)),
            reference=f"{_LW_1994}; C. Schlick, Computer Graphics Forum 13(3) 1994",
            description="modified Phong with Schlick F(wo.h) as the specular reflectance",
        ),
        Entry(
            name="blinn-phong",
            year=1977,
            catalogue="Blinn-Phong",
            sampler="exact half-vector lobe",
            builder=lambda rho_s, exponent: BlinnPhong(rho_s=rho_s, exponent=exponent,
                                                       normalisation="ndf"),
            params=(unit("rho_s", (0.5, 0.5, 0.5), "specular scale"), expo(20.0)),
            reference=f"{_BLINN_1977}; NDF normalisation (n+2)/(2 pi): Walter et al. 2007, 5.2",
            description="rho_s (n+2)/(2 pi) cos^n(theta_h) (NDF-normalised, not BRDF-normalised)",
            expected_failures=_BLINN_NDF_FAILURES,
        ),
        Entry(
            name="blinn-phong-approx",
            year=1977,
            catalogue="Blinn-Phong",
            sampler="exact half-vector lobe",
            builder=lambda rho_s, exponent: BlinnPhong(rho_s=rho_s, exponent=exponent,
                                                       normalisation="approx"),
            params=(unit("rho_s", (0.5, 0.5, 0.5), "specular scale"), expo(20.0)),
            reference=f"{_BLINN_1977}; normalisation (n+8)/(8 pi): {_RTR3}",
            description=(
                "rho_s (n+8)/(8 pi) cos^n(theta_h) (approximately BRDF-normalised: normal-view "
                "albedo rho_s (n+8)(2^(-n/2)+n)/((n+2)(n+4)), up to 1.075 rho_s at n ~ 8..10, "
                "1.0607 rho_s at n = 20; passes 'energy' at the default rho_s = 0.5)"
            ),
        ),
    ]
