"""Burley's Disney "principled" BRDF (2012), reflection lobes: :class:`DisneyBRDF`.

Sources. B. Burley, "Physically-Based Shading at Disney", SIGGRAPH 2012 course "Practical
Physically-Based Shading in Film and Game Production" (revised Aug 31 2012): section 5 (the
parameter list), 5.3 (diffuse with the Fresnel-like retro-reflection factor, and the
Hanrahan-Krueger-like "subsurface" flattening), 5.4 (specular D: the GTR family, eq. 4, with the
corrected normalisation; the clearcoat layer and its GTR1), 5.5 (Schlick F), 5.6 (Smith GGX G
with the roughness remapped for G), appendix B (importance sampling of GTR1 and GTR2); the
anisotropic aspect ratio of the addenda. The reference implementation is
``src/brdfs/disney.brdf`` of Disney's BRDF Explorer (github.com/wdas/brdf), function
``BRDF(L, V, N, X, Y)``. Its 2012 revision computes G isotropically at the remapped roughness
(``roughg``), as section 5.6 says; the file's later revision (the one on the repository's
master branch) uses the anisotropic G at the D's widths without the remapping, offered here as
``masking="anisotropic"``. No code or text of either source is copied here; the formulas are
restated in our notation.

Notation: ``wi`` toward the light (the file's ``L``), ``wo`` toward the viewer (``V``), local
frame ``n = z``, tangent ``x`` (the file's ``X``), bitangent ``y`` (``Y``); ``ci = n.wi``,
``co = n.wo``, ``h = normalize(wi + wo)``, ``d = wi.h`` (the file's ``LdotH``; ``= wo.h``, taken
here as ``|wi + wo|/2``, which is symmetric in the two directions), ``w(c) = (1 - c)^5``
(Schlick's weight, clamped), ``lerp(a, b, t) = a + t (b - a)``, ``r = roughness``,
``m = metallic``. Every formula is written with dot products (no angles)::

    f = (1 - m) [ lerp(Fd, ss, subsurface) Cd / pi + sheen w(d) Csheen ]
        + Fs D Gs + clearcoat/4 Fr Dr Gr                                   (disney.brdf, BRDF)

    Cd      = baseColor^2.2          (mon2lin: baseColor is the Explorer's display colour;
                                      ``mon2lin=False`` takes a linear colour as it is)
    lum     = 0.3 Cd.R + 0.6 Cd.G + 0.1 Cd.B,  Ctint = Cd/lum (1 where lum = 0)
    Cspec0  = lerp(0.08 specular lerp(1, Ctint, specularTint), Cd, m)
    Csheen  = lerp(1, Ctint, sheenTint)
    Fd      = (1 + (Fd90 - 1) w(ci)) (1 + (Fd90 - 1) w(co)),  Fd90 = 1/2 + 2 r d^2     (5.3)
    ss      = 1.25 (Fss (1/(ci + co) - 1/2) + 1/2),
    Fss     = (1 + (Fss90 - 1) w(ci)) (1 + (Fss90 - 1) w(co)),  Fss90 = r d^2   (disney.brdf)
    aspect  = sqrt(1 - 0.9 anisotropic),  ax = max(0.001, r^2/aspect), ay = max(0.001, r^2 aspect)
    D       = 1 / (pi ax ay ((h.x/ax)^2 + (h.y/ay)^2 + (h.z)^2)^2)      GTR2 = GGX (5.4, eq. 4)
    Fs      = Cspec0 + (1 - Cspec0) w(d)                                       Schlick (5.5)
    Gs      = 1 / ((ci + P_g(wi)) (co + P_g(wo)))                         Smith GGX (5.6), i.e.
              G1(wi) G1(wo) / (4 ci co) with G1(w) = 2 (n.w)/((n.w) + P_g(w))
              "2012":        P_g(w) = sqrt(ag^2 ((w.x)^2 + (w.y)^2) + (w.z)^2),
                             ag = (1/2 + r/2)^2                  (the remapping of 5.6)
              "anisotropic": P_g(w) = sqrt((ax w.x)^2 + (ay w.y)^2 + (w.z)^2)
    Dr      = (ac^2 - 1) / (pi log(ac^2) ((h.x)^2 + (h.y)^2 + ac^2 (h.z)^2)),
              ac = lerp(0.1, 0.001, clearcoatGloss)                   GTR1 (5.4, eq. 4, gamma=1)
    Fr      = 0.04 + 0.96 w(d)                              (clearcoat, ior 1.5 -> F0 = 0.04)
    Gr      = 1 / ((ci + P_c(wi)) (co + P_c(wo))),  P_c(w) = sqrt(0.0625 ((w.x)^2 + (w.y)^2)
              + (w.z)^2)                      (Smith GGX at the fixed alpha 0.25, as Gs's form)

``sqrt(ag^2 + c^2 - ag^2 c^2)`` of the file equals ``P_g`` for unit directions (``1 - c^2 =
x^2 + y^2``) and ``1 + (ac^2 - 1)(n.h)^2`` equals ``h.x^2 + h.y^2 + ac^2 h.z^2`` for a unit
``h``; the forms here avoid the cancellations near the horizon and near the clearcoat's peak.
``disney.brdf`` returns the BRDF itself (the Explorer multiplies by the cosine): ``Gs`` and
``Gr`` already hold the ``1/(4 ci co)``, so ``eval`` is ``f`` without the cosine, as the
library's convention wants. Both G factors are the uncorrelated (separable) Smith form.

Departures from the reference (each deliberate):

* the file returns 0 only for ``ci < 0`` or ``co < 0``; the library's convention is 0 at
  ``ci <= 0`` or ``co <= 0`` (the horizon itself), and where ``wi + wo`` vanishes;
* ``d = |wi + wo|/2`` instead of ``wi.h`` (equal for unit vectors; this form makes ``f``
  exactly reciprocal in floating point, also for directions unit only to rounding).

Channels: ``baseColor`` is RGB (a trailing axis of 3) or grey (a scalar: ``Ctint = 1``).
``Ctint`` divides by the luminance of all three channels, so ``specularTint`` and ``sheenTint``
couple the colour channels (a channel's value depends on the other channels' baseColor).

Numerics: the widths are clamped at :data:`DISNEY_ALPHA_MIN` = 0.001, the reference's own
clamp (gradient 0 below it); directions at or below the horizon and pairs without a half vector
are replaced by the normal before any formula sees them and masked afterwards (double where,
:func:`brdf_fit.models._lobes.half_geometry`); on unit vectors ``P_g, P_c >= 0.25 sin``,
``P >= 0.001 sin`` and all of them ``>= z``, so no square root sees 0; ``1/(ci + co)``, ``D``,
``Dr`` are bounded on valid lanes (``ax`` reaches ``1/sqrt(0.1)`` at ``r = 1``, anisotropic 1: D's
denominator stays >= 0.1^2); ``Cd/lum`` is a double where (0 gradient at black); ``mon2lin``
is :func:`brdf_fit.core.numerics.safe_pow` (finite derivative 0 at 0).

Sampling (exact mixture; the ``uc`` uniform picks the lobe): with probability ``p_d`` the
cosine hemisphere (for the diffuse, subsurface and sheen terms), ``p_c`` the clearcoat's GTR1
half vectors (Burley 2012, appendix B: ``phi = 2 pi u1``, ``cos^2(theta_h) = (1 - ac^(2 (1 - u2)))/
(1 - ac^2)``, written with ``expm1``), otherwise GGX visible normals of the specular D's widths
(spherical caps, :meth:`brdf_fit.core.microfacet.GGX.sample_visible`; the "2012" G is not D's
own Smith G1, but any proposal density is exact for its own pdf). The lobe probabilities are
proportional to ``(1 - m) (max Cd + 0.1 sheen max Csheen)``, ``max Cspec0 + (1 - max
Cspec0)/21`` (the cosine-weighted average of Schlick's F) and ``clearcoat/4 (0.04 + 0.96/21)``;
the specular weight is >= 1/21, so the sum never vanishes. The pdf::

    pdf = p_d ci/pi + p_s D(h) / (2 (co + P(wo))) + p_c Dr(h) (n.h) / (4 d)

with ``P(wo) = sqrt((ax wo.x)^2 + (ay wo.y)^2 + (wo.z)^2)`` (the visible-normal density
``G1(wo) (wo.h) D(h)/co`` times ``dh/dwi = 1/(4 wi.h)``). A reflection at or below the horizon
is a failed sample (pdf 0, weight 0); a GTR1 or visible normal with ``wo.m <= 0`` always
reflects below the horizon, so no direction is reached from two half vectors.
"""

