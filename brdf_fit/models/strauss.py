"""Strauss's shading model read as a BRDF (P. S. Strauss, "A realistic lighting model for computer
animators", IEEE Computer Graphics and Applications 10(6):56-64, 1990; models.md 4.13).

Strauss gives reflected intensity per unit light intensity, ``Q = Q_d + Q_s``, for a colour
``C``, smoothness ``s``, metalness ``m`` and transparency ``t`` (all in [0, 1])::

    Q_d = cl d rd C,                 d = 1 - m s,      rd = (1 - s^3)(1 - t)
    Q_s = max(0, r_l.wo)^(3/(1-s)) rj Cs
    rn  = (1 - t) - rd,              rj = min(1, rn + (rn + kj) j),   j = Fr(x_l) Sh(x_l) Sh(x_v)
    Cs  = C_white + m (1 - Fr(x_l)) (C - C_white)
    Fr(x) = [1/(x - kf)^2 - 1/kf^2] / [1/(1 - kf)^2 - 1/kf^2]       (0 at x = 0, 1 at x = 1)
    Sh(x) = [1/(1 - ks)^2 - 1/(x - ks)^2] / [1/(1 - ks)^2 - 1/ks^2]  (1 at x = 0, 0 at x = 1)
    kf = 1.12, ks = 1.01, kj = 0.1

with ``r_l = 2 cl n - wi`` the mirror direction of the light (``r_l.wo = r_o.wi``) and the
**normalised angles** ``x_l = theta_i/(pi/2)``, ``x_v = theta_o/(pi/2)``. As a BRDF
``f = Q/cl = d rd C + max(0, r_l.wo)^(3/(1-s)) rj Cs / cl``, with no radiometric normalisation:
Strauss's is an artist's model. Its diffuse albedo is ``pi d rd C`` (e.g. 1.35 C for s = 0.6,
m = 0.3), the specular lobe is unnormalised (``Int max(0, r.w)^n dw = 2 pi/(n+1)``), and ``Fr``
depends on the light's angle only and ``1/cl`` divides the specular term, so the model is neither
reciprocal nor energy conserving (the failing checks are declared with measured values in
:func:`registry_entries`). ``rn = (1 - t) s^3 >= 0`` and ``Cs >= 1 - m >= 0`` for parameters in
[0, 1], so ``f >= 0`` without the clamps of shader implementations.

Sources and disagreements:

* Angles, not cosines: the 3ds Max SDK style Strauss shader and SIPP (J. Yngvesson, via
  G. Garramuno's mental ray port ``gg_strauss``) feed normalised angles or ``1 - cos``; the
  D3DBook GLSL port and osgSample's ``strauss.fsh`` feed the cosines themselves, which reverses
  ``Fr`` (``Fr = 1`` at normal incidence, 0 at grazing) and ``Sh`` (shadowing strongest at normal
  incidence). The paper's functions are of the angle normalised to [0, 1], so the angle form is
  right; the angles are computed as ``atan2(|w_xy|, w_z)`` (finite derivative at the normal,
  unlike ``acos``).
* Constants: ``kf = 1.12`` everywhere; ``ks = 1.01`` in the 3ds Max SDK shader, osgSample and the
  D3DBook port, and in the formula block of ``gg_strauss``, whose prose says the article has
  1.02. The paper was not available to settle it; 1.01 (the majority) is used and the constant
  is a class field (``ks``) for whoever can check.
* ``rd = (1 - s^3)(1 - t)`` (models.md, SIPP); the 3ds Max shader's ``(1 - m s^3)`` variant is not
  followed.
* ``transparency`` is a field (default 0) but not a registry parameter: a BRDF carries no
  transmitted light, so the registry entry holds it at 0.
* Exponent cap: ``3/(1 - s)`` is infinite at ``s = 1``; it is capped at :data:`EXPONENT_MAX`
  (3ds Max caps at 600); the gradient in ``s`` is 0 above the cap.

Sampler (a documented fallback: Strauss gives none): cosine-weighted with probability ``p_d``,
else the power-cosine lobe about ``r_o = mirror(wo)`` with Strauss's exponent ``n = 3/(1-s)``
(Lafortune & Willems 1994); ``pdf = p_d cl/pi + (1 - p_d)(n+1)/(2 pi) max(0, r_o.wi)^n`` exactly.
``p_d = h_d/(h_d + h_s)`` with ``h_d = pi d rd max C`` (the diffuse albedo) and
``h_s = 2 pi min(1, rn + (rn + kj)) max(1, max C)/(n+1)`` (a bound on the lobe's albedo).
Lobe samples below the horizon fail (pdf 0, weight 0). Quadrature hint: the mirror-lobe rule at
``n``.
"""

