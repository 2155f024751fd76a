"""Oren-Nayar rough diffuse reflection (Oren & Nayar 1994): the full model with interreflection
and the qualitative (A, B) model.

M. Oren, S. K. Nayar, "Generalization of Lambert's reflectance model", SIGGRAPH 94, pp. 239-246,
1994 (section 4.4, the functional approximation, and section 5, the qualitative model);
models.md 4.20. Surface: V-cavities with Lambertian facets of albedo ``rho`` whose slope *angles*
are Gaussian with standard deviation ``sigma`` **in radians** (the paper's ``sigma``; published
shaders often take degrees, e.g. ``wdas/brdf`` ``orennayar.brdf``). Mitsuba 0.6
(``roughdiffuse.cpp``) takes a Beckmann-style RMS slope ``alpha`` instead and converts
``sigma = alpha/sqrt(2)``; this library takes ``sigma`` directly and applies no such mapping.

Angles: ``theta_i, theta_r`` of ``wi, wo``, ``alpha = max``, ``beta = min``, ``dphi`` the azimuth
difference, ``s2 = sigma^2``. Full model (the paper's functional approximation)::

    C1 = 1 - 0.5 s2/(s2 + 0.33)
    C2 = 0.45 s2/(s2 + 0.09) sin(alpha)                          if cos(dphi) >= 0
       = 0.45 s2/(s2 + 0.09) (sin(alpha) - (2 beta/pi)^3)        otherwise
    C3 = 0.125 s2/(s2 + 0.09) (4 alpha beta/pi^2)^2
    f1 = rho/pi [C1 + cos(dphi) C2 tan(beta) + (1 - |cos(dphi)|) C3 tan((alpha + beta)/2)]
    f2 = 0.17 rho^2/pi s2/(s2 + 0.13) [1 - cos(dphi) (2 beta/pi)^2]        (interreflection)
    f  = max(f1, 0) + f2

Qualitative model (the paper's eq. for ``A`` and ``B``)::

    f = rho/pi [A + B max(0, cos(dphi)) sin(alpha) tan(beta)],  A = C1,  B = 0.45 s2/(s2 + 0.09)

Checked against three public implementations, which agree with each other and with the above
(read, not copied): ``wdas/brdf`` ``src/brdfs/orennayar.brdf`` (full, angles from ``acos``),
Mitsuba 0.6 ``src/bsdfs/roughdiffuse.cpp`` (full and ``useFastApprox``; it tests
``cos(dphi) > 0`` where the paper has ``>= 0``, which changes nothing since the term carries a
factor ``cos(dphi)``), and pbrt-v3 ``OrenNayar::f`` (qualitative). Some game shaders drop one
``rho`` from the interreflection term (``rho^2`` in the paper: light reflected twice).

Written without ``acos``, ``tan`` or ``atan2`` of cosines (models.md 4.20 identities):

* ``d = l.v - cl cv = x_i x_o + y_i y_o = sin(theta_i) sin(theta_r) cos(dphi)`` (the
  tangential dot product, formed directly: no cancellation);
* ``sin(alpha) sin(beta) = sin(theta_i) sin(theta_r)``, so ``cos(dphi) sin(alpha) tan(beta) =
  d/cos(beta)`` with ``cos(beta) = max(cl, cv) > 0``: the C2 term is ``B d/cos(beta)`` (and the
  extra ``-B (2 beta/pi)^3 d/(sin(alpha) cos(beta))`` where ``d < 0``);
* ``tan((alpha + beta)/2) = (sin alpha + sin beta)/(cos alpha + cos beta)`` (Mitsuba 0.6);
* the qualitative model is ``rho/pi [A + B max(0, d)/max(cl, cv)]`` (exactly equal).

The full model needs the angles ``alpha`` and ``beta`` themselves (in ``C3``, in
``(2 beta/pi)^3`` and in ``f2``): they are ``atan2(sin, cos)`` with ``sin = sqrt(x^2 + y^2)``, whose
derivatives are bounded everywhere (``acos`` has an infinite one at normal incidence).

Clamp of the single-scattering term (a choice, not in the paper): with ``cos(dphi) = -1`` and
both directions at grazing, ``C2 tan(beta)`` tends to ``(6/pi) B`` (``sin(alpha) - (2 beta/pi)^3
~ 6 eps/pi`` while ``tan(beta) ~ 1/eps``), so ``f1`` becomes negative once ``C1 < 1.91 B``, i.e.
for ``sigma >~ 0.65`` rad: measured ``min f1 = -0.0249 rho/pi`` at ``sigma = 0.7``,
``-0.164 rho/pi`` at ``sigma = 1``. ``f2`` compensates only for ``rho`` near 1, so the paper's
formula gives a negative BRDF for dark, very rough surfaces. ``f1`` is clamped at 0 (as some
public shaders do); it changes nothing for ``sigma <= 0.6``.

Reciprocal (alpha, beta, |dphi| symmetric). Not energy conserving in general. Albedo for
``rho = 1``, measured by an independent converged quadrature (tests/test_oren_nayar.py) on
``sigma`` in [0.05, 1] x ``cos_o`` in [1e-3, 1]: full 0.7745 (``sigma = 1``, normal view) to
1.0504 (``sigma = 0.3``, ``cos_o = 1e-3``); qualitative 0.6241 to 1.0151 (``sigma = 0.2``,
``cos_o = 1e-3``). models.md 4.20 quotes "<= 1.03" (1.029 / 1.012 at ``theta_o = 1.5`` rad,
where we measure 1.0319 / 1.0119 at those ``sigma``); the maximum is at the most grazing view.
The registry defaults (``rho <= 0.8``) pass the ``energy`` check (max 0.8291 full, 0.8042
qualitative); ``rho = 1, sigma = 0.3`` fails it (1.0504).

Sampler: cosine-weighted hemisphere (as pbrt, Mitsuba and BBM), ``pdf = cl/pi`` exactly; it
matches the BRDF only approximately (exactly for ``sigma = 0``): weight ``pi f``.
"""

