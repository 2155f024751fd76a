"""Mitsuba 3's ``principled`` BSDF, reflection only: a renderer-native model.

:class:`MitsubaPrincipled` evaluates what Mitsuba 3.9.1's ``principled`` plugin returns from
``BSDF.eval`` (divided by the cosine of the light direction) on the front side with
``spec_trans = 0``, parametrised exactly as a scene file sets the plugin (``base_color``,
``roughness``, ``metallic``, ``specular``, ...), so that a model fitted here is written to a
Mitsuba scene with no loss (:func:`to_mitsuba_dict`). It is Burley's "Disney principled" model
(B. Burley, "Physically-Based Shading at Disney", SIGGRAPH 2012 course "Practical
Physically-Based Shading in Film and Game Production", revised Aug 31 2012: section 5.3
diffuse, 5.4 specular D (the GTR family, eq. 4), 5.5 F, 5.6 G, the sheen and clearcoat
paragraphs of section 5, the anisotropy aspect of its addenda; B. Burley, "Extending the Disney
BRDF to a BSDF with Integrated Subsurface Scattering", SIGGRAPH 2015 course notes, section 3:
the diffuse split into a Lambert part and a retro-reflection part) as Mitsuba implements it,
with Mitsuba's departures from the papers kept (listed below). The terms were read in Mitsuba's
sources (``src/bsdfs/principled.cpp``: ``Principled::eval``, ``Principled::pdf``,
``Principled::sample``; ``src/bsdfs/principledhelpers.h``: ``calc_dist_params``,
``principled_fresnel``, ``calc_schlick``, ``schlick_weight``, ``schlick_R0_eta``,
``GTR1Isotropic``, ``clearcoat_G``, ``smith_ggx1``, ``mac_mic_compatibility``;
``include/mitsuba/render/microfacet.h``: ``MicrofacetDistribution::eval``, ``smith_g1``,
``G``, ``pdf``; ``include/mitsuba/render/fresnel.h``: ``fresnel``;
``include/mitsuba/core/spectrum.h``: ``luminance``) and every term is checked against the
installed Mitsuba 3.9.1 (``tests/models/test_mitsuba_principled.py``).

Notation: ``wi`` toward the light, ``wo`` toward the viewer (Mitsuba's ``si.wi`` is our ``wo``;
the direction passed to ``eval`` is our ``wi``), ``ci = n.wi``, ``co = n.wo``,
``h = normalize(wi + wo)``, ``d = wo.h`` (= ``wi.h`` for unit vectors; see "Which dot
product" below), ``w(c) = (1 - c)^5`` (Schlick's weight, ``schlick_weight``),
``lum = 0.212671 R + 0.715160 G + 0.072169 B`` (``luminance``, linear sRGB Y),
``c_tint = base_color / lum`` (1 where ``lum = 0``), ``m = metallic``, ``r = roughness``,
``fl = flatness``, ``gloss = clearcoat_gloss``::

    f = f_spec + f_diffuse + f_sheen + f_clearcoat

    alpha_x, alpha_y = max(1e-3, r^2 / a), max(1e-3, r^2 a),  a = sqrt(1 - 0.9 anisotropic)
    eta = 2 / (1 - sqrt(0.08 specular)) - 1,  i.e. ((eta - 1)/(eta + 1))^2 = 0.08 specular
    f_spec  = F D(h) G1(wi) G1(wo) / (4 ci co)       GGX D, separable Smith G1 (microfacet.h)
      F     = (1 - m)(1 - spec_tint) F_dielectric(d, eta)             exact Fresnel (fresnel.h)
              + m (base_color + (1 - base_color) w(d))                 Schlick, F0 = base_color
              + (1 - m) spec_tint (F0t + (1 - F0t) w(d)),  F0t = 0.08 specular c_tint
    f_diffuse = (1 - m) base_color / pi [(1 - fl) (f_lambert + f_retro) + fl f_ss]
      f_lambert = (1 - w(ci)/2)(1 - w(co)/2)                            (Burley 2015, sec. 3)
      f_retro   = Rr (w(ci) + w(co) + w(ci) w(co) (Rr - 1)),  Rr = 2 r (wi.h)^2   (ditto)
                  (the two together are Burley 2012's (1 + (FD90 - 1) w(ci))(1 + (FD90 - 1)
                  w(co)), FD90 = 1/2 + Rr, section 5.3)
      f_ss      = 1.25 (Fss (1/(ci + co) - 1/2) + 1/2),
                  Fss = (1 + (Rr/2 - 1) w(ci))(1 + (Rr/2 - 1) w(co))  (Burley 2012's
                  Hanrahan-Krueger-like "subsurface" term, here Mitsuba's ``flatness``)
    f_sheen   = (1 - m) sheen w(wi.h) (1 + sheen_tint (c_tint - 1))     (Burley 2012, sec. 5)
    f_clearcoat = clearcoat/4 (0.04 + 0.96 w(d)) D_GTR1(h) G1cc(wi) G1cc(wo)
      D_GTR1  = (ac^2 - 1) / (pi log(ac^2) (1 + (ac^2 - 1)(n.h)^2)),  ac = 0.1 - 0.099 gloss
                                                  (GTR1Isotropic; Burley 2012, 5.4, eq. 4)
      G1cc(w) = 2 / (1 + sqrt(1 + 0.0625 tan^2 theta))   (smith_ggx1: GGX G1 at alpha = 0.25)

Written with dot products: ``D(h) = 1/(pi ax ay q^2)``, ``q = (h.x/ax)^2 + (h.y/ay)^2 +
(h.z)^2``; Smith's ``G1(w)/(2 n.w) = 1/(n.w + P(w))`` with ``P(w) = sqrt((ax w.x)^2 +
(ay w.y)^2 + (w.z)^2)``, so ``f_spec = F D / ((ci + P(wi))(co + P(wo)))`` has no cosine in a
denominator; ``G1cc(w) = 2 (n.w) / (n.w + sqrt((n.w)^2 + 0.0625 ((w.x)^2 + (w.y)^2)))``;
``1 + (ac^2 - 1)(n.h)^2 = (h.x)^2 + (h.y)^2 + ac^2 (h.z)^2`` (Mitsuba's float32 form cancels
near ``h = n``: relative error up to ``eps / ac^2``, the largest parity difference measured,
6e-6 at ``gloss = 1``; ours does not).

Mitsuba's departures from Burley's papers, all reproduced (measured with Mitsuba 3.9.1):

* the dielectric part of F is the *exact* dielectric Fresnel of ``eta`` (Burley 2012, 5.5:
  Schlick), and ``specular`` maps to ``eta`` as above; the tinted part is Schlick with
  ``F0 = 0.08 specular c_tint``; G uses the same ``alpha`` as D (Burley 2012, 5.6, remapped
  ``alpha_g = (0.5 + r/2)^2``);
* the clearcoat has **no** ``1/(4 ci co)`` (Burley's clearcoat G contains it; Mitsuba's
  ``smith_ggx1`` is a plain G1): measured, with it the parity fails by more than 10%;
* ``specular = 0`` (``eta = 1``) switches the *whole* specular lobe off, its metallic and tinted
  parts included (``Principled::eval`` gates the lobe on ``F_dielectric > 0``): with
  ``metallic = 0.5`` Mitsuba's value jumps by a factor 193 between ``specular = 0`` and
  ``1e-6``; reproduced, so ``f`` is discontinuous in ``specular`` at 0;
* the clearcoat Fresnel is Schlick with ``F0 = 0.04`` whatever ``specular`` is (Mitsuba's
  ``calc_schlick`` switches to the refracted cosine for ``eta <= 1``, i.e. only at
  ``specular = 0``, where it equals ``d`` in exact arithmetic: not reproduced);
* the diffuse retro-reflection uses the raw ``roughness``, the specular D the clamped
  ``alpha``.

Which dot product. Mitsuba reads ``wo.h`` (its ``dot(si.wi, wh)``) in the Fresnel terms and the
visible-normal pdf, ``wi.h`` (its ``dot(wo, wh)``) in the retro-reflection, the sheen and the
``1/(4 wi.h)`` of the pdf. Equal for unit vectors; for directions unit only to rounding (float32
inputs) they differ by ``(|wo|^2 - |wi|^2)/|wi + wo|``, which is large at near-opposite grazing
pairs. The model reads each where Mitsuba does, which keeps the parity there.

Reciprocity: every term is symmetric in ``(wi, wo)`` for unit vectors (measured 9e-15 in
float64). Mitsuba, fed float32 directions, is reciprocal to 2.6e-6 .. 4.2e-6 (22 .. 35 float32
eps, at near-opposite grazing pairs, by the rounding above); the model on the same inputs shows
the same asymmetry.

Energy: not conserved, as in Burley's model (no energy compensation; sheen and clearcoat added
on top): the directional albedo of ``base_color = 1`` reaches 1.04 at normal view and 1.42 /
1.56 at ``cos = 0.1 / 0.02`` for ``roughness = 1`` (the retro-reflection), 1.65 with
``sheen = 1`` (measured with :func:`brdf_fit.verify.checks.directional_albedo`). The registry
entries' defaults (``base_color = 0.5``) pass the energy check (0.69).

Optional parameters. ``spec_tint``, ``anisotropic``, ``sheen``, ``sheen_tint``, ``clearcoat``,
``clearcoat_gloss`` and ``flatness`` default to None (not given): their terms are not traced at
all, as Mitsuba's ``m_has_*`` flags skip them; the value equals that at 0 (``anisotropic =
None`` is the isotropic path, equal to ``anisotropic = 0``). ``spec_tint`` and ``sheen_tint``
couple the colour channels through ``lum``; the registry entries leave them out (see
``_BASIC``).

Not modelled (0 here, as in Mitsuba with these parameters at their defaults): ``spec_trans``
(the transmission lobe; with ``spec_trans > 0`` Mitsuba also rescales the reflection by
``1 - spec_trans``), the back side (``wo`` below the horizon), textures, the spectral and
polarised variants (``luminance`` is the RGB one), and an ``eta`` given instead of ``specular``
(the two are one-to-one on ``eta in [1, 1.789]``: ``specular = ((eta - 1)/(eta + 1))^2 / 0.08``,
:func:`specular_from_eta`; other ``eta`` are not representable). ``principledthin`` is another
plugin.

Sampling follows ``Principled::sample``: a lobe is chosen with probabilities proportional to
``(1 - m) diffuse_reflectance_sampling_rate`` (cosine hemisphere),
``clearcoat / 4 * clearcoat_sampling_rate`` (GTR1 normals ``D_GTR1(m) (n.m)``, reflected) and
``main_specular_sampling_rate`` (GGX visible normals, reflected; here by spherical caps, Dupuy &
Benyoub 2023, Mitsuba by Heitz 2018's method: the same density); ``pdf`` is the exact mixture
density, which is Mitsuba's ``Principled::pdf`` (measured equal to float32 rounding)::

    pdf = p_d ci/pi + p_s D(h) (wo.h) / (2 (co + P(wo)) (wi.h)) + p_c D_GTR1(h) (n.h) / (4 wi.h)

A reflection below the horizon is a failed sample (pdf 0, weight 0). The sampling rates do not
change ``f`` (Mitsuba's defaults: 1, 1, 1; its documentation says 0 for the clearcoat rate, its
code and 3.9.1 say 1).

Epsilons (each one Mitsuba's, so values agree where it cuts):

``ALPHA_FLOOR = 1e-3``
    ``calc_dist_params`` clamps each GGX width below at 1e-3 (not brdf_fit's ``ALPHA_MIN``
    1e-4): a roughness below ``sqrt(1e-3) = 0.0316`` has the specular lobe of 0.0316, and the
    gradient of the specular lobe in ``roughness`` is 0 there (the diffuse still sees it).
``D_FLOOR = 1e-20``
    ``MicrofacetDistribution::eval`` and ``GTR1Isotropic::eval`` return 0 where
    ``D (n.h) <= 1e-20`` (only reached for ``n.h`` below ~1e-13 at the smallest widths). Applied
    to ``eval`` as Mitsuba does; ``pdf`` is our sampler's exact density and does not apply it.
Horizon and half vector
    As every model here (:func:`brdf_fit.models._lobes.half_geometry`): 0 at or below the
    horizon, lanes sanitised to the normal before any formula sees them (double where), and the
    specular and clearcoat lobes 0 where ``wo.h`` or ``wi.h`` rounds to 0 or below
    (``mac_mic_compatibility`` and ``smith_g1`` cut there). ``safe_sqrt`` in ``eta``: the
    derivative of ``sqrt(0.08 specular)`` is infinite at 0, where the lobe is off anyway.
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp

from brdf_fit.core.frame import join, split
from brdf_fit.core.fresnel import dielectric, schlick
from brdf_fit.core.microfacet import GGX, reflect_about
from brdf_fit.core.numerics import INV_PI, TWO_PI, pow5, safe_div, safe_sqrt
from brdf_fit.core.params import Channels, Entry, Param, Scalar, bounded
from brdf_fit.core.validate import check_param
from brdf_fit.core.warp import sample_cosine_hemisphere
from brdf_fit.models._base import AbstractBRDF, QuadratureLobe, expand_channels
from brdf_fit.models._lobes import finish_sample, half_geometry, sanitize

__all__ = [
    "ALPHA_FLOOR",
    "D_FLOOR",
    "LUMINANCE_RGB",
    "MITSUBA_DEFAULTS",
    "MitsubaPrincipled",
    "eta_from_specular",
    "registry_entries",
    "specular_from_eta",
    "to_mitsuba_dict",
]

#: ``calc_dist_params``: the floor of each GGX width (see the module docstring).
ALPHA_FLOOR = 1e-3
#: ``MicrofacetDistribution::eval`` / ``GTR1Isotropic::eval``: D is 0 where ``D (n.h) <= 1e-20``.
D_FLOOR = 1e-20
#: ``luminance`` (include/mitsuba/core/spectrum.h): linear sRGB -> Y weights.
LUMINANCE_RGB = (0.212671, 0.715160, 0.072169)
#: Clearcoat: ``alpha_cc = lerp(0.1, 0.001, clearcoat_gloss)`` (Burley 2012, section 5.4).
_CC_ALPHA_ROUGH, _CC_ALPHA_GLOSSY = 0.1, 0.001
#: ``clearcoat_G``: the clearcoat masking is the GGX Smith G1 at alpha = 0.25 (squared: 0.0625).
_CC_G_ALPHA2 = 0.25 * 0.25
#: The parameters of the plugin that this model reads, in the order of its fields.
_PARAMETERS = ("base_color", "roughness", "metallic", "specular", "spec_tint", "anisotropic",
               "sheen", "sheen_tint", "clearcoat", "clearcoat_gloss", "flatness")
#: ``Principled(props)``: the plugin's defaults (also the registry defaults).
MITSUBA_DEFAULTS = {
    "base_color": 0.5,
    "roughness": 0.5,
    "metallic": 0.0,
    "specular": 0.5,
    "spec_tint": 0.0,
    "anisotropic": 0.0,
    "sheen": 0.0,
    "sheen_tint": 0.0,
    "clearcoat": 0.0,
    "clearcoat_gloss": 0.0,
    "flatness": 0.0,
}

_REF_BURLEY_2012 = ("B. Burley, \"Physically-Based Shading at Disney\", SIGGRAPH 2012 course "
                    "notes (Practical physically-based shading in film and game production), "
                    "sections 5.3-5.6")
_REF_BURLEY_2015 = ("B. Burley, \"Extending the Disney BRDF to a BSDF with Integrated Subsurface "
                    "Scattering\", SIGGRAPH 2015 course notes, section 3")
_REF_MITSUBA = ("Mitsuba 3.9.1 'principled' plugin (src/bsdfs/principled.cpp, "
                "src/bsdfs/principledhelpers.h), reflection, spec_trans = 0")


def eta_from_specular(specular):
    """``eta = 2 / (1 - sqrt(0.08 specular)) - 1`` (``Principled(props)``), 1 at ``specular = 0``
    (gradient 0 there: ``safe_sqrt``)."""
    return 2.0 / (1.0 - safe_sqrt(0.08 * specular)) - 1.0


def specular_from_eta(eta):
    """Inverse of :func:`eta_from_specular`: ``((eta - 1)/(eta + 1))^2 / 0.08`` (in [0, 1] for
    ``eta`` in [1, 1.789])."""
    r = (eta - 1.0) / (eta + 1.0)
    return r * r / 0.08


def _ggx_g1_parts(x, y, z, a2):
    """``z + sqrt(z^2 + a2 (x^2 + y^2))``: Smith's GGX ``G1 = 2 z / (this)`` at ``alpha^2 = a2``."""
    return z + jnp.sqrt(z * z + a2 * (x * x + y * y))


