"""Fresnel reflectance: Schlick's approximation and the exact dielectric and conductor formulas.

All functions take the cosine of the angle of incidence *on the (micro)facet* (``wo.h`` for a
microfacet model, ``n.w`` for a smooth interface) and broadcast it against their parameters, which
may carry a trailing channel axis (RGB or wavelengths). Values and gradients stay finite at
cos = 0 and 1, k = 0, eta = 1 and at the critical angle (see ``tests/test_fresnel.py``).

References
----------
- C. Schlick, "An inexpensive BRDF model for physically-based rendering", Computer Graphics
  Forum 13(3), 1994, eq. 24 (``F0 + (1 - F0)(1 - cos)^5``).
- M. Born, E. Wolf, "Principles of Optics", 7th ed., section 1.5.2 (Fresnel equations, s and p
  amplitudes); the unpolarised reflectance is the mean of ``|r_s|^2`` and ``|r_p|^2``.
- K. D. Moeller, "Optics", University Science Books, 1988: the real-arithmetic form of the
  conductor reflectance used by pbrt-v3 ``FrConductor`` and Mitsuba 3 ``fresnel_conductor``.
"""

from __future__ import annotations

import abc

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from brdf_fit.core.numerics import pow5, safe_div, safe_hypot, safe_sqrt
from brdf_fit.core.params import Channels, Scalar, bounded

__all__ = [
    "schlick",
    "dielectric",
    "conductor",
    "f0_from_ior",
    "ior_from_f0",
    "AbstractFresnel",
    "SchlickFresnel",
    "DielectricFresnel",
    "ConductorFresnel",
    "ConstantFresnel",
    "FRESNEL_AVERAGE_ORDER",
    "fresnel_average",
]

#: Gauss-Legendre order of :func:`fresnel_average` (the cosine-weighted hemispherical average of
#: a Fresnel curve). Measured against 4000 nodes (float64): gold (the registry's effective RGB
#: n, k, red channel at the box k = 100) 6.7e-13, copper- and aluminium-like n, k <= 1e-14,
#: eta = 1.5 with k = 100: 1.1e-9, a dielectric (k = 0, eta = 1.5) 1.6e-14. Only the kink of
#: total internal reflection (k = 0, eta < 1, not a conductor: eta = 1/1.5 misses by 1e-2)
#: converges slowly.
FRESNEL_AVERAGE_ORDER = 32


def schlick(cos, f0, f90=1.0):
    """Schlick (1994, eq. 24) approximation ``F0 + (F90 - F0)(1 - cos)^5``.

    ``cos`` is clamped to [0, 1]. ``f90 = 1`` is the physical value; other values are the
    artistic extension of Burley (2012). Exact at cos = 1 and (for f90 = 1) at cos = 0.
    """
    c = jnp.clip(cos, 0.0, 1.0)
    return f0 + (f90 - f0) * pow5(1.0 - c)


def dielectric(cos_i, eta):
    """Exact unpolarised Fresnel reflectance of a smooth dielectric interface.

    ``eta = eta_t / eta_i`` is the relative index of the medium *below* the surface (the side the
    normal points away from). ``cos_i < 0`` means the light arrives from inside; then the interface
    is seen with relative index ``1/eta`` and total internal reflection gives exactly 1.

    Formula: Born & Wolf section 1.5.2 with Snell's law ``sin_t = sin_i / eta``::

        r_par  = (eta c - cos_t)/(eta c + cos_t),   r_perp = (c - eta cos_t)/(c + eta cos_t)
        F      = (r_par^2 + r_perp^2)/2,            F = 1 when sin_t^2 >= 1 (TIR)
    """
    c = jnp.clip(cos_i, -1.0, 1.0)
    inside = c < 0
    eta = jnp.where(inside, 1.0 / eta, eta)
    c = jnp.abs(c)
    # cos_t^2 = 1 - (1 - c^2)/eta^2 written as ((eta - 1)(eta + 1) + c^2)/eta^2: no cancellation
    # of 1 - c^2 in float32 at grazing (where 1 - c^2 rounds to 1 for c < 3e-4)
    cos2_t = ((eta - 1.0) * (eta + 1.0) + c * c) / (eta * eta)
    tir = cos2_t <= 0.0
    cos_t = safe_sqrt(cos2_t)  # gradient-safe at the critical angle
    r_par = safe_div(eta * c - cos_t, eta * c + cos_t)
    r_perp = safe_div(c - eta * cos_t, c + eta * cos_t)
    F = 0.5 * (r_par * r_par + r_perp * r_perp)
    # cos_t = c = 0 (grazing at eta = 1) is the limit F -> 1, like TIR.
    degenerate = (eta * c + cos_t) <= 0
    return jnp.where(tir | degenerate, 1.0, F)