from __future__ import annotations

import math

import equinox as eqx
import jax.numpy as jnp

from brdf_fit.core.frame import split
from brdf_fit.core.numerics import INV_PI, safe_div, safe_sqrt
from brdf_fit.core.params import Channels, Entry, Param, Scalar, bounded
from brdf_fit.core.validate import ParameterError, check_param, check_scalar
from brdf_fit.models._base import AbstractBRDF, expand_channels
from brdf_fit.models._lobes import cosine_pdf, max_over_channels, sample_cosine, upper

__all__ = ["OrenNayar", "registry_entries"]

TWO_OVER_PI = 2.0 / math.pi

#: Sines of polar angles at or below this count as 0 where the azimuth difference is formed:
#: ``cos(dphi)`` is set to 0 and the ``(2 beta/pi)^3 / sin(alpha)`` correction to 0. Every term
#: they multiply vanishes like ``beta^2`` (``C3``, ``(2 beta/pi)^2``), so the value changes by
#: < 1e-16 relative; and ``1/(sin_i sin_r)^2 <= 1e32`` stays finite in float32 gradients (a sine
#: of 1e-30 from a direction such as (1e-30, 0, 1) would overflow it). pbrt-v3 uses 1e-4 here,
#: Mitsuba 0.6 its ``Epsilon``; 1e-8 keeps the formula exact to double precision.
SIN_EPS = 1e-8

_VARIANTS = ("full", "qualitative")

_ON_1994 = (
    "M. Oren, S. K. Nayar, Generalization of Lambert's reflectance model, SIGGRAPH 94, "
    "pp. 239-246, 1994"
)


