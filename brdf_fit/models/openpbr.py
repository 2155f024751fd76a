"""OpenPBR Surface as MaterialX 1.39 renders it, reflection lobes: a renderer-native model.

:class:`OpenPBRSurface` evaluates what MaterialX's GLSL implementation of the
``open_pbr_surface`` node (OpenPBR Surface 1.1, node version 1.1.1) computes for one light:
the node graph ``NG_open_pbr_surface_surfaceshader`` of ``libraries/bxdf/open_pbr_surface.mtlx``
built from the ``pbrlib`` BSDF nodes as ``libraries/pbrlib/genglsl`` implements them
(MaterialX 1.39.5, the ``materialx`` package on the registry), divided by the light's cosine.
The parameters are the node's inputs, so a fit here is written to a ``.mtlx`` document with no
loss (:func:`to_openpbr_inputs`, :mod:`brdf_fit.convert.materialx`). Parity with the generated
shader itself is a test (``tests/convert/test_materialx.py``: MaterialX's GLSL generator,
run on an OpenGL context).

Transcribed (MaterialX 1.39.5 ``libraries/``; ``L`` = ``wi`` toward the light, ``V`` = ``wo``):

* ``bxdf/open_pbr_surface.mtlx``: the graph. The coat roughens the specular lobe,
  ``r' = mix(r, min(1, r^4 + 2 r_c^4)^(1/4), coat_weight)``; ``open_pbr_anisotropy``:
  ``alpha_x = r'^2 sqrt(2 / (1 + (1 - a)^2))``, ``alpha_y = (1 - a) alpha_x``; the specular IOR
  ``eta_s = mix(specular_ior, max(specular_ior/coat_ior, coat_ior/specular_ior), coat_weight)``
  modulated by ``specular_weight``: ``e = sqrt(clamp(specular_weight F0(eta_s), 0, 0.99999))``,
  ``eta = (1 + e)/(1 - e)``; the coat darkening ``(1 - K)/(1 - E_base K)``, ``K = 1 - (1 -
  F0(coat_ior))/coat_ior^2``, mixed in by ``coat_weight coat_darkening``; the coat's colour
  mixed in by ``coat_weight``; layering ``top + base x top.throughput`` (``mx_layer_bsdf.glsl``),
  ``mix`` as GLSL's ``mix`` (``mx_mix_bsdf.glsl``), a BSDF times a colour clamped to [0, 1]
  (``mx_multiply_bsdf_color3.glsl``)::

      fuzz over (coat over (attenuation x darkening x mix(dielectric, metal, base_metalness)))
      dielectric = specular (dielectric_bsdf, tint specular_color) over diffuse (Oren-Nayar)
      metal = generalized_schlick_bsdf (color0 = base_color base_weight, color82 = specular_color)

* ``pbrlib/genglsl/mx_dielectric_bsdf.glsl``, ``mx_generalized_schlick_bsdf.glsl``: a GGX lobe
  ``D F G2 comp w / (4 n.wo n.wi)`` with ``D`` of the widths ``alpha`` (B. Burley, "Physically
  Based Shading at Disney", 2012, App. B.2 eq. 13), height-correlated ``G2`` of the *average*
  width ``sqrt(alpha_x alpha_y)`` (E. Heitz, JCGT 3(2) 2014, eqs. 72, 99), the energy
  compensation ``comp = 1 + F (1 - E)/E`` (E. Turquin, "Practical multiple scattering
  compensation for microfacet models", 2019, eqs. 14, 16) with ``F`` at ``wo.h`` and
  ``E = A + B``, and the throughput ``1 - (F0 A + F90 B) comp w`` (the generalized Schlick's
  averaged over the channels); ``A, B`` MaterialX's rational fit of the GGX directional
  albedo (``mx_ggx_dir_albedo_analytic``, the generator's default method);
* ``pbrlib/genglsl/lib/mx_microfacet_specular.glsl``: the exact dielectric Fresnel
  (``mx_fresnel_dielectric``) and the F82-tint generalized Schlick Fresnel
  (``mx_fresnel_hoffman_schlick``: N. Hoffman, "Generalization of Adobe's Fresnel model",
  2023; M. Kutz et al., "Novel aspects of the Adobe Standard Material", 2021);
* ``pbrlib/genglsl/lib/mx_microfacet_diffuse.glsl``: the energy-compensated Oren-Nayar of
  OpenPBR (``mx_oren_nayar_compensated_diffuse``: J. Portsmouth et al., "EON: A practical
  energy-preserving rough diffuse BRDF", JCGT 14(1) 2025, with Fujii's single-scattering lobe
  and its albedos);
* ``pbrlib/genglsl/lib/mx_microfacet_sheen.glsl``: the fuzz, Zeltner et al.'s LTC sheen with
  MaterialX's rational fits of the LTC and a Gaussian fit of its albedo (T. Zeltner, B. Burley,
  M. J.-Y. Chiang, "Practical Multiple-Scattering Sheen Using Linearly Transformed Cosines",
  SIGGRAPH 2022 talks), roughness clamped to [0.01, 1].

Epsilons. MaterialX clamps every cosine it uses (``n.wo``, ``n.wi``, ``wo.h``, ``wi.wo`` in the
diffuse) and every width to ``[M_FLOAT_EPS, 1]`` (:data:`M_FLOAT_EPS` = 1e-8); so does this
model, with one exception: the GGX lobes' ``D`` and ``G2`` take their widths floored at
``ALPHA_MIN`` = 1e-4 (:mod:`brdf_fit.core.numerics`, as every GGX of this package), not 1e-8.
A lobe of width 1e-8 (roughness 0, the coat's default) is a numerical delta whose float32
derivatives overflow (NaN gradients at grazing mirror pairs); with the floor, a roughness
below 0.01 evaluates as 0.01 in the lobe's shape, which differs from MaterialX's only within
about a degree of the mirror direction (the albedo fits, compensation and throughputs keep
MaterialX's 1e-8). A BSDF node whose weight is below ``M_FLOAT_EPS`` is skipped (response 0,
throughput 1), as in the shader. ``(ior - 1)(ior + 1)`` in the dielectric Fresnel:
:func:`fresnel_dielectric`.

Reciprocity: not reciprocal, as in MaterialX: the compensation, the throughputs and the fuzz's
LTC depend on the view ``wo``. Energy: the albedo fits are not exact, so a white furnace can
read slightly above 1 (the registry entries say by how much where it matters).

Not modelled: transmission, subsurface, thin film, emission, opacity, thin walls, the geometry
inputs (the normal is the surface's, the tangent its x axis), the back side. ``specular_color``,
``coat_color``, ``fuzz_color``, ``base_weight``, ``specular_weight``, ``coat_darkening``,
``base_diffuse_roughness`` and ``coat_roughness_anisotropy`` are modelled by the class and left
out of the registry entries.

Sampling (not MaterialX's; the density is exact): a lobe by probabilities proportional to the
lobes' albedo estimates at ``wo``, GGX visible normals for the specular/metal and the coat,
cosine-weighted for the diffuse and the fuzz.
"""