from __future__ import annotations

import math

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from brdf_fit.core.frame import join, split
from brdf_fit.core.microfacet import GGX, reflect_about
from brdf_fit.core.numerics import INV_PI, TWO_PI, pow5, safe_div, safe_pow, safe_sqrt
from brdf_fit.core.params import Channels, Entry, Param, Scalar, bounded
from brdf_fit.core.validate import check_param, check_scalar, concrete
from brdf_fit.core.warp import sample_cosine_hemisphere
from brdf_fit.models._base import AbstractBRDF, QuadratureLobe, expand_channels
from brdf_fit.models._lobes import finish_sample, half_geometry, max_over_channels, sanitize

__all__ = [
    "CLEARCOAT_G_ALPHA",
    "DISNEY_2012_DEFAULTS",
    "DISNEY_ALPHA_MIN",
    "DisneyBRDF",
    "DisneyPart",
    "LUMINANCE_WEIGHTS",
    "MASKINGS",
    "MON2LIN_GAMMA",
    "registry_entries",
]

#: ``max(.001, ...)`` of the reference's ``ax``, ``ay``: the floor of the specular GGX widths
#: (a roughness below ``sqrt(0.001) = 0.032`` has the specular lobe of 0.032; the gradient of
#: the specular lobe in ``roughness`` is 0 there, the diffuse terms still see it).
DISNEY_ALPHA_MIN = 1e-3
#: The clearcoat's Smith G uses the fixed GGX width 0.25 (Burley 2012, section 5 "clearcoat";
#: ``smithG_GGX(., .25)`` in disney.brdf).
CLEARCOAT_G_ALPHA = 0.25
#: ``mon2lin``: the Explorer's display colour is linearised with the power 2.2.
MON2LIN_GAMMA = 2.2
#: The reference's luminance approximation (``Cdlum``), not the Rec. 709 weights.
LUMINANCE_WEIGHTS = (0.3, 0.6, 0.1)
#: Clearcoat GTR1 width: ``lerp(0.1, 0.001, clearcoatGloss)``.
_CC_ALPHA_ROUGH, _CC_ALPHA_GLOSSY = 0.1, 0.001
#: Clearcoat Fresnel: Schlick with ``F0 = 0.04`` (ior 1.5).
_CC_F0 = 0.04
#: The cosine-weighted hemispherical average of Schlick's weight: ``2 Int_0^1 (1 - mu)^5 mu dmu
#: = 1/21`` (used only for the lobe probabilities of the sampler).
_SCHLICK_AVG = 1.0 / 21.0
#: Share of the sheen in the diffuse lobe's sampling weight (the sheen reflects little: its
#: directional albedo at ``sheen = 1`` is a few percent except at grazing views).
_SHEEN_SAMPLING = 0.1
#: ``masking`` choices (module docstring).
MASKINGS = ("2012", "anisotropic")