def _light_side(ix, iy, iz, hx, hy, hz, d_o):
    """``(|wi.h|, facing)``: Mitsuba reads ``wi.h`` (its ``dot(wo, wh)``) where it means the
    light side (retro-reflection, sheen, the ``1/(4 wi.h)`` of the pdf) and ``wo.h`` (its
    ``dot(si.wi, wh)``) for the Fresnel terms; equal for unit vectors, not for directions unit
    only to rounding at near-opposite grazing pairs (``|wi + wo|`` small), where following
    Mitsuba keeps the parity. ``facing``: both positive (``mac_mic_compatibility``)."""
    d_i = ix * hx + iy * hy + iz * hz
    return jnp.abs(d_i), (d_i > 0) & (d_o > 0)


class MitsubaPrincipled(AbstractBRDF):
    """Mitsuba 3.9.1 ``principled``, reflection on the front side (module docstring: formulas,
    Mitsuba's departures from Burley 2012/2015, epsilons, sampling).

    Every parameter is the scene-file parameter of the same name, with the interval [0, 1]
    Mitsuba documents. ``roughness`` is Mitsuba's (perceptual) roughness: ``alpha =
    roughness^2`` is part of the model (``calc_dist_params``), as in the scene file.
    ``base_color`` is RGB (a trailing axis of 3; a scalar is grey).

    The optional parameters (``spec_tint``, ``anisotropic``, ``sheen``, ``sheen_tint``,
    ``clearcoat``, ``clearcoat_gloss``, ``flatness``) default to None: not given, so their
    terms are not traced at all (Mitsuba's ``m_has_*`` flags do the same); the value is that
    of 0, except ``anisotropic``: None is Mitsuba's isotropic path, any value (0 included) the
    anisotropic one (equal values at 0). The sampling rates are static (they change ``pdf`` and
    ``sample``, not ``f``)."""

    base_color: Channels = bounded(0.5, lo=0.0, hi=1.0, channels=True)
    roughness: Scalar = bounded(0.5, lo=0.0, hi=1.0)
    metallic: Scalar = bounded(0.0, lo=0.0, hi=1.0)
    specular: Scalar = bounded(0.5, lo=0.0, hi=1.0)
    spec_tint: Scalar | None = bounded(None, lo=0.0, hi=1.0)
    anisotropic: Scalar | None = bounded(None, lo=0.0, hi=1.0)
    sheen: Scalar | None = bounded(None, lo=0.0, hi=1.0)
    sheen_tint: Scalar | None = bounded(None, lo=0.0, hi=1.0)
    clearcoat: Scalar | None = bounded(None, lo=0.0, hi=1.0)
    clearcoat_gloss: Scalar | None = bounded(None, lo=0.0, hi=1.0)
    flatness: Scalar | None = bounded(None, lo=0.0, hi=1.0)
    diffuse_reflectance_sampling_rate: float = eqx.field(static=True, default=1.0)
    main_specular_sampling_rate: float = eqx.field(static=True, default=1.0)
    clearcoat_sampling_rate: float = eqx.field(static=True, default=1.0)

    def __check_init__(self):
        for name in _PARAMETERS:
            value = getattr(self, name)
            if value is not None:
                check_param(name, value, lo=0.0, hi=1.0, owner="MitsubaPrincipled")
        shape = jnp.shape(self.base_color)
        if len(shape) > 0 and shape[-1] not in (1, 3):
            raise ValueError(f"base_color must be RGB (a trailing axis of 3) or grey, got "
                             f"shape {shape}")
        rates = (self.diffuse_reflectance_sampling_rate, self.main_specular_sampling_rate,
                 self.clearcoat_sampling_rate)
        if min(rates) < 0 or self.main_specular_sampling_rate + \
                self.diffuse_reflectance_sampling_rate <= 0:
            raise ValueError(f"sampling rates must be >= 0 with a positive main specular or "
                             f"diffuse rate, got {rates}")

    # ------------------------------------------------------------------ parameters

    def given(self) -> dict:
        """The parameters a scene file would set: every one that is not None (for
        :func:`to_mitsuba_dict`)."""
        return {n: getattr(self, n) for n in _PARAMETERS if getattr(self, n) is not None}

    def widths(self):
        """``(alpha_x, alpha_y)`` of the GGX lobe (``calc_dist_params``)."""
        r2 = self.roughness * self.roughness
        if self.anisotropic is None:
            a = jnp.maximum(ALPHA_FLOOR, r2)
            return a, a
        aspect = jnp.sqrt(1.0 - 0.9 * self.anisotropic)
        return jnp.maximum(ALPHA_FLOOR, r2 / aspect), jnp.maximum(ALPHA_FLOOR, r2 * aspect)

    def clearcoat_alpha(self):
        """``lerp(0.1, 0.001, clearcoat_gloss)``: the GTR1 width of the clearcoat."""
        gloss = 0.0 if self.clearcoat_gloss is None else self.clearcoat_gloss
        return _CC_ALPHA_ROUGH + (_CC_ALPHA_GLOSSY - _CC_ALPHA_ROUGH) * gloss

    def _distribution(self):
        ax, ay = self.widths()
        return GGX(ax, ay)

    def _tint(self):
        """``base_color / luminance(base_color)`` (1 where the luminance is 0; double where)."""
        bc = jnp.asarray(self.base_color)
        if bc.ndim == 0 or bc.shape[-1] == 1:
            return jnp.ones_like(bc)
        lum = (LUMINANCE_RGB[0] * bc[..., 0] + LUMINANCE_RGB[1] * bc[..., 1]
               + LUMINANCE_RGB[2] * bc[..., 2])[..., None]
        ok = lum > 0
        return jnp.where(ok, bc / jnp.where(ok, lum, 1.0), 1.0)

    def _gtr1(self, hx, hy, hz):
        """``D_GTR1(h)`` (``GTR1Isotropic::eval`` without its floor), for unit ``h``."""
        a = self.clearcoat_alpha()
        a2 = a * a
        den = jnp.pi * jnp.log(a2) * (hx * hx + hy * hy + a2 * hz * hz)
        return jnp.where(hz > 0, (a2 - 1.0) / den, 0.0)

    def lobe_probabilities(self):
        """``(p_diffuse, p_clearcoat, p_specular)`` of :meth:`sample` (``Principled::sample``)."""
        pd = (1.0 - self.metallic) * self.diffuse_reflectance_sampling_rate
        pc = 0.0 if self.clearcoat is None else \
            0.25 * self.clearcoat * self.clearcoat_sampling_rate
        ps = self.main_specular_sampling_rate
        tot = pd + pc + ps
        ok = tot > 0
        inv = 1.0 / jnp.where(ok, tot, 1.0)
        return (jnp.where(ok, pd * inv, 0.0), jnp.where(ok, pc * inv, 0.0),
                jnp.where(ok, ps * inv, 1.0))

    # ------------------------------------------------------------------ the BRDF

    def eval(self, wi, wo):
        valid, (ix, iy, iz), (ox, oy, oz), (hx, hy, hz), d = half_geometry(wi, wo)
        d_i, facing = _light_side(ix, iy, iz, hx, hy, hz, d)
        ch = self.channels()

        def ex(x):
            return expand_channels(x, ch)

        m = self.metallic
        bc = self.base_color
        tinted = self.spec_tint is not None or self.sheen_tint is not None
        tint = self._tint() if tinted else None
        # main specular: F D G1 G1 / (4 ci co) = F D / ((ci + P(wi)) (co + P(wo)))
        dist = self._distribution()
        D = dist.D(hx, hy, hz)
        D = jnp.where(D * hz > D_FLOOR, D, 0.0)
        vis = 1.0 / ((iz + dist.P(ix, iy, iz)) * (oz + dist.P(ox, oy, oz)))
        g = safe_sqrt(0.08 * self.specular)  # = (eta - 1)/(eta + 1)
        spec_on = g > 0  # eta = 1: F_dielectric = 0 switches the lobe off (Principled::eval)
        eta = jnp.where(spec_on, 2.0 / (1.0 - g) - 1.0, 1.5)
        f_diel = ex(dielectric(d, eta))
        if self.spec_tint is None:
            F = (1.0 - m) * f_diel + m * schlick(ex(d), bc)
        else:
            st = self.spec_tint
            F = ((1.0 - m) * (1.0 - st) * f_diel + m * schlick(ex(d), bc)
                 + (1.0 - m) * st * schlick(ex(d), tint * (0.08 * self.specular)))
        total = jnp.where(ex(facing & spec_on), F * ex(D * vis), 0.0)
        # diffuse and retro-reflection (Burley 2015, sec. 3), fake subsurface (Burley 2012, 5.3)
        w_i = pow5(jnp.clip(1.0 - iz, 0.0, 1.0))
        w_o = pow5(jnp.clip(1.0 - oz, 0.0, 1.0))
        rr = 2.0 * self.roughness * d_i * d_i
        shape_d = (1.0 - 0.5 * w_i) * (1.0 - 0.5 * w_o) + rr * (w_i + w_o + w_i * w_o * (rr - 1.0))
        if self.flatness is not None:
            fss = (1.0 + (0.5 * rr - 1.0) * w_i) * (1.0 + (0.5 * rr - 1.0) * w_o)
            f_ss = 1.25 * (fss * (1.0 / (iz + oz) - 0.5) + 0.5)
            shape_d = shape_d + self.flatness * (f_ss - shape_d)
        total = total + ((1.0 - m) * INV_PI) * bc * ex(shape_d)
        # sheen (Burley 2012, sec. 5)
        if self.sheen is not None:
            c_sheen = 1.0 if self.sheen_tint is None else 1.0 + self.sheen_tint * (tint - 1.0)
            total = total + ((1.0 - m) * self.sheen) * c_sheen * ex(pow5(1.0 - d_i))
        # clearcoat: clearcoat/4 F_cc D_GTR1 G1cc G1cc, no 1/(4 ci co) (Principled::eval)
        if self.clearcoat is not None:
            dcc = self._gtr1(hx, hy, hz)
            dcc = jnp.where(dcc * hz > D_FLOOR, dcc, 0.0)
            gcc = (4.0 * iz * oz) / (_ggx_g1_parts(ix, iy, iz, _CC_G_ALPHA2)
                                      * _ggx_g1_parts(ox, oy, oz, _CC_G_ALPHA2))
            fcc = 0.04 + 0.96 * pow5(1.0 - d)
            total = total + ex(jnp.where(facing, (0.25 * self.clearcoat) * fcc * dcc * gcc, 0.0))
        return jnp.where(ex(valid), total, 0.0)

    def pdf(self, wi, wo):
        valid, (ix, iy, iz), (ox, oy, oz), (hx, hy, hz), d = half_geometry(wi, wo)
        d_i, facing = _light_side(ix, iy, iz, hx, hy, hz, d)
        pd, pc, ps = self.lobe_probabilities()
        dist = self._distribution()
        # GGX visible normals D G1(wo) (wo.h)/co, times dwh/dwi = 1/(4 wi.h)
        glossy = ps * dist.D(hx, hy, hz) / (2.0 * (oz + dist.P(ox, oy, oz))) * safe_div(d, d_i)
        if self.clearcoat is not None:
            glossy = glossy + pc * self._gtr1(hx, hy, hz) * safe_div(hz, 4.0 * d_i)
        p = pd * iz * INV_PI + jnp.where(facing, glossy, 0.0)
        return jnp.where(valid, p, 0.0)

    def sample(self, wo, uc, u):
        ox, oy, oz = split(wo)
        ok = oz > 0
        ox, oy, oz = sanitize(ok, ox, oy, oz)
        u1, u2 = u[..., 0], u[..., 1]
        pd, pc, _ = self.lobe_probabilities()
        # main specular: GGX visible normals
        m_s = self._distribution().sample_visible(ox, oy, oz, u1, u2)
        wi = join(*reflect_about(ox, oy, oz, *m_s))
        if self.clearcoat is not None:
            # GTR1 normals: cos^2 = (1 - a2^(1 - u2)) / (1 - a2) (GTR1Isotropic::sample), and
            # sin^2 = a2 (a2^(-u2) - 1) / (1 - a2), both by expm1 (no cancellation)
            a2 = self.clearcoat_alpha() ** 2
            la2 = jnp.log(a2)
            inv = 1.0 / (1.0 - a2)
            cos_t = safe_sqrt(-jnp.expm1((1.0 - u2) * la2) * inv)
            sin_t = safe_sqrt(a2 * jnp.expm1(-u2 * la2) * inv)
            phi = TWO_PI * u1
            m_c = (sin_t * jnp.cos(phi), sin_t * jnp.sin(phi), cos_t)
            w_c = join(*reflect_about(ox, oy, oz, *m_c))
            wi = jnp.where((uc < pd + pc)[..., None], w_c, wi)
        # diffuse: cosine hemisphere
        wi = jnp.where((uc < pd)[..., None], sample_cosine_hemisphere(u), wi)
        return finish_sample(self, wi, wo, ok)

    # ------------------------------------------------------------------ declared hooks

    def quadrature_lobe(self) -> QuadratureLobe:
        """The GGX lobe's widths (the half-vector rule integrates the smooth diffuse and sheen
        terms as well; a clearcoat much narrower than the GGX lobe is not followed)."""
        ax, ay = self.widths()
        return QuadratureLobe("half", (ax, ay) if self.anisotropic is not None else ax)

    def is_anisotropic(self) -> bool:
        return self.anisotropic is not None