@jax.custom_jvp
def conductor(cos_i, eta, k):
    """Exact unpolarised Fresnel reflectance of a conductor with complex index ``eta + i k``.

    In float32 (and narrower) the value is :func:`_conductor_fast` (2 square roots and 3
    divisions per channel instead of 3 and 5 plus a ``hypot``: evaluation throughput, issue 15);
    in float64 it is :func:`_conductor_careful`, bit for bit the value it always had (the stored
    gold default is a float64 Levenberg-Marquardt fit through this function whose relative-cost
    stop, 1e-14, turns 1e-16 changes of the value into 7e-9 changes of the fitted eta). The two
    agree to ~1e-15 relative in float64 (tests/core/test_fresnel.py). Derivatives, in every
    dtype, are those of :func:`_conductor_careful` (custom JVP): the guarded formulas whose
    gradients stay finite at grazing, eta = 1, k = 0 and k = 100 in float32.
    """
    if jnp.result_type(cos_i, eta, k) == jnp.float64:
        return _conductor_careful(cos_i, eta, k)
    return _conductor_fast(cos_i, eta, k)


def _conductor_fast(cos_i, eta, k):
    """The value of :func:`conductor` in float32: exact unpolarised conductor reflectance.

    Light arrives from outside (``cos_i`` is clamped to [0, 1]). The real-arithmetic form of
    Moeller (1988) (no complex dtype, differentiable in eta and k), with ``a + i b`` the complex
    cosine of refraction times the index::

        s2 = 1 - c^2,  t0 = eta^2 - k^2 - s2,  a2b2 = a^2 + b^2 = sqrt(t0^2 + 4 eta^2 k^2)
        a^2 - b^2 = t0,  a^2 b^2 = eta^2 k^2
        Rs = ((a - c)^2 + b^2)/((a + c)^2 + b^2)
        Rp = Rs ((a c - s2)^2 + b^2 c^2)/((a c + s2)^2 + b^2 c^2),   F = (Rs + Rp)/2

    2 square roots and 3 divisions per channel. ``u = (a2b2 + |t0|)/2`` is ``a^2`` for
    ``t0 >= 0`` and ``b^2`` otherwise; the other one is ``eta^2 k^2/u`` (no cancellation of
    ``a2b2 - |t0|`` for large k or small ``eta k``). ``a - c = (a^2 - c^2)/(a + c)`` with
    ``a^2 - c^2 = b^2 + eta^2 - 1 - k^2`` for ``t0 >= 0`` (exactly 0 at eta = 1, k = 0).
    ``Rs + Rp = Rs (Dp + Np)/Dp``: one division for both. Only single-where guards, no
    finite-gradient guarantees of its own: it is never differentiated (:func:`conductor`'s JVP
    is :func:`_conductor_careful`'s). Agrees with :func:`_conductor_careful` to ~1e-15
    relative in float64 (1e-10 at eta = 1, k = 1e-3, where the careful form's
    ``a2b2 - a^2`` cancels and this one is the accurate one).
    """
    c = jnp.clip(cos_i, 0.0, 1.0)
    c2 = c * c
    s2 = 1.0 - c2
    em1 = (eta - 1.0) * (eta + 1.0)  # eta^2 - 1, exact near eta = 1
    kk = k * k
    ek2 = (eta * k) ** 2  # a^2 b^2
    t0 = em1 + c2 - kk  # = eta^2 - k^2 - s2 without cancelling 1 - c^2 (float32 at grazing)
    at0 = jnp.abs(t0)
    # sqrt(t0^2 + 4 eta^2 k^2); |t0| exactly where eta k = 0 (t0^2 underflows for tiny t0)
    a2b2 = jnp.where(ek2 > 0, jnp.sqrt(t0 * t0 + 4.0 * ek2), at0)
    u = 0.5 * (a2b2 + at0)
    v = ek2 / jnp.where(u > 0, u, 1.0)
    pos = t0 >= 0
    a2 = jnp.where(pos, u, v)
    b2 = jnp.where(pos, v, u)
    a = jnp.sqrt(a2)
    a2mc2 = jnp.where(pos, b2 + (em1 - kk), a2 - c2)  # a^2 - c^2
    apc = a + c
    den_s = apc * apc + b2
    amc = a2mc2 / jnp.where(apc > 0, apc, 1.0)  # a - c
    ac = a * c
    b2c2 = b2 * c2
    num_p = (ac - s2) ** 2 + b2c2  # sums of squares: never negative
    den_p = (ac + s2) ** 2 + b2c2
    num = (amc * amc + b2) * (den_p + num_p)
    den = den_s * den_p
    F = 0.5 * num / jnp.where(den > 0, den, 1.0)
    # den_s = 0 only for eta = 1, k = 0 at exact grazing: the limit there is 1.
    return jnp.where(den_s > 0, F, 1.0)


