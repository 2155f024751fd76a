"""Microfacet normal distributions, masking-shadowing terms and their samplers.

Normal distributions ``D`` are normalised on projected area, ``Int_H D(m) (n.m) dw_m = 1``, and
written in Cartesian form (no azimuth angle), so normal incidence has no 0/0 under ``jax.grad``.
Anisotropic roughness ``(alpha_x, alpha_y)``: ``alpha_x`` is the width along the tangent x.

Masking is expressed through one division-free per-direction quantity,

    P(w) = (n.w) (1 + 2 Lambda(w)),

from which every Smith term follows without dividing by a cosine:

    G1(w) = 2 (n.w) / ((n.w) + P(w))
    V_separable        = G1(wi) G1(wo) / (4 ci co) = 1 / ((ci + P(wi)) (co + P(wo)))
    V_height_correlated = G2 / (4 ci co)           = 1 / (2 (co P(wi) + ci P(wo)))

with ``G2 = 1/(1 + Lambda(wi) + Lambda(wo))`` (Heitz 2014, eq. 99). For GGX,
``P = sqrt(alpha_x^2 x^2 + alpha_y^2 y^2 + z^2)``; for Beckmann ``P = z erf(a) + sqrt(B/pi)
exp(-a^2)`` with ``B = alpha_x^2 x^2 + alpha_y^2 y^2`` and ``a = z/sqrt(B)``.

References
----------
- P. Beckmann, A. Spizzichino, "The Scattering of Electromagnetic Waves from Rough Surfaces", 1963.
- T. S. Trowbridge, K. P. Reitz, "Average irregularity representation of a rough surface for
  ray reflection", JOSA 65(5), 1975.
- B. Walter, S. Marschner, H. Li, K. Torrance, "Microfacet models for refraction through rough
  surfaces", EGSR 2007: GGX (eq. 33), Beckmann (eq. 25), rational Beckmann G1 (eq. 27),
  Blinn-Phong exponent/Beckmann mapping (section 5.2).
- E. Heitz, "Understanding the masking-shadowing function in microfacet-based BRDFs", JCGT 3(2),
  2014: anisotropic D and Lambda (eqs. 80-86), height-correlated G2 (eq. 99), V-cavity G1.
- E. Heitz, E. d'Eon, "Importance sampling microfacet-based BSDFs using the distribution of
  visible normals", CGF 33(4), 2014: visible-normal sampling (Beckmann slopes), V-cavity sampling.
- J. Dupuy, A. Benyoub, "Sampling visible GGX normals with spherical caps", CGF 42(8), 2023.
- K. E. Torrance, E. M. Sparrow, "Theory for off-specular reflection from roughened surfaces",
  JOSA 57(9), 1967; J. F. Blinn, "Models of light reflection for computer synthesized pictures",
  SIGGRAPH 1977 (V-groove masking in vector form).
"""

from __future__ import annotations

import abc
import math
from typing import ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
from jax.scipy.special import erf, erfc, erfinv

from brdf_fit.core.numerics import (
    ALPHA_MIN,
    safe_div,
    safe_normalize3,
    safe_pow,
    safe_rsqrt,
    safe_sqrt,
)
from brdf_fit.core.params import Scalar, bounded
from brdf_fit.core.validate import check_param

__all__ = [
    "AbstractDistribution",
    "AbstractMasking",
    "GGX",
    "Beckmann",
    "BlinnPhongNDF",
    "SmithSeparable",
    "SmithHeightCorrelated",
    "SchlickSmithKaris",
    "VCavity",
    "reflect_about",
]

PI = math.pi
SQRT_PI = math.sqrt(math.pi)
INV_SQRT_PI = 1.0 / SQRT_PI

#: Exponent below which ``exp`` underflows to exactly 0 even in float64 (``exp(-745.2)`` is the
#: smallest denormal); used to cut the Beckmann tails without producing ``0 * inf``.
EXP_UNDERFLOW = -745.0
#: Uniforms fed to ``erfinv`` are kept in [U_EPS, 1 - U_EPS]: ``erfinv(+-1)`` is infinite. This
#: drops a tail of probability 1e-6 of the Beckmann slope distribution (as Mitsuba 3 does).
U_EPS = 1e-6
#: Beckmann visible-slope inversion: number of safeguarded Newton iterations (fixed trip count for
#: ``jit``). A rejected Newton step halves the bracket; Newton converges quadratically near the
#: root. With the closed-bracket safeguard, 12 iterations agree with an independent bisection
#: to 1e-12 in ``m`` (tests/core/test_inversions.py; measured max 1e-13 on 20,000 random pairs,
#: alpha 0.05-1, grazing views included; the open-bracket safeguard left 12% above 1e-9).
BECKMANN_NEWTON_ITERS = 12


