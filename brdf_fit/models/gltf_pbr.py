"""The glTF 2.0 metallic-roughness BRDF with its material extensions: a renderer-native model.

:class:`GltfPBR` evaluates the BRDF of the glTF 2.0 specification, Appendix B ("BRDF
Implementation", KhronosGroup/glTF ``specification/2.0/Specification.adoc``), with the
extensions ``KHR_materials_ior``, ``KHR_materials_specular``, ``KHR_materials_anisotropy``,
``KHR_materials_sheen`` and ``KHR_materials_clearcoat`` (KhronosGroup/glTF
``extensions/2.0/Khronos/<name>/README.md``), parametrised as a glTF material's factors, so that
a model fitted here is written as a glTF material with no loss
(:func:`brdf_fit.models.gltf_material.to_gltf_material`; ``from_gltf_material`` reads one
back). Textures, normal maps and the clearcoat normal are not modelled (the factors are the
whole material).

Notation: ``L = wi`` (toward the light), ``V = wo`` (toward the viewer), ``N = (0, 0, 1)``,
``H = normalize(L + V)``, ``mu_i = N.L``, ``mu_o = N.V``, ``d = V.H = L.H``,
``w = (1 - |V.H|)^5`` (Appendix B.3.4, ``fresnel_w``), ``max3(c)`` the largest channel, and every
formula below written with dot products (DESIGN.md section 2)::

    alpha     = max(roughness^2, ALPHA_MIN)                              (B.3.2; see epsilons)
    D(H)      = alpha^2 / (pi ((N.H)^2 (alpha^2 - 1) + 1)^2)              (B.3.2, GGX)
              = 1 / (pi a_t a_b ((H.t/a_t)^2 + (H.b/a_b)^2 + (N.H)^2)^2)  (KHR_materials_anisotropy)
    Vis       = 1 / (2 (mu_o P(L) + mu_i P(V))),                          (B.3.2, height-
                P(W) = sqrt(a_t^2 (W.t)^2 + a_b^2 (W.b)^2 + (N.W)^2)        correlated Smith)
    specular_brdf = Vis D                                                 (B.3.2)
    diffuse_brdf  = baseColor / pi                                        (B.3.3)
    metal_brdf    = specular_brdf (baseColor + (1 - baseColor) w)         (B.3.4, B.3.5)
    f0_ior        = ((ior - 1)/(ior + 1))^2                               (KHR_materials_ior)
    f0            = min(f0_ior specularColor, 1) specular                 (KHR_materials_specular,
    F             = f0 + (specular - f0) w                                 "Implementation")
    dielectric_brdf = F specular_brdf + (1 - max3(F)) diffuse_brdf        (KHR_materials_specular)
    material  = (1 - metallic) dielectric_brdf + metallic metal_brdf       (B.3.5, mix)

``P(W) = sqrt(alpha^2 + (1 - alpha^2)(N.W)^2)`` for a unit ``W`` when isotropic, Appendix B's
form. Without the extensions (``ior = 1.5``, ``specular = 1``, ``specularColor = 1``) ``F`` is
grey, ``0.04 + 0.96 w``, and ``dielectric_brdf`` is B.3.5's ``mix(diffuse_brdf, specular_brdf,
0.04 + 0.96 w)``. ``ior = 0`` (KHR_materials_ior's specular-glossiness compatibility mode, "the
Fresnel term MUST evaluate to 1") gives ``f0_ior = 1`` from the same formula.

**Anisotropy** (KHR_materials_anisotropy, "Anisotropy"): the direction of increased roughness
is ``t = cos(rotation) x + sin(rotation) y`` (radians, counter-clockwise from the tangent ``x``),
``b = N x t``; ``a_t = mix(alpha, 1, strength^2) = alpha + (1 - alpha) strength^2``,
``a_b = alpha``. ``D`` is the extension's anisotropic GGX and ``Vis`` the height-correlated Smith
term of that distribution (the extension's "Implementation" section, ``V_GGX_anisotropic``, which
is the Appendix B term with ``P`` above). Both directions are rotated into ``(t, b, N)`` once.

**Sheen** (KHR_materials_sheen, "Implementation Notes"; A. Conty Estevez, C. Kulla, "Production
Friendly Microfacet Sheen BRDF", SIGGRAPH 2017, the "Charlie" sheen)::

    r         = max(sheenRoughness^2, ALPHA_MIN)           (the extension's alphaG = roughness^2)
    D_s(H)    = (2 + 1/r) (sin^2 theta_H)^(1/(2 r)) / (2 pi),   sin^2 theta_H = (H.x)^2 + (H.y)^2
                                                                   (Estevez & Kulla, eq. 2)
    Lambda(mu) = exp(l(mu))                  mu < 0.5            (Estevez & Kulla's fitted
               = exp(2 l(0.5) - l(1 - mu))   mu >= 0.5            Lambda, as the extension's
    l(x)      = a/(1 + b x^c) + d x + e,  (a..e) = p_1 + (p_0 - p_1)(1 - r)^2   "Sheen visibility")
    f_sheen   = sheenColor D_s / ((1 + Lambda(mu_o) + Lambda(mu_i)) 4 mu_o mu_i)
    f         = f_sheen + material s,
    s         = max(0, min(1 - max3(sheenColor) E(mu_o), 1 - max3(sheenColor) E(mu_i)))
              = max(0, 1 - max3(sheenColor) max(E(mu_o), E(mu_i)))
                                                       (the extension's "Albedo-scaling technique")

with ``p_0``, ``p_1`` the fitted parameters at ``r = 0`` and ``r = 1`` (:data:`CHARLIE_L_R0`,
:data:`CHARLIE_L_R1`; the paper's table, as the extension's ``l(x, alphaG)`` writes them), no
sheen Fresnel (the extension: ``F = 1``), no terminator softening (the paper's optional change
of ``Lambda`` near the horizon: the extension does not use it), and no clamp of the visibility at
1 (some viewers clamp it in their shaders; the extension's formula has none). ``E(mu, r)`` is the
directional albedo of the sheen lobe with ``sheenColor = 1`` (the extension's ``E(x)`` for the
"Charlie" visibility), looked up in the packaged table :data:`SHEEN_TABLE_FILE` written by
``python -m brdf_fit.tables.sheen`` (:func:`sheen_albedo`: cubic in ``log10(sheenRoughness)`` and
``log10(mu)``, accuracy in the table's metadata and :data:`SHEEN_TABLE_ERROR`: 2.5e-5 absolute,
largest next to ``mu = 0.5``, where ``Lambda``'s two branches join with a continuous first
derivative only, and on the steep fall of ``E`` at small sheen roughness). The extension's
formula lets ``s`` go negative where ``max3(sheenColor) E > 1``: the fitted ``Lambda`` is finite
at ``mu = 0`` (``exp(a + e)``), so ``E`` exceeds 1 at grazing views for small sheen roughness
(measured: ``E = 1.15`` at ``mu = 0.01`` for ``sheenRoughness = 0.2``, 5.0 for 0.01, and
``E ~ 1/(mu Lambda(0))`` diverges as ``mu -> 0``); ``s`` is clamped at 0 there so that ``f`` stays
non-negative (the only departure from the extension's formula; the sheen layer alone then
reflects more than it receives, which is the Charlie model's, not ours).

**Energy.** The model is the specification's sample implementation (Appendix B.3, informative),
so it inherits what B.3.6 ("Coupling Diffuse and Specular Reflection") says of ``fresnel_mix``:
it is not energy conserving. Measured
(:func:`brdf_fit.verify.albedo.directional_albedo`): a white dielectric (``baseColor = 1``,
``metallic = 0``) reflects up to 1.38 at ``mu_o = 0.001`` for ``roughness = 0.3`` and 1.018 for
``roughness = 1``; the sheen lobe alone up to 2.1 at ``sheenRoughness = 0.1`` (the Charlie
``Lambda``, above). The registry defaults (``baseColor = (0.8, 0.6, 0.4)``) stay below 1.

**Clearcoat** (KHR_materials_clearcoat, "Clearcoat" and "Implementation", ``fresnel_coat`` with
``ior = 1.5``, the clearcoat normal = ``N``)::

    alpha_c   = max(clearcoatRoughness^2, ALPHA_MIN)
    F_c       = 0.04 + 0.96 (1 - |N.V|)^5
    coated    = (1 - clearcoat F_c) f + clearcoat F_c Vis_c D_c     (mix(f, clearcoat_brdf, ...))

``Vis_c D_c`` is B.3.2's ``specular_brdf(alpha_c)``. The clearcoat sits on top of the sheen
(KHR_materials_sheen: "If clearcoat is active at the same time, clearcoat is layered on top of
sheen"; KHR_materials_clearcoat: on top of "the glTF 2.0 Metallic-Roughness material, including
... all extensions"). ``F_c`` depends on ``V`` only, so the coated model is **not reciprocal**
(the extension's choice, "Discussion"); everything else is symmetric in ``(L, V)``.

Epsilons (each named, each with its reason):

``ALPHA_MIN`` (1e-4, :mod:`brdf_fit.core.numerics`)
    Appendix B.2.3 ("Microfacet Surfaces") makes ``alpha = 0`` a perfectly specular surface,
    where B.3.2's ``D`` is ``0/0`` at ``N.H = 1`` (a delta), and the sheen's ``1/r`` is infinite.
    Every GGX width and the sheen ``r`` are clamped below at ALPHA_MIN, as the package's
    microfacet models and :func:`brdf_fit.convert.gltf.appendix_b_eval` do (a roughness below
    0.01 evaluates as 0.01; the gradient in it is 0 there). The specification's own defaults
    ``roughness = 0`` of the clearcoat and the sheen are therefore evaluated at 0.01.
:data:`SHEEN_TABLE_MU_MIN` (1e-6)
    The sheen albedo table starts at ``mu = 1e-6``; below, ``E(1e-6)`` is used (``E`` diverges
    as ``mu -> 0``, see above; directions within 1e-6 of the horizon carry a negligible part of
    any integral).
:data:`P_DEFENSIVE` (0.05)
    The cosine lobe's floor probability in the sampler: every lobe of ``f`` is positive on the
    whole open hemisphere, but the lobe probabilities are computed from ``wo`` alone and one may
    vanish while its lobe does not (a black metal viewed along ``N``: Schlick's ``w(mu_o) = 0``);
    the floor keeps ``pdf > 0`` wherever ``f > 0``.
Horizon and half vector
    As every model here (:func:`brdf_fit.models._lobes.half_geometry`): 0 at or below the horizon,
    lanes sanitised to the normal before any formula sees them (double where). ``x^c`` of the
    sheen ``l(x)`` at ``x = 0`` (``mu = 1``) and ``(sin^2)^(1/(2 r))`` at ``sin = 0`` use
    :func:`~brdf_fit.core.numerics.safe_pow` (value 0, gradient finite).

Sampling: a one-sample mixture with the exact mixture pdf (Veach & Guibas 1995, balance
heuristic) of four lobes, each a warp with a closed-form density:

    pdf = p_d mu_i/pi + p_u/(2 pi) + p_s D(H)/(2 (mu_o + P(V))) + p_c D_c(H)/(2 (mu_o + P_c(V)))

the cosine hemisphere (diffuse), the uniform hemisphere (sheen: a lobe at grazing angles), GGX
visible normals of ``(a_t, a_b)`` in the rotated frame (Dupuy & Benyoub 2023, spherical caps;
:meth:`~brdf_fit.core.microfacet.GGX.sample_visible`) and those of ``alpha_c``, reflected
(``D G1(V) (V.H)/mu_o`` times ``1/(4 V.H)``, Walter et al. 2007, eq. 14). The probabilities follow
each lobe's Schlick estimate at ``mu_o`` and a fixed guess of the sheen albedo
(:meth:`GltfPBR.lobe_probabilities`). A reflection below
the horizon is a failed sample (pdf 0, weight 0).
"""