from __future__ import annotations

import math

import jax.numpy as jnp
import numpy as np

from brdf_fit.core.frame import join, split
from brdf_fit.core.microfacet import GGX, reflect_about
from brdf_fit.core.numerics import ALPHA_MIN, INV_PI, safe_sqrt
from brdf_fit.core.params import Channels, Entry, Param, Scalar, bounded
from brdf_fit.core.validate import check_param
from brdf_fit.core.warp import sample_cosine_hemisphere
from brdf_fit.models._base import AbstractBRDF, QuadratureLobe, expand_channels
from brdf_fit.models._lobes import finish_sample, sanitize

__all__ = ["INPUT_TYPES", "M_FLOAT_EPS", "OPENPBR_DEFAULTS", "OpenPBRSurface",
           "registry_entries", "to_openpbr_inputs"]

#: MaterialX's ``M_FLOAT_EPS`` (``stdlib/genglsl/lib/mx_math.glsl``): the floor of every
#: cosine and width the shader clamps, and the weight under which a BSDF node is skipped
M_FLOAT_EPS = 1e-8
#: the node's defaults (``ND_open_pbr_surface_surfaceshader``, also the registry defaults)
OPENPBR_DEFAULTS = {
    "base_weight": 1.0,
    "base_color": 0.8,
    "base_diffuse_roughness": 0.0,
    "base_metalness": 0.0,
    "specular_weight": 1.0,
    "specular_color": 1.0,
    "specular_roughness": 0.3,
    "specular_ior": 1.5,
    "specular_roughness_anisotropy": 0.0,
    "fuzz_weight": 0.0,
    "fuzz_color": 1.0,
    "fuzz_roughness": 0.5,
    "coat_weight": 0.0,
    "coat_color": 1.0,
    "coat_roughness": 0.0,
    "coat_roughness_anisotropy": 0.0,
    "coat_ior": 1.6,
    "coat_darkening": 1.0,
}
#: each input's MaterialX type
INPUT_TYPES = {name: ("color3" if name.endswith("_color") else "float")
               for name in OPENPBR_DEFAULTS}
_COLOURS = tuple(n for n, t in INPUT_TYPES.items() if t == "color3")
#: the IOR interval of the entries (the node's soft range is [1, 3])
IOR_MAX = 3.0
#: the fuzz roughness range of Zeltner et al.'s fit (``mx_sheen_bsdf.glsl`` clamps to it)
FUZZ_ROUGHNESS_MIN = 0.01
#: MaterialX's rational fit of GGX's directional albedo (``mx_ggx_dir_albedo_analytic``):
#: ``(A, B) = clamp(r.xy / r.zw, 0, 1)``, ``r`` a polynomial in ``x = n.wo``, ``y = alpha``
#: with these coefficients of 1, x, y, xy, x^2, y^2, x^2 y, x y^2, x^2 y^2 (rows)
GGX_ALBEDO_FIT = np.array([
    [0.1003, 0.9345, 1.0, 1.0],
    [-0.6303, -2.323, -1.765, 0.2281],
    [9.748, 2.229, 8.263, 15.94],
    [-2.038, -3.748, 11.53, -55.83],
    [29.34, 1.424, 28.96, 13.08],
    [-8.245, -0.7684, -7.507, 41.26],
    [-26.44, 1.436, -36.11, 54.9],
    [19.99, 0.2913, 15.86, 300.2],
    [-5.448, 0.6286, 33.37, -285.1],
])
#: Fujii's constants of the Oren-Nayar albedos (``mx_microfacet_diffuse.glsl``)
FUJII_1 = 0.5 - 2.0 / (3.0 * math.pi)
FUJII_2 = 2.0 / 3.0 - 28.0 / (15.0 * math.pi)