def reflect_about(wx, wy, wz, mx, my, mz):
    """Components of ``2 (w.m) m - w``."""
    d2 = 2.0 * (wx * mx + wy * my + wz * mz)
    return d2 * mx - wx, d2 * my - wy, d2 * mz - wz


def _check_widths(alpha_x, alpha_y):
    check_param("alpha_x", alpha_x, lo=0.0, lo_open=True)
    if alpha_y is not None:
        check_param("alpha_y", alpha_y, lo=0.0, lo_open=True)


def _widths(alpha_x, alpha_y):
    """``(alpha_x, alpha_y)`` as a distribution evaluates them: ``alpha_y = alpha_x`` when None,
    both clamped below at ``ALPHA_MIN`` (gradient 0 below the clamp)."""
    ay = alpha_x if alpha_y is None else alpha_y
    return jnp.maximum(alpha_x, ALPHA_MIN), jnp.maximum(ay, ALPHA_MIN)


class AbstractDistribution(eqx.Module):
    """A microfacet normal distribution ``D`` with its Smith masking quantity ``P`` and its
    samplers (abstract; every concrete distribution is final: compose, don't inherit).

    Methods take components ``(x, y, z)`` of unit vectors in the local frame.
    """

    #: whether :meth:`sample_visible` exists (else :class:`~brdf_fit.models.MicrofacetBRDF` draws
    #: ``m ~ D(m)(n.m)`` or, with V-cavity masking, the V-cavity visible normals)
    supports_visible: ClassVar[bool] = True

    @abc.abstractmethod
    def D(self, mx, my, mz):
        """The distribution of normals, normalised on projected area (0 for ``m.z <= 0``)."""

    @abc.abstractmethod
    def P(self, wx, wy, wz):
        """``(n.w)(1 + 2 Lambda(w))``, division-free (see the module docstring)."""

    @abc.abstractmethod
    def sample_normal(self, u1, u2):
        """Sample ``m ~ D(m)(n.m)`` from two uniforms; returns the components of ``m``."""

    @abc.abstractmethod
    def sample_visible(self, wx, wy, wz, u1, u2):
        """Sample the normals visible from ``w`` (density :meth:`pdf_visible`)."""

    @abc.abstractmethod
    def widths(self):
        """``(alpha_x, alpha_y)``: the Beckmann/GGX widths the lobe has (or is equivalent to), as
        evaluated (clamped below at ``ALPHA_MIN``); what the half-vector quadrature rule of
        :func:`brdf_fit.core.quadrature.halfvector_rule` is built for. May return tracers."""

    def is_anisotropic(self) -> bool:
        """Whether the distribution is given two widths (views at several azimuths needed)."""
        return False

    def D_half_sum(self, hx, hy, hz, l2):
        """``D(h/|h|)`` from the unnormalised half vector ``h = wi + wo`` and ``l2 = |h|^2 > 0``:
        what :class:`~brdf_fit.models.MicrofacetBRDF`'s float32 evaluation calls (issue 15).
        This default normalises ``h`` (a square root and a division per lane); a distribution
        whose ``D`` is written in ratios homogeneous in ``m`` overrides it without them."""
        inv = 1.0 / jnp.sqrt(l2)
        return self.D(hx * inv, hy * inv, hz * inv)

    def P_exact(self, wx, wy, wz):
        """``P`` with the exact Lambda (what the visible-normal sampler draws from)."""
        return self.P(wx, wy, wz)

    def Lambda(self, wx, wy, wz):
        """Smith's Lambda for a direction in the upper hemisphere (inf at exact grazing)."""
        return safe_div(self.P(wx, wy, wz) - wz, 2.0 * wz)

    def G1(self, wx, wy, wz):
        """Smith masking ``1/(1 + Lambda)`` (0 below the horizon)."""
        return jnp.where(wz > 0, safe_div(2.0 * wz, wz + self.P(wx, wy, wz)), 0.0)

    def pdf_normal(self, mx, my, mz):
        """Density of :meth:`sample_normal`: ``D(m) (n.m)`` per solid angle of ``m``."""
        return self.D(mx, my, mz) * jnp.maximum(mz, 0.0)

    def pdf_visible(self, wx, wy, wz, mx, my, mz):
        """Density of :meth:`sample_visible`: ``G1(w) max(0, w.m) D(m) / (n.w)`` (Heitz & d'Eon
        2014, eq. 2), written as ``2 max(0, w.m) D(m) / (z + P(w))``."""
        wm = wx * mx + wy * my + wz * mz
        return jnp.where(
            wz > 0,
            safe_div(
                2.0 * jnp.maximum(wm, 0.0) * self.D(mx, my, mz), wz + self.P_exact(wx, wy, wz)
            ),
            0.0,
        )


