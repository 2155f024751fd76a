"""Ashikhmin-Shirley anisotropic Phong BRDF (M. Ashikhmin, P. Shirley, "An anisotropic Phong BRDF
model", Journal of Graphics Tools 5(2):25-32, 2000; tech. report UUCS-00-014; models.md 4.23,
2.5.9).

Notation (local frame, ``n = z``, ``t = x``, ``b = y``): ``h = normalize(wi + wo)``,
``d = wi.h = wo.h``, ``cl = n.wi``, ``cv = n.wo``. The paper's formulas (its eqs. 4, 5, 6-10):

* specular (eq. 4)::

      f_s = sqrt((nu+1)(nv+1))/(8 pi) (n.h)^e(h) / (d max(cl, cv)) F(d),
      e(h) = (nu (h.t)^2 + nv (h.b)^2) / (1 - (n.h)^2)   (= nu cos^2 phi_h + nv sin^2 phi_h),
      F(d) = Rs + (1 - Rs)(1 - d)^5                      (Schlick's approximation, eq. 5's F)

* coupled diffuse (eq. 5)::

      f_d = 28 Rd/(23 pi) (1 - Rs) (1 - (1 - cl/2)^5)(1 - (1 - cv/2)^5)

  The constant 28/23 makes ``2 Int_0^1 (1 - (1 - mu/2)^5) mu dmu = 23/28`` cancel, so the diffuse
  albedo is ``Rd (1 - Rs)(1 - (1 - cv/2)^5) <= (31/32) Rd (1 - Rs)`` (measured in
  tests/test_ashikhmin_shirley.py).

* half-vector sampler (section 3, eqs. 9, 10): in the first quadrant
  ``phi = atan(sqrt((nu+1)/(nv+1)) tan(pi xi1/2))``, ``cos(theta_h) = (1 - xi2)^(1/(e+1))`` with
  ``e = nu cos^2 phi + nv sin^2 phi``; mirrored to the four quadrants. Its density over ``h`` is
  exactly ``p_h = sqrt((nu+1)(nv+1))/(2 pi) (n.h)^e(h)`` (the azimuth density of eq. 9 is
  ``sqrt((nu+1)(nv+1))/(2 pi (e+1))`` and the zenith density ``(e+1) cos^e``), and
  ``p(wi | wo) = p_h / (4 d)`` (the paper's ``p(k2)``, eq. 8, with the ``1/(4 k.h)`` Jacobian).
  ``f_s cl / p = F(d) cl / max(cl, cv)`` is nearly constant (paper, section 3).

Implementation notes (the paper and the public implementations agree on the formulas; they differ
in guards only):

* ``(n.h)^e`` is computed as ``exp(e log(n.h))`` with ``e log(n.h) = (nu hx^2 + nv hy^2)
  log1p(-q)/(2 q)``, ``q = hx^2 + hy^2 = 1 - (n.h)^2``: the 0/0 of ``e(h)`` at ``h = n`` (BBM
  ``ashikhminshirley.h`` selects 0 there, wdas/brdf divides by ``1 - (n.h)^2`` unguarded) becomes
  the smooth factor ``log1p(-q)/q -> -1``, evaluated by its series below :data:`Q_SERIES` (the
  quotient's derivative cancels catastrophically for small q). Values and gradients in nu, nv
  and both directions are then finite everywhere, exponents up to 1e5 included.
* wdas/brdf ``ashikhman_shirley.brdf`` and shrimp evaluate F at ``k.h`` (= ``d``) like the paper;
  shrimp's ``anisophongspec`` variant evaluates it at ``n.v``, which is not the paper's model.
* Sampling mixes the paper's half-vector sampler with cosine-weighted sampling for ``f_d`` (lobe
  probability ``p_d = max Rd(1 - Rs) / (max Rd(1 - Rs) + max Rs)``); ``pdf`` is the exact mixture
  ``p_d cl/pi + (1 - p_d) p_h/(4 d)``. A specular sample fails (pdf 0, weight 0) when ``wi`` is
  below the horizon or ``wo.h <= 0``.
* Quadrature hint: a half-vector lobe of Beckmann widths ``alpha_x = sqrt(2/(nu+2))``,
  ``alpha_y = sqrt(2/(nv+2))``: ``cos^e(theta_h) ~ exp(-tan^2(theta_h) (nu cos^2 phi +
  nv sin^2 phi)/2)`` near the peak, i.e. the Blinn-Phong -> Beckmann map of Walter et al. 2007
  (sec. 5.2) applied per axis. The rule is adapted to the lobe, not exact for it.
"""

