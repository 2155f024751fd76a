"""MaterialX 1.39.5's BSDF arithmetic (``libraries/pbrlib/genglsl``), in JAX: the pieces the
OpenPBR Surface model (:mod:`brdf_fit.models.openpbr`) is built from, each named after the GLSL
function it transcribes (the module docstring of :mod:`~brdf_fit.models.openpbr` cites the
papers). Float32 parity with MaterialX's generated shader: ``tests/convert/test_materialx.py``.
"""

from __future__ import annotations

import math

import jax.numpy as jnp
import numpy as np

from brdf_fit.core.numerics import ALPHA_MIN, INV_PI, safe_sqrt

#: MaterialX's ``M_FLOAT_EPS`` (``stdlib/genglsl/lib/mx_math.glsl``): the floor of every
#: cosine and width the shader clamps, and the weight under which a BSDF node is skipped
M_FLOAT_EPS = 1e-8
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


def mix(bg, fg, t):
    """GLSL's ``mix(bg, fg, t) = bg (1 - t) + fg t``."""
    return bg * (1.0 - t) + fg * t


def clamp_eps(x):
    return jnp.clip(x, M_FLOAT_EPS, 1.0)


def clamp_width(a, floor=M_FLOAT_EPS):
    """A GGX width clamped to ``[floor, 1]`` by selection (``clip``'s gradient multiplies the
    lobe's derivatives at the floor by 0, which is NaN where they overflow float32; ``where``
    drops them). ``floor``: MaterialX's ``M_FLOAT_EPS`` for the albedo fits and compensation,
    ``ALPHA_MIN`` for the lobe's shape (module docstring, "Epsilons")."""
    return jnp.where(a < floor, floor, jnp.where(a > 1.0, 1.0, a))


def ggx_lobe(hx, hy, hz, cl, cv, ax, ay):
    """``D G2 / (4 n.wi n.wo)`` of GGX widths ``(ax, ay)`` floored at ``ALPHA_MIN``, ``G2`` of
    their geometric mean (``mx_average_alpha``)."""
    ax, ay = clamp_width(ax, ALPHA_MIN), clamp_width(ay, ALPHA_MIN)
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
    a = mix(f0, f90, (1.0 - cmax) ** exponent) * (1.0 - f82) * factor
    return mix(f0, f90, (1.0 - x) ** exponent) - a * x * (1.0 - x) ** 6


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