def _stretched_slopes_to_normal(sx, sy, ax, ay):
    """Microfacet normal of slopes ``(ax sx, ay sy)``: ``normalize(-ax sx, -ay sy, 1)``."""
    x, y, z, _ = safe_normalize3(-ax * sx, -ay * sy, jnp.ones_like(sx))
    return x, y, z


class GGX(AbstractDistribution):
    """Trowbridge-Reitz / GGX distribution (Trowbridge & Reitz 1975; Walter et al. 2007, eq. 33),
    anisotropic form of Heitz 2014 (eq. 85)::

        D(m) = 1 / (pi ax ay ((m.x/ax)^2 + (m.y/ay)^2 + (m.z)^2)^2)      for m.z > 0
        Lambda(w) = (-1 + sqrt(1 + (ax^2 x^2 + ay^2 y^2)/z^2)) / 2    (Heitz 2014, eq. 86)

    Visible normals are sampled with spherical caps (Dupuy & Benyoub 2023).
    """

    alpha_x: Scalar = bounded(0.5, lo=0.0, hi=1.0, lo_open=True)
    alpha_y: Scalar | None = bounded(None, lo=0.0, hi=1.0, lo_open=True)

    def __check_init__(self):
        _check_widths(self.alpha_x, self.alpha_y)

    def widths(self):
        return _widths(self.alpha_x, self.alpha_y)

    def is_anisotropic(self) -> bool:
        return self.alpha_y is not None

    def D(self, mx, my, mz):
        ax, ay = self.widths()
        # x/ax as x * (1/ax): the reciprocals are per-lobe scalars, a division per lane each
        # otherwise (LLVM may not rewrite x/a as x*(1/a) without fast-math); 1 ulp apart
        iax, iay = 1.0 / ax, 1.0 / ay
        s = (mx * iax) ** 2 + (my * iay) ** 2 + mz * mz
        return jnp.where(mz > 0, 1.0 / (PI * ax * ay * s * s), 0.0)

    def D_half_sum(self, hx, hy, hz, l2):
        """``D(h/|h|)`` without normalising ``h``: with ``q = (hx/ax)^2 + (hy/ay)^2 + hz^2`` (the
        ``s`` of :meth:`D` times ``|h|^2``), ``D = (l2/q)^2/(pi ax ay)``. The ratio ``l2/q`` of
        numbers of one magnitude (``1 <= q/l2 <= 1/min(ax, ay)^2``, widths <= 1) is formed before
        squaring, so neither ``l2^2`` nor ``q^2`` can underflow float32 at the grazing
        near-mirror pairs where ``l2`` is ~1e-20. One division per lane instead of a reciprocal
        square root and a division."""
        ax, ay = self.widths()
        iax, iay = 1.0 / ax, 1.0 / ay
        q = (hx * iax) ** 2 + (hy * iay) ** 2 + hz * hz
        r = l2 / jnp.where(hz > 0, q, 1.0)
        return jnp.where(hz > 0, r * r * (1.0 / (PI * ax * ay)), 0.0)

    def P(self, wx, wy, wz):
        ax, ay = self.widths()
        return jnp.sqrt((ax * wx) ** 2 + (ay * wy) ** 2 + wz * wz)

    def sample_normal(self, u1, u2):
        """Sample ``m ~ D(m)(n.m)``: isotropic unit-roughness slope radius
        ``r = sqrt(u1/(1-u1))`` (inverse CDF of the GGX slope distribution), uniform azimuth, then
        stretched by ``(ax, ay)`` (Heitz 2014, section 5.3: anisotropic NDFs are stretched ones)."""
        ax, ay = self.widths()
        r = safe_sqrt(safe_div(u1, 1.0 - u1))
        phi = 2.0 * PI * u2
        return _stretched_slopes_to_normal(r * jnp.cos(phi), r * jnp.sin(phi), ax, ay)

    def sample_visible(self, wx, wy, wz, u1, u2):
        """Visible normals by spherical caps (Dupuy & Benyoub 2023, listing 3): stretch ``w`` to
        the unit-roughness configuration, sample the spherical cap ``z in (-w.z, 1]`` uniformly,
        add ``w``, unstretch. Branch-free."""
        ax, ay = self.widths()
        sx, sy, sz, _ = safe_normalize3(ax * wx, ay * wy, wz)
        phi = 2.0 * PI * u1
        z = (1.0 - u2) * (1.0 + sz) - sz
        sin_t = safe_sqrt(1.0 - z * z)
        hx = sin_t * jnp.cos(phi) + sx
        hy = sin_t * jnp.sin(phi) + sy
        hz = z + sz
        x, y, zz, _ = safe_normalize3(ax * hx, ay * hy, hz)
        return x, y, zz