_REF_MX = ("MaterialX 1.39.5 open_pbr_surface (libraries/bxdf/open_pbr_surface.mtlx; "
           "libraries/pbrlib/genglsl), OpenPBR Surface 1.1, reflection lobes")


def _mix(bg, fg, t):
    """GLSL's ``mix(bg, fg, t) = bg (1 - t) + fg t``."""
    return bg * (1.0 - t) + fg * t


def _clamp_eps(x):
    return jnp.clip(x, M_FLOAT_EPS, 1.0)


def _clamp_width(a, floor=M_FLOAT_EPS):
    """A GGX width clamped to ``[floor, 1]`` by selection (``clip``'s gradient multiplies the
    lobe's derivatives at the floor by 0, which is NaN where they overflow float32; ``where``
    drops them). ``floor``: MaterialX's ``M_FLOAT_EPS`` for the albedo fits and compensation,
    ``ALPHA_MIN`` for the lobe's shape (module docstring, "Epsilons")."""
    return jnp.where(a < floor, floor, jnp.where(a > 1.0, 1.0, a))


def _lobe(hx, hy, hz, cl, cv, ax, ay):
    """``D G2 / (4 n.wi n.wo)`` of GGX widths ``(ax, ay)`` floored at ``ALPHA_MIN``, ``G2`` of
    their geometric mean (``mx_average_alpha``)."""
    ax, ay = _clamp_width(ax, ALPHA_MIN), _clamp_width(ay, ALPHA_MIN)
    return _ggx_d(hx, hy, hz, ax, ay) * _ggx_g2_over_cosines(cl, cv, jnp.sqrt(ax * ay)) / 4.0


def ggx_albedo_ab(mu, alpha):
    """``(A, B)`` of MaterialX's fit: GGX's directional albedo at view cosine ``mu`` and width
    ``alpha`` is ``F0 A + F90 B``."""
    x, y = mu, alpha
    terms = (1.0, x, y, x * y, x * x, y * y, x * x * y, x * y * y, x * x * y * y)
    r = [sum(float(GGX_ALBEDO_FIT[k, j]) * t for k, t in enumerate(terms)) for j in range(4)]
    return jnp.clip(r[0] / r[2], 0.0, 1.0), jnp.clip(r[1] / r[3], 0.0, 1.0)


def fresnel_dielectric(c, ior):
    """``mx_fresnel_dielectric``: exact, unpolarised; 1 under total internal reflection.
    ``g^2 = ior^2 + c^2 - 1`` is formed as ``(ior - 1)(ior + 1) + c^2`` (MaterialX adds the
    terms in order): the same number, without float32's cancellation at ``ior`` near 1 and a
    grazing ``c``, where MaterialX's order turned ``F`` at ``ior = 1``, ``c = 1e-3`` from 0 into a
    value 100 times the BRDF's."""
    g2 = (ior - 1.0) * (ior + 1.0) + c * c
    tir = g2 < 0.0
    g = jnp.sqrt(jnp.where(tir, 1.0, g2))
    f = 0.5 * ((g - c) / (g + c)) ** 2 * (1.0 + (((g + c) * c - 1.0) / ((g - c) * c + 1.0)) ** 2)
    return jnp.where(tir, 1.0, f)


def fresnel_f82(c, f0, f82, f90=1.0, exponent=5.0):
    """``mx_fresnel_hoffman_schlick``: Schlick's curve from ``f0`` to ``f90`` less Hoffman's
    term that makes it ``f82``-tinted at ``cos = 1/7`` (not clamped)."""
    cmax = 1.0 / 7.0
    factor = 1.0 / (cmax * (1.0 - cmax) ** 6)
    x = jnp.clip(c, 0.0, 1.0)
    a = _mix(f0, f90, (1.0 - cmax) ** exponent) * (1.0 - f82) * factor
    return _mix(f0, f90, (1.0 - x) ** exponent) - a * x * (1.0 - x) ** 6


def ior_to_f0(ior):
    return ((ior - 1.0) / (ior + 1.0)) ** 2


def roughness_widths(roughness, anisotropy):
    """``open_pbr_anisotropy``: ``(alpha_x, alpha_y)`` of a roughness and an anisotropy."""
    inv = 1.0 - anisotropy
    alpha_x = roughness * roughness * jnp.sqrt(2.0 / (inv * inv + 1.0))
    return alpha_x, inv * alpha_x