# ----------------------------------------------------------------------------- registry


_ENTRY_PARAMS = {
    "base_color": ("RGB base colour (diffuse albedo; F0 of the metallic part)", True),
    "roughness": ("Mitsuba roughness: GGX alpha = max(1e-3, roughness^2); the diffuse "
                  "retro-reflection uses it directly", False),
    "metallic": ("blend from the dielectric (diffuse + specular) to the metallic response",
                 False),
    "specular": ("Fresnel strength: eta = 2/(1 - sqrt(0.08 specular)) - 1 (0 turns the whole "
                 "specular lobe off, as in Mitsuba)", False),
    "spec_tint": ("fraction of the dielectric specular tinted toward base_color", False),
    "anisotropic": ("anisotropy: alpha_x, alpha_y = roughness^2 / a, roughness^2 a, "
                    "a = sqrt(1 - 0.9 anisotropic)", False),
    "sheen": ("sheen lobe weight (1 - metallic) sheen (1 - wo.h)^5", False),
    "sheen_tint": ("fraction of the sheen tinted toward base_color", False),
    "clearcoat": ("clearcoat weight (GTR1 lobe, F0 = 0.04)", False),
    "clearcoat_gloss": ("clearcoat glossiness: GTR1 alpha = 0.1 - 0.099 clearcoat_gloss", False),
    "flatness": ("blend of the diffuse toward Burley's fake subsurface", False),
}