from __future__ import annotations

import math

import equinox as eqx
import jax.numpy as jnp

from brdf_fit.core.frame import split
from brdf_fit.core.numerics import INV_PI, safe_hypot
from brdf_fit.core.params import Channels, Entry, Param, Scalar, bounded
from brdf_fit.core.validate import ParameterError, check_param, check_scalar
from brdf_fit.models._base import AbstractBRDF, QuadratureLobe, expand_channels
from brdf_fit.models._lobes import (
    cos_alpha_r_pow,
    lobe_probability,
    power_cosine_pdf,
    sample_diffuse_or_mirror,
    sanitize_direction,
    upper,
)

__all__ = ["Strauss", "registry_entries", "strauss_fresnel", "strauss_shadow"]

#: Strauss's constants (his "kf", "ks", "kj"; the 3ds Max SDK calls them magic constants)
KF = 1.12
KS = 1.01
KJ = 0.1
#: Cap of the specular exponent 3/(1-s) (reached at s = 1 - 3e-6): the power-cosine sampler and
#: the mirror-lobe quadrature are verified to n = 1e6 (tests/test_phong.py, docs/quadrature.md).
EXPONENT_MAX = 1e6

_REFERENCE = (
    "P. S. Strauss, A realistic lighting model for computer animators, IEEE Computer Graphics "
    "and Applications 10(6):56-64, 1990"
)


def strauss_fresnel(x, kf=KF):
    """Strauss's Fresnel-like ``Fr(x)`` of the normalised angle ``x`` in [0, 1]."""
    return (1.0 / (x - kf) ** 2 - 1.0 / kf**2) / (1.0 / (1.0 - kf) ** 2 - 1.0 / kf**2)


def strauss_shadow(x, ks=KS):
    """Strauss's shadowing ``Sh(x)`` of the normalised angle ``x`` in [0, 1]."""
    return (1.0 / (1.0 - ks) ** 2 - 1.0 / (x - ks) ** 2) / (1.0 / (1.0 - ks) ** 2 - 1.0 / ks**2)


def _normalised_angle(w):
    """``theta/(pi/2)`` with ``theta = atan2(|w_xy|, w_z)`` (value and gradient finite at the
    normal)."""
    x, y, z = split(w)
    return jnp.arctan2(safe_hypot(x, y), z) * (2.0 / math.pi)