def _ggx_d(hx, hy, hz, ax, ay):
    """``mx_ggx_NDF``."""
    ex, ey = hx / ax, hy / ay
    denom = ex * ex + ey * ey + hz * hz
    return 1.0 / (math.pi * ax * ay * denom * denom)


def _ggx_g2_over_cosines(cl, cv, alpha):
    """``mx_ggx_smith_G2 / (n.wi n.wo)``."""
    a2 = alpha * alpha
    lam_l = jnp.sqrt(a2 + (1.0 - a2) * cl * cl)
    lam_v = jnp.sqrt(a2 + (1.0 - a2) * cv * cv)
    return 2.0 / (lam_l * cv + lam_v * cl)


def fujii_dir_albedo(c, roughness):
    """``mx_oren_nayar_fujii_diffuse_dir_albedo``: the directional albedo of Fujii's
    single-scattering Oren-Nayar lobe at cosine ``c``."""
    a = 1.0 / (1.0 + FUJII_1 * roughness)
    # sin and acos as safe_sqrt and atan2(sin, cos): the same values, and a finite gradient at
    # c = 1 (normal incidence), where sqrt's and acos's derivatives are infinite
    si = safe_sqrt(1.0 - c * c)
    g = si * (jnp.arctan2(si, c) - si * c) \
        + 2.0 * ((si / c) * (1.0 - si * si * si) - si) / 3.0
    return a + (roughness * a) * g * INV_PI


def fujii_avg_albedo(roughness):
    """``mx_oren_nayar_fujii_diffuse_avg_albedo``."""
    return (1.0 + FUJII_2 * roughness) / (1.0 + FUJII_1 * roughness)


def eon_multiple_scattering_colour(color, roughness):
    """EON's multiple-scattering colour ``color^2 E_avg / (1 - color (1 - E_avg))``."""
    avg = fujii_avg_albedo(roughness)
    return color * color * avg / (1.0 - color * jnp.maximum(0.0, 1.0 - avg))


def oren_nayar_eon(cv, cl, lv, roughness, color):
    """``mx_oren_nayar_compensated_diffuse / pi``: EON's single- plus multiple-scattering
    lobes (a BRDF; the shader's response is this times ``n.wi``)."""
    s = lv - cl * cv
    stinv = jnp.where(s > 0.0, s / jnp.maximum(cl, cv), s)
    a = 1.0 / (1.0 + FUJII_1 * roughness)
    single = color * a * (1.0 + roughness * stinv)
    avg = fujii_avg_albedo(roughness)
    multi = eon_multiple_scattering_colour(color, roughness) \
        * jnp.maximum(M_FLOAT_EPS, 1.0 - fujii_dir_albedo(cv, roughness)) \
        * jnp.maximum(M_FLOAT_EPS, 1.0 - fujii_dir_albedo(cl, roughness)) \
        / jnp.maximum(M_FLOAT_EPS, 1.0 - avg)
    return (single + multi) * INV_PI


def zeltner_fits(mu, roughness):
    """``(albedo, a_inv, b_inv)`` of MaterialX's fits of Zeltner et al.'s sheen at view cosine
    ``mu`` (``mx_zeltner_sheen_dir_albedo``, ``_ltc_aInv``, ``_ltc_bInv``)."""
    x, y = mu, roughness
    s = y * (0.0206607 + 1.58491 * y) / (0.0379424 + y * (1.32227 + y))
    m = y * (-0.193854 + y * (-1.14885 + y * (1.7932 - 0.95943 * y * y))) / (0.046391 + y)
    o = y * (0.000654023 + (-0.0207818 + 0.119681 * y) * y) / (1.26264 + y * (-1.92021 + y))
    albedo = jnp.exp(-0.5 * ((x - m) / s) ** 2) / (s * math.sqrt(2.0 * math.pi)) + o
    a_inv = (2.58126 * x + 0.813703 * y) * y / (1.0 + 0.310327 * x * x + 2.60994 * x * y)
    b_inv = safe_sqrt(1.0 - x) * (y - 1.0) * y * y * y \
        / (0.0000254053 + 1.71228 * x - 1.71506 * x * y + 1.34174 * y * y)
    return albedo, a_inv, b_inv