_PARAMETERS = ("baseColor", "subsurface", "metallic", "specular", "specularTint", "roughness",
               "anisotropic", "sheen", "sheenTint", "clearcoat", "clearcoatGloss")

#: The slider defaults of ``src/brdfs/disney.brdf`` (its ``::begin parameters`` block).
DISNEY_2012_DEFAULTS = {
    "baseColor": (0.82, 0.67, 0.16),
    "subsurface": 0.0,
    "metallic": 0.0,
    "specular": 0.5,
    "specularTint": 0.0,
    "roughness": 0.5,
    "anisotropic": 0.0,
    "sheen": 0.0,
    "sheenTint": 0.5,
    "clearcoat": 0.0,
    "clearcoatGloss": 1.0,
}

_REF_BURLEY_2012 = ("B. Burley, \"Physically-Based Shading at Disney\", SIGGRAPH 2012 course "
                    "\"Practical Physically-Based Shading in Film and Game Production\" (revised "
                    "Aug 31 2012), sections 5.3-5.6, appendix B (sampling)")
_REF_EXPLORER = ("Walt Disney Animation Studios, BRDF Explorer, src/brdfs/disney.brdf "
                 "(github.com/wdas/brdf), 2012 revision")


def _p_smith(x, y, z, a2x, a2y):
    """``sqrt(a2x x^2 + a2y y^2 + z^2)``: Smith GGX's ``G1(w)/(2 n.w) = 1/(z + this)`` with the
    squared widths ``a2x, a2y`` (> 0 on unit vectors above the horizon)."""
    return jnp.sqrt(a2x * x * x + a2y * y * y + z * z)