@conductor.defjvp
def _conductor_jvp(primals, tangents):
    return jax.jvp(_conductor_careful, primals, tangents)


def _conductor_careful(cos_i, eta, k):
    """The conductor reflectance written for its derivatives (every division and square root
    guarded by the double-where idiom): :func:`conductor`'s JVP is this function's.

    Exact unpolarised Fresnel reflectance of a conductor with complex index ``eta + i k``.

    Light arrives from outside (``cos_i`` is clamped to [0, 1]). The real-arithmetic form of
    Moeller (1988) is used (no complex dtype, differentiable in eta and k)::

        s2 = 1 - c^2,  t0 = eta^2 - k^2 - s2,  a2b2 = sqrt(t0^2 + 4 eta^2 k^2),  a^2 = (a2b2 + t0)/2
        Rs = (a2b2 + c^2 - 2 a c)/(a2b2 + c^2 + 2 a c)
        Rp = Rs (a2b2 c^2 + s2^2 - 2 a c s2)/(a2b2 c^2 + s2^2 + 2 a c s2),   F = (Rs + Rp)/2

    For large k, ``t0`` is large and negative and ``a2b2 + t0`` cancels catastrophically; there we
    use the algebraically equal ``a^2 = 2 eta^2 k^2/(a2b2 - t0)`` (robust to k = 100 and beyond in
    float32). With ``k = 0`` this equals :func:`dielectric` for light from outside.
    """
    c = jnp.clip(cos_i, 0.0, 1.0)
    c2 = c * c
    s2 = 1.0 - c2
    em1 = (eta - 1.0) * (eta + 1.0)  # eta^2 - 1, exact near eta = 1
    kk = k * k
    t0 = em1 + c2 - kk  # = eta^2 - k^2 - s2 without cancelling 1 - c^2 (float32 at grazing)
    a2b2 = safe_hypot(t0, 2.0 * eta * k)  # sqrt(t0^2 + 4 eta^2 k^2), gradient bounded by 1
    pos = t0 >= 0
    t0p = jnp.where(pos, t0, 0.0)
    t0n = jnp.where(pos, 0.0, t0)
    # a^2 = (a2b2 + t0)/2; for t0 < 0 the equal 2 eta^2 k^2/(a2b2 - t0) avoids cancellation
    a2 = jnp.where(pos, 0.5 * (a2b2 + t0p), safe_div(2.0 * eta * eta * kk, a2b2 - t0n))
    a = safe_sqrt(a2)
    b2 = jnp.maximum(a2b2 - a2, 0.0)
    # a - c = (a^2 - c^2)/(a + c), with a^2 - c^2 = (a2b2 - t0)/2 + eta^2 - 1 - k^2 for t0 >= 0:
    # both exact where the reflectance vanishes (eta = 1, k = 0), so F keeps its zero and its
    # zero derivative there without huge intermediate terms (which overflow float32 gradients
    # at cos = 1e-7, where F ~ (eta - 1)^2/(4 cos^4))
    a2mc2 = jnp.where(pos, 0.5 * (a2b2 - t0p) + em1 - kk, a2 - c2)
    amc = safe_div(a2mc2, a + c)
    # numerators as sums of squares, (a - c)^2 + b^2 = a2b2 + c^2 - 2ac and
    # (ac - s2)^2 + b^2 c^2 = a2b2 c^2 + s2^2 - 2ac s2: never negative
    den_s = (a + c) ** 2 + b2
    Rs = safe_div(amc * amc + b2, den_s)
    Rp = Rs * safe_div((a * c - s2) ** 2 + b2 * c2, (a * c + s2) ** 2 + b2 * c2)
    F = 0.5 * (Rs + Rp)
    # den_s = 0 only for eta = 1, k = 0 at exact grazing: the limit there is 1.
    return jnp.where(den_s > 0, F, 1.0)


def f0_from_ior(eta, k=0.0):
    """Normal-incidence reflectance ``((eta - 1)^2 + k^2)/((eta + 1)^2 + k^2)`` (exact F at
    cos = 1)."""
    return ((eta - 1.0) ** 2 + k * k) / ((eta + 1.0) ** 2 + k * k)