def _param(name: str) -> Param:
    doc, channels = _ENTRY_PARAMS[name]
    default = MITSUBA_DEFAULTS[name]
    if channels:
        default = (default, default, default)
    return Param(name, default, lo=0.0, hi=1.0, channels=channels, doc=doc)


#: The registry entries' parameters. ``sheen_tint`` is not among them, and ``spec_tint`` only in
#: ``mitsuba-principled-tinted``: their tint ``base_color / luminance(base_color)`` couples the
#: colour channels (a channel's value depends on the other channels' base_color), which the
#: fitters' one-tangent-per-channel Jacobian and the pseudo-channel grid guess assume never
#: happens unless the entry declares it (``Entry.channels_coupled``: the registry-wide test
#: ``test_structured_jacobian_matches_jacfwd`` measured 5.8e-11 against its 1e-12 bar with
#: spec_tint near 0 in an entry that did not). The class models both (parity-tested).
_BASIC = ("base_color", "roughness", "metallic", "specular")
_ANISO = _BASIC + ("anisotropic",)
_FULL = _ANISO + ("sheen", "clearcoat", "clearcoat_gloss", "flatness")
#: the base with one of Mitsuba's added lobes (issue 40): a selection for Mitsuba offers them
#: as the base's extensions, so that a clearcoated or sheened principled material comes back as
#: one, with the lobe's own parameters, instead of as the base or the nine-parameter full entry
_CLEARCOAT = _BASIC + ("clearcoat", "clearcoat_gloss")
_SHEEN = _BASIC + ("sheen",)
#: the base with its dielectric specular tinted toward the base colour; the tint's luminance
#: normalisation couples the channels, so the entry says so (Entry.channels_coupled) and the
#: fitters take base_color entry by entry (a dielectric with spec_tint 0.6 came back as the base
#: at 1.8% error without it: benchmarks/results/renderer_roundtrip.md)
_TINTED = _BASIC + ("spec_tint",)
_TINT_COUPLED = ("spec_tint tints the specular by base_color / luminance(base_color): a "
                 "channel's value reads the other channels' base_color")