from __future__ import annotations

import functools

import jax.numpy as jnp
import numpy as np

from brdf_fit.core.frame import join, split
from brdf_fit.core.microfacet import GGX, SmithHeightCorrelated, reflect_about
from brdf_fit.core.numerics import (
    ALPHA_MIN,
    INV_PI,
    INV_TWO_PI,
    TWO_PI,
    pow5,
    safe_norm3,
)
from brdf_fit.core.params import Channels, Entry, Param, Scalar, bounded
from brdf_fit.core.validate import ParameterError, check_param, concrete
from brdf_fit.core.warp import sample_cosine_hemisphere
from brdf_fit.models._base import AbstractBRDF, QuadratureLobe, expand_channels
from brdf_fit.models._lobes import finish_sample, half_geometry, sanitize
from brdf_fit.models.charlie_sheen import (
    CHARLIE_L_R0,
    CHARLIE_L_R1,
    SHEEN_ROUGHNESS_MIN,
    SHEEN_TABLE_ERROR,
    SHEEN_TABLE_FILE,
    SHEEN_TABLE_MU_MIN,
    SHEEN_TABLE_N_MU,
    SHEEN_TABLE_N_ROUGHNESS,
    charlie_lambda,
    charlie_lobe,
    charlie_sheen,
    sheen_albedo,
)
from brdf_fit.models.gltf_material import (
    GLTF_COLOURS,
    GLTF_DEFAULTS,
    gltf_material_params,
    to_gltf_material,
)

