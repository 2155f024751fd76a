"""Torrance-Sparrow (1967) with the paper's Gaussian distribution of facet angles.

K. E. Torrance, E. M. Sparrow, "Theory for off-specular reflection from roughened surfaces",
JOSA 57(9):1105-1114, 1967. The facet slope distribution is Gaussian in the *angle* ``alpha``
between the facet normal and the mean normal (their eq. 9, ``P(alpha) = b exp(-c^2 alpha^2)``),
masking-shadowing is that of V-grooves (their section 4, in Blinn's 1977 vector form, see
:class:`brdf_fit.microfacet.VCavity`), the facets reflect with the exact Fresnel factor, and a
Lambert term stands for the multiply scattered / subsurface light (their "diffuse component").
In the microfacet form of Walter et al. 2007 (eq. 20), with ``h = normalize(wi + wo)``::

    f = kd / pi + ks F(wo.h) D(h) G_V(wi, wo, h) / (4 (n.wi)(n.wo))
    D(h) = b(sigma) exp(-theta_h^2 / sigma^2),      theta_h = angle(n, h),  sigma = 1/c

The registry parameter ``alpha`` is the Gaussian width ``sigma = 1/c`` in radians (for narrow
lobes ``D`` approaches the Beckmann distribution of the same ``alpha``, since
``tan(theta) ~ theta``). ``b`` has no closed form: it makes ``Int_H D(m) (n.m) dw_m = 1``,

    1/b = 2 pi Int_0^{pi/2} exp(-a^2/sigma^2) cos(a) sin(a) da = 2 pi sigma^2 K(sigma),
    K(sigma) = Int_0^{T} exp(-t^2) sin(2 sigma t)/(2 sigma) dt,      T = min(pi/(2 sigma), T_CUT)

(``a = sigma t``), computed by a fixed Gauss-Legendre rule in JAX (:data:`NORM_NODES` nodes), so
gradients with respect to ``alpha`` flow through it. Measured quadrature error of ``K``: below
1e-14 relative for sigma in [1e-4, 1] against 256 nodes, and ``b`` agrees with SciPy's adaptive
quadrature to 1e-12 (tests/test_torrance_sparrow.py; the ``ndf-normalisation`` check measures
``|Int D cos - 1|`` = 7e-16 at the default). For
``sigma -> 0``, ``K -> 1/2`` and ``b -> 1/(pi sigma^2) = c^2/pi`` (models.md 4.4).

Hazards (models.md 1.4, 4.4): ``acos(n.h)`` has an infinite derivative at ``h = n``. Only
``theta_h^2`` enters, computed from ``T2 = tan^2(theta_h) = (h_x^2 + h_y^2)/h_z^2`` as
``atan(sqrt(T2))^2``, with the Taylor series ``T2 - 2/3 T2^2 + 23/45 T2^3`` below
:data:`SERIES_T2_MAX` (smooth in ``T2``; the truncation error there is < 1e-12 relative).

Sampling: exact. ``m ~ D(m) (n.m)`` by inverting the CDF of ``t = theta/sigma``,
``C(t) = Int_0^t exp(-x^2) sin(2 sigma x)/(2 sigma) dx / K``, with a bracketed Newton iteration
(fixed trip count) and the integral by Gauss-Legendre on ``[0, t]``; uniform azimuth. The
microfacet model then uses it through the V-cavity visible-normal sampler (Heitz & d'Eon 2014,
exact for V-groove masking), so the reported pdf is the exact density of what is drawn (to the
accuracy of the inversion: ``|C(t(u)) - u|`` measured <= 1e-13 for sigma <= 0.3 and <= 6e-10
for sigma = 1, where the last bracket iterations fall in the flat tail near ``u -> 1``).
This is our own construction: the paper gives no
sampler, and public implementations (PiscisRT ``BRDF_TS``, shrimp) replace the Gaussian-angle D by
Beckmann's, which is the registry's "torrance-sparrow" entry.

The distribution :class:`GaussianAngle` is an
:class:`~brdf_fit.core.microfacet.AbstractDistribution` usable with V-cavity masking (``D``,
``sample_normal``; ``supports_visible`` is False); its ``widths()`` let
:func:`brdf_fit.verify.albedo.lobe_widths` and :mod:`brdf_fit.verify.checks` (ndf-normalisation,
weak and full white furnace) treat it as a lobe of that width. It has no Smith ``Lambda`` (``P``
and ``sample_visible`` raise).
"""