def _builder(**params):
    return MitsubaPrincipled(**params)


def to_mitsuba_dict(params: dict) -> dict:
    """The ``mi.load_dict`` dict of a ``mitsuba-principled*`` entry's parameters: ``{"type":
    "principled", name: value, ...}`` with every given parameter (``base_color`` as
    ``{"type": "rgb", "value": [r, g, b]}``, a grey scalar repeated; the others as floats).
    Mitsuba then evaluates what :class:`MitsubaPrincipled` with the same parameters does."""
    out: dict = {"type": "principled"}
    for name, value in params.items():
        if name not in MITSUBA_DEFAULTS:
            raise ValueError(f"{name!r} is not a parameter of Mitsuba's principled BSDF here; "
                             f"valid: {', '.join(MITSUBA_DEFAULTS)}")
        v = [float(x) for x in jnp.ravel(jnp.asarray(value))]
        if name == "base_color":
            if len(v) == 1:
                v = v * 3
            if len(v) != 3:
                raise ValueError(f"base_color must be RGB or grey, got {len(v)} values")
            out[name] = {"type": "rgb", "value": v}
        else:
            if len(v) != 1:
                raise ValueError(f"{name} must be a scalar, got {len(v)} values")
            out[name] = v[0]
    return out


#: what makes the entries renderer-native (:class:`~brdf_fit.core.params.Entry`)
_NATIVE = {"target": "mitsuba", "native_export": to_mitsuba_dict}