class OpenPBRSurface(AbstractBRDF):
    """MaterialX 1.39's ``open_pbr_surface``, reflection (module docstring: formulas, sources).

    Every parameter is the node input of the same name; colours are RGB (a trailing axis of 3;
    a scalar is grey). The optional inputs default to None (the node's default,
    :data:`OPENPBR_DEFAULTS`, and their terms not traced)."""

    base_color: Channels = bounded(0.8, lo=0.0, hi=1.0, channels=True)
    base_metalness: Scalar = bounded(0.0, lo=0.0, hi=1.0)
    specular_roughness: Scalar = bounded(0.3, lo=0.0, hi=1.0)
    specular_ior: Scalar = bounded(1.5, lo=1.0, hi=IOR_MAX)
    specular_roughness_anisotropy: Scalar | None = bounded(None, lo=0.0, hi=1.0)
    base_weight: Scalar | None = bounded(None, lo=0.0, hi=1.0)
    base_diffuse_roughness: Scalar | None = bounded(None, lo=0.0, hi=1.0)
    specular_weight: Scalar | None = bounded(None, lo=0.0, hi=1.0)
    specular_color: Channels | None = bounded(None, lo=0.0, hi=1.0, channels=True)
    coat_weight: Scalar | None = bounded(None, lo=0.0, hi=1.0)
    coat_color: Channels | None = bounded(None, lo=0.0, hi=1.0, channels=True)
    coat_roughness: Scalar | None = bounded(None, lo=0.0, hi=1.0)
    coat_roughness_anisotropy: Scalar | None = bounded(None, lo=0.0, hi=1.0)
    coat_ior: Scalar | None = bounded(None, lo=1.0, hi=IOR_MAX)
    coat_darkening: Scalar | None = bounded(None, lo=0.0, hi=1.0)
    fuzz_weight: Scalar | None = bounded(None, lo=0.0, hi=1.0)
    fuzz_color: Channels | None = bounded(None, lo=0.0, hi=1.0, channels=True)
    fuzz_roughness: Scalar | None = bounded(None, lo=0.0, hi=1.0)

    def __check_init__(self):
        for name in OPENPBR_DEFAULTS:
            value = getattr(self, name)
            if value is None:
                continue
            if name in ("specular_ior", "coat_ior"):
                check_param(name, value, lo=1.0, hi=IOR_MAX, owner="OpenPBRSurface")
            else:
                check_param(name, value, lo=0.0, hi=1.0, owner="OpenPBRSurface")
            shape = jnp.shape(value)
            if name in _COLOURS and len(shape) > 0 and shape[-1] not in (1, 3):
                raise ValueError(f"{name} must be RGB (a trailing axis of 3) or grey, got "
                                 f"shape {shape}")

    def given(self) -> dict:
        """The inputs a MaterialX document would set: every one that is not None."""
        return {n: getattr(self, n) for n in OPENPBR_DEFAULTS if getattr(self, n) is not None}

    def _opt(self, name):
        value = getattr(self, name)
        return OPENPBR_DEFAULTS[name] if value is None else value

    # ------------------------------------------------------------------ the graph's scalars

    def main_widths(self):
        """``(alpha_x, alpha_y)`` of the specular and metal lobes before the shader's clamp:
        the coat-roughened specular roughness through ``open_pbr_anisotropy``."""
        r = self.specular_roughness
        if self.coat_weight is not None:
            rc = self._opt("coat_roughness")
            rough4 = jnp.minimum(1.0, 2.0 * rc ** 4 + r ** 4)
            r = _mix(r, safe_sqrt(safe_sqrt(rough4)), self.coat_weight)
        return roughness_widths(r, self._opt("specular_roughness_anisotropy"))

    def coat_widths(self):
        return roughness_widths(self._opt("coat_roughness"),
                                self._opt("coat_roughness_anisotropy"))

    def specular_eta(self):
        """The dielectric's IOR after the coat's ratio and ``specular_weight``'s modulation."""
        ior = self.specular_ior
        if self.coat_weight is not None:
            ci = self._opt("coat_ior")
            ratio = ior / ci
            ratio = jnp.where(ratio > 1.0, ratio, ci / ior)
            ior = _mix(ior, ratio, self.coat_weight)
        f0 = jnp.clip(self._opt("specular_weight") * ior_to_f0(ior), 0.0, 0.99999)
        e = jnp.sign(ior - 1.0) * safe_sqrt(f0)
        return (1.0 + e) / (1.0 - e)

    def _base_factor(self):
        """The colour multiplying the base (metal/dielectric mix): the coat's darkening and
        attenuation, each clamped to [0, 1] (``mx_multiply_bsdf_color3``); None: no coat."""
        if self.coat_weight is None:
            return None
        ci, cw = self._opt("coat_ior"), self.coat_weight
        k = 1.0 - (1.0 - ior_to_f0(ci)) / (ci * ci)
        # E_base reads the raw base_color, as the graph does (the diffuse clamps it at 0)
        e_metal = self.base_color * self._opt("specular_weight")
        e_base = _mix(self.base_color, e_metal, self.base_metalness)
        darkening = (1.0 - k) / (1.0 - e_base * k)
        dark = _mix(1.0, darkening, cw * self._opt("coat_darkening"))
        atten = _mix(1.0, self._opt("coat_color"), cw)
        return jnp.clip(dark, 0.0, 1.0) * jnp.clip(atten, 0.0, 1.0)

    # ------------------------------------------------------------------ the BRDF

    def _terms(self, wi, wo):
        """``(valid, f, parts)``: the BRDF and, for the sampler, the lobes' throughputs."""
        ix, iy, iz = split(wi)
        ox, oy, oz = split(wo)
        valid = (iz > 0) & (oz > 0)
        ix, iy, iz = sanitize(valid, ix, iy, iz)
        ox, oy, oz = sanitize(valid, ox, oy, oz)
        ch = self.channels()

        def ex(x):
            return expand_channels(x, ch)

        hx, hy, hz = ix + ox, iy + oy, iz + oz
        inv_len = 1.0 / jnp.sqrt(hx * hx + hy * hy + hz * hz)
        hx, hy, hz = hx * inv_len, hy * inv_len, hz * inv_len
        cv, cl = _clamp_eps(oz), _clamp_eps(iz)
        c = _clamp_eps(ox * hx + oy * hy + oz * hz)
        lv = _clamp_eps(ix * ox + iy * oy + iz * oz)

        # specular (dielectric_bsdf, weight 1, tint specular_color) and metal lobes share D, G2
        ax, ay = self.main_widths()
        lobe = _lobe(hx, hy, hz, cl, cv, ax, ay)
        a_fit, b_fit = ggx_albedo_ab(cv, jnp.sqrt(_clamp_width(ax) * _clamp_width(ay)))
        e_ss = a_fit + b_fit
        eta = self.specular_eta()
        f_d = fresnel_dielectric(c, eta)
        comp_d = 1.0 + f_d * (1.0 - e_ss) / e_ss
        tint = jnp.clip(self._opt("specular_color"), 0.0, None)
        spec = ex(lobe * f_d * comp_d) * tint
        spec_t = 1.0 - (ior_to_f0(eta) * a_fit + b_fit) * comp_d
        bw = self._opt("base_weight")
        colour = jnp.clip(self.base_color, 0.0, None)
        diffuse = oren_nayar_eon(ex(cv), ex(cl), ex(lv), self._opt("base_diffuse_roughness"),
                                 colour) * bw
        diffuse = jnp.where(bw < M_FLOAT_EPS, 0.0, diffuse)
        dielectric = spec + ex(spec_t) * diffuse
        # metal (generalized_schlick_bsdf, weight specular_weight)
        sw = self._opt("specular_weight")
        f0_m = jnp.clip(self.base_color * bw, 0.0, None)
        f82 = jnp.clip(self._opt("specular_color"), 0.0, None)
        f_m = fresnel_f82(ex(c), f0_m, f82)
        comp_m = 1.0 + f_m * ex((1.0 - e_ss) / e_ss)
        metal = jnp.where(sw < M_FLOAT_EPS, 0.0, ex(lobe) * f_m * comp_m * sw)
        m = self.base_metalness
        base = _mix(dielectric, metal, m)
        parts = {"spec_t": spec_t, "a": a_fit, "b": b_fit, "eta": eta, "f0_m": f0_m}
        factor = self._base_factor()
        if factor is not None:
            base = base * factor
            cw = self.coat_weight
            cax, cay = self.coat_widths()
            ci = self._opt("coat_ior")
            f_c = fresnel_dielectric(c, ci)
            ac, bc = ggx_albedo_ab(cv, jnp.sqrt(_clamp_width(cax) * _clamp_width(cay)))
            comp_c = 1.0 + f_c * (1.0 - (ac + bc)) / (ac + bc)
            coat = _lobe(hx, hy, hz, cl, cv, cax, cay) \
                * f_c * comp_c * cw
            coat_t = 1.0 - (ior_to_f0(ci) * ac + bc) * comp_c * cw
            off = cw < M_FLOAT_EPS
            coat, coat_t = jnp.where(off, 0.0, coat), jnp.where(off, 1.0, coat_t)
            base = ex(coat) + ex(coat_t) * base
            parts.update(coat_t=coat_t, coat_albedo=(ior_to_f0(ci) * ac + bc) * cw)
        if self.fuzz_weight is not None:
            fw = self.fuzz_weight
            albedo, a_inv, b_inv = zeltner_fits(cv, jnp.clip(self._opt("fuzz_roughness"),
                                                             FUZZ_ROUGHNESS_MIN, 1.0))
            # the LTC's frame: x along wo's tangent component (mx_orthonormal_basis_ltc)
            s2 = ox * ox + oy * oy
            flat = s2 > 0.0
            inv_s = jnp.where(flat, 1.0 / jnp.sqrt(jnp.where(flat, s2, 1.0)), 0.0)
            tx, ty = jnp.where(flat, ox * inv_s, 1.0), jnp.where(flat, oy * inv_s, 0.0)
            wx, wy = ix * tx + iy * ty, iy * tx - ix * ty
            lx, ly = a_inv * wx + b_inv * iz, a_inv * wy
            len2 = lx * lx + ly * ly + iz * iz
            # the shader's response albedo D(wi) has D = max(wi.z, 0)/pi (a_inv/len2)^2
            fuzz = albedo * fw * (a_inv / len2) ** 2 * INV_PI
            fuzz_t = 1.0 - albedo * fw
            off = fw < M_FLOAT_EPS
            fuzz, fuzz_t = jnp.where(off, 0.0, fuzz), jnp.where(off, 1.0, fuzz_t)
            base = ex(fuzz) * self._opt("fuzz_color") + ex(fuzz_t) * base
            parts.update(fuzz_t=fuzz_t, fuzz_albedo=albedo * fw)
        return valid, base, parts

    def eval(self, wi, wo):
        valid, f, _ = self._terms(wi, wo)
        return jnp.where(expand_channels(valid, self.channels()), f, 0.0)

    def lobe_probabilities(self, wo):
        """``(p_cosine, p_main, p_coat)`` of :meth:`sample` at ``wo``: the lobes' albedo
        estimates (MaterialX's fits at the mirror direction's Fresnel), normalised."""
        _, _, p = self._terms(jnp.stack([-wo[..., 0], -wo[..., 1], wo[..., 2]], -1), wo)
        mean = (lambda x: jnp.mean(x, axis=-1)) if self.channels() else (lambda x: x)
        above = jnp.ones_like(p["a"])
        pc = jnp.zeros_like(above)
        pf = jnp.zeros_like(above)
        if "fuzz_t" in p:
            pf = p["fuzz_albedo"]
            above = p["fuzz_t"]
        if "coat_t" in p:
            pc = above * p["coat_albedo"]
            above = above * p["coat_t"]
        m = self.base_metalness
        e_spec = ior_to_f0(p["eta"]) * p["a"] + p["b"]
        e_metal = mean(p["f0_m"]) * p["a"] + p["b"]
        pm = above * (m * e_metal + (1.0 - m) * e_spec)
        pd = pf + above * (1.0 - m) * p["spec_t"] * mean(jnp.clip(self.base_color, 0.0, 1.0))
        tot = pd + pm + pc
        ok = tot > 0
        inv = 1.0 / jnp.where(ok, tot, 1.0)
        return (jnp.where(ok, pd * inv, 0.0), jnp.where(ok, pm * inv, 1.0),
                jnp.where(ok, pc * inv, 0.0))

    def _dists(self):
        main = GGX(*(_clamp_width(a, ALPHA_MIN) for a in self.main_widths()))
        coat = None
        if self.coat_weight is not None:
            coat = GGX(*(_clamp_width(a, ALPHA_MIN) for a in self.coat_widths()))
        return main, coat

    def pdf(self, wi, wo):
        ix, iy, iz = split(wi)
        ox, oy, oz = split(wo)
        valid = (iz > 0) & (oz > 0)
        ix, iy, iz = sanitize(valid, ix, iy, iz)
        ox, oy, oz = sanitize(valid, ox, oy, oz)
        hx, hy, hz = ix + ox, iy + oy, iz + oz
        inv_len = 1.0 / jnp.sqrt(hx * hx + hy * hy + hz * hz)
        hx, hy, hz = hx * inv_len, hy * inv_len, hz * inv_len
        pd, pm, pc = self.lobe_probabilities(join(ox, oy, oz))
        main, coat = self._dists()
        # visible normals D G1(wo) (wo.h)/cos_o times dwh/dwi = 1/(4 wi.h)
        p = pd * iz * INV_PI + pm * main.D(hx, hy, hz) / (2.0 * (oz + main.P(ox, oy, oz)))
        if coat is not None:
            p = p + pc * coat.D(hx, hy, hz) / (2.0 * (oz + coat.P(ox, oy, oz)))
        return jnp.where(valid, p, 0.0)

    def sample(self, wo, uc, u):
        ox, oy, oz = split(wo)
        ok = oz > 0
        ox, oy, oz = sanitize(ok, ox, oy, oz)
        u1, u2 = u[..., 0], u[..., 1]
        pd, pm, _ = self.lobe_probabilities(join(ox, oy, oz))
        main, coat = self._dists()
        wi = join(*reflect_about(ox, oy, oz, *main.sample_visible(ox, oy, oz, u1, u2)))
        if coat is not None:
            w_c = join(*reflect_about(ox, oy, oz, *coat.sample_visible(ox, oy, oz, u1, u2)))
            wi = jnp.where((uc >= pd + pm)[..., None], w_c, wi)
        wi = jnp.where((uc < pd)[..., None], sample_cosine_hemisphere(u), wi)
        return finish_sample(self, wi, wo, ok & (wi[..., 2] > 0))

    def quadrature_lobe(self) -> QuadratureLobe:
        """The main GGX lobe's widths (a narrower coat is not followed)."""
        ax, ay = (jnp.maximum(a, ALPHA_MIN) for a in self.main_widths())
        if self.specular_roughness_anisotropy is None:
            return QuadratureLobe("half", ax)
        return QuadratureLobe("half", (ax, ay))

    def is_anisotropic(self) -> bool:
        return self.specular_roughness_anisotropy is not None