class DisneyBRDF(AbstractBRDF):
    """Burley's 2012 Disney "principled" BRDF, reflection lobes (module docstring: formulas,
    sources, departures, numerics, sampler).

    Parameters are those of ``disney.brdf`` with its names and [0, 1] intervals: ``baseColor``
    (RGB, a trailing axis of 3, or grey; the Explorer's display colour, linearised by
    ``baseColor^2.2`` unless ``mon2lin=False``), ``subsurface``, ``metallic``, ``specular``,
    ``specularTint``, ``roughness`` (perceptual: the D's widths are ``roughness^2`` stretched by
    the aspect; this is the model's own mapping, not a silent conversion), ``anisotropic``,
    ``sheen``, ``sheenTint``, ``clearcoat``, ``clearcoatGloss``. The class defaults are the
    reference's slider defaults.

    Static options: ``masking`` (``"2012"``: isotropic Smith GGX at the remapped width
    ``(1/2 + roughness/2)^2``, Burley 2012 section 5.6; ``"anisotropic"``: the later revision of
    the reference file, anisotropic Smith GGX at ``(ax, ay)``) and ``mon2lin``.
    """

    baseColor: Channels = bounded((0.82, 0.67, 0.16), lo=0.0, hi=1.0, channels=True,
                                  converter=jnp.asarray)
    subsurface: Scalar = bounded(0.0, lo=0.0, hi=1.0)
    metallic: Scalar = bounded(0.0, lo=0.0, hi=1.0)
    specular: Scalar = bounded(0.5, lo=0.0, hi=1.0)
    specularTint: Scalar = bounded(0.0, lo=0.0, hi=1.0)
    roughness: Scalar = bounded(0.5, lo=0.0, hi=1.0)
    anisotropic: Scalar = bounded(0.0, lo=0.0, hi=1.0)
    sheen: Scalar = bounded(0.0, lo=0.0, hi=1.0)
    sheenTint: Scalar = bounded(0.5, lo=0.0, hi=1.0)
    clearcoat: Scalar = bounded(0.0, lo=0.0, hi=1.0)
    clearcoatGloss: Scalar = bounded(1.0, lo=0.0, hi=1.0)
    masking: str = eqx.field(static=True, default="2012")
    mon2lin: bool = eqx.field(static=True, default=True)

    def __check_init__(self):
        if self.masking not in MASKINGS:
            raise ValueError(f"DisneyBRDF: masking must be one of {MASKINGS}, got "
                             f"{self.masking!r}")
        for name in _PARAMETERS:
            value = getattr(self, name)
            check_param(name, value, lo=0.0, hi=1.0, owner="DisneyBRDF")
            if name != "baseColor":
                check_scalar(name, value, "DisneyBRDF")
        shape = jnp.shape(self.baseColor)
        if len(shape) > 0 and shape[-1] not in (1, 3):
            raise ValueError(f"DisneyBRDF: baseColor must be RGB (a trailing axis of 3) or grey, "
                             f"got shape {shape}")

    # ------------------------------------------------------------------ parameter terms

    def linear_color(self):
        """``Cd``: ``baseColor^2.2`` (``mon2lin``) or ``baseColor`` itself."""
        bc = jnp.asarray(self.baseColor)
        return safe_pow(bc, MON2LIN_GAMMA) if self.mon2lin else bc

    def tint(self, cd=None):
        """``Ctint = Cd / lum(Cd)`` with the reference's weights (0.3, 0.6, 0.1); 1 where the
        luminance is 0 (double where) and for a grey (scalar) colour."""
        cd = self.linear_color() if cd is None else cd
        if cd.ndim == 0 or cd.shape[-1] == 1:
            return jnp.ones_like(cd)
        wr, wg, wb = LUMINANCE_WEIGHTS
        lum = (wr * cd[..., 0] + wg * cd[..., 1] + wb * cd[..., 2])[..., None]
        ok = lum > 0
        return jnp.where(ok, cd * (1.0 / jnp.where(ok, lum, 1.0)), 1.0)

    def colors(self):
        """``(Cd, Cspec0, Csheen)`` (module docstring)."""
        cd = self.linear_color()
        tint = self.tint(cd)
        dielectric = 0.08 * self.specular * (1.0 + self.specularTint * (tint - 1.0))
        cspec0 = dielectric + self.metallic * (cd - dielectric)
        csheen = 1.0 + self.sheenTint * (tint - 1.0)
        return cd, cspec0, csheen

    def widths(self):
        """``(ax, ay)`` of the specular GTR2 (GGX) lobe: ``max(0.001, r^2 / aspect)``,
        ``max(0.001, r^2 aspect)`` with ``aspect = sqrt(1 - 0.9 anisotropic)`` (x = tangent)."""
        aspect = jnp.sqrt(1.0 - 0.9 * self.anisotropic)
        r2 = self.roughness * self.roughness
        return (jnp.maximum(DISNEY_ALPHA_MIN, r2 / aspect),
                jnp.maximum(DISNEY_ALPHA_MIN, r2 * aspect))

    def masking_width(self):
        """``ag = (1/2 + roughness/2)^2``: the GGX width of the "2012" specular G (section 5.6)."""
        a = 0.5 + 0.5 * self.roughness
        return a * a

    def clearcoat_alpha(self):
        """``ac = lerp(0.1, 0.001, clearcoatGloss)``: the GTR1 width of the clearcoat."""
        return _CC_ALPHA_ROUGH + (_CC_ALPHA_GLOSSY - _CC_ALPHA_ROUGH) * self.clearcoatGloss

    def gtr1(self, hx, hy, hz):
        """``Dr(h)`` for a unit ``h`` with ``h.z > 0`` (GTR1, normalised: ``Int Dr (n.h) = 1``)."""
        a = self.clearcoat_alpha()
        a2 = a * a
        return (a2 - 1.0) / (math.pi * jnp.log(a2) * (hx * hx + hy * hy + a2 * hz * hz))

    def lobe_weights(self):
        """``(w_diffuse, w_clearcoat, w_specular)``: unnormalised sampling weights (module
        docstring); ``w_specular >= 1/21``."""
        cd, cspec0, csheen = self.colors()
        w_d = (1.0 - self.metallic) * (max_over_channels(cd)
                                       + _SHEEN_SAMPLING * self.sheen * max_over_channels(csheen))
        s = max_over_channels(cspec0)
        w_s = s + (1.0 - s) * _SCHLICK_AVG
        w_c = 0.25 * self.clearcoat * (_CC_F0 + (1.0 - _CC_F0) * _SCHLICK_AVG)
        return w_d, w_c, w_s

    def lobe_probabilities(self):
        """``(p_diffuse, p_clearcoat, p_specular)`` of :meth:`sample`: the
        :meth:`lobe_weights` normalised."""
        w_d, w_c, w_s = self.lobe_weights()
        inv = 1.0 / (w_d + w_s + w_c)  # w_s >= 1/21
        return w_d * inv, w_c * inv, w_s * inv

    # ------------------------------------------------------------------ the BRDF

    def _geometry(self, wi, wo):
        """Sanitised geometry and the symmetric ``d = |wi + wo|/2`` in [0, 1]."""
        valid, (ix, iy, iz), (ox, oy, oz), (hx, hy, hz), _ = half_geometry(wi, wo)
        d = 0.5 * ((ix + ox) * hx + (iy + oy) * hy + (iz + oz) * hz)
        return valid, (ix, iy, iz), (ox, oy, oz), (hx, hy, hz), jnp.clip(d, 0.0, 1.0)

    def parts(self, wi, wo):
        """``(base, coat)``: the two additive parts of ``f`` (module docstring), ``base`` the
        diffuse, subsurface, sheen and specular terms (batch + channels), ``coat`` the clearcoat
        (batch); both 0 where the pair is invalid."""
        valid, (ix, iy, iz), (ox, oy, oz), (hx, hy, hz), d = self._geometry(wi, wo)
        ch = self.channels()

        def ex(x):
            return expand_channels(x, ch)

        cd, cspec0, csheen = self.colors()
        r = self.roughness
        # diffuse with retro-reflection (5.3) and the subsurface flattening (5.3)
        w_i = pow5(jnp.clip(1.0 - iz, 0.0, 1.0))
        w_o = pow5(jnp.clip(1.0 - oz, 0.0, 1.0))
        d2r = d * d * r
        fd_m1 = 2.0 * d2r - 0.5  # Fd90 - 1
        fd = (1.0 + fd_m1 * w_i) * (1.0 + fd_m1 * w_o)
        fss = (1.0 + (d2r - 1.0) * w_i) * (1.0 + (d2r - 1.0) * w_o)
        ss = 1.25 * (fss * (1.0 / (iz + oz) - 0.5) + 0.5)
        diffuse = fd + self.subsurface * (ss - fd)
        w_h = pow5(1.0 - d)
        sheen = self.sheen * ex(w_h) * csheen
        # specular: GTR2 D (5.4), Schlick F (5.5), separable Smith GGX G (5.6)
        ax, ay = self.widths()
        D = GGX(ax, ay).D(hx, hy, hz)
        if self.masking == "2012":
            a2x = a2y = self.masking_width() ** 2
        else:
            a2x, a2y = ax * ax, ay * ay
        gs = 1.0 / ((iz + _p_smith(ix, iy, iz, a2x, a2y)) * (oz + _p_smith(ox, oy, oz, a2x, a2y)))
        fs = cspec0 + (1.0 - cspec0) * ex(w_h)
        base = (1.0 - self.metallic) * (INV_PI * ex(diffuse) * cd + sheen) + fs * ex(D * gs)
        # clearcoat: GTR1 D, Schlick F0 = 0.04, Smith GGX G at 0.25
        c2 = CLEARCOAT_G_ALPHA * CLEARCOAT_G_ALPHA
        gr = 1.0 / ((iz + _p_smith(ix, iy, iz, c2, c2)) * (oz + _p_smith(ox, oy, oz, c2, c2)))
        fr = _CC_F0 + (1.0 - _CC_F0) * w_h
        coat = 0.25 * self.clearcoat * fr * self.gtr1(hx, hy, hz) * gr
        return jnp.where(ex(valid), base, 0.0), jnp.where(valid, coat, 0.0)

    def eval(self, wi, wo):
        base, coat = self.parts(wi, wo)
        return base + expand_channels(coat, self.channels())

    def pdf_parts(self, wi, wo):
        """``(cosine, specular, clearcoat)``: the densities of the three samplers (each
        normalised on its own; 0 where the pair is invalid)."""
        valid, (_, _, iz), (ox, oy, oz), (hx, hy, hz), d = self._geometry(wi, wo)
        ax, ay = self.widths()
        dist = GGX(ax, ay)
        spec = dist.D(hx, hy, hz) / (2.0 * (oz + dist.P(ox, oy, oz)))
        coat = safe_div(self.gtr1(hx, hy, hz) * hz, 4.0 * d)
        return (jnp.where(valid, iz * INV_PI, 0.0), jnp.where(valid, spec, 0.0),
                jnp.where(valid, coat, 0.0))

    def pdf(self, wi, wo):
        pd, pc, ps = self.lobe_probabilities()
        cos_pdf, spec, coat = self.pdf_parts(wi, wo)
        return pd * cos_pdf + ps * spec + pc * coat

    def sample_clearcoat_normal(self, u1, u2):
        """GTR1 half vector ``m ~ Dr(m)(n.m)`` (Burley 2012, appendix B), components of ``m``:
        ``cos^2 = -expm1((1 - u2) log ac^2)/(1 - ac^2)``, ``sin^2 = ac^2 expm1(-u2 log ac^2)/
        (1 - ac^2)`` (the same two numbers as ``(1 - ac^(2 (1 - u2)))/(1 - ac^2)`` and one minus
        it, without cancellation), azimuth ``2 pi u1``."""
        a = self.clearcoat_alpha()
        a2 = a * a
        la2 = jnp.log(a2)
        inv = 1.0 / (1.0 - a2)
        cos_t = safe_sqrt(-jnp.expm1((1.0 - u2) * la2) * inv)
        sin_t = safe_sqrt(a2 * jnp.expm1(-u2 * la2) * inv)
        phi = TWO_PI * u1
        return sin_t * jnp.cos(phi), sin_t * jnp.sin(phi), cos_t

    def draw(self, wo, uc, u, p_diffuse, p_clearcoat):
        """``(wi, ok)``: ``uc < p_diffuse``: cosine hemisphere; ``uc < p_diffuse + p_clearcoat``:
        ``wo`` reflected about a GTR1 normal; otherwise about a GGX visible normal. ``ok``:
        ``wo`` above the horizon."""
        ox, oy, oz = split(wo)
        ok = oz > 0
        ox, oy, oz = sanitize(ok, ox, oy, oz)
        u1, u2 = u[..., 0], u[..., 1]
        ax, ay = self.widths()
        m_s = GGX(ax, ay).sample_visible(ox, oy, oz, u1, u2)
        wi = join(*reflect_about(ox, oy, oz, *m_s))
        m_c = self.sample_clearcoat_normal(u1, u2)
        w_c = join(*reflect_about(ox, oy, oz, *m_c))
        wi = jnp.where((uc < p_diffuse + p_clearcoat)[..., None], w_c, wi)
        wi = jnp.where((uc < p_diffuse)[..., None], sample_cosine_hemisphere(u), wi)
        return wi, ok

    def sample(self, wo, uc, u):
        pd, pc, _ = self.lobe_probabilities()
        wi, ok = self.draw(wo, uc, u, pd, pc)
        return finish_sample(self, wi, wo, ok)

    # ------------------------------------------------------------------ declared hooks

    def is_compound(self) -> bool:
        """True: verification integrates the base and the clearcoat (:class:`DisneyPart`)
        each with its own rule (the clearcoat's GTR1 at ``clearcoatGloss = 1`` is 250 times
        narrower than the specular lobe at the default roughness)."""
        return True

    def terms(self):
        return ((1.0, DisneyPart(self, "base")), (1.0, DisneyPart(self, "clearcoat")))

    def pdf_terms(self):
        pd, pc, ps = self.lobe_probabilities()
        return ((pd + ps, DisneyPart(self, "base")), (pc, DisneyPart(self, "clearcoat")))

    def quadrature_lobe(self) -> QuadratureLobe:
        """The specular GGX lobe's widths (what quadrature of the whole model follows; the
        verification integrates the parts instead, :meth:`terms`)."""
        return QuadratureLobe("half", self.widths())

    def selection_hint(self):
        """The sum of the :meth:`lobe_weights` (roughly the largest channel's albedo)."""
        return sum(self.lobe_weights())

    def is_anisotropic(self) -> bool:
        """True unless ``anisotropic`` is a concrete 0 (then ``ax = ay`` and both G forms are
        isotropic, so ``f`` depends on the azimuths only through their difference); a traced
        value (under ``jit``/``vmap``) counts as anisotropic."""
        a = concrete(self.anisotropic)
        return a is None or a.dtype == object or bool(np.any(a != 0))