from __future__ import annotations

import math
from typing import ClassVar

import jax
import jax.numpy as jnp
import numpy as np

from brdf_fit.core.fresnel import DielectricFresnel
from brdf_fit.core.microfacet import AbstractDistribution, VCavity
from brdf_fit.core.numerics import ALPHA_MIN, safe_sqrt
from brdf_fit.core.params import Entry, Param, Scalar, bounded
from brdf_fit.core.validate import check_param
from brdf_fit.models.lambert import Lambert
from brdf_fit.models.microfacet_brdf import MicrofacetBRDF
from brdf_fit.models.mixture import Mixture, Scaled

__all__ = ["GaussianAngle", "registry_entries"]

PI = math.pi
#: Upper limit of ``t = theta/sigma`` in the normaliser and the sampler: ``exp(-T_CUT^2)`` =
#: 4e-44 is far below float64 round-off relative to the integral (~1/2), so the cut-off tail
#: changes nothing; it keeps the rule on the lobe when ``pi/(2 sigma)`` is huge (sigma = 1e-4).
T_CUT = 10.0
#: Gauss-Legendre nodes of the normaliser ``K(sigma)`` on ``[0, T]`` (measured: 64 nodes agree
#: with 256 to < 1e-14 relative over sigma in [1e-4, 1]).
NORM_NODES = 64
#: Gauss-Legendre nodes of the sampler's CDF ``Int_0^t``; measured agreement with 256 nodes
#: < 6e-15 (relative to K) for t in (0, T] and sigma in [1e-4, 1].
CDF_NODES = 40
#: Fixed number of bracketed Newton iterations of the sampler (bisection when a Newton step
#: leaves the bracket; a step onto the bracket's end is accepted, so a converged iterate stays;
#: so is a step just outside it, from a rounding-level residual: see ``sample_normal``).
NEWTON_ITERS = 16
#: ``tan^2(theta_h)`` below which ``theta^2 = atan(sqrt(T2))^2`` is replaced by its Taylor series
#: (the next term, ``-44/105 T2^4``, is < 5e-17 relative there).
SERIES_T2_MAX = 1e-4


def _gl(n):
    x, w = np.polynomial.legendre.leggauss(n)
    return 0.5 * (x + 1.0), 0.5 * w


_GL_NORM = _gl(NORM_NODES)
_GL_CDF = _gl(CDF_NODES)


def _q(t, sigma):
    """Density of ``t = theta/sigma`` before normalisation: ``exp(-t^2) sin(2 sigma t)/(2 sigma)``
    (``= exp(-theta^2/sigma^2) cos(theta) sin(theta) / sigma^2``, times ``d theta = sigma dt``)."""
    return jnp.exp(-t * t) * jnp.sin(2.0 * sigma * t) / (2.0 * sigma)


def _t_max(sigma):
    return jnp.minimum(0.5 * PI / sigma, T_CUT)


def _integral(upper, sigma, rule):
    """``Int_0^upper _q(t) dt`` by the Gauss-Legendre rule ``rule`` mapped to ``[0, upper]``;
    ``upper`` may be batched (a trailing node axis is added)."""
    x, w = rule
    dt = jnp.result_type(upper, sigma)
    x = jnp.asarray(x, dtype=dt)
    w = jnp.asarray(w, dtype=dt)
    t = upper[..., None] * x
    return upper * jnp.sum(w * _q(t, sigma[..., None]), axis=-1)