def ior_from_f0(f0):
    """Dielectric index with normal-incidence reflectance ``f0`` (inverse of :func:`f0_from_ior`
    with k = 0, the branch eta >= 1): ``(1 + sqrt(f0))/(1 - sqrt(f0))``, as Cook & Torrance 1982."""
    s = jnp.sqrt(f0)
    return (1.0 + s) / (1.0 - s)


class AbstractFresnel(eqx.Module):
    """The Fresnel part of a microfacet model or of a mirror: ``F(cos)`` with ``cos`` the cosine
    on the (micro)facet (abstract; the concrete parts below are final)."""

    @abc.abstractmethod
    def __call__(self, cos):
        """Reflectance at ``cos`` (broadcast against the parameters' channel axis)."""

    @abc.abstractmethod
    def reflectance_hint(self):
        """Largest normal-incidence reflectance over channels (mixtures pick lobes with it)."""

    def average(self):
        """The cosine-weighted hemispherical average ``F_avg = 2 Int_0^1 F(mu) mu dmu`` (per
        channel): :func:`fresnel_average` by default, closed forms where they exist."""
        return fresnel_average(self)


class SchlickFresnel(AbstractFresnel):
    """Schlick's approximation as a microfacet-model component. ``f0`` may be RGB."""

    f0: Channels = bounded(0.04, lo=0.0, hi=1.0, channels=True)
    f90: Scalar = bounded(1.0, lo=0.0, hi=1.0)

    def __call__(self, cos):
        return schlick(cos, self.f0, self.f90)

    def reflectance_hint(self):
        return jnp.max(jnp.asarray(self.f0))

    def average(self):
        """``F0 + (F90 - F0)/21``: ``2 Int_0^1 (1 - mu)^5 mu dmu = 2 B(2, 6) = 2 (1! 5!/7!) =
        1/21``, so for ``F90 = 1`` it is ``(20 F0 + 1)/21`` (Kulla & Conty 2017)."""
        return self.f0 + (self.f90 - self.f0) / 21.0


class DielectricFresnel(AbstractFresnel):
    """Exact dielectric Fresnel (:func:`dielectric`) with relative index ``eta``."""

    eta: Channels = bounded(1.5, lo=0.0, lo_open=True, channels=True)

    def __call__(self, cos):
        return dielectric(cos, self.eta)

    def reflectance_hint(self):
        return jnp.max(f0_from_ior(jnp.asarray(self.eta)))


class ConductorFresnel(AbstractFresnel):
    """Exact conductor Fresnel (:func:`conductor`) with complex index ``eta + i k``.

    ``eta`` and ``k`` may be RGB triples (effective values, see :mod:`brdf_fit.spectra`) or
    spectral vectors (channels = wavelengths). A tabulated metal:
    :func:`brdf_fit.core.spectra.conductor_fresnel` (``conductor_fresnel("Cu")``).
    """

    eta: Channels = bounded(0.2, lo=0.0, lo_open=True, channels=True)
    k: Channels = bounded(3.0, lo=0.0, channels=True)

    def __call__(self, cos):
        return conductor(cos, self.eta, self.k)

    def reflectance_hint(self):
        return jnp.max(f0_from_ior(jnp.asarray(self.eta), jnp.asarray(self.k)))


class ConstantFresnel(AbstractFresnel):
    """F = ``value`` for every angle (``value = 1`` for white-furnace tests)."""

    value: Channels = bounded(1.0, lo=0.0, hi=1.0, channels=True)

    def __call__(self, cos):
        return jnp.asarray(self.value) + 0.0 * cos

    def reflectance_hint(self):
        return jnp.max(jnp.asarray(self.value))

    def average(self):
        return jnp.asarray(self.value)


def fresnel_average(fresnel) -> jnp.ndarray:
    """``F_avg = 2 Int_0^1 F(mu) mu dmu`` of a Fresnel part (any callable of ``cos``), by
    Gauss-Legendre of order :data:`FRESNEL_AVERAGE_ORDER` in ``mu`` on (0, 1); shape of the
    part's channels. Differentiable in the part's parameters."""
    x, w = np.polynomial.legendre.leggauss(FRESNEL_AVERAGE_ORDER)
    dts = [jnp.asarray(v).dtype for v in jax.tree_util.tree_leaves(fresnel)]
    dts = [d for d in dts if jnp.issubdtype(d, jnp.floating)]
    dt = dts[0] if dts else jnp.zeros(()).dtype
    mu = jnp.asarray(0.5 * (x + 1.0), dt)
    wmu = jnp.asarray(0.5 * w, dt) * mu
    channels = jnp.ndim(fresnel(mu[0]))  # 0, or 1 with a trailing channel axis
    F = fresnel(mu[:, None] if channels else mu)
    return 2.0 * jnp.tensordot(wmu, F, axes=1)