@jax.jit
def _beckmann_visible_newton(b, lo, hi, k, tan_t, target):
    """The bracketed Newton iteration of :meth:`Beckmann.sample_visible` on ``C(b) = target``
    (``BECKMANN_NEWTON_ITERS`` steps): its own compiled program, so that sampling outside jit does
    not trace and compile the loop on every call (measured: 0.5 s per eager ``sample`` of
    ``beckmann`` before, 2026-12-05); inside an enclosing jit it is inlined."""

    def body(_, state):
        b, lo, hi = state
        b_in = jnp.clip(b, -1.0 + 1e-12, 1.0 - 1e-12)
        s = erfinv(b_in)
        value = 1.0 + b_in + k * jnp.exp(-s * s) - target
        deriv = 1.0 - s * tan_t
        lo = jnp.where(value < 0, b_in, lo)
        hi = jnp.where(value < 0, hi, b_in)
        step = b_in - safe_div(value, deriv)
        # closed bracket: a converged step that rounds onto an end is kept (issue 16); so is
        # one that leaves it by less than half its width (a rounding-level residual whose
        # sign disagrees with the bracket update; a true overshoot travels further), clipped
        inside = (step >= lo) & (step <= hi)
        near = jnp.abs(step - b_in) <= 0.5 * (hi - lo)
        b = jnp.where(inside | near, jnp.clip(step, lo, hi), 0.5 * (lo + hi))
        return b, lo, hi

    return jax.lax.fori_loop(0, BECKMANN_NEWTON_ITERS, body, (b, lo, hi))