def normaliser_K(sigma):
    """``K(sigma) = Int_0^T exp(-t^2) sin(2 sigma t)/(2 sigma) dt`` (module docstring), so that
    ``b = 1/(2 pi sigma^2 K)``. Differentiable in ``sigma``."""
    sigma = jnp.asarray(sigma)
    return _integral(_t_max(sigma), sigma, _GL_NORM)


def theta_squared(mx, my, mz):
    """``theta^2`` of a unit vector with ``mz > 0`` from ``tan^2`` (smooth at the pole)."""
    T2 = (mx * mx + my * my) / (mz * mz)
    small = T2 < SERIES_T2_MAX
    Ts = jnp.where(small, 1.0, T2)
    series = T2 * (1.0 - T2 * (2.0 / 3.0 - T2 * (23.0 / 45.0)))
    return jnp.where(small, series, jnp.arctan(jnp.sqrt(Ts)) ** 2)


@jax.jit
def _angle_newton(t, lo, hi, s_b, target):
    """The bracketed Newton iteration of :meth:`GaussianAngle.sample_normal` on ``C(t) = target``
    (``NEWTON_ITERS`` steps): its own compiled program, so that sampling outside jit does not
    trace and compile the loop on every call (measured: 0.55 s per eager ``sample`` of
    ``torrance-sparrow-gaussian`` before, 2026-12-05); inside an enclosing jit it is inlined."""

    def body(_, state):
        t, lo, hi = state
        value = _integral(t, s_b, _GL_CDF) - target
        lo = jnp.where(value < 0, t, lo)
        hi = jnp.where(value < 0, hi, t)
        deriv = _q(t, s_b)
        ok = deriv > 0
        step = t - value / jnp.where(ok, deriv, 1.0)
        inside = ok & (step >= lo) & (step <= hi)
        # A step leaving the bracket by less than half its width can only come from a sign
        # of ``value`` at rounding level that disagrees with the bracket update (seen under
        # vmap in XLA's CPU code: 0.3% of samples discarded the converged iterate for
        # bisection, 7e-11 off in m; issue 16): it is clipped onto the bracket, i.e. the
        # converged iterate is kept. A genuine Newton overshoot leaves from the other end
        # of the bracket and travels more than its width, so it still bisects.
        near = ok & (jnp.abs(step - t) <= 0.5 * (hi - lo))
        t = jnp.where(inside | near, jnp.clip(step, lo, hi), 0.5 * (lo + hi))
        return t, lo, hi

    return jax.lax.fori_loop(0, NEWTON_ITERS, body, (t, lo, hi))[0]


