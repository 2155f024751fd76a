"""Blender's Principled BSDF as Cycles 4.5 renders it, reflection lobes: a renderer-native model.

:class:`BlenderPrincipled` evaluates what Cycles (Blender 4.5 LTS) computes for a Principled BSDF
node lit by a light: the sum over the closures the node sets up of ``closure weight x
bsdf_eval``, divided by the cosine of the light direction, parametrised as the node's inputs
(``Base Color``, ``Metallic``, ``Roughness``, ``IOR``, ``Specular IOR Level``, ``Specular
Tint``, ``Anisotropic``, ``Anisotropic Rotation``, ``Coat Weight``, ``Coat Roughness``, ``Coat
IOR``, ``Coat Tint``, ``Sheen Weight``, ``Sheen Roughness``, ``Sheen Tint``), so that a model
fitted here is written to Blender with no loss (:func:`to_blender_inputs`,
:mod:`brdf_fit.convert.blender`). Transcribed from Cycles' sources (the Blender 4.5 release
branch of the Cycles repository; the helpers in :mod:`brdf_fit.models._cycles`):

* ``src/kernel/svm/closure.h``, ``svm_node_closure_bsdf``, case ``CLOSURE_BSDF_PRINCIPLED_ID``:
  the layering (sheen over coat over metal over specular over diffuse), the width mapping, the
  coat tint, the specular IOR level;
* ``src/kernel/closure/bsdf_microfacet.h``: ``bsdf_microfacet_eval`` (GGX ``D``, height-correlated
  Smith ``G2 = 1/(1 + Lambda_i + Lambda_o)``: B. Walter et al., "Microfacet models for refraction
  through rough surfaces", EGSR 2007, eq. 33; E. Heitz, "Understanding the masking-shadowing
  function in microfacet-based BRDFs", JCGT 3(2) 2014, eqs. 72, 85, 99), ``microfacet_fresnel``
  (the ``F82_TINT``, ``GENERALIZED_SCHLICK`` with negative exponent and ``DIELECTRIC`` cases),
  ``microfacet_ggx_preserve_energy``, ``bsdf_microfacet_estimate_albedo``, the
  ``bsdf_microfacet_setup_fresnel_*`` functions;
* ``src/kernel/closure/bsdf_util.h``: ``fresnel_dielectric_cos``, ``fresnel_dielectric_Fss``
  (C. Kulla, A. Conty, "Revisiting Physically Based Shading at Imageworks", SIGGRAPH 2017 course
  notes: its fit of the average Fresnel), ``fresnel_f82tint_B``, ``fresnel_f82_Fss`` (the F82-tint
  model: M. Kutz et al., "Novel aspects of the Adobe Standard Material", 2021),
  ``F0_from_ior``, ``ior_from_F0``, ``closure_layering_weight``;
* ``src/kernel/closure/bsdf_diffuse.h``: ``bsdf_diffuse_eval`` (Lambert);
* ``src/kernel/closure/bsdf_sheen.h``: ``bsdf_sheen_setup``, ``bsdf_sheen_eval`` (T. Zeltner,
  B. Burley, M. J.-Y. Chiang, "Practical Multiple-Scattering Sheen Using Linearly Transformed
  Cosines", SIGGRAPH 2022 talks: a clamped cosine transformed by ``M^-1 = [[A, 0, B], [0, A,
  0], [0, 0, 1]]`` in the view's tangent frame);
* ``src/kernel/util/lookup_table.h``: the tables' clamped linear interpolation.

Notation: ``wi`` toward the light, ``wo`` toward the viewer (Cycles' ``sd->wi`` is our ``wo``),
``mu = n.wo``, ``h = normalize(wi + wo)``, ``c = wo.h``, ``r = roughness``,
``G(alpha) = D G2 / (4 (n.wi) mu)`` the GGX lobe of width ``alpha``. Top to bottom, ``W``
the weight left for the layers below (1 at the top, one value per channel)::

    sheen:  W sw tint R L(wi),  L = (1/pi) (A / |M^-1 wi|^2)^2 / (n.wi)   (A, B, R: the table)
           W <- W clamp(1 - max_channels(sw tint R), 0, 1)
    coat   (coat_weight > 1e-5):  W cw A_c F_diel(c; coat_ior) G(coat_roughness^2)
           W <- W clamp(1 - cw A_c est_c, 0, 1)                        (closure_layering_weight)
           W <- W mix(1, coat_tint^(1/cos_t), cw),  cos_t = sqrt(1 - (1 - mu^2)/coat_ior^2)
    metal  (metallic > 1e-5):     W m A_m F82(c) G(alpha_x, alpha_y);   W <- W (1 - m)
           F82(c) = clamp(mix(f0, 1, (1-c)^5) - b c (1-c)^6, 0, 1),  f0 = base_color,
           b = mix(f0, 1, (6/7)^5) (7^6/6^6) (1 - specular_tint)      (fresnel_f82tint_B)
    specular (eta != 1):           W A_s mix(f0_s, 1, s_real(c)) G(alpha_x, alpha_y)
           f0 = F0(ior) 2 specular_ior_level,  eta = ior_from_F0(f0),  f0_s = f0 specular_tint
           s_real(c) = clamp((F_diel(c; eta) - F0(eta)) / (1 - F0(eta)), 0, 1)
           W <- W clamp(1 - max_channels(A_s est_s), 0, 1)
    diffuse:                       W base_color / pi

with ``alpha_x, alpha_y = min(r^2 / a, 1), min(r^2 a, 1)``, ``a = sqrt(1 - 0.9 anisotropic)``,
``F0(eta) = ((eta - 1)/(eta + 1))^2``, ``ior_from_F0(f) = (1 + sqrt(f))/(1 - sqrt(f))`` (``f``
clamped to 0.99). ``A`` is the multiple-scattering compensation
(``microfacet_ggx_preserve_energy``; "Multiscatter GGX", the node's default distribution; 1 with
``multiscatter=False``, the node's "GGX"): with ``E = ggx_E(rough, mu)`` and ``E_avg =
ggx_Eavg(rough)`` from the tables, ``rough = (alpha_x alpha_y)^(1/4)``,

    A = 1 + F_ms (1 - E) / E,   F_ms = F_ss E_avg / (1 - F_ss (1 - E_avg))

(one factor of ``F_ss`` cancelled, as Cycles writes it), ``F_ss`` the lobe's average Fresnel:
``fresnel_dielectric_Fss(coat_ior)`` for the coat (compensated whatever the distribution),
``mix(f0, 1, 1/21) - b/126`` for the metal, ``mix(f0_s, 1, clamp((Fss(eta) - F0(eta))/(1 -
F0(eta)), 0, 1))`` for the specular. ``est`` is Cycles' estimate of a lobe's albedo at ``mu``
(``bsdf_microfacet_estimate_albedo``): ``mix(F0(coat_ior), 1, s)`` and ``mix(f0_s, 1, s)`` with
``s = ggx_gen_schlick_ior_s(rough, mu, sqrt((eta - 1)/(eta + 1)))``.

The sheen's ``A``, ``B`` and albedo ``R`` come from Zeltner et al.'s table of fitted LTCs at
(view cosine, sheen roughness), transcribed from Cycles (``resources/tables/cycles_sheen_ltc
.npz``; an LTC whose ``A`` or ``R`` interpolates below 1e-5 is no closure). The other tables
(``ggx_E``, ``ggx_Eavg``, ``ggx_gen_schlick_ior_s``) are this package's own, rebuilt by
quadrature on Cycles' grids (:mod:`brdf_fit.tables.cycles`; shipped as
``resources/tables/cycles_ggx.npz``): measured against Cycles' printed tables, within 1.0e-6
(``ggx_E``), 6.2e-7 (``ggx_Eavg``) and 1.9e-5 (``ggx_gen_schlick_ior_s``), which is the
largest source of difference from a Cycles render (``tests/convert/test_blender.py``).

Reciprocity: not reciprocal, as in Cycles: ``A``, ``est``, the coat tint and the sheen's LTC
depend on the view ``wo`` only (the registry entries declare the expected failure).

Not modelled: transmission, subsurface, emission, alpha, thin film, ``Diffuse Roughness`` > 0
(Oren-Nayar), normal and coat-normal maps, ``IOR`` below 1, the back side; the ``Specular
Tint``, ``Sheen Tint``, ``Coat Tint`` and ``Anisotropic Rotation`` inputs are modelled by the
class and left out of the registry entries (the tints couple the channels through
``max_channels``).

Epsilons: ``ROUGHNESS_SQ_THRESH = 2e-10`` (Cycles': ``alpha_x alpha_y`` at or below, the lobe
is a mirror, which ``eval`` does not see: 0). Cycles also skips a coat or metal closure whose
weight is at most ``CLOSURE_WEIGHT_CUTOFF = 1e-5`` (with the ``1 - metallic`` it would apply);
the model does not: the difference is below 1e-5 of the value, and with the cutoff a fit of a
dielectric sat on ``metallic = 1e-5``, where the value steps, for 247 steps.

Sampling (not Cycles'; the density is exact): a lobe by probabilities proportional to the
estimated albedos at ``wo``, GGX visible normals (spherical caps) for the glossy lobes,
cosine-weighted for the diffuse and the sheen.
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp

from brdf_fit.core.frame import join, split
from brdf_fit.core.fresnel import dielectric
from brdf_fit.core.microfacet import GGX, reflect_about
from brdf_fit.core.numerics import INV_PI, safe_div, safe_sqrt
from brdf_fit.core.params import (
    Channels,
    Entry,
    Param,
    Scalar,
    bounded,
    node_input_values,
    node_param,
)
from brdf_fit.core.validate import check_param
from brdf_fit.core.warp import sample_cosine_hemisphere
from brdf_fit.models import _cycles as _cy
from brdf_fit.models._base import AbstractBRDF, QuadratureLobe, expand_channels
from brdf_fit.models._cycles import (
    ROUGHNESS_SQ_THRESH,
    SAMPLER_ALPHA_FLOOR,
    SHEEN_INVALID,
    SHEEN_ROUGHNESS_MIN,
)
from brdf_fit.models._lobes import finish_sample, half_geometry, sanitize

__all__ = ["BLENDER_DEFAULTS", "INPUT_NAMES", "BlenderPrincipled", "registry_entries",
           "to_blender_inputs"]

#: the node's defaults in Blender 4.5 (also the registry defaults)
BLENDER_DEFAULTS = {
    "base_color": 0.8,
    "metallic": 0.0,
    "roughness": 0.5,
    "ior": 1.5,
    "specular_ior_level": 0.5,
    "specular_tint": 1.0,
    "anisotropic": 0.0,
    "anisotropic_rotation": 0.0,
    "coat_weight": 0.0,
    "coat_roughness": 0.03,
    "coat_ior": 1.5,
    "coat_tint": 1.0,
    "sheen_weight": 0.0,
    "sheen_roughness": 0.5,
    "sheen_tint": 1.0,
}
#: the node's input socket of each parameter
INPUT_NAMES = {
    "base_color": "Base Color",
    "metallic": "Metallic",
    "roughness": "Roughness",
    "ior": "IOR",
    "specular_ior_level": "Specular IOR Level",
    "specular_tint": "Specular Tint",
    "anisotropic": "Anisotropic",
    "anisotropic_rotation": "Anisotropic Rotation",
    "coat_weight": "Coat Weight",
    "coat_roughness": "Coat Roughness",
    "coat_ior": "Coat IOR",
    "coat_tint": "Coat Tint",
    "sheen_weight": "Sheen Weight",
    "sheen_roughness": "Sheen Roughness",
    "sheen_tint": "Sheen Tint",
}
_COLOURS = ("base_color", "specular_tint", "coat_tint", "sheen_tint")
#: the IOR interval of the entries: Blender's node accepts any IOR >= 0; below 1 Cycles inverts
#: it (not modelled), and 4 covers dielectrics (the Specular IOR Level reaches F0 up to 0.16)
IOR_MAX = 4.0

_REF_CYCLES = ("Blender 4.5 LTS Cycles, Principled BSDF (src/kernel/svm/closure.h "
               "svm_node_closure_bsdf; src/kernel/closure/bsdf_microfacet.h; "
               "src/kernel/closure/bsdf_util.h), reflection lobes")
_REF_KUTZ = "M. Kutz et al., Novel aspects of the Adobe Standard Material, 2021 (F82 tint)"
_REF_KC = ("C. Kulla, A. Conty, Revisiting Physically Based Shading at Imageworks, SIGGRAPH 2017 "
           "course notes (multiple-scattering compensation)")


class BlenderPrincipled(AbstractBRDF):
    """Cycles 4.5's Principled BSDF, reflection (module docstring: formulas, sources, tables).

    Every parameter is the node input of the same meaning (:data:`INPUT_NAMES`); colours are RGB
    (a trailing axis of 3; a scalar is grey). The optional inputs default to None: not given, so
    their terms are not traced; the value is that of the node's default (:data:`BLENDER_DEFAULTS`).
    ``multiscatter`` is the node's distribution: True for "Multiscatter GGX" (Blender's default),
    False for "GGX"."""

    base_color: Channels = bounded(0.8, lo=0.0, hi=1.0, channels=True)
    roughness: Scalar = bounded(0.5, lo=0.0, hi=1.0)
    metallic: Scalar = bounded(0.0, lo=0.0, hi=1.0)
    ior: Scalar = bounded(1.5, lo=1.0, hi=IOR_MAX)
    specular_ior_level: Scalar | None = bounded(None, lo=0.0, hi=1.0)
    specular_tint: Channels | None = bounded(None, lo=0.0, hi=1.0, channels=True)
    anisotropic: Scalar | None = bounded(None, lo=0.0, hi=1.0)
    anisotropic_rotation: Scalar | None = bounded(None, lo=0.0, hi=1.0)
    coat_weight: Scalar | None = bounded(None, lo=0.0, hi=1.0)
    coat_roughness: Scalar | None = bounded(None, lo=0.0, hi=1.0)
    coat_ior: Scalar | None = bounded(None, lo=1.0, hi=IOR_MAX)
    coat_tint: Channels | None = bounded(None, lo=0.0, hi=1.0, channels=True)
    sheen_weight: Scalar | None = bounded(None, lo=0.0, hi=1.0)
    sheen_roughness: Scalar | None = bounded(None, lo=0.0, hi=1.0)
    sheen_tint: Channels | None = bounded(None, lo=0.0, hi=1.0, channels=True)
    multiscatter: bool = eqx.field(static=True, default=True)

    def __check_init__(self):
        for name in ("base_color", "roughness", "metallic", "specular_ior_level",
                     "specular_tint", "anisotropic", "anisotropic_rotation", "coat_weight",
                     "coat_roughness", "coat_tint", "sheen_weight", "sheen_roughness",
                     "sheen_tint"):
            value = getattr(self, name)
            if value is not None:
                check_param(name, value, lo=0.0, hi=1.0, owner="BlenderPrincipled")
        for name in ("ior", "coat_ior"):
            value = getattr(self, name)
            if value is not None:
                check_param(name, value, lo=1.0, hi=IOR_MAX, owner="BlenderPrincipled")
        for name in _COLOURS:
            value = getattr(self, name)
            shape = () if value is None else jnp.shape(value)
            if len(shape) > 0 and shape[-1] not in (1, 3):
                raise ValueError(f"{name} must be RGB (a trailing axis of 3) or grey, got "
                                 f"shape {shape}")

    # ------------------------------------------------------------------ parameters

    def given(self) -> dict:
        """The inputs a Blender material would set: every one that is not None."""
        return {n: getattr(self, n) for n in INPUT_NAMES if getattr(self, n) is not None}

    def _opt(self, name):
        value = getattr(self, name)
        return BLENDER_DEFAULTS[name] if value is None else value

    def widths(self):
        """``(alpha_x, alpha_y)``: ``roughness^2`` stretched by the anisotropy, clamped to 1
        (``bsdf_microfacet_ggx_setup``)."""
        r2 = self.roughness * self.roughness
        if self.anisotropic is None:
            return r2, r2
        aspect = jnp.sqrt(1.0 - 0.9 * self.anisotropic)
        return jnp.minimum(r2 / aspect, 1.0), jnp.minimum(r2 * aspect, 1.0)

    def _rotate(self, x, y):
        """Local x, y components in the frame of the rotated tangent: Cycles turns the tangent
        about the normal by ``anisotropic_rotation`` turns (``rotate_around_axis``)."""
        if self.anisotropic_rotation is None:
            return x, y
        a = 2.0 * jnp.pi * self.anisotropic_rotation
        c, s = jnp.cos(a), jnp.sin(a)
        return c * x + s * y, -s * x + c * y

    def _specular_eta(self):
        """``(f0, eta)`` of the specular layer after the IOR level (``svm_node_closure_bsdf``)."""
        f0 = _cy.f0_from_ior(self.ior)
        if self.specular_ior_level is not None:
            f0 = f0 * (2.0 * self.specular_ior_level)
        return f0, _cy.ior_from_f0(f0)

    # ------------------------------------------------------------------ the BRDF

    def _layers(self, mu):
        """Per-view quantities of the layering at view cosine ``mu``: ``(w, est)``. ``w`` maps
        each lobe to the factor multiplying its ``F G`` (the closure weight times ``A``, per
        channel) and holds the Fresnel inputs; ``est`` each lobe's estimated albedo, averaged
        over the channels (the lobe probabilities of :meth:`sample`)."""
        ch = self.channels()

        def ex(x):
            return expand_channels(x, ch)

        def mean_c(x):
            return jnp.mean(x, axis=-1) if ch else x

        W = ex(jnp.ones_like(mu))
        w, est = {}, {}
        ax, ay = self.widths()
        rough = safe_sqrt(safe_sqrt(ax * ay))
        if self.sheen_weight is not None:
            # the first layer: Zeltner et al.'s LTC sheen (bsdf_sheen_setup), its weight
            # sheen_weight x tint x the table's albedo, which also layers what is below
            a, b, albedo, on = self._sheen_ltc(mu)
            tint = self._opt("sheen_tint")
            k = jnp.where(on, self.sheen_weight * albedo, 0.0)
            w["sheen"] = W * ex(k) * tint
            w["sheen_ab"] = (a, b)
            ratio = ex(k) * tint * jnp.ones_like(W)
            s_max = jnp.max(ratio, axis=-1) if ch else ratio
            est["sheen"] = mean_c(W) * s_max
            W = W * ex(jnp.clip(1.0 - s_max, 0.0, 1.0))
        if self.coat_weight is not None:
            cw = self.coat_weight
            on = cw >= 0.0  # not Cycles' cutoff (module docstring, "Epsilons")
            cr, ci = self._opt("coat_roughness"), self._opt("coat_ior")
            # the coat is compensated whatever the distribution (setup_fresnel_dielectric)
            a_c, dark_c = _cy.compensation(cr, mu, _cy.fresnel_dielectric_fss(ci))
            f0_c = _cy.f0_from_ior(ci)
            e_c = jnp.where(ci > 1.0, f0_c + (1.0 - f0_c) * _cy.estimated_s(cr, mu, ci), 0.0)
            w["coat"] = W * ex(jnp.where(on, cw * a_c, 0.0))
            est["coat"] = jnp.where(on, cw * dark_c * e_c, 0.0)
            W = W * ex(jnp.where(on, jnp.clip(1.0 - cw * dark_c * e_c, 0.0, 1.0), 1.0))
            if self.coat_tint is not None:
                cos_t = jnp.sqrt(1.0 - (1.0 - mu * mu) / (ci * ci))
                tint = jnp.power(self.coat_tint, 1.0 / ex(cos_t))
                W = W * jnp.where(ex(on), 1.0 + cw * (tint - 1.0), 1.0)
        # metal: F82 tint with f0 = base colour
        m = self.metallic
        on = m >= 0.0  # not Cycles' cutoff (module docstring, "Epsilons")
        tint_s = self._opt("specular_tint")
        f0_m = jnp.clip(self.base_color, 0.0, 1.0)
        b = self._f82_b(f0_m, tint_s)
        a_m = 1.0
        if self.multiscatter:
            a_m, _ = _cy.compensation(ex(rough), ex(mu), f0_m + (1.0 - f0_m) / 21.0 - b / 126.0)
        w["metal"] = W * jnp.where(on, m, 0.0) * a_m
        w["metal_b"] = b
        est["metal"] = mean_c(W * jnp.where(on, m, 0.0))
        W = W * jnp.where(on, 1.0 - m, 1.0)
        # specular: the dielectric GGX layer over the diffuse
        f0, eta = self._specular_eta()
        on = f0 > 0.0  # eta != 1
        f0_s = jnp.clip(f0 * tint_s, 0.0, 1.0)
        a_s = dark_s = 1.0
        if self.multiscatter:
            fe = _cy.f0_from_ior(eta)
            s_avg = jnp.clip(safe_div(_cy.fresnel_dielectric_fss(eta) - fe, 1.0 - fe), 0.0, 1.0)
            a_s, dark_s = _cy.compensation(ex(rough), ex(mu), f0_s + (1.0 - f0_s) * s_avg)
        e_s = dark_s * (f0_s + (1.0 - f0_s) * ex(_cy.estimated_s(rough, mu, eta)))
        e_max = jnp.max(e_s, axis=-1) if ch else e_s  # closure_layering_weight's reduce_max
        w["specular"] = W * jnp.where(on, 1.0, 0.0) * a_s
        w["specular_f0"] = f0_s
        w["specular_eta"] = eta
        est["specular"] = mean_c(W) * jnp.where(on, e_max, 0.0)
        W = W * ex(jnp.where(on, jnp.clip(1.0 - e_max, 0.0, 1.0), 1.0))
        w["diffuse"] = W * self.base_color
        est["diffuse"] = mean_c(w["diffuse"])
        return w, est

    def _sheen_ltc(self, mu):
        """``(A, B, albedo, valid)`` of the sheen at view cosine ``mu`` (``bsdf_sheen_setup``:
        the table read at ``(mu, clamped roughness)``)."""
        t = _cy.tables()["sheen_ltc"]
        r = jnp.clip(self._opt("sheen_roughness"), SHEEN_ROUGHNESS_MIN, 1.0)
        a = _cy.lookup_2d(t[0], mu, r)
        b = _cy.lookup_2d(t[1], mu, r)
        albedo = _cy.lookup_2d(t[2], mu, r)
        return a, b, albedo, (jnp.abs(a) >= SHEEN_INVALID) & (albedo >= SHEEN_INVALID)

    @staticmethod
    def _f82_b(f0, tint):
        """``fresnel_f82tint_B``: 0 where the tint is 1 (Cycles skips it there)."""
        f = 6.0 / 7.0
        f5 = f ** 5
        f_schlick = f0 + (1.0 - f0) * f5
        return f_schlick * (7.0 / (f5 * f)) * (1.0 - tint)

    def eval(self, wi, wo):
        valid, (ix, iy, iz), (ox, oy, oz), (hx, hy, hz), c = half_geometry(wi, wo)
        ch = self.channels()

        def ex(x):
            return expand_channels(x, ch)

        w, _ = self._layers(oz)
        # the GGX lobe G = D G2 / (4 ci co) = D / (2 (co P(wi) + ci P(wo))) of the main widths
        ax, ay = self.widths()
        lx, ly = self._rotate(ix, iy)
        vx, vy = self._rotate(ox, oy)
        hxr, hyr = self._rotate(hx, hy)
        lobe_on = ax * ay > ROUGHNESS_SQ_THRESH
        ax, ay = jnp.where(lobe_on, ax, 1.0), jnp.where(lobe_on, ay, 1.0)  # double where
        dist = GGX(ax, ay) if self.anisotropic is not None else GGX(ax)
        g_main = dist.D(hxr, hyr, hz) * 0.5 / (oz * dist.P(lx, ly, iz) + iz * dist.P(vx, vy, oz))
        g_main = jnp.where(lobe_on, g_main, 0.0)
        # metal: F82 tint
        f0 = jnp.clip(self.base_color, 0.0, 1.0)
        one_c = ex(jnp.clip(1.0 - c, 0.0, 1.0))
        c5 = one_c ** 5
        f82 = jnp.clip(f0 + (1.0 - f0) * c5 - w["metal_b"] * ex(c) * c5 * one_c, 0.0, 1.0)
        total = w["metal"] * f82 * ex(g_main)
        # specular: the remapped dielectric Fresnel
        f0_s = w["specular_f0"]
        f_s = f0_s + (1.0 - f0_s) * ex(_cy.remapped_fresnel(c, w["specular_eta"]))
        total = total + w["specular"] * f_s * ex(g_main)
        # coat
        if self.coat_weight is not None:
            a_c = self._opt("coat_roughness") ** 2
            coat_on = a_c * a_c > ROUGHNESS_SQ_THRESH
            dc = GGX(jnp.where(coat_on, a_c, 1.0))  # double where
            g_c = dc.D(hx, hy, hz) * 0.5 / (oz * dc.P(ix, iy, iz) + iz * dc.P(ox, oy, oz))
            g_c = jnp.where(coat_on, g_c, 0.0)
            total = total + w["coat"] * ex(dielectric(c, self._opt("coat_ior")) * g_c)
        if self.sheen_weight is not None:
            total = total + w["sheen"] * ex(_cy.sheen_lobe(w["sheen_ab"], ix, iy, iz, ox, oy))
        total = total + w["diffuse"] * INV_PI
        return jnp.where(ex(valid), total, 0.0)

    def lobe_probabilities(self, mu):
        """``(p_diffuse, p_main, p_coat)`` of :meth:`sample` at view cosine ``mu``: proportional
        to the estimated albedos of the diffuse, the metal and specular (one GGX lobe) and the
        coat."""
        _, est = self._layers(mu)
        pd = est["diffuse"] + est.get("sheen", jnp.zeros_like(mu))  # sheen: cosine-sampled
        pm = est["metal"] + est["specular"]
        pc = est.get("coat", jnp.zeros_like(mu))
        tot = pd + pm + pc
        ok = tot > 0
        inv = 1.0 / jnp.where(ok, tot, 1.0)
        return (jnp.where(ok, pd * inv, 0.0), jnp.where(ok, pm * inv, 1.0),
                jnp.where(ok, pc * inv, 0.0))

    def _dists(self):
        ax, ay = self.widths()
        f = SAMPLER_ALPHA_FLOOR
        main = GGX(jnp.maximum(ax, f), jnp.maximum(ay, f)) \
            if self.anisotropic is not None else GGX(jnp.maximum(ax, f))
        coat = None
        if self.coat_weight is not None:
            cr = self._opt("coat_roughness")
            coat = GGX(jnp.maximum(cr * cr, f))
        return main, coat

    def pdf(self, wi, wo):
        valid, (ix, iy, iz), (ox, oy, oz), (hx, hy, hz), c = half_geometry(wi, wo)
        pd, pm, pc = self.lobe_probabilities(oz)
        main, coat = self._dists()
        hxr, hyr = self._rotate(hx, hy)
        vx, vy = self._rotate(ox, oy)
        # visible normals D G1(wo) (wo.h)/co, times dwh/dwi = 1/(4 wi.h) (wi.h = wo.h)
        p = pd * iz * INV_PI + pm * main.D(hxr, hyr, hz) / (2.0 * (oz + main.P(vx, vy, oz)))
        if coat is not None:
            p = p + pc * coat.D(hx, hy, hz) / (2.0 * (oz + coat.P(ox, oy, oz)))
        return jnp.where(valid & (c > 0), p, jnp.where(valid, pd * iz * INV_PI, 0.0))

    def sample(self, wo, uc, u):
        ox, oy, oz = split(wo)
        ok = oz > 0
        ox, oy, oz = sanitize(ok, ox, oy, oz)
        u1, u2 = u[..., 0], u[..., 1]
        pd, pm, _ = self.lobe_probabilities(oz)
        main, coat = self._dists()
        vx, vy = self._rotate(ox, oy)
        mx, my, mz = main.sample_visible(vx, vy, oz, u1, u2)
        if self.anisotropic_rotation is not None:  # back to the surface frame
            a = 2.0 * jnp.pi * self.anisotropic_rotation
            cs, sn = jnp.cos(a), jnp.sin(a)
            mx, my = cs * mx - sn * my, sn * mx + cs * my
        wi = join(*reflect_about(ox, oy, oz, mx, my, mz))
        if coat is not None:
            m_c = coat.sample_visible(ox, oy, oz, u1, u2)
            w_c = join(*reflect_about(ox, oy, oz, *m_c))
            wi = jnp.where((uc >= pd + pm)[..., None], w_c, wi)
        wi = jnp.where((uc < pd)[..., None], sample_cosine_hemisphere(u), wi)
        return finish_sample(self, wi, wo, ok & (wi[..., 2] > 0))

    # ------------------------------------------------------------------ declared hooks

    def quadrature_lobe(self) -> QuadratureLobe:
        """The main GGX lobe's widths (a coat much narrower than it is not followed)."""
        ax, ay = self.widths()
        return QuadratureLobe("half", (ax, ay) if self.anisotropic is not None else ax)

    def is_anisotropic(self) -> bool:
        return self.anisotropic is not None