class Beckmann(AbstractDistribution):
    """Beckmann distribution (Beckmann & Spizzichino 1963; Walter et al. 2007, eq. 25; anisotropic
    form Heitz 2014, eq. 84)::

        D(m) = exp(-((m.x/ax)^2 + (m.y/ay)^2) / (m.z)^2) / (pi ax ay (m.z)^4)

    Masking: the exact Smith Lambda with ``a = z/sqrt(ax^2 x^2 + ay^2 y^2)``,
    ``Lambda = (exp(-a^2)/(a sqrt(pi)) - erfc(a))/2`` (Walter 2007, eq. 27 without the
    approximation), or with ``lambda_approx="walter"`` the rational approximation of Walter 2007
    (eq. 27): ``Lambda ~ (1 - 1.259 a + 0.396 a^2)/(3.535 a + 2.181 a^2)`` for ``a < 1.6``, else 0.
    (Its G1 exceeds 1 by up to 5.7e-5 just below a = 1.6 and jumps there; kept for compatibility.)
    The visible-normal sampler always follows the exact Lambda.
    """

    alpha_x: Scalar = bounded(0.5, lo=0.0, hi=1.0, lo_open=True)
    alpha_y: Scalar | None = bounded(None, lo=0.0, hi=1.0, lo_open=True)
    lambda_approx: str = eqx.field(static=True, default="exact")

    def __check_init__(self):
        _check_widths(self.alpha_x, self.alpha_y)
        if self.lambda_approx not in ("exact", "walter"):
            raise ValueError(
                f"lambda_approx must be 'exact' or 'walter', got {self.lambda_approx!r}"
            )

    def widths(self):
        return _widths(self.alpha_x, self.alpha_y)

    def is_anisotropic(self) -> bool:
        return self.alpha_y is not None

    def D(self, mx, my, mz):
        ax, ay = self.widths()
        pos = mz > 0
        mzs = jnp.where(pos, mz, 1.0)
        t = ((mx / ax) ** 2 + (my / ay) ** 2) / (mzs * mzs)
        e = -t - 4.0 * jnp.log(mzs)
        ok = pos & (e > EXP_UNDERFLOW)
        es = jnp.where(ok, e, 0.0)
        return jnp.where(ok, jnp.exp(es) / (PI * ax * ay), 0.0)

    def D_half_sum(self, hx, hy, hz, l2):
        """``D(h/|h|)`` without normalising ``h``: the slope term ``t = ((hx/ax)^2 +
        (hy/ay)^2)/hz^2`` is homogeneous of degree 0, and ``1/(n.m)^4 = q^2`` with
        ``q = l2/hz^2``, so ``D = exp(-t) q^2/(pi ax ay)``: one division, no square root and no
        logarithm. ``q^2`` overflows float32 only where ``q > 1.8e19``; there ``t >= q - 1``
        (alpha <= 1) and ``exp(-t)`` is 0, so lanes where ``exp(-t)`` underflows are 0. (:meth:`D`
        forms ``exp(-t - 4 log(n.m))``, which underflows later: in float32 this form reads 0 for
        values below ~1e-30, where ``exp(-t)`` flushes before ``q^2`` scales it back up.)"""
        ax, ay = self.widths()
        pos = hz > 0
        r = 1.0 / jnp.where(pos, hz * hz, 1.0)
        t = ((hx / ax) ** 2 + (hy / ay) ** 2) * r
        e = jnp.exp(-t)
        q = l2 * r
        return jnp.where(pos & (e > 0), e * q * q * (1.0 / (PI * ax * ay)), 0.0)

    def _B_a(self, wx, wy, wz):
        ax, ay = self.widths()
        B = (ax * wx) ** 2 + (ay * wy) ** 2
        rsB = safe_rsqrt(B)
        # B = 0 (direction along the normal): a = +inf, Lambda = 0. 1e30 stands in for infinity.
        a = jnp.where(B > 0, wz * rsB, 1e30)
        return B, a

    def P_exact(self, wx, wy, wz):
        B, a = self._B_a(wx, wy, wz)
        a_c = jnp.minimum(a, 30.0)  # exp(-900) = 0: the clamp only avoids overflow of a^2
        return wz * erf(a_c) + safe_sqrt(B / PI) * jnp.exp(-a_c * a_c)

    def P(self, wx, wy, wz):
        if self.lambda_approx == "exact":
            return self.P_exact(wx, wy, wz)
        B, a = self._B_a(wx, wy, wz)
        small = a < 1.6
        a_s = jnp.where(small, a, 0.0)
        # P = z + 2 z Lambda = z + 2 sqrt(B) a Lambda(a), with a Lambda(a) rational and finite at 0
        corr = 2.0 * safe_sqrt(B) * (1.0 - 1.259 * a_s + 0.396 * a_s * a_s) / (3.535 + 2.181 * a_s)
        return wz + jnp.where(small, corr, 0.0)

    def sample_normal(self, u1, u2):
        """Sample ``m ~ D(m)(n.m)``: unit-roughness slope radius ``r = sqrt(-log(1 - u1))``
        (inverse CDF of the Beckmann slope distribution), uniform azimuth, stretched by
        ``(ax, ay)``."""
        ax, ay = self.widths()
        r = safe_sqrt(-jnp.log1p(-jnp.minimum(u1, 1.0 - U_EPS)))
        phi = 2.0 * PI * u2
        return _stretched_slopes_to_normal(r * jnp.cos(phi), r * jnp.sin(phi), ax, ay)

    def sample_visible(self, wx, wy, wz, u1, u2):
        """Visible normals (Heitz & d'Eon 2014, section 4 and appendix): stretch ``w`` to unit
        roughness, draw the slope ``x~`` along the incident azimuth from its visible-slope CDF

            C(b) = (1 + b + tan(theta) exp(-erfinv(b)^2)/sqrt(pi)) / (1 + erf(cot theta)
                   + tan(theta) exp(-cot^2 theta)/sqrt(pi)),        b = erf(x~),

        which is inverted by a bracketed Newton iteration in ``b`` with a fixed trip count (the
        paper's direct fit is discontinuous, which Jakob's later implementations replace by a
        numerical inversion; this is our own safeguarded version). A Newton step is kept when it
        lies in the *closed* bracket: once converged, a step rounds onto a bracket end, and
        rejecting it (open bracket) restarted bisection from a bracket whose other end never
        moved, leaving 12% of samples off by more than 1e-9 (up to 7e-3) in ``m`` (issue 16).
        One last Newton step in the slope ``x~`` itself, on ``erfc(-x~) + tan(theta)
        exp(-x~^2)/sqrt(pi) = C`` (the same equation; ``erfc`` keeps ``1 + erf`` exact in the
        tail, where ``b`` near -1 resolves ``x~`` only to ~1e-11), is kept if it stays in the
        bracket. The transverse slope is ``erfinv(2 u2 - 1)``; rotate back to the azimuth of
        ``w``, unstretch.
        """
        ax, ay = self.widths()
        sx, sy, sz, _ = safe_normalize3(ax * wx, ay * wy, wz)
        rxy2 = sx * sx + sy * sy
        has_az = rxy2 > 1e-30
        inv_rxy = safe_rsqrt(rxy2)
        cos_phi = jnp.where(has_az, sx * inv_rxy, 1.0)
        sin_phi = jnp.where(has_az, sy * inv_rxy, 0.0)
        # Incidence angle of the stretched direction; sin is floored at 1e-7 so that cot stays
        # finite at normal incidence (cot = 1e7 makes erf(cot) = 1 and exp(-cot^2) = 0 exactly).
        sin_t = jnp.maximum(jnp.sqrt(rxy2), 1e-7)
        cos_t = jnp.maximum(sz, 1e-7)
        tan_t = sin_t / cos_t
        cot_t = cos_t / sin_t
        u1 = jnp.clip(u1, U_EPS, 1.0 - U_EPS)
        u2 = jnp.clip(u2, U_EPS, 1.0 - U_EPS)
        c_hi = erf(cot_t)
        k = tan_t * INV_SQRT_PI
        norm = 1.0 + c_hi + k * jnp.exp(-cot_t * cot_t)
        target = u1 * norm
        lo = jnp.full_like(u1, -1.0)
        hi = c_hi
        b = lo + u1 * (hi - lo)

        b, lo, hi = _beckmann_visible_newton(b, lo, hi, k, tan_t, target)
        b_lo = jnp.clip(b, -1.0 + 1e-12, 1.0 - 1e-12)
        x = erfinv(b_lo)
        # polish in x~: f(x) = erfc(-x) + k exp(-x^2) - target, f'(x) = 2/sqrt(pi) exp(-x^2)
        # (1 - x tan(theta)) > 0 below the root's upper bound cot(theta)
        ex = jnp.exp(-x * x)
        fx = erfc(-x) + k * ex - target
        dfx = 2.0 * INV_SQRT_PI * ex * (1.0 - x * tan_t)
        x_new = x - safe_div(fx, dfx)
        x_lo = erfinv(jnp.clip(lo, -1.0 + 1e-12, 1.0 - 1e-12))
        x_hi = erfinv(jnp.clip(hi, -1.0 + 1e-12, 1.0 - 1e-12))
        keep = (dfx > 0) & (x_new >= x_lo) & (x_new <= x_hi)
        slope_x = jnp.where(keep, x_new, x)
        slope_y = erfinv(2.0 * u2 - 1.0)
        # rotate the slopes to the azimuth of the stretched direction
        rx = cos_phi * slope_x - sin_phi * slope_y
        ry = sin_phi * slope_x + cos_phi * slope_y
        return _stretched_slopes_to_normal(rx, ry, ax, ay)