class GaussianAngle(AbstractDistribution):
    """Torrance & Sparrow's 1967 facet distribution, Gaussian in the facet angle, normalised on
    projected area (module docstring)::

        D(m) = exp(-theta_m^2 / sigma^2) / (2 pi sigma^2 K(sigma))   for m.z > 0

    ``alpha_x`` is ``sigma`` (radians), clamped below at ``ALPHA_MIN`` like the other
    distributions; ``alpha_y`` is None (isotropic).
    """

    alpha_x: Scalar = bounded(0.3, lo=0.0, hi=1.0, lo_open=True)
    alpha_y: ClassVar[None] = None
    supports_visible: ClassVar[bool] = False

    def __check_init__(self):
        check_param("alpha", self.alpha_x, lo=0.0, lo_open=True, owner="GaussianAngle")

    def _sigma(self):
        return jnp.maximum(jnp.asarray(self.alpha_x), ALPHA_MIN)

    def b(self):
        """The normalisation constant ``b`` of Torrance & Sparrow's eq. (9)."""
        s = self._sigma()
        inv_s = 1.0 / s
        # (1/s)^2, not 1/s^2: reverse mode divides the cotangent by (s^2)^2 = 1e-16 at
        # sigma = 1e-4, which overflowed float32 at a grazing mirror pair (NaN; issue 16)
        return inv_s * inv_s / (2.0 * PI * normaliser_K(s))

    def D(self, mx, my, mz):
        s = self._sigma()
        pos = mz > 0
        mzs = jnp.where(pos, mz, 1.0)
        th2 = theta_squared(jnp.where(pos, mx, 0.0), jnp.where(pos, my, 0.0), mzs)
        inv_s = 1.0 / s  # th2 (1/s)^2, not th2/s^2: see b()
        return jnp.where(pos, self.b() * jnp.exp(-th2 * inv_s * inv_s), 0.0)

    def P(self, wx, wy, wz):
        raise NotImplementedError("GaussianAngle has no Smith Lambda; use VCavity masking")

    def sample_visible(self, wx, wy, wz, u1, u2):
        raise NotImplementedError("GaussianAngle has no visible-normal sampler; use VCavity "
                                  "masking (V-cavity visible normals) or sample_normal")

    def widths(self):
        s = self._sigma()
        return s, s

    def sample_normal(self, u1, u2):
        """``m ~ D(m)(n.m)``: ``theta = sigma t`` with ``C(t) = u1`` solved by bracketed Newton
        (module docstring), azimuth ``2 pi u2``."""
        s = self._sigma()
        u1 = jnp.clip(u1, 0.0, 1.0)
        tmax = _t_max(s)
        target = u1 * normaliser_K(s)
        s_b = jnp.broadcast_to(s, jnp.shape(u1))
        # start: the sigma -> 0 limit C(t) = 1 - exp(-t^2), exact for narrow lobes
        t0 = safe_sqrt(-jnp.log1p(-jnp.minimum(u1, 1.0 - 1e-16)))
        t = jnp.clip(t0, 0.0, tmax)
        lo = jnp.zeros_like(t)
        hi = jnp.broadcast_to(tmax, jnp.shape(t))

        t = _angle_newton(t, lo, hi, s_b, target)
        theta = s * t
        st, ct = jnp.sin(theta), jnp.cos(theta)
        phi = 2.0 * PI * u2
        return st * jnp.cos(phi), st * jnp.sin(phi), ct


def _lobe(alpha, eta):
    return MicrofacetBRDF(distribution=GaussianAngle(alpha), masking=VCavity(),
                          fresnel=DielectricFresnel(eta))


_TS_1967 = (
    "K. E. Torrance, E. M. Sparrow, Theory for off-specular reflection from roughened surfaces, "
    "JOSA 57(9):1105-1114, 1967 (Gaussian facet-angle distribution eq. 9, V-groove masking "
    "section 4); V-groove in vector form: J. F. Blinn, SIGGRAPH 1977; microfacet form F D G/(4 "
    "cos_i cos_o): B. Walter et al., EGSR 2007, eq. 20"
)


def registry_entries():
    """The ``torrance-sparrow-gaussian`` entry (the registry's ``torrance-sparrow`` uses
    Beckmann's D instead)."""
    return [
        Entry(
            name="torrance-sparrow-gaussian",
            builder=lambda kd, ks, alpha, eta: Mixture(lobes=(
                Lambert(rho=kd), Scaled(lobe=_lobe(alpha, eta), scale=ks))),
            params=(
                Param("kd", (0.2, 0.2, 0.2), lo=0.0, hi=1.0, channels=True,
                      doc="diffuse albedo"),
                Param("ks", 0.8, lo=0.0, hi=1.0, doc="specular scale"),
                Param("alpha", 0.3, lo=0.0, hi=1.0, lo_open=True,
                      doc="Gaussian facet-angle width sigma = 1/c (radians)"),
                Param("eta", 1.5, lo=0.0, lo_open=True, channels=True,
                      doc="relative index of refraction of the facets"),
            ),
            reference=_TS_1967,
            description=(
                "kd Lambert + ks microfacet lobe with Torrance & Sparrow's Gaussian-angle D "
                "(normalised numerically in JAX), V-groove masking, exact dielectric Fresnel"
            ),
            aliases=("ts-gaussian",),
            year=1967,
            catalogue="Torrance-Sparrow",
            sampler="exact V-cavity visible normals (numerical CDF inversion) + cosine",
        ),
    ]