# ----------------------------------------------------------------------------- registry


_ENTRY_PARAMS = {
    "base_color": ("base_color: the diffuse albedo and the metal's F0 (linear RGB)", True, 0.0,
                   1.0),
    "base_metalness": ("base_metalness: mix from the dielectric (specular over diffuse) to the "
                       "F82-tinted metal", False, 0.0, 1.0),
    "specular_roughness": ("specular_roughness: GGX alpha = specular_roughness^2", False, 0.0,
                           1.0),
    "specular_ior": ("specular_ior: the dielectric's IOR", False, 1.0, IOR_MAX),
    "specular_roughness_anisotropy": (
        "specular_roughness_anisotropy a: alpha_x = r^2 sqrt(2/(1 + (1 - a)^2)), alpha_y = "
        "(1 - a) alpha_x; x is the tangent (the UV map's u)", False, 0.0, 1.0),
    "coat_weight": ("coat_weight: a dielectric GGX coat over the rest (darkening the base)",
                    False, 0.0, 1.0),
    "coat_roughness": ("coat_roughness: the coat's GGX alpha = coat_roughness^2", False, 0.0,
                       1.0),
    "coat_ior": ("coat_ior", False, 1.0, IOR_MAX),
    "fuzz_weight": ("fuzz_weight: Zeltner et al.'s LTC microfiber layer over the rest", False,
                    0.0, 1.0),
    "fuzz_roughness": ("fuzz_roughness", False, 0.0, 1.0),
}