class DisneyPart(AbstractBRDF):
    """One additive part of a :class:`DisneyBRDF` (its :meth:`~DisneyBRDF.terms`), so that
    quadrature follows each lobe: ``part = "base"`` (diffuse, subsurface, sheen, specular;
    sampled by the cosine / visible-normal mixture renormalised to it, quadrature at the GGX
    widths) or ``"clearcoat"`` (the GTR1 lobe; sampled by GTR1 half vectors, quadrature at the
    GTR1 width)."""

    model: DisneyBRDF
    part: str = eqx.field(static=True, default="base")

    def __check_init__(self):
        if self.part not in ("base", "clearcoat"):
            raise ValueError(f"DisneyPart: part must be 'base' or 'clearcoat', got {self.part!r}")

    def channels(self):
        return self.model.channels() if self.part == "base" else None

    def _p_diffuse(self):
        pd, _, ps = self.model.lobe_probabilities()
        return pd / (pd + ps)  # ps > 0

    def eval(self, wi, wo):
        base, coat = self.model.parts(wi, wo)
        return base if self.part == "base" else coat

    def pdf(self, wi, wo):
        cos_pdf, spec, coat = self.model.pdf_parts(wi, wo)
        if self.part == "clearcoat":
            return coat
        q = self._p_diffuse()
        return q * cos_pdf + (1.0 - q) * spec

    def sample(self, wo, uc, u):
        if self.part == "clearcoat":
            wi, ok = self.model.draw(wo, uc, u, 0.0, 1.0)
        else:
            wi, ok = self.model.draw(wo, uc, u, self._p_diffuse(), 0.0)
        return finish_sample(self, wi, wo, ok)

    def quadrature_lobe(self) -> QuadratureLobe:
        if self.part == "clearcoat":
            return QuadratureLobe("half", self.model.clearcoat_alpha())
        return QuadratureLobe("half", self.model.widths())

    def is_anisotropic(self) -> bool:
        return self.part == "base" and self.model.is_anisotropic()