class OrenNayar(AbstractBRDF):
    """Oren-Nayar BRDF (Oren & Nayar 1994; formulas, sources and numerics in the module
    docstring). ``rho`` (facet albedo, may carry channels) in [0, 1]; ``sigma`` (standard
    deviation of the facet slope angle, radians, scalar) >= 0; ``sigma = 0`` is Lambert exactly.
    ``variant``: ``"full"`` (``C1, C2, C3`` and the interreflection term ``f2``) or
    ``"qualitative"`` (``A, B``).

    Sampling: cosine hemisphere, ``pdf = cos(theta_i)/pi`` (approximate match to ``f cos``).
    """

    rho: Channels = bounded(0.8, lo=0.0, hi=1.0, channels=True)
    sigma: Scalar = bounded(0.3, lo=0.0, hi=1.0)
    variant: str = eqx.field(static=True, default="full")

    def __check_init__(self):
        owner = "OrenNayar"
        if self.variant not in _VARIANTS:
            raise ParameterError(f"{owner}: variant must be one of {_VARIANTS}, got "
                                 f"{self.variant!r}")
        check_param("rho", self.rho, lo=0.0, hi=1.0, owner=owner)
        check_param("sigma", self.sigma, lo=0.0, owner=owner)
        check_scalar("sigma", self.sigma, owner)

    def _terms(self, wi, wo):
        """Channel-free pieces: ``(ok, g1, g2)`` with ``f = rho/pi g1 + rho^2/pi g2``, where
        ``g1`` is the (unclamped) single-scattering bracket and ``g2`` the interreflection one."""
        ok = upper(wi, wo)
        ix, iy, iz = split(wi)
        ox, oy, oz = split(wo)
        # sanitise: invalid lanes become the normal (every formula below is finite there)
        ix, iy, ox, oy = (jnp.where(ok, c, 0.0) for c in (ix, iy, ox, oy))
        cl, cv = jnp.where(ok, iz, 1.0), jnp.where(ok, oz, 1.0)
        # sin = sqrt(x^2 + y^2), not hypot: jnp.hypot's gradient is NaN in float32 for
        # components below ~1e-19 (measured at (1e-30, 0)); the squares underflow harmlessly
        si, sv = safe_sqrt(ix * ix + iy * iy), safe_sqrt(ox * ox + oy * oy)
        d = ix * ox + iy * oy  # sin_i sin_r cos(dphi)
        cb, ca = jnp.maximum(cl, cv), jnp.minimum(cl, cv)  # cos(beta), cos(alpha)
        sa, sb = jnp.maximum(si, sv), jnp.minimum(si, sv)  # sin(alpha), sin(beta)
        s2 = self.sigma * self.sigma
        A = 1.0 - 0.5 * s2 / (s2 + 0.33)
        B = 0.45 * s2 / (s2 + 0.09)
        d_over_cb = d / cb
        if self.variant == "qualitative":
            return ok, A + B * jnp.maximum(d_over_cb, 0.0), None
        alpha = jnp.arctan2(sa, ca)
        beta = jnp.arctan2(sb, cb)
        b2 = TWO_OVER_PI * beta
        both = (si > SIN_EPS) & (sv > SIN_EPS)
        cos_dphi = jnp.clip(jnp.where(both, safe_div(d, jnp.where(both, si * sv, 1.0)), 0.0),
                            -1.0, 1.0)
        # C2 tan(beta) cos(dphi) = B d/cos(beta) [1 - (2 beta/pi)^3/sin(alpha) if d < 0]
        big = sa > SIN_EPS
        corr = jnp.where(big & (d < 0), safe_div(b2 * b2 * b2, jnp.where(big, sa, 1.0)), 0.0)
        term2 = B * d_over_cb * (1.0 - corr)
        C3 = 0.125 * s2 / (s2 + 0.09) * (TWO_OVER_PI * TWO_OVER_PI * alpha * beta) ** 2
        tan_half = (sa + sb) / (ca + cb)
        term3 = (1.0 - jnp.abs(cos_dphi)) * C3 * tan_half
        g1 = A + term2 + term3
        g2 = 0.17 * s2 / (s2 + 0.13) * (1.0 - cos_dphi * b2 * b2)
        return ok, g1, g2

    def eval(self, wi, wo):
        ok, g1, g2 = self._terms(wi, wo)
        ch = self.channels()
        if g2 is None:
            val = self.rho * INV_PI * expand_channels(g1, ch)
        else:
            val = (self.rho * INV_PI * expand_channels(jnp.maximum(g1, 0.0), ch)
                   + self.rho * self.rho * INV_PI * expand_channels(g2, ch))
        return jnp.where(expand_channels(ok, ch), val, 0.0)

    def pdf(self, wi, wo):
        return cosine_pdf(wi, wo)

    def sample(self, wo, uc, u):
        return sample_cosine(self, wo, u)

    def selection_hint(self):
        return max_over_channels(self.rho)


def registry_entries():
    """:class:`brdf_fit.registry.Entry` objects for the two Oren-Nayar variants (not registered
    here)."""
    def params():
        return (
            Param("rho", (0.8, 0.6, 0.4), lo=0.0, hi=1.0, channels=True,
                  doc="facet (Lambertian) albedo"),
            Param("sigma", 0.3, lo=0.0, hi=1.0,
                  doc="standard deviation of the facet slope angle, radians (0: Lambert); "
                      "Mitsuba 0.6's alpha corresponds to sigma = alpha/sqrt(2)"),
        )

    return [
        Entry(
            name="oren-nayar",
            builder=lambda rho, sigma: OrenNayar(rho=rho, sigma=sigma, variant="full"),
            params=params(),
            reference=(f"{_ON_1994} (functional approximation with C1, C2, C3 and the "
                       "interreflection term); models.md 4.20"),
            description=(
                "full Oren-Nayar: single scattering (C1, C2, C3; clamped at 0) + "
                "interreflection 0.17 rho^2 ...; trig-free except atan2 for the angles"
            ),
            aliases=("oren-nayar-full", "rough-diffuse"),
            year=1994,
            catalogue="Oren-Nayar",
            sampler="cosine fallback (exact pdf)",
        ),
        Entry(
            name="oren-nayar-qualitative",
            builder=lambda rho, sigma: OrenNayar(rho=rho, sigma=sigma, variant="qualitative"),
            params=params(),
            reference=f"{_ON_1994} (qualitative model, A and B); models.md 4.20",
            description=(
                "qualitative Oren-Nayar rho/pi [A + B max(0, l.v - cl cv)/max(cl, cv)] "
                "(trig-free)"
            ),
            aliases=("oren-nayar-simple",),
            year=1994,
            catalogue="Oren-Nayar",
            sampler="cosine fallback (exact pdf)",
        ),
    ]