def _param(name: str) -> Param:
    doc, channels, lo, hi = _ENTRY_PARAMS[name]
    default = OPENPBR_DEFAULTS[name]
    if channels:
        default = (default, default, default)
    return Param(name, default, lo=lo, hi=hi, channels=channels, doc=doc)


_BASIC = ("base_color", "base_metalness", "specular_roughness", "specular_ior")
_ANISO = _BASIC + ("specular_roughness_anisotropy",)
_COAT = _BASIC + ("coat_weight", "coat_roughness", "coat_ior")
_FUZZ = _BASIC + ("fuzz_weight", "fuzz_roughness")


def _builder(**params):
    return OpenPBRSurface(**params)


def to_openpbr_inputs(params: dict) -> dict:
    """The ``open_pbr_surface`` node's input values of an ``openpbr-surface*`` entry's
    parameters: ``{input name: value}`` (colours as 3 floats, scalars as a float), every given
    parameter. MaterialX then renders what :class:`OpenPBRSurface` with the same parameters
    evaluates."""
    out = {}
    for name, value in params.items():
        if name not in OPENPBR_DEFAULTS:
            raise ValueError(f"{name!r} is not an input of OpenPBR Surface here; valid: "
                             f"{', '.join(OPENPBR_DEFAULTS)}")
        v = [float(x) for x in np.ravel(np.asarray(value, np.float64))]
        if name in _COLOURS:
            if len(v) == 1:
                v = v * 3
            if len(v) != 3:
                raise ValueError(f"{name} must be RGB or grey, got {len(v)} values")
            out[name] = v
        else:
            if len(v) != 1:
                raise ValueError(f"{name} must be a scalar, got {len(v)} values")
            out[name] = v[0]
    return out