class BlinnPhongNDF(AbstractDistribution):
    """Blinn-Phong normal distribution ``D(m) = (n + 2)/(2 pi) (n.m)^n`` (Blinn 1977, normalised
    on projected area as in Walter et al. 2007, eq. 30).

    There is no exact Smith Lambda for it; masking uses the Beckmann Lambda at the equivalent
    roughness ``alpha_b = sqrt(2/(n + 2))`` as Walter et al. 2007 (section 5.2) recommend, so the
    weak white furnace identity holds only approximately. Sampling draws ``m ~ D(m)(n.m)``
    (``cos = u^(1/(n+2))``); visible-normal sampling is not available.
    """

    exponent: Scalar = bounded(20.0, lo=0.0)
    supports_visible: ClassVar[bool] = False

    def __check_init__(self):
        check_param("exponent", self.exponent, lo=0.0)

    def D(self, mx, my, mz):
        n = self.exponent
        return jnp.where(mz > 0, (n + 2.0) / (2.0 * PI) * safe_pow(mz, n), 0.0)

    def _beckmann(self):
        ab = jnp.sqrt(2.0 / (self.exponent + 2.0))
        return Beckmann(ab, ab)

    def widths(self):
        """The equivalent Beckmann width ``sqrt(2/(n + 2))`` (Walter et al. 2007, section 5.2)
        in both directions, e.g. 0.0141 for ``n = 1e4``."""
        a = jnp.maximum(jnp.sqrt(2.0 / (jnp.asarray(self.exponent) + 2.0)), ALPHA_MIN)
        return a, a

    def P(self, wx, wy, wz):
        return self._beckmann().P(wx, wy, wz)

    def sample_normal(self, u1, u2):
        cos_t = safe_pow(u1, 1.0 / (self.exponent + 2.0))
        sin_t = safe_sqrt(1.0 - cos_t * cos_t)
        phi = 2.0 * PI * u2
        return sin_t * jnp.cos(phi), sin_t * jnp.sin(phi), cos_t

    def sample_visible(self, wx, wy, wz, u1, u2):
        raise NotImplementedError("BlinnPhongNDF has no visible-normal sampler; use sample_normal")


