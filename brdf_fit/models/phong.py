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

import math

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from brdf_fit.core.frame import frame_from_normal, join, split, to_world
from brdf_fit.core.fresnel import dielectric, ior_from_f0, schlick
from brdf_fit.core.numerics import safe_div, safe_normalize3, safe_pow, safe_sqrt
from brdf_fit.core.params import Entry, Param
from brdf_fit.core.validate import ParameterError, check_param, concrete
from brdf_fit.core.warp import sample_cosine_hemisphere
from brdf_fit.models._base import AbstractBRDF, BRDFSample, sample_weight, expand_channels

__all__ = [
    "PhongOriginal",
    "ModifiedPhong",
    "ModifiedPhongFresnel",
    "BlinnPhong",
    "registry_entries",
]

INV_PI = 1.0 / math.pi
INV_TWO_PI = 0.5 / math.pi

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


# ----------------------------------------------------------------------------- geometry helpers


def _cos_alpha_r(wi, wo):
    """``max(0, r_o.wi) = max(0, 2 (n.wi)(n.wo) - wi.wo)`` (symmetric in wi and wo)."""
    ix, iy, iz = split(wi)
    ox, oy, oz = split(wo)
    return jnp.maximum(2.0 * iz * oz - (ix * ox + iy * oy + iz * oz), 0.0)


def _upper(wi, wo):
    return (wi[..., 2] > 0) & (wo[..., 2] > 0)


def _sanitize_wo(wo):
    """``wo`` where it is above the horizon, the normal elsewhere (and the flag)."""
    ok = wo[..., 2] > 0
    okv = ok[..., None]
    n = jnp.zeros_like(wo).at[..., 2].set(1.0)
    return jnp.where(okv, wo, n), ok


def _power_cosine_local(u, exponent):
    """Power-cosine lobe about +z: ``cos = u0^(1/(n+1))`` (Lafortune & Willems 1994, section 3),
    with ``1 - cos`` from ``expm1`` so narrow lobes (n = 1e4..1e6) keep their width in float32."""
    u0 = u[..., 0]
    ok = u0 > 0
    lu = jnp.log(jnp.where(ok, u0, 1.0)) / (exponent + 1.0)
    one_minus = jnp.where(ok, -jnp.expm1(lu), 1.0)  # 1 - cos; cos = 0 when u0 = 0
    z = 1.0 - one_minus
    r = safe_sqrt(one_minus * (2.0 - one_minus))
    phi = 2.0 * math.pi * u[..., 1]
    return join(r * jnp.cos(phi), r * jnp.sin(phi), z)


def _sample_lobe_about_mirror(wo, u, exponent):
    """Power-cosine sample about ``r_o = mirror(wo)`` (``wo`` assumed above the horizon)."""
    r = wo * jnp.asarray([-1.0, -1.0, 1.0], dtype=wo.dtype)
    t, b, nn = frame_from_normal(r)
    w = to_world(_power_cosine_local(u, exponent), t, b, nn)
    x, y, z, _ = safe_normalize3(w[..., 0], w[..., 1], w[..., 2])
    return join(x, y, z)


def _lobe_pdf(wi, wo, exponent):
    """``(n+1)/(2 pi) max(0, r_o.wi)^n`` (the power-cosine density, whole-sphere normalised)."""
    return (exponent + 1.0) * INV_TWO_PI * safe_pow(_cos_alpha_r(wi, wo), exponent)


def _max_over_channels(x):
    return jnp.max(jnp.asarray(x))


def _check_exponent(exponent, owner):
    check_param("exponent", exponent, lo=0.0, owner=owner)
    v = concrete(exponent)
    if v is not None and v.dtype != object and v.ndim != 0:
        raise ParameterError(f"{owner}: parameter 'exponent' must be a scalar, got shape {v.shape}")


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

    rho_s: object = 0.5
    exponent: object = 20.0

    def __check_init__(self):
        check_param("rho_s", self.rho_s, lo=0.0, hi=1.0, owner="PhongOriginal")
        _check_exponent(self.exponent, "PhongOriginal")

    def eval(self, wi, wo):
        ok = _upper(wi, wo)
        lobe = _lobe_pdf(wi, wo, self.exponent)
        val = safe_div(lobe, jnp.where(ok, wi[..., 2], 0.0))
        ch = self.channels()
        return jnp.where(expand_channels(ok, ch), self.rho_s * expand_channels(val, ch), 0.0)

    def pdf(self, wi, wo):
        return jnp.where(_upper(wi, wo), _lobe_pdf(wi, wo, self.exponent), 0.0)

    def sample(self, wo, uc, u):
        wos, ok = _sanitize_wo(wo)
        wi = _sample_lobe_about_mirror(wos, u, self.exponent)
        pdf = jnp.where(ok, self.pdf(wi, wo), 0.0)
        return BRDFSample(wi=wi, pdf=pdf, weight=sample_weight(self, wi, wo, pdf))

    def quadrature_lobe(self):
        """Quadrature hint (:func:`brdf_fit.verify.albedo.lobe_rule`): a power-cosine lobe about the
        mirror direction."""
        return "mirror", self.exponent

    def selection_hint(self):
        return _max_over_channels(self.rho_s)