# ----------------------------------------------------------------------------- registry


_ENTRY_PARAMS = {
    "base_color": ("Base Color: diffuse albedo and the metal's F0 (linear RGB)", True, 0.0, 1.0),
    "roughness": ("Roughness: GGX alpha = roughness^2", False, 0.0, 1.0),
    "metallic": ("Metallic: blend from the dielectric (specular over diffuse) to the F82 metal",
                 False, 0.0, 1.0),
    "ior": ("IOR of the specular layer (F0 = ((ior - 1)/(ior + 1))^2)", False, 1.0, IOR_MAX),
    "anisotropic": ("Anisotropic: alpha_x, alpha_y = roughness^2 / a, roughness^2 a, "
                    "a = sqrt(1 - 0.9 anisotropic); x is the tangent (the UV map's u)",
                    False, 0.0, 1.0),
    "coat_weight": ("Coat Weight: a dielectric GGX coat over the rest", False, 0.0, 1.0),
    "coat_roughness": ("Coat Roughness: the coat's GGX alpha = coat_roughness^2", False, 0.0, 1.0),
    "coat_ior": ("Coat IOR", False, 1.0, IOR_MAX),
    "sheen_weight": ("Sheen Weight: Zeltner et al.'s LTC microfiber sheen over the rest", False,
                     0.0, 1.0),
    "sheen_roughness": ("Sheen Roughness", False, 0.0, 1.0),
}