# ----------------------------------------------------------------------------- registry

_DOCS = {
    "baseColor": ("RGB base colour as the BRDF Explorer's slider sets it (display-referred: "
                  "linearised as baseColor^2.2); diffuse albedo and the metallic F0", True),
    "subsurface": ("blend of the diffuse toward the Hanrahan-Krueger-like flattened lobe "
                   "(Burley 2012, 5.3)", False),
    "metallic": ("blend from dielectric (diffuse + sheen + 0.08 specular F0) to metal "
                 "(F0 = linear baseColor, no diffuse)", False),
    "specular": "dielectric F0 = 0.08 specular (0.5: 0.04, ior 1.5)",
    "specularTint": "fraction of the dielectric F0 tinted by baseColor / luminance",
    "roughness": ("perceptual roughness: GGX widths roughness^2 (stretched by anisotropic), "
                  "G width (1/2 + roughness/2)^2, diffuse retro-reflection", False),
    "anisotropic": ("aspect sqrt(1 - 0.9 anisotropic): alpha_x = roughness^2 / aspect along "
                    "the tangent, alpha_y = roughness^2 aspect", False),
    "sheen": "sheen lobe weight: sheen (1 - d)^5 Csheen (1 - metallic)",
    "sheenTint": "fraction of the sheen tinted by baseColor / luminance",
    "clearcoat": "clearcoat weight (GTR1 lobe, F0 = 0.04, scaled by 1/4)",
    "clearcoatGloss": "clearcoat glossiness: GTR1 alpha = lerp(0.1, 0.001, clearcoatGloss)",
}