from __future__ import annotations

import math
from typing import ClassVar

import equinox as eqx
import jax.numpy as jnp

from brdf_fit.core.frame import join
from brdf_fit.core.numerics import INV_PI, pow5, safe_sqrt
from brdf_fit.core.params import Channels, Entry, Param, Scalar, bounded
from brdf_fit.core.validate import check_param, check_scalar
from brdf_fit.models._base import AbstractBRDF, QuadratureLobe, expand_channels
from brdf_fit.models._lobes import (
    half_angles,
    lobe_probability,
    max_over_channels,
    sample_diffuse_or_half,
)

__all__ = ["AshikhminShirley", "registry_entries"]

#: ``q = 1 - (n.h)^2`` below which ``log1p(-q)/q`` is replaced by its series
#: ``-(1 + q/2 + q^2/3 + q^3/4 + q^4/5)`` (truncation error q^5/6 = 1.7e-16 at q = 1e-3); above
#: it the quotient's round-off in the derivative is ~eps/q (1e-13 in float64).
Q_SERIES = 1e-3
#: Diffuse normalisation of eq. 5: 28/(23 pi).
DIFFUSE_NORM = 28.0 / (23.0 * math.pi)

_REFERENCE = (
    "M. Ashikhmin, P. Shirley, An anisotropic Phong BRDF model, Journal of Graphics Tools "
    "5(2):25-32, 2000 (eqs. 4, 5; sampling eqs. 9, 10)"
)


def _log1p_neg_over(q):
    """``log1p(-q)/q`` for ``q`` in [0, 1) (-1 at q = 0), with a series below :data:`Q_SERIES`
    and finite value and gradient everywhere (q -> 1 gives -inf only for q == 1, masked by the
    caller)."""
    small = q < Q_SERIES
    qs = jnp.where(small, 0.5, q)
    big = jnp.log1p(-qs) / qs
    ser = -(1.0 + q * (0.5 + q * (1.0 / 3.0 + q * (0.25 + q * 0.2))))
    return jnp.where(small, ser, big)


def _lobe_log(hx, hy, nu, nv, hz=None):
    """``log((n.h)^e(h)) = (nu hx^2 + nv hy^2) log1p(-q)/(2 q)`` with ``q = hx^2 + hy^2``; the
    caller guarantees n.h > 0; q is clamped below 1 (round-off at grazing half vectors).

    With ``hz = n.h`` given, ``log1p(-q)`` is replaced by ``2 log(hz)`` for ``q >= 1/2``: at a
    grazing half vector ``1 - q = hz^2`` is far below the rounding of ``q`` (float32:
    ``hz = 1e-3`` left ``1 - q`` with 6% error, 2.4e-3 of the value at nu = 0.1), while ``hz``
    itself is accurate; below 1/2 ``log1p(-q)`` is the accurate one (``hz`` rounds to 1 for
    ``q < eps``)."""
    q = hx * hx + hy * hy
    # n.h > 0 but q may round to 1 at grazing half vectors: keep log1p(-q) finite
    q = jnp.minimum(q, 1.0 - jnp.finfo(jnp.result_type(q)).eps)
    ratio = _log1p_neg_over(q)
    if hz is not None:
        far = q >= 0.5
        ratio = jnp.where(far, 2.0 * jnp.log(jnp.where(far, hz, 1.0)) / jnp.where(far, q, 1.0),
                          ratio)
    return 0.5 * (nu * hx * hx + nv * hy * hy) * ratio


def _check_exponent(name, value, owner):
    check_param(name, value, lo=0.0, owner=owner)
    check_scalar(name, value, owner)