__all__ = [
    "CHARLIE_L_R0",
    "CHARLIE_L_R1",
    "CLEARCOAT_F0",
    "GLTF_COLOURS",
    "GLTF_DEFAULTS",
    "GltfPBR",
    "P_DEFENSIVE",
    "SHEEN_ALBEDO_GUESS",
    "SHEEN_ROUGHNESS_MIN",
    "SHEEN_TABLE_ERROR",
    "SHEEN_TABLE_FILE",
    "SHEEN_TABLE_MU_MIN",
    "SHEEN_TABLE_N_MU",
    "SHEEN_TABLE_N_ROUGHNESS",
    "charlie_lambda",
    "charlie_sheen",
    "from_gltf_material",
    "registry_entries",
    "sheen_albedo",
    "to_gltf_material",
]

#: ``fresnel_coat``'s ``f0 = ((1 - ior)/(1 + ior))^2`` at the clearcoat's fixed ``ior = 1.5``;
#: the extension writes 0.04.
CLEARCOAT_F0 = 0.04
#: The cosine lobe's floor probability in :meth:`GltfPBR.sample` (module docstring).
P_DEFENSIVE = 0.05
#: The sheen albedo the lobe probabilities assume (:meth:`GltfPBR.lobe_probabilities`): ``E`` of
#: the table is 0.2-0.9 over most views and roughnesses; only the sampling efficiency depends on
#: it, never the pdf's exactness.
SHEEN_ALBEDO_GUESS = 0.5