#: the registry's names (the package's snake_case) of disney.brdf's parameters
ENTRY_NAMES = {n: "".join("_" + c.lower() if c.isupper() else c for c in n)
               for n in _PARAMETERS}
#: left out of the registry entry: ``Ctint = Cd/lum`` makes each colour channel depend on the
#: others through these two (fit_batch's per-channel Jacobian assumes channels separate, and
#: metallic and specularTint then change F0 in the same per-channel shape: an exact
#: one-parameter family of equal values); the class keeps them
_ENTRY_LEFT_OUT = ("specularTint", "sheenTint")


def _param(name: str) -> Param:
    doc = _DOCS[name]
    doc, channels = doc if isinstance(doc, tuple) else (doc, False)
    return Param(ENTRY_NAMES[name], DISNEY_2012_DEFAULTS[name], lo=0.0, hi=1.0,
                 channels=channels, doc=f"{doc} (disney.brdf's {name})")


def _build(**params):
    by_entry = {v: k for k, v in ENTRY_NAMES.items()}
    # the tints held at 0 (not the sliders' 0.5 sheenTint): untinted, the channels separate
    return DisneyBRDF(**{by_entry[k]: v for k, v in params.items()}, specularTint=0.0,
                      sheenTint=0.0)


#: Measured with brdf_fit.verify.checks.run_checks on the entry at its defaults (float64); see
#: tests/models/test_disney.py::test_registry_checks_pass_or_declare.
_FAILURES: dict[str, str] = {}


def registry_entries():
    """:class:`~brdf_fit.core.params.Entry` objects of this module (not registered here):
    ``disney-2012`` with nine of the eleven parameters free (the two tints left out:
    :data:`_ENTRY_LEFT_OUT`), in snake_case (:data:`ENTRY_NAMES`), and ``disney.brdf``'s slider
    defaults."""
    return [
        Entry(
            name="disney-2012",
            builder=_build,
            params=tuple(_param(n) for n in _PARAMETERS if n not in _ENTRY_LEFT_OUT),
            reference=f"{_REF_BURLEY_2012}; {_REF_EXPLORER}",
            description=("Disney principled BRDF (Burley 2012), reflection lobes: diffuse with "
                         "retro-reflection and subsurface flattening, sheen, anisotropic GTR2 "
                         "specular with Schlick F and remapped Smith GGX G, GTR1 clearcoat"),
            aliases=("disney", "disney-principled", "burley-2012"),
            expected_failures=_FAILURES,
            tags=("layered", "anisotropic"),
            year=2012,
            catalogue=None,
            sampler=("exact mixture: cosine (diffuse, subsurface, sheen), GGX visible normals "
                     "(specular), GTR1 half vectors (clearcoat, Burley 2012 appendix B)"),
        ),
    ]