def registry_entries():
    """:class:`~brdf_fit.core.params.Entry` objects of Mitsuba's ``principled`` (not registered
    here): ``mitsuba-principled`` (base_color, roughness, metallic, specular),
    ``mitsuba-principled-aniso`` (+ anisotropic), ``mitsuba-principled-clearcoat`` (+
    clearcoat, clearcoat_gloss), ``mitsuba-principled-sheen`` (+ sheen),
    ``mitsuba-principled-tinted`` (+ spec_tint; its channels coupled) and
    ``mitsuba-principled-full`` (+ anisotropic, sheen, clearcoat, clearcoat_gloss, flatness);
    defaults are Mitsuba's. ``sheen_tint`` is left out (it couples the channels, and no
    entry needs it yet)."""
    reference = f"{_REF_MITSUBA}; {_REF_BURLEY_2012}; {_REF_BURLEY_2015}"
    sampler = ("Mitsuba's: cosine / GGX visible normals / GTR1 normals by its lobe "
               "probabilities, exact mixture pdf")
    common = {"reference": reference, "sampler": sampler, "year": 2012, **_NATIVE}
    return [
        Entry(
            name="mitsuba-principled",
            builder=_builder,
            params=tuple(_param(n) for n in _BASIC),
            description=("Mitsuba 3 principled (reflection): Burley diffuse + retro-reflection, "
                         "GGX with separable Smith G and the metallic/dielectric Fresnel blend; "
                         "parameters as in the scene file (to_mitsuba_dict)"),
            aliases=("principled-mitsuba",),
            tags=("native", "mitsuba"),
            **common,
        ),
        Entry(
            name="mitsuba-principled-aniso",
            builder=_builder,
            params=tuple(_param(n) for n in _ANISO),
            description="mitsuba-principled with Mitsuba's anisotropic GGX widths",
            tags=("native", "mitsuba", "anisotropic"),
            **common,
        ),
        Entry(
            name="mitsuba-principled-clearcoat",
            builder=_builder,
            params=tuple(_param(n) for n in _CLEARCOAT),
            description=("mitsuba-principled with Mitsuba's clearcoat (GTR1 lobe, F0 0.04, no "
                         "1/(4 ci co)) on top"),
            tags=("native", "mitsuba", "layered"),
            **common,
        ),
        Entry(
            name="mitsuba-principled-sheen",
            builder=_builder,
            params=tuple(_param(n) for n in _SHEEN),
            description="mitsuba-principled with Mitsuba's untinted sheen lobe",
            tags=("native", "mitsuba", "layered"),
            **common,
        ),
        Entry(
            name="mitsuba-principled-tinted",
            builder=_builder,
            params=tuple(_param(n) for n in _TINTED),
            description="mitsuba-principled with its dielectric specular tinted (spec_tint)",
            tags=("native", "mitsuba"),
            channels_coupled=_TINT_COUPLED,
            **common,
        ),
        Entry(
            name="mitsuba-principled-full",
            builder=_builder,
            params=tuple(_param(n) for n in _FULL),
            description=("mitsuba-principled with anisotropy, untinted sheen, clearcoat (no "
                         "1/(4 ci co), as Mitsuba) and flatness"),
            tags=("native", "mitsuba", "anisotropic"),
            **common,
        ),
    ]