_SPEC = "KhronosGroup/glTF specification/2.0/Specification.adoc, Appendix B"
_EXT = "KhronosGroup/glTF extensions/2.0/Khronos/{}/README.md"
_CHARLIE = ("A. Conty Estevez, C. Kulla, Production Friendly Microfacet Sheen BRDF, SIGGRAPH "
            "2017")


# ----------------------------------------------------------------------------- the model


def _rotate(w, c, s):
    """Components of ``w`` (..., 3) in the frame ``t = (c, s, 0)``, ``b = (-s, c, 0)``."""
    x, y, z = split(w)
    return join(c * x + s * y, c * y - s * x, z)


def _channel_max(x):
    """The largest entry along the last (channel) axis, as pairwise ``jnp.maximum``. The
    derivative of ``jnp.max`` divides by the count of entries that compare equal to the maximum;
    compiled at LLVM optimisation level 0 it gave NaN gradients of the pdf in ``base_color``,
    ``ior`` and the specular parameters at ordinary directions (measured; eager and the default
    optimisation level were finite), consistent with the entries and the maximum being rounded
    differently in two fusions. ``maximum``'s derivative is a select: nothing to divide."""
    return functools.reduce(jnp.maximum, [x[..., k] for k in range(x.shape[-1])])


def _cmax(x, ch):
    """The largest channel of a per-direction quantity (itself without a channel axis)."""
    return x if ch is None else _channel_max(x)


def _max3(colour):
    """``max3`` of a colour parameter (a scalar as it is: ``jnp.max`` would make a weakly typed
    Python float a float64 array, which strict promotion refuses next to float32 values)."""
    return colour if jnp.ndim(colour) == 0 else _channel_max(colour)