def _param(name: str) -> Param:
    return node_param(name, _ENTRY_PARAMS[name], BLENDER_DEFAULTS[name])


_BASIC = ("base_color", "roughness", "metallic", "ior")
_ANISO = _BASIC + ("anisotropic",)
_COAT = _BASIC + ("coat_weight", "coat_roughness", "coat_ior")
_SHEEN = _BASIC + ("sheen_weight", "sheen_roughness")


def _builder(**params):
    return BlenderPrincipled(**params)


def to_blender_inputs(params: dict) -> dict:
    """The Principled BSDF node's input values of a ``blender-principled*`` entry's parameters:
    ``{socket name: value}`` (colours as RGBA lists, alpha 1; scalars as floats), every given
    parameter. Blender then renders what :class:`BlenderPrincipled` with the same parameters
    evaluates."""
    values = node_input_values(params, tuple(INPUT_NAMES), _COLOURS,
                               "Blender's Principled BSDF")
    return {INPUT_NAMES[name]: v + [1.0] if name in _COLOURS else v
            for name, v in values.items()}


_NATIVE = {"target": "blender", "native_export": to_blender_inputs}
_NOT_RECIPROCAL = {"reciprocity": "Cycles' multiple-scattering compensation, layering weights, "
                                  "coat tint and sheen LTC depend on the view direction only"}