# --------------------------------------------------------------------------- masking-shadowing


class AbstractMasking(eqx.Module):
    """Masking-shadowing term: ``V(dist, wi, wo, h) = G2 / (4 ci co)`` on components (abstract;
    the concrete terms are final)."""

    @abc.abstractmethod
    def V(self, dist: AbstractDistribution, ix, iy, iz, ox, oy, oz, hz, d):
        """``G2 / (4 (n.wi)(n.wo))`` with ``hz = n.h`` and ``d = wo.h`` (sanitised inputs)."""

    def G2(self, dist, ix, iy, iz, ox, oy, oz, hz, d):
        return 4.0 * iz * oz * self.V(dist, ix, iy, iz, ox, oy, oz, hz, d)

    def V_parts(self, dist, ix, iy, iz, ox, oy, oz, hz, d):
        """``(num, den)`` with ``V = num/den`` for the float32 evaluation of
        :class:`~brdf_fit.models.MicrofacetBRDF` (issue 15), which divides ``D num`` by ``den``
        once: a per-pair value that ends in a division is one loop fusion for XLA, whereas
        ``D * V`` is split at the product (XLA fuses the cheap product into the per-channel
        output and leaves each division behind as a kernel of its own). Unguarded: the inputs
        are unit directions above the horizon. This default is ``(V, 1)``."""
        return self.V(dist, ix, iy, iz, ox, oy, oz, hz, d), 1.0


class SmithSeparable(AbstractMasking):
    """Uncorrelated Smith ``G2 = G1(wi) G1(wo)`` (Smith 1967; Walter et al. 2007, eq. 23)."""

    def V(self, dist, ix, iy, iz, ox, oy, oz, hz, d):
        return 1.0 / ((iz + dist.P(ix, iy, iz)) * (oz + dist.P(ox, oy, oz)))

    def V_parts(self, dist, ix, iy, iz, ox, oy, oz, hz, d):
        return 1.0, (iz + dist.P(ix, iy, iz)) * (oz + dist.P(ox, oy, oz))


class SmithHeightCorrelated(AbstractMasking):
    """Height-correlated Smith ``G2 = 1/(1 + Lambda(wi) + Lambda(wo))`` (Heitz 2014, eq. 99)."""

    def V(self, dist, ix, iy, iz, ox, oy, oz, hz, d):
        return 0.5 / (oz * dist.P(ix, iy, iz) + iz * dist.P(ox, oy, oz))

    def V_parts(self, dist, ix, iy, iz, ox, oy, oz, hz, d):
        return 0.5, oz * dist.P(ix, iy, iz) + iz * dist.P(ox, oy, oz)