class GltfPBR(AbstractBRDF):
    """The glTF 2.0 metallic-roughness BRDF with KHR_materials_ior, _specular, _anisotropy,
    _sheen and _clearcoat (module docstring: formulas with their sections, epsilons, sampling).

    Every parameter is the glTF factor of the same meaning with the specification's default
    (each extension off): ``base_color`` (``baseColorFactor`` RGB), ``metallic``, ``roughness``
    (perceptual: ``alpha = roughness^2``, part of the model), ``ior``, ``specular_factor``,
    ``specular_color``, ``anisotropy_strength``, ``anisotropy_rotation`` (radians,
    counter-clockwise from the tangent ``x``), ``sheen_color``, ``sheen_roughness``,
    ``clearcoat``, ``clearcoat_roughness``. Colours are RGB (a trailing axis of 3) or a grey
    scalar."""

    base_color: Channels = bounded(1.0, lo=0.0, hi=1.0, channels=True)
    metallic: Scalar = bounded(1.0, lo=0.0, hi=1.0)
    roughness: Scalar = bounded(1.0, lo=0.0, hi=1.0)
    ior: Scalar = bounded(1.5, lo=0.0)
    specular_factor: Scalar = bounded(1.0, lo=0.0, hi=1.0)
    specular_color: Channels = bounded(1.0, lo=0.0, channels=True)
    anisotropy_strength: Scalar = bounded(0.0, lo=0.0, hi=1.0)
    anisotropy_rotation: Scalar = bounded(0.0)
    sheen_color: Channels = bounded(0.0, lo=0.0, hi=1.0, channels=True)
    sheen_roughness: Scalar = bounded(0.0, lo=0.0, hi=1.0)
    clearcoat: Scalar = bounded(0.0, lo=0.0, hi=1.0)
    clearcoat_roughness: Scalar = bounded(0.0, lo=0.0, hi=1.0)

    def __check_init__(self):
        unit = ("base_color", "metallic", "roughness", "specular_factor", "anisotropy_strength",
                "sheen_color", "sheen_roughness", "clearcoat", "clearcoat_roughness")
        for name in unit:
            check_param(name, getattr(self, name), lo=0.0, hi=1.0, owner="GltfPBR")
        check_param("specular_color", self.specular_color, lo=0.0, owner="GltfPBR")
        check_param("anisotropy_rotation", self.anisotropy_rotation, owner="GltfPBR")
        check_param("ior", self.ior, lo=0.0, owner="GltfPBR")
        v = concrete(self.ior)
        if v is not None and v.dtype != object and np.any((v > 0.0) & (v < 1.0)):
            raise ParameterError(f"GltfPBR: parameter 'ior' must be 0 or >= 1 "
                                 f"(KHR_materials_ior), got {v.tolist()}")
        for name in GLTF_COLOURS:
            shape = jnp.shape(getattr(self, name))
            if len(shape) > 1:
                raise ParameterError(f"GltfPBR: parameter {name!r} must be a scalar or a 1-D "
                                     f"channel vector, got shape {shape}")

    # ------------------------------------------------------------------ parameters

    def alpha(self):
        """``max(roughness^2, ALPHA_MIN)`` (Appendix B.3.2 ``alpha = roughness^2``, clamped)."""
        return jnp.maximum(self.roughness * self.roughness, ALPHA_MIN)

    def widths(self):
        """``(a_t, a_b)``: ``mix(alpha, 1, strength^2)`` along the anisotropy direction and
        ``alpha`` across it (KHR_materials_anisotropy)."""
        a = self.alpha()
        s2 = self.anisotropy_strength * self.anisotropy_strength
        return a + (1.0 - a) * s2, a

    def clearcoat_alpha(self):
        """``max(clearcoatRoughness^2, ALPHA_MIN)``."""
        return jnp.maximum(self.clearcoat_roughness * self.clearcoat_roughness, ALPHA_MIN)

    def _base_distribution(self) -> GGX:
        at, ab = self.widths()
        return GGX(at, ab)

    def _coat_distribution(self) -> GGX:
        return GGX(self.clearcoat_alpha())

    def _frame(self):
        """``(cos, sin)`` of the anisotropy rotation; the identity where the strength is 0 (the
        BRDF is isotropic then, and a rotation would only add rounding: the export, which
        omits an inactive extension, stays exact to the bit)."""
        on = self.anisotropy_strength > 0
        return (jnp.where(on, jnp.cos(self.anisotropy_rotation), 1.0),
                jnp.where(on, jnp.sin(self.anisotropy_rotation), 0.0))

    def dielectric_f0(self):
        """``min(((ior - 1)/(ior + 1))^2 specularColor, 1) specular`` (KHR_materials_specular
        with KHR_materials_ior); ``dielectric_f90 = specular``."""
        g = (self.ior - 1.0) / (self.ior + 1.0)
        return jnp.minimum(g * g * self.specular_color, 1.0) * self.specular_factor

    def _sheen_max(self):
        return _max3(self.sheen_color)

    # ------------------------------------------------------------------ the BRDF

    def eval(self, wi, wo):
        c, s = self._frame()
        valid, (ix, iy, iz), (ox, oy, oz), (hx, hy, hz), _ = half_geometry(
            _rotate(wi, c, s), _rotate(wo, c, s))
        # |V.H| = |L + V|/2 for unit directions: o.h takes the rounding of h's components,
        # ~1e-16/|L + V| each, which at a grazing pair of opposite azimuths (|L + V| = 2e-7)
        # is 5e-10 absolute in V.H; clamped to 1 (rounding above it made (1 - d)^5 < 0)
        d = jnp.minimum(0.5 * safe_norm3(ix + ox, iy + oy, iz + oz), 1.0)
        ch = self.channels()

        def ex(x):
            return expand_channels(x, ch)

        hc = SmithHeightCorrelated()
        # base specular_brdf = Vis D (Appendix B.3.2; anisotropic: KHR_materials_anisotropy)
        dist = self._base_distribution()
        spec = ex(dist.D(hx, hy, hz) * hc.V(dist, ix, iy, iz, ox, oy, oz, hz, d))
        w = ex(pow5(1.0 - d))  # fresnel_w, B.3.4 (d = |V.H| >= 0)
        bc = self.base_color
        # dielectric_brdf (KHR_materials_specular, with KHR_materials_ior's f0)
        f0 = self.dielectric_f0()
        F = f0 + (self.specular_factor - f0) * w
        dielectric = F * spec + ex(1.0 - _cmax(F, ch)) * (INV_PI * bc)
        metal = spec * (bc + (1.0 - bc) * w)  # B.3.4 conductor_fresnel, B.3.5
        material = (1.0 - self.metallic) * dielectric + self.metallic * metal
        # sheen on top, with albedo scaling (KHR_materials_sheen)
        sr = self.sheen_roughness
        sheen = self.sheen_color * ex(charlie_lobe(hx, hy, iz, oz, sr))
        m_sheen = self._sheen_max()
        e = sheen_albedo(jnp.stack(jnp.broadcast_arrays(oz, iz)), sr)  # one lookup for both
        scaling = 1.0 - m_sheen * jnp.maximum(e[0], e[1])
        f = sheen + material * ex(jnp.maximum(scaling, 0.0))
        # clearcoat on top of everything (KHR_materials_clearcoat, fresnel_coat with N.V)
        coat = self._coat_distribution()
        f_coat = coat.D(hx, hy, hz) * hc.V(coat, ix, iy, iz, ox, oy, oz, hz, d)
        k = self.clearcoat * (CLEARCOAT_F0 + (1.0 - CLEARCOAT_F0) * pow5(1.0 - oz))
        out = ex(1.0 - k) * f + ex(k * f_coat)
        return jnp.where(ex(valid), out, 0.0)

    # ------------------------------------------------------------------ sampling

    def lobe_probabilities(self, oz):
        """``(p_d, p_u, p_s, p_c)`` of the cosine, uniform, base-GGX and clearcoat-GGX lobes at
        ``mu_o = oz`` (shape of ``oz``): proportional to each layer's Schlick estimate of its
        albedo with ``w(mu_o)`` in place of ``w(V.H)`` (the diffuse ``(1 - metallic)(1 -
        max3 F) max3(baseColor)``, the specular ``(1 - metallic) max3 F + metallic
        max3(baseColor + (1 - baseColor) w)``, both times the sheen scaling with
        :data:`SHEEN_ALBEDO_GUESS` for ``E``, the sheen ``max3(sheenColor)
        SHEEN_ALBEDO_GUESS``, all three times ``1 - clearcoat F_c``, the clearcoat
        ``clearcoat F_c``), with :data:`P_DEFENSIVE` added to the cosine lobe; all to the cosine
        lobe where every estimate is 0. (A guess, not the table, for the sheen: any positive
        weights give an exact pdf, and the table lookup would double the pdf's program.)"""
        ch = self.channels()
        w = pow5(1.0 - oz)
        wx = expand_channels(w, ch)
        f0 = self.dielectric_f0()
        Fd = _cmax(f0 + (self.specular_factor - f0) * wx, ch)
        bc = self.base_color
        Fm = _cmax(bc + (1.0 - bc) * wx, ch)
        m = self.metallic
        e_sheen = SHEEN_ALBEDO_GUESS * self._sheen_max()
        k = self.clearcoat * (CLEARCOAT_F0 + (1.0 - CLEARCOAT_F0) * w)
        below = (1.0 - k) * (1.0 - e_sheen)
        w_d = below * (1.0 - m) * (1.0 - Fd) * _max3(bc)
        w_s = below * ((1.0 - m) * Fd + m * Fm)
        w_u = (1.0 - k) * e_sheen
        w_c = k
        tot = w_d + w_u + w_s + w_c
        ok = tot > 0
        scale = jnp.where(ok, (1.0 - P_DEFENSIVE) / jnp.where(ok, tot, 1.0), 0.0)
        p_d = jnp.where(ok, P_DEFENSIVE + scale * w_d, 1.0)
        return p_d, scale * w_u, scale * w_s, scale * w_c

    def pdf(self, wi, wo):
        c, s = self._frame()
        valid, (_, _, iz), (ox, oy, oz), (hx, hy, hz), _ = half_geometry(
            _rotate(wi, c, s), _rotate(wo, c, s))
        p_d, p_u, p_s, p_c = self.lobe_probabilities(oz)
        dist = self._base_distribution()
        coat = self._coat_distribution()
        # visible normals, reflected: D G1(V) (V.H)/mu_o times 1/(4 V.H) (Walter 2007, eq. 14)
        pdf_s = dist.D(hx, hy, hz) / (2.0 * (oz + dist.P(ox, oy, oz)))
        pdf_c = coat.D(hx, hy, hz) / (2.0 * (oz + coat.P(ox, oy, oz)))
        p = p_d * iz * INV_PI + p_u * INV_TWO_PI + p_s * pdf_s + p_c * pdf_c
        return jnp.where(valid, p, 0.0)

    def sample(self, wo, uc, u):
        c, s = self._frame()
        ox, oy, oz = split(_rotate(wo, c, s))
        ok = oz > 0
        ox, oy, oz = sanitize(ok, ox, oy, oz)
        u1, u2 = u[..., 0], u[..., 1]
        p_d, p_u, p_s, _ = self.lobe_probabilities(oz)
        w_d = sample_cosine_hemisphere(u)
        # uniform hemisphere: z = 1 - u1 in (0, 1], sin = sqrt(u1 (2 - u1))
        r_u = jnp.sqrt(u1 * (2.0 - u1))
        w_u = join(r_u * jnp.cos(TWO_PI * u2), r_u * jnp.sin(TWO_PI * u2), 1.0 - u1)
        m_s = self._base_distribution().sample_visible(ox, oy, oz, u1, u2)
        w_s = join(*reflect_about(ox, oy, oz, *m_s))
        m_c = self._coat_distribution().sample_visible(ox, oy, oz, u1, u2)
        w_c = join(*reflect_about(ox, oy, oz, *m_c))
        wl = jnp.where((uc < p_d + p_u + p_s)[..., None], w_s, w_c)
        wl = jnp.where((uc < p_d + p_u)[..., None], w_u, wl)
        wl = jnp.where((uc < p_d)[..., None], w_d, wl)
        x, y, z = split(wl)
        wi = join(c * x - s * y, s * x + c * y, z)  # back from the anisotropy frame
        return finish_sample(self, wi, wo, ok)

    # ------------------------------------------------------------------ declared hooks

    def quadrature_lobe(self) -> QuadratureLobe:
        """A half-vector lobe of the narrowest GGX width in use (``alpha``, or the clearcoat's
        when a clearcoat is on): the half-vector rule follows the sharpest lobe and integrates the
        wider ones and the smooth diffuse and sheen terms with it. Isotropic: the anisotropy
        direction is rotated, and ``a_b = alpha <= a_t``."""
        a = self.alpha()
        return QuadratureLobe("half", jnp.where(self.clearcoat > 0,
                                                jnp.minimum(a, self.clearcoat_alpha()), a))

    def is_anisotropic(self) -> bool:
        v = concrete(self.anisotropy_strength)
        return v is None or v.dtype == object or bool(np.any(v != 0))

    def selection_hint(self):
        return jnp.maximum(_max3(self.base_color), 0.04) + self._sheen_max() \
            + self.clearcoat