class AshikhminShirley(AbstractBRDF):
    """Ashikhmin & Shirley (2000) anisotropic Phong BRDF: ``f = f_s + f_d`` (see the module
    docstring for the formulas and their sources).

    Parameters: ``Rs`` specular reflectance at normal incidence and ``Rd`` diffuse reflectance
    (both in [0, 1], may carry channels); ``nu``, ``nv`` >= 0 the Phong-like exponents along the
    tangent ``x`` and the bitangent ``y`` (scalars). ``diffuse=False`` drops ``f_d`` (the
    specular term alone, sampled by the half-vector sampler only).

    Reciprocal (every factor is symmetric in ``wi``, ``wo``). Not exactly energy conserving:
    ``f_s`` uses Neumann's ``1/max(cl, cv)`` in place of masking; ``Rd`` is designed so that
    ``f_d`` adds at most ``Rd (1 - Rs)`` to the albedo.
    """

    #: the checks look at three view azimuths (brdf_fit.checks._views)
    anisotropic: ClassVar[bool] = True

    Rs: Channels = bounded(0.05, lo=0.0, hi=1.0, channels=True)
    Rd: Channels = bounded(0.5, lo=0.0, hi=1.0, channels=True)
    nu: Scalar = bounded(100.0, lo=0.0, hi=1e5)
    nv: Scalar = bounded(100.0, lo=0.0, hi=1e5)
    diffuse: bool = eqx.field(static=True, default=True)

    def __check_init__(self):
        owner = "AshikhminShirley"
        check_param("Rs", self.Rs, lo=0.0, hi=1.0, owner=owner)
        check_param("Rd", self.Rd, lo=0.0, hi=1.0, owner=owner)
        _check_exponent("nu", self.nu, owner)
        _check_exponent("nv", self.nv, owner)

    # ------------------------------------------------------------------ pieces

    def _norm(self):
        return jnp.sqrt((self.nu + 1.0) * (self.nv + 1.0))

    def _p_d(self):
        if not self.diffuse:
            return jnp.asarray(0.0)
        hd = max_over_channels(self.Rd * (1.0 - jnp.asarray(self.Rs)))
        return lobe_probability(hd, max_over_channels(self.Rs))

    @staticmethod
    def _geometry(wi, wo):
        """Sanitised half-vector quantities ``(ok, hx, hy, d, cl, cv, hz)``
        (:func:`~brdf_fit.models._lobes.half_angles`; ``d = wi.h``)."""
        ok, hx, hy, hz, d, cl, cv = half_angles(wi, wo)
        return ok, hx, hy, d, cl, cv, hz

    def _spec_hpdf(self, hx, hy, hz=None):
        """``p_h(h) = sqrt((nu+1)(nv+1))/(2 pi) (n.h)^e(h)`` (the paper's eq. 6 density of h)."""
        return self._norm() * (0.5 * INV_PI) * jnp.exp(_lobe_log(hx, hy, self.nu, self.nv, hz))

    # ------------------------------------------------------------------ interface

    def eval(self, wi, wo):
        ok, hx, hy, d, cl, cv, hz = self._geometry(wi, wo)
        ch = self.channels()
        ph = self._spec_hpdf(hx, hy, hz)
        # f_s = p_h F / (4 d max(cl, cv)): the 1/(8 pi) of eq. 4 is 1/(2 pi) x 1/4
        spec = ph / (4.0 * d * jnp.maximum(cl, cv))
        F = self.Rs + (1.0 - self.Rs) * expand_channels(pow5(1.0 - jnp.clip(d, 0.0, 1.0)), ch)
        val = F * expand_channels(spec, ch)
        if self.diffuse:
            g = (1.0 - pow5(1.0 - 0.5 * cl)) * (1.0 - pow5(1.0 - 0.5 * cv))
            val = val + DIFFUSE_NORM * self.Rd * (1.0 - self.Rs) * expand_channels(g, ch)
        return jnp.where(expand_channels(ok, ch), val, 0.0)

    def pdf(self, wi, wo):
        ok, hx, hy, d, cl, _, hz = self._geometry(wi, wo)
        p_d = self._p_d()
        spec = self._spec_hpdf(hx, hy, hz) / (4.0 * d)
        return jnp.where(ok, p_d * cl * INV_PI + (1.0 - p_d) * spec, 0.0)

    def _sample_h(self, u):
        """The paper's eqs. 9, 10, mirrored to four quadrants by ``u0``; returns ``h`` (..., 3).

        ``tan(phi) = a tan(beta)``, ``a = sqrt((nu+1)/(nv+1))``, ``beta = pi xi1/2`` is written
        as ``cos(phi) = cos(beta)/s``, ``sin(phi) = a sin(beta)/s``, ``s = |(cos beta,
        a sin beta)|`` (no tangent, so xi1 -> 1 is harmless)."""
        u0 = 4.0 * u[..., 0]
        quadrant = jnp.clip(jnp.floor(u0), 0.0, 3.0)
        xi1 = jnp.clip(u0 - quadrant, 0.0, 1.0)
        beta = 0.5 * math.pi * xi1
        a = jnp.sqrt((self.nu + 1.0) / (self.nv + 1.0))
        cb, sb = jnp.cos(beta), a * jnp.sin(beta)
        s = jnp.sqrt(cb * cb + sb * sb)
        cphi, sphi = cb / s, sb / s
        # quadrants 1..3: (-c, s), (-c, -s), (c, -s)
        cphi = jnp.where((quadrant == 1) | (quadrant == 2), -cphi, cphi)
        sphi = jnp.where(quadrant >= 2, -sphi, sphi)
        e = self.nu * cphi * cphi + self.nv * sphi * sphi
        u1 = u[..., 1]
        # cos(theta_h) = (1 - u1)^(1/(e+1)); 1 - cos from expm1 keeps narrow lobes' width
        one_minus = -jnp.expm1(jnp.log1p(-u1) / (e + 1.0))
        z = 1.0 - one_minus
        r = safe_sqrt(one_minus * (2.0 - one_minus))
        return join(r * cphi, r * sphi, z)

    def sample(self, wo, uc, u):
        p_d = self._p_d() if self.diffuse else None
        return sample_diffuse_or_half(self, wo, uc, u, self._sample_h(u), p_d)

    def quadrature_lobe(self) -> QuadratureLobe:
        """Quadrature hint (:func:`brdf_fit.verify.albedo.lobe_rule`): a half-vector lobe of
        Beckmann widths ``(sqrt(2/(nu+2)), sqrt(2/(nv+2)))`` (see the module docstring)."""
        ax = jnp.sqrt(2.0 / (jnp.asarray(self.nu) + 2.0))
        ay = jnp.sqrt(2.0 / (jnp.asarray(self.nv) + 2.0))
        return QuadratureLobe("half", (ax, ay))

    def selection_hint(self):
        hs = max_over_channels(self.Rs)
        if not self.diffuse:
            return hs
        return hs + max_over_channels(self.Rd * (1.0 - jnp.asarray(self.Rs)))