# ----------------------------------------------------------------------------- modified Phong


def _lobe_probability(hint_d, hint_s):
    """``p_d = hint_d / (hint_d + hint_s)`` (1 when both vanish: then nothing reflects)."""
    tot = hint_d + hint_s
    return jnp.where(tot > 0, safe_div(hint_d, tot), 1.0)


def _mixture_sample(model, wo, uc, u, p_d):
    """Classic one-sample lobe choice: ``uc < p_d``: cosine hemisphere, else the power-cosine lobe
    about ``r_o``; the returned pdf is the combined mixture pdf ``model.pdf``."""
    wos, ok = _sanitize_wo(wo)
    wd = sample_cosine_hemisphere(u)
    ws = _sample_lobe_about_mirror(wos, u, model.exponent)
    wi = jnp.where((uc < p_d)[..., None], wd, ws)
    pdf = jnp.where(ok, model.pdf(wi, wo), 0.0)
    return BRDFSample(wi=wi, pdf=pdf, weight=sample_weight(model, wi, wo, pdf))


def _mixture_pdf(wi, wo, exponent, p_d):
    diff = jnp.maximum(wi[..., 2], 0.0) * INV_PI
    spec = _lobe_pdf(wi, wo, exponent)
    return jnp.where(_upper(wi, wo), p_d * diff + (1.0 - p_d) * spec, 0.0)


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

    rho_d: object = 0.3
    rho_s: object = 0.5
    exponent: object = 20.0

    def __check_init__(self):
        owner = "ModifiedPhong"
        check_param("rho_d", self.rho_d, lo=0.0, hi=1.0, owner=owner)
        check_param("rho_s", self.rho_s, lo=0.0, hi=1.0, owner=owner)
        _check_exponent(self.exponent, owner)
        d, s = concrete(self.rho_d), concrete(self.rho_s)
        if d is not None and s is not None and d.dtype != object and s.dtype != object:
            tot = np.asarray(d, dtype=float) + np.asarray(s, dtype=float)
            if np.any(tot > 1.0):
                raise ParameterError(
                    f"{owner}: rho_d + rho_s must be <= 1 in every channel (energy "
                    f"conservation), got rho_d + rho_s = {tot.tolist()}"
                )

    def _p_d(self):
        return _lobe_probability(_max_over_channels(self.rho_d), _max_over_channels(self.rho_s))

    def eval(self, wi, wo):
        ok = _upper(wi, wo)
        lobe = (self.exponent + 2.0) * INV_TWO_PI * safe_pow(_cos_alpha_r(wi, wo), self.exponent)
        ch = self.channels()
        val = self.rho_d * INV_PI + self.rho_s * expand_channels(lobe, ch)
        return jnp.where(expand_channels(ok, ch), val, 0.0)

    def pdf(self, wi, wo):
        return _mixture_pdf(wi, wo, self.exponent, self._p_d())

    def sample(self, wo, uc, u):
        return _mixture_sample(self, wo, uc, u, self._p_d())

    def quadrature_lobe(self):
        """Quadrature hint (:func:`brdf_fit.verify.albedo.lobe_rule`): a power-cosine lobe about the
        mirror direction."""
        return "mirror", self.exponent

    def selection_hint(self):
        return _max_over_channels(self.rho_d) + _max_over_channels(self.rho_s)


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

    rho_d: object = 0.3
    f0: object = 0.04
    exponent: object = 20.0
    fresnel: str = eqx.field(static=True, default="schlick")

    def __check_init__(self):
        owner = "ModifiedPhongFresnel"
        if self.fresnel not in _FRESNEL:
            raise ParameterError(f"{owner}: fresnel must be one of {_FRESNEL}, got "
                                 f"{self.fresnel!r}")
        check_param("rho_d", self.rho_d, lo=0.0, hi=1.0, owner=owner)
        hi_open = self.fresnel == "dielectric"
        check_param("f0", self.f0, lo=0.0, hi=1.0, hi_open=hi_open, owner=owner)
        _check_exponent(self.exponent, owner)

    def _p_d(self):
        return _lobe_probability(_max_over_channels(self.rho_d), _max_over_channels(self.f0))

    def _F(self, cos):
        if self.fresnel == "schlick":
            return schlick(cos, self.f0)
        return dielectric(cos, ior_from_f0(self.f0))

    def eval(self, wi, wo):
        ok = _upper(wi, wo)
        ix, iy, iz = split(wi)
        ox, oy, oz = split(wo)
        hx, hy, hz, _ = safe_normalize3(ix + ox, iy + oy, iz + oz)
        d = jnp.clip(ox * hx + oy * hy + oz * hz, 0.0, 1.0)
        lobe = (self.exponent + 2.0) * INV_TWO_PI * safe_pow(_cos_alpha_r(wi, wo), self.exponent)
        ch = self.channels()
        F = self._F(expand_channels(jnp.where(ok, d, 1.0), ch))
        val = self.rho_d * INV_PI + F * expand_channels(lobe, ch)
        return jnp.where(expand_channels(ok, ch), val, 0.0)

    def pdf(self, wi, wo):
        return _mixture_pdf(wi, wo, self.exponent, self._p_d())

    def sample(self, wo, uc, u):
        return _mixture_sample(self, wo, uc, u, self._p_d())

    def quadrature_lobe(self):
        """Quadrature hint (:func:`brdf_fit.verify.albedo.lobe_rule`): a power-cosine lobe about the
        mirror direction."""
        return "mirror", self.exponent

    def selection_hint(self):
        return _max_over_channels(self.rho_d) + _max_over_channels(self.f0)


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

    rho_s: object = 0.5
    exponent: object = 20.0
    normalisation: str = eqx.field(static=True, default="ndf")

    def __check_init__(self):
        owner = "BlinnPhong"
        if self.normalisation not in _NORMALISATIONS:
            raise ParameterError(f"{owner}: normalisation must be one of {_NORMALISATIONS}, got "
                                 f"{self.normalisation!r}")
        check_param("rho_s", self.rho_s, lo=0.0, hi=1.0, owner=owner)
        _check_exponent(self.exponent, owner)

    def _K(self):
        n = self.exponent
        if self.normalisation == "ndf":
            return (n + 2.0) * INV_TWO_PI
        if self.normalisation == "approx":
            return (n + 8.0) * (0.125 * INV_PI)
        return 1.0

    @staticmethod
    def _half(wi, wo):
        ix, iy, iz = split(wi)
        ox, oy, oz = split(wo)
        hx, hy, hz, hok = safe_normalize3(ix + ox, iy + oy, iz + oz)
        return hz, ox * hx + oy * hy + oz * hz, hok

    def eval(self, wi, wo):
        hz, _, hok = self._half(wi, wo)
        ok = _upper(wi, wo) & hok
        val = self._K() * safe_pow(jnp.maximum(hz, 0.0), self.exponent)
        ch = self.channels()
        return jnp.where(expand_channels(ok, ch), self.rho_s * expand_channels(val, ch), 0.0)

    def pdf(self, wi, wo):
        hz, d, hok = self._half(wi, wo)
        ok = _upper(wi, wo) & hok & (d > 0)
        ph = (self.exponent + 1.0) * INV_TWO_PI * safe_pow(jnp.maximum(hz, 0.0), self.exponent)
        return jnp.where(ok, safe_div(ph, 4.0 * d), 0.0)

    def sample(self, wo, uc, u):
        wos, ok = _sanitize_wo(wo)
        h = _power_cosine_local(u, self.exponent)
        d = jnp.sum(wos * h, axis=-1, keepdims=True)
        wi = 2.0 * d * h - wos
        ok = ok & (d[..., 0] > 0)
        pdf = jnp.where(ok, self.pdf(wi, wo), 0.0)
        return BRDFSample(wi=wi, pdf=pdf, weight=sample_weight(self, wi, wo, pdf))

    def quadrature_lobe(self):
        """Quadrature hint (:func:`brdf_fit.verify.albedo.lobe_rule`): a half-vector lobe of the
        equivalent Beckmann width ``sqrt(2/(n+2))`` (Walter et al. 2007, sec. 5.2)."""
        return "half", jnp.sqrt(2.0 / (jnp.asarray(self.exponent) + 2.0))

    def selection_hint(self):
        return _max_over_channels(self.rho_s)


# ----------------------------------------------------------------------------- registry entries


# Measured with brdf_fit.checks.run_checks on the default parameters (float64); the slow test
# tests/test_phong.py::test_registry_entries_run_checks asserts that each still fails. The checks
# integrate these lobes with brdf_fit.quadrature.mirror_lobe_rule (Phong lobes) and the
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
        return Param("exponent", default, lo=0.0, hi=1e6, doc=doc)

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