def registry_entries():
    """:class:`~brdf_fit.core.params.Entry` objects of Cycles' Principled BSDF (not registered
    here): ``blender-principled`` (base_color, roughness, metallic, ior),
    ``blender-principled-aniso`` (+ anisotropic), ``blender-principled-coat`` (+ coat_weight,
    coat_roughness, coat_ior) and ``blender-principled-sheen`` (+ sheen_weight,
    sheen_roughness); defaults are Blender's, the distribution Multiscatter GGX."""
    common = {"reference": f"{_REF_CYCLES}; {_REF_KUTZ}; {_REF_KC}",
              "sampler": ("lobe by estimated albedo: cosine / GGX visible normals (main, coat); "
                          "exact mixture pdf"),
              "year": 2024, "expected_failures": dict(_NOT_RECIPROCAL), **_NATIVE}
    return [
        Entry(name="blender-principled", builder=_builder,
              params=tuple(_param(n) for n in _BASIC),
              description=("Blender 4.5 Principled BSDF as Cycles renders it: Lambert under a "
                           "dielectric GGX layer, F82 metal, Multiscatter GGX; the node's inputs"),
              aliases=("principled-blender", "cycles-principled"),
              tags=("native", "blender", "layered"), **common),
        Entry(name="blender-principled-aniso", builder=_builder,
              params=tuple(_param(n) for n in _ANISO),
              description="blender-principled with Cycles' anisotropic GGX widths",
              tags=("native", "blender", "anisotropic", "layered"), **common),
        Entry(name="blender-principled-coat", builder=_builder,
              params=tuple(_param(n) for n in _COAT),
              description="blender-principled under Cycles' dielectric GGX coat",
              tags=("native", "blender", "layered"), **common),
        Entry(name="blender-principled-sheen", builder=_builder,
              params=tuple(_param(n) for n in _SHEEN),
              description=("blender-principled under Cycles' sheen (Zeltner et al. 2022's LTC "
                           "microfiber, untinted)"),
              tags=("native", "blender", "layered"), **common),
    ]