def from_gltf_material(material: dict) -> GltfPBR:
    """The :class:`GltfPBR` of a glTF 2.0 ``materials[]`` object
    (:func:`~brdf_fit.models.gltf_material.gltf_material_params`: its factors with the
    specification's defaults and the five extensions of this module)."""
    return GltfPBR(**gltf_material_params(material))


# ----------------------------------------------------------------------------- registry

#: Registry defaults: a representative dielectric with each entry's extension switched on (the
#: class's defaults are the specification's, :data:`GLTF_DEFAULTS`, where every extension is
#: off and its parameters have no effect or a zero gradient).
_ENTRY_PARAMS = {
    "base_color": Param("base_color", (0.8, 0.6, 0.4), lo=0.0, hi=1.0, channels=True,
                        doc="baseColorFactor (linear RGB): the dielectric's diffuse albedo, the "
                            "metal's F0"),
    "metallic": Param("metallic", 0.0, lo=0.0, hi=1.0, doc="metallicFactor"),
    "roughness": Param("roughness", 0.5, lo=0.0, hi=1.0,
                       doc="roughnessFactor (perceptual): GGX alpha = max(roughness^2, 1e-4)"),
    "specular_factor": Param("specular_factor", 1.0, lo=0.0, hi=1.0,
                             doc="KHR_materials_specular specularFactor"),
    # entry defaults with unequal channels: glTF's max over the colour channels has a kink
    # where two channels tie, and a default there makes derivatives one-sided
    "specular_color": Param("specular_color", (1.0, 0.9, 0.8), lo=0.0, channels=True,
                            doc="KHR_materials_specular specularColorFactor (F0 = min(0.04 c, "
                                "1) specular; > 1 allowed)"),
    "anisotropy_strength": Param("anisotropy_strength", 0.5, lo=0.0, hi=1.0,
                                 doc="KHR_materials_anisotropy anisotropyStrength: "
                                     "a_t = mix(alpha, 1, strength^2)"),
    "anisotropy_rotation": Param("anisotropy_rotation", 0.3,
                                 doc="KHR_materials_anisotropy anisotropyRotation (radians, "
                                     "counter-clockwise from the tangent)"),
    "sheen_color": Param("sheen_color", (0.5, 0.4, 0.3), lo=0.0, hi=1.0, channels=True,
                         doc="KHR_materials_sheen sheenColorFactor (linear RGB)"),
    "sheen_roughness": Param("sheen_roughness", 0.5, lo=0.0, hi=1.0,
                             doc="KHR_materials_sheen sheenRoughnessFactor: Charlie "
                                 "r = max(roughness^2, 1e-4)"),
    "clearcoat": Param("clearcoat", 1.0, lo=0.0, hi=1.0,
                       doc="KHR_materials_clearcoat clearcoatFactor"),
    "clearcoat_roughness": Param("clearcoat_roughness", 0.2, lo=0.0, hi=1.0,
                                 doc="KHR_materials_clearcoat clearcoatRoughnessFactor: "
                                     "alpha_c = max(roughness^2, 1e-4)"),
}