_NATIVE = {"target": "openpbr", "native_export": to_openpbr_inputs}
_NOT_RECIPROCAL = {"reciprocity": "MaterialX's energy compensation, layer throughputs and fuzz "
                                  "LTC depend on the view direction only"}


def registry_entries():
    """:class:`~brdf_fit.core.params.Entry` objects of OpenPBR Surface (not registered here):
    ``openpbr-surface`` (base_color, base_metalness, specular_roughness, specular_ior),
    ``openpbr-surface-aniso`` (+ specular_roughness_anisotropy), ``openpbr-surface-coat``
    (+ coat_weight, coat_roughness, coat_ior) and ``openpbr-surface-fuzz`` (+ fuzz_weight,
    fuzz_roughness); defaults are the node's."""
    common = {"reference": _REF_MX,
              "sampler": ("lobe by albedo estimate: cosine (diffuse, fuzz) / GGX visible normals "
                          "(specular and metal, coat); exact mixture pdf"),
              "year": 2024, "expected_failures": dict(_NOT_RECIPROCAL), **_NATIVE}
    return [
        Entry(name="openpbr-surface", builder=_builder,
              params=tuple(_param(n) for n in _BASIC),
              description=("OpenPBR Surface 1.1 as MaterialX 1.39 renders it: EON diffuse under "
                           "a compensated dielectric GGX layer, F82-tinted metal; the node's "
                           "inputs"),
              aliases=("open-pbr-surface", "openpbr"),
              tags=("native", "openpbr", "layered"), **common),
        Entry(name="openpbr-surface-aniso", builder=_builder,
              params=tuple(_param(n) for n in _ANISO),
              description="openpbr-surface with OpenPBR's anisotropic GGX widths",
              tags=("native", "openpbr", "anisotropic", "layered"), **common),
        Entry(name="openpbr-surface-coat", builder=_builder,
              params=tuple(_param(n) for n in _COAT),
              description="openpbr-surface under OpenPBR's dielectric GGX coat",
              tags=("native", "openpbr", "layered"), **common),
        Entry(name="openpbr-surface-fuzz", builder=_builder,
              params=tuple(_param(n) for n in _FUZZ),
              description=("openpbr-surface under OpenPBR's fuzz (Zeltner et al. 2022's LTC "
                           "microfiber, white)"),
              tags=("native", "openpbr", "layered"), **common),
    ]