class SchlickSmithKaris(AbstractMasking):
    """Separable Schlick-Smith masking with Karis's remapping ``k = alpha/2``::

        G1(w) = (n.w) / ((n.w)(1 - k) + k),   G2 = G1(wi) G1(wo)

    (B. Karis, "Real Shading in Unreal Engine 4", SIGGRAPH 2013 course notes, the geometric term
    used for image-based lighting; the G1 form is Schlick's 1994 rational approximation of the
    Smith G1, "An inexpensive BRDF model for physically-based rendering", eq. 19). With
    ``k = alpha/2`` it matches the GGX Smith G1 at normal incidence and as ``alpha -> 0``; it
    is not an exact Smith term (the weak white furnace holds only approximately). Isotropic: ``k``
    uses ``alpha_x``.
    """

    def V(self, dist, ix, iy, iz, ox, oy, oz, hz, d):
        k = 0.5 * dist.widths()[0]
        return 0.25 / ((iz * (1.0 - k) + k) * (oz * (1.0 - k) + k))

    def V_parts(self, dist, ix, iy, iz, ox, oy, oz, hz, d):
        k = 0.5 * dist.widths()[0]
        return 0.25, (iz * (1.0 - k) + k) * (oz * (1.0 - k) + k)


class VCavity(AbstractMasking):
    """V-groove (V-cavity) masking-shadowing of Torrance & Sparrow 1967, in Blinn's 1977 vector
    form as used by Cook & Torrance 1982::

        G2 = min(1, 2 (n.h)(n.wo)/(wo.h), 2 (n.h)(n.wi)/(wo.h))

    Its G1 ``min(1, 2 (n.m)(n.w)/(w.m))`` is the masking of Heitz & d'Eon's V-cavity
    microsurface, which their V-cavity visible-normal sampler draws exactly.
    """

    def V(self, dist, ix, iy, iz, ox, oy, oz, hz, d):
        # 1/(4 iz oz) as a product of two reciprocals: at a grazing pair (iz = oz = 1e-8) the
        # reverse-mode factor 1/(4 iz oz)^2 = 6e30 times a cotangent D ~ 3e7 (alpha = 1e-4)
        # overflowed float32 and gave NaN gradients (issue 16)
        a = safe_div(0.5, iz) * safe_div(0.5, oz)
        b = safe_div(hz, 2.0 * iz * d)
        c = safe_div(hz, 2.0 * oz * d)
        # d = wo.h <= 0 (directions unit only to rounding, see half_geometry): the limit
        # wo.h -> 0+ of the groove terms is +inf, so G = 1; safe_div's 0 there would make G = 0
        return jnp.where(d > 0, jnp.minimum(a, jnp.minimum(b, c)), a)

    def V_parts(self, dist, ix, iy, iz, ox, oy, oz, hz, d):
        # min(1, 2 hz oz/d, 2 hz iz/d)/(4 iz oz) over the common denominator 4 iz oz d (d > 0:
        # the float32 form's d = |wi + wo|/2 is positive on every valid lane)
        return jnp.minimum(d, 2.0 * hz * jnp.minimum(iz, oz)), 4.0 * iz * oz * d


def vcavity_pdf_visible(dist, wx, wy, wz, mx, my, mz):
    """Density of :func:`vcavity_sample_visible`: ``G1_vc(w, m) max(0, w.m) D(m)/(n.w)`` with
    ``G1_vc = min(1, 2 (n.m)(n.w)/(w.m))``, i.e. ``min(w.m, 2 (n.m)(n.w)) D(m)/(n.w)``."""
    wm = wx * mx + wy * my + wz * mz
    val = jnp.minimum(wm, 2.0 * mz * wz) * dist.D(mx, my, mz)
    return jnp.where((wz > 0) & (wm > 0), safe_div(val, wz), 0.0)


def vcavity_sample_visible(dist, wx, wy, wz, u1, u2, uflip):
    """V-cavity visible normals (Heitz & d'Eon 2014, section 5): draw ``m ~ D(m)(n.m)``, form the
    groove partner ``m' = (-m.x, -m.y, m.z)`` and return ``m'`` with probability
    ``max(0, w.m')/(max(0, w.m) + max(0, w.m'))``. Valid for any D symmetric under
    ``(x, y) -> (-x, -y)`` (all of ours)."""
    mx, my, mz = dist.sample_normal(u1, u2)
    p = jnp.maximum(wx * mx + wy * my + wz * mz, 0.0)
    q = jnp.maximum(-wx * mx - wy * my + wz * mz, 0.0)
    flip = uflip * (p + q) < q
    return jnp.where(flip, -mx, mx), jnp.where(flip, -my, my), mz