_CORE = ("base_color", "metallic", "roughness")


def _builder(**params):
    """``GltfPBR`` with the parameters not given at the specification's defaults as arrays (RGB
    colours) of the given ones' dtype: every entry builds models of one pytree structure, so the
    compiled programs of one entry serve the others."""
    dt = jnp.result_type(*params.values()) if params else jnp.result_type(float)
    return GltfPBR(**{k: jnp.asarray(params[k]) if k in params else jnp.asarray(v, dt)
                      for k, v in GLTF_DEFAULTS.items()})


def registry_entries():
    """:class:`~brdf_fit.core.params.Entry` objects (not registered here): ``gltf-pbr`` (Appendix
    B: base_color, metallic, roughness), ``gltf-pbr-specular`` (+ KHR_materials_specular;
    ``ior`` stays 1.5: for reflection it enters only through ``f0_ior specularColor``, so it is
    exactly degenerate with ``specular_color``), ``gltf-pbr-anisotropy``, ``gltf-pbr-sheen``,
    ``gltf-pbr-clearcoat``; each exports to a glTF material with
    :func:`~brdf_fit.models.gltf_material.to_gltf_material`."""
    sampler = ("cosine / uniform (sheen) / GGX visible normals (base, anisotropic, and "
               "clearcoat) by Schlick estimates at mu_o, exact mixture pdf")
    entries = [
        ("gltf-pbr", (), (), "glTF 2.0 metallic-roughness BRDF (Appendix B: GGX, "
         "height-correlated Smith, Schlick; fresnel_mix and conductor_fresnel)", {}),
        ("gltf-pbr-specular", ("specular_factor", "specular_color"), ("KHR_materials_specular",),
         "gltf-pbr + KHR_materials_specular (dielectric F0 colour and strength; ior 1.5)", {}),
        ("gltf-pbr-anisotropy", ("anisotropy_strength", "anisotropy_rotation"),
         ("KHR_materials_anisotropy",),
         "gltf-pbr + KHR_materials_anisotropy (a_t = mix(alpha, 1, strength^2), rotated)", {}),
        ("gltf-pbr-sheen", ("sheen_color", "sheen_roughness"), ("KHR_materials_sheen",),
         "gltf-pbr + KHR_materials_sheen (Charlie sheen on top, albedo scaling of the base from "
         "a packaged E table)", {}),
        ("gltf-pbr-clearcoat", ("clearcoat", "clearcoat_roughness"),
         ("KHR_materials_clearcoat",),
         "gltf-pbr + KHR_materials_clearcoat (GGX coat on top, mixed by clearcoat "
         "(0.04 + 0.96 (1 - N.V)^5))",
         {"reciprocity": "KHR_materials_clearcoat weights the coat with a Fresnel term of N.V "
                         "alone (its 'Discussion'), so f(wi, wo) != f(wo, wi) where the coat "
                         "is on"}),
    ]
    out = []
    for name, extra, exts, description, failures in entries:
        refs = "; ".join([_SPEC] + [_EXT.format(e) for e in exts])
        if "KHR_materials_sheen" in exts:
            refs += f"; {_CHARLIE}"
        tags = ("native", "gltf") + (("anisotropic",) if "anisotropy_strength" in extra else ())
        out.append(Entry(
            name=name,
            builder=_builder,
            params=tuple(_ENTRY_PARAMS[n] for n in _CORE + extra),
            reference=refs,
            description=description,
            tags=tags,
            year=2017 if name == "gltf-pbr" else None,
            sampler=sampler,
            expected_failures=dict(failures),
            target="gltf",
            native_export=_native_export,
            channels_coupled=_COUPLED,
        ))
    return out


#: ``Entry.channels_coupled`` of every glTF entry: the dielectric mix weights the diffuse lobe
#: by ``1 - max(F.r, F.g, F.b)`` (KHR_materials_specular) and the sheen scales the base by
#: ``1 - max3(sheenColor) E``: one channel's value reads the others' colour entries
_COUPLED = ("the dielectric mix weights the diffuse by 1 - max3(F) and the sheen scales the "
            "base by 1 - max3(sheenColor) E: a channel's value reads the other channels")


def _native_export(params: dict) -> tuple[dict, list[str]]:
    """``Entry.native_export`` of the glTF entries:
    :func:`~brdf_fit.models.gltf_material.to_gltf_material` (the exporter names the material)."""
    return to_gltf_material(params, "")