class Strauss(AbstractBRDF):
    """Strauss (1990) as a BRDF ``Q/cos(theta_i)`` (see the module docstring for the formulas,
    the sources, and why it is neither reciprocal nor energy conserving).

    Parameters: ``color`` in [0, 1] (may carry channels); ``smoothness``, ``metalness``,
    ``transparency`` scalars in [0, 1]; ``kf``, ``ks`` Strauss's constants (static).
    """

    color: Channels = bounded(0.8, lo=0.0, hi=1.0, channels=True)
    smoothness: Scalar = bounded(0.6, lo=0.0, hi=1.0)
    metalness: Scalar = bounded(0.3, lo=0.0, hi=1.0)
    transparency: Scalar = bounded(0.0, lo=0.0, hi=1.0)
    kf: float = eqx.field(static=True, default=KF)
    ks: float = eqx.field(static=True, default=KS)

    def __check_init__(self):
        owner = "Strauss"
        check_param("color", self.color, lo=0.0, hi=1.0, owner=owner)
        for name in ("smoothness", "metalness", "transparency"):
            value = getattr(self, name)
            check_param(name, value, lo=0.0, hi=1.0, owner=owner)
            check_scalar(name, value, owner)
        if not (self.kf > 1.0 and self.ks > 1.0):
            raise ParameterError(f"{owner}: kf and ks must be > 1 (poles outside [0, 1]), got "
                                 f"kf = {self.kf}, ks = {self.ks}")

    # ------------------------------------------------------------------ pieces

    def exponent(self):
        """Strauss's specular exponent ``3/(1 - s)``, capped at :data:`EXPONENT_MAX`."""
        return 3.0 / jnp.maximum(1.0 - self.smoothness, 3.0 / EXPONENT_MAX)

    def _terms(self):
        s, m, t = self.smoothness, self.metalness, self.transparency
        rd = (1.0 - s * s * s) * (1.0 - t)
        return 1.0 - m * s, rd, (1.0 - t) - rd

    def _p_d(self):
        d, rd, rn = self._terms()
        cmax = jnp.max(jnp.asarray(self.color))
        hd = math.pi * d * rd * cmax
        hs = 2.0 * math.pi * jnp.minimum(1.0, 2.0 * rn + KJ) * jnp.maximum(1.0, cmax) / (
            self.exponent() + 1.0)
        return lobe_probability(hd, hs)

    # ------------------------------------------------------------------ interface

    def eval(self, wi, wo):
        ok = upper(wi, wo)
        wis, wos = sanitize_direction(wi, ok), sanitize_direction(wo, ok)
        cl = wis[..., 2]
        x_l, x_v = _normalised_angle(wis), _normalised_angle(wos)
        fr = strauss_fresnel(x_l, self.kf)
        j = fr * strauss_shadow(x_l, self.ks) * strauss_shadow(x_v, self.ks)
        d, rd, rn = self._terms()
        rj = jnp.minimum(1.0, rn + (rn + KJ) * j)
        ch = self.channels()
        cs = 1.0 + self.metalness * expand_channels(1.0 - fr, ch) * (self.color - 1.0)
        lobe = cos_alpha_r_pow(wis, wos, self.exponent()) * rj / cl
        val = d * rd * self.color + cs * expand_channels(lobe, ch)
        return jnp.where(expand_channels(ok, ch), val, 0.0)

    def pdf(self, wi, wo):
        # the density of sample_diffuse_or_mirror, written (p_d cos) / pi (diffuse_mirror_pdf
        # has p_d (cos / pi): the same up to round-off, kept as it was)
        p_d = self._p_d()
        lobe = power_cosine_pdf(wi, wo, self.exponent())
        return jnp.where(upper(wi, wo),
                         p_d * jnp.maximum(wi[..., 2], 0.0) * INV_PI + (1.0 - p_d) * lobe, 0.0)

    def sample(self, wo, uc, u):
        return sample_diffuse_or_mirror(self, wo, uc, u, self.exponent(), self._p_d())

    def quadrature_lobe(self) -> QuadratureLobe:
        """Quadrature hint (:func:`brdf_fit.verify.albedo.lobe_rule`): the power-cosine lobe about
        the mirror direction with Strauss's exponent."""
        return QuadratureLobe("mirror", self.exponent())

    def selection_hint(self):
        d, rd, rn = self._terms()
        return jnp.max(jnp.asarray(self.color)) * d * rd + rn + KJ


# ----------------------------------------------------------------------------- registry entries

#: measured with brdf_fit.checks.run_checks at the defaults (float64); see the test file
_FAILURES: dict[str, str] = {
    "reciprocity": (
        "Fr(x_l) uses the light's angle only and 1/cos(theta_i) divides the specular term: "
        "measured max relative asymmetry 2.23 at the defaults"
    ),
    "energy": (
        "no radiometric normalisation: the diffuse albedo alone is pi d rd C = 1.616 in the red "
        "channel (s = 0.6, m = 0.3, C = 0.8); measured max albedo 1.780 (cos_o = 0.5)"
    ),
}


def registry_entries():
    """:class:`brdf_fit.registry.Entry` objects of this module (registered by the registry)."""
    return [
        Entry(
            name="strauss",
            builder=lambda color, smoothness, metalness: Strauss(
                color=color, smoothness=smoothness, metalness=metalness),
            params=(Param("color", (0.8, 0.5, 0.3), lo=0.0, hi=1.0, channels=True,
                          doc="surface colour C"),
                    Param("smoothness", 0.6, lo=0.0, hi=1.0,
                          doc="s: 0 rough/diffuse, 1 mirror-like (exponent 3/(1-s))"),
                    Param("metalness", 0.3, lo=0.0, hi=1.0,
                          doc="m: tints the highlight with C and dims the diffuse term")),
            reference=_REFERENCE + "; as a BRDF Q/cos(theta_i), transparency 0",
            description=(
                "Strauss's artist model: d rd C + max(0, r_l.v)^(3/(1-s)) rj Cs/cl with "
                "Fr/Sh of normalised angles (not radiometric: not reciprocal, albedo > 1)"
            ),
            expected_failures=_FAILURES,
            year=1990,
            catalogue="Strauss",
            sampler="fallback: cosine + power-cosine about the mirror, n = 3/(1-s) (exact pdf)",
        ),
    ]