# ----------------------------------------------------------------------------- registry entries

#: measured with brdf_fit.checks.run_checks at the defaults (float64); see the test file
_FAILURES: dict[str, str] = {}
_SPEC_FAILURES: dict[str, str] = {}


def registry_entries():
    """:class:`brdf_fit.registry.Entry` objects of this module (registered by the registry)."""
    def unit(name, default, doc):
        return Param(name, default, lo=0.0, hi=1.0, channels=True, doc=doc)

    def expo(name, default, axis):
        return Param(name, default, lo=0.0, hi=1e5,
                     doc=f"Phong-like exponent along the {axis} (lobe sharpness)")

    return [
        Entry(
            name="ashikhmin-shirley",
            builder=lambda Rs, Rd, nu, nv: AshikhminShirley(Rs=Rs, Rd=Rd, nu=nu, nv=nv),
            params=(unit("Rs", (0.25, 0.2, 0.15), "specular reflectance at normal incidence"),
                    unit("Rd", (0.6, 0.4, 0.3), "diffuse reflectance"),
                    expo("nu", 20.0, "tangent x"), expo("nv", 200.0, "bitangent y")),
            reference=_REFERENCE,
            description=(
                "anisotropic Phong: sqrt((nu+1)(nv+1))/(8 pi) (n.h)^e F/(h.l max(cl, cv)) + "
                "28 Rd/(23 pi) (1-Rs)(1-(1-cl/2)^5)(1-(1-cv/2)^5)"
            ),
            aliases=("as", "anisotropic-phong"),
            expected_failures=_FAILURES,
            tags=("anisotropic",),
            year=2000,
            catalogue="Ashikhmin-Shirley",
            sampler="exact half-vector (paper eqs. 9-10) + cosine mixture (exact pdf)",
        ),
        Entry(
            name="ashikhmin-shirley-specular",
            builder=lambda Rs, nu, nv: AshikhminShirley(Rs=Rs, Rd=0.0, nu=nu, nv=nv,
                                                        diffuse=False),
            params=(unit("Rs", (0.9, 0.7, 0.5), "specular reflectance at normal incidence"),
                    expo("nu", 20.0, "tangent x"), expo("nv", 200.0, "bitangent y")),
            reference=_REFERENCE + " (specular term, eq. 4, alone)",
            description="the Ashikhmin-Shirley specular lobe alone (eq. 4), Schlick Fresnel",
            expected_failures=_SPEC_FAILURES,
            tags=("anisotropic",),
            year=2000,
            catalogue=None,
            sampler="exact half-vector (paper eqs. 9-10)",
        ),
    ]
