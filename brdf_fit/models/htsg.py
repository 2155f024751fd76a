"""He-Torrance-Sillion-Greenberg BRDF (He, Torrance, Sillion & Greenberg 1991).

X. D. He, K. E. Torrance, F. X. Sillion, D. P. Greenberg, "A comprehensive physical model for
light reflection", SIGGRAPH 1991, Computer Graphics 25(4):175-186 (equation numbers below are the
paper's); errata: R. Pacanowski, N. Holzschuch, "Demystifying the He, Torrance, Sillion and
Greenberg BRDF" (web notes and ``he_errata.pdf``); conventions cross-checked against the two
public implementations we could read, bsdfbenchmark/bbm ``include/bsdfmodel/he.h`` (three
variants, after Westin's Cornell reference code) and PiscisRT ``PRTMaterial.cpp`` (``BRDF_HTSG``).

The model is ``rho = rho_sp + rho_dd + rho_ud`` (eq. 1). ``eval`` is the directional-diffuse plus
the uniform-diffuse part; the coherent specular part ``rho_sp`` is a delta lobe in the mirror
direction and is left out of ``eval`` (as the mirror's delta lobe is, see ``Mirror``); its
reflectance is available separately as :meth:`HTSG.coherent_reflectance`.

Directional diffuse (eqs. 76-84), written in dot products with ``l = wi``, ``v = wo`` (both away
from the surface), ``H = l + v`` (``= k_r - k_i`` for the unit wave directions ``k_i = -l``,
``k_r = v``), ``|H| = 2 d``, ``d = l.h``::

    rho_dd = F(d) S(l) S(v) G D / (pi cl cv)
    G      = (H.H / H_z)^2                                                  (eq. 76, see below)
    D      = (pi tau/(2 lam))^2 sum_{m>=1} g^m e^-g / (m! m) exp(-T/m)       (eq. 78)
    g      = (2 pi sigma (cl + cv)/lam)^2                                   (eq. 79)
    T      = v_xy^2 tau^2/4 = (pi tau/lam)^2 |H_xy|^2    (v = (2 pi/lam) H: the wave-vector change)
    S(w)   = (1 - erfc(a)/2)/(Lambda(a) + 1),  a = tau cot(theta_w)/(2 sigma0)      (eq. 24)
    Lambda = (exp(-a^2)/(a sqrt(pi)) - erfc(a))/2                       (eq. 25 with the errata)
    sigma  = sigma0 / sqrt(1 + x^2),  x e^(x^2/2) = (K_l + K_v)/sqrt(8 pi)           (eqs. 80-81)
    K_w    = tan(theta_w) erfc(tau/(2 sigma0 tan(theta_w)))                          (eq. 82)
    rho_ud = a(lam)/pi                                                   (uniform diffuse, eq. 1)

Choices where the sources disagree (and why):

* **Wave number in eq. 78** (models.md section 5): BBM's default ``he`` variant uses
  ``|H_xy|^2 tau^2/4`` without ``(2 pi/lam)^2``; BBM's ``hewestin`` and PiscisRT use
  ``(pi tau/lam)^2 |H_xy|^2/m``. ``v`` in the paper is the wave-vector difference
  ``k (k_r - k_i)``, so the exponent must carry the wave number; without it the expression is not
  dimensionless. We follow Westin / PiscisRT.
* **Eq. 25**: the printed equation lacks ``exp(-a^2)`` (errata; BBM ``he_eq25::Errata``). With it,
  ``S`` is Smith's (1967) shadowing for a Gaussian surface of RMS slope ``sqrt(2) sigma0/tau``;
  without it ``S`` is not the Smith function (PiscisRT and BBM's default ``he`` omit it). We
  include it.
* **G (eq. 76)**: ``G = (H.H/H_z)^2 [(s_r.k_i)^2 + (p_r.k_i)^2][(s_i.k_r)^2 + (p_i.k_r)^2] /
  |k_r x k_i|^4`` with ``s_w = k_w x n/|k_w x n|``, ``p_w = s_w x k_w``. Since ``{s_r, p_r, k_r}``
  is an orthonormal basis, ``(s_r.k_i)^2 + (p_r.k_i)^2 = 1 - (k_r.k_i)^2 = |k_r x k_i|^2``, and the
  same holds for the other bracket: for unpolarised light **G = (H.H/H_z)^2 exactly**. The printed
  form is 0/0 at ``l = v`` (retro-reflection) and at normal incidence; BBM replaces it there by
  ``G = 1`` (its limit is ``4/cv^2`` at ``l = v``, so BBM is discontinuous there), PiscisRT divides
  by zero. We use the closed form, which is finite everywhere.
* **Fresnel**: unpolarised reflectance of the complex index ``eta + i k`` at the bisector angle
  ``d = l.h`` (:func:`brdf_fit.fresnel.conductor`); the sign of ``k`` does not matter.
* **Normalisation** ``1/(pi cl cv)``: BBM and PiscisRT agree. PiscisRT also multiplies the
  directional-diffuse term by an extra "specular reflectivity" factor that is not in the paper;
  we do not.

Evaluation without cosine divisions: ``S(w) = cos(theta_w) S^(w)`` with
``S^ = tau (1 + erf a)/(tau c (1 + erf a) + 2 sigma0 s e^(-a^2)/sqrt(pi))`` (``c, s`` = cosine and
sine of ``theta_w``; multiply Smith's form through by ``2 sigma0 s``), and ``G D = (H.H)^2
(pi tau/(2 lam))^2 (2 pi sigma/lam)^2 Sigma'`` with ``Sigma' = sum_m g^(m-1) e^-g e^(-T/m)/(m! m)``
(``g`` carries the factor ``H_z^2``), so ``rho_dd = F S^(l) S^(v) (H.H)^2 (pi tau/(2 lam))^2
(2 pi sigma/lam)^2 Sigma'/pi``: no ``1/cl``, ``1/cv`` or ``1/H_z`` remains, and values and gradients
stay finite at grazing angles (cos = 1e-7) in float32.

**The series** (eq. 78) is a Poisson(g)-weighted mean of ``phi(m) = e^(-T/m)/m``. Terms are formed
in log space, ``(m - 1) log g - g - gammaln(m + 1) - log m - T/m``, and summed over a FIXED set of
``N_TERMS = 128`` nodes (no data-dependent loop):

* ``g <= G_SERIES = 55``: the exact partial sum ``m = 1..128``. Truncation error: the tail
  ``sum_{m>128}`` of ``Sigma'`` is at most ``P(N > 128)/(129 g)`` for ``N ~ Poisson(g)``
  (``phi <= 1/m``); relative to the specular-peak value ``Sigma'(g, T=0) = e^-g Ein(g)/g >= 1/g^2``
  (for ``g >= 1``) that is ``<= g P(N > 128)/129 = 6e-18`` at ``g = 55``
  (``scipy.stats.poisson.sf(128, 55) = 1.4e-17``). BBM's 64 terms bound the tail by 1e-17 only
  up to ``g = 18`` (``sf(64, 18) = 9.9e-18``), where it switches to
  Beckmann's crude ``e^(-T/g)/g``; PiscisRT's 40 terms switch at ``g = 15``.
* ``g > G_SERIES``: the Poisson weights vary on the scale ``sqrt(g) >= 7.4``, so the sum over
  integers equals the integral of the smooth (``gammaln``-interpolated) summand up to
  ``O(exp(-2 pi^2 g))`` (Poisson summation), and that integral is taken by the trapezoid rule on
  128 equally spaced real nodes over ``[max(1, g - 9 sqrt(g)), g + 14 sqrt(g)]`` (Poisson mass
  outside: left ``< 2e-19`` (``poisson.cdf``, g = 55..1e4), right ``< 4e-30``; aliasing
  ``exp(-2 pi^2 g/h^2) < exp(-600)`` for the node spacing ``h <= 23 sqrt(g)/127``). The nodes are
  placed in ``t = (x - g)/sqrt(g)`` (in ``x`` itself, float32 cannot even resolve the spacing
  for ``g > 1e10``) and the Poisson log-weight is evaluated in Loader's saddle-point form
  ``log p(x) = -bd0(x, g) - log(2 pi x)/2 - stirlerr(x)``, ``bd0 = g D(u)``,
  ``D(u) = (1 + u) log(1 + u) - u``, ``u = t/sqrt(g)`` (C. Loader, "Fast and accurate computation
  of binomial probabilities", 2000; the form of R's ``dpois``), with ``D`` from a cancellation-free
  series near ``u = 0``. Every term of the exponent is then ``O(t^2) <= O(100)`` instead of
  ``O(g log g)``: the direct form ``x log g - g - gammaln(x + 1)`` lost ``g log g eps`` to
  round-off, i.e. all digits in float32 for ``g > 1e5`` (issue 16: sigma0 = 300 gave 1e14 and
  1e29 instead of 1e-6, sigma0 = 1000 inf) and 3e-7 relative in float64 at ``g = 1e8``.
  ``Sigma' = (h/g^2) sum_j exp(lw_j)`` with the ``1/g^2`` applied in log space. Measured
  against a 400+ term log-sum-exp for ``g = 1e-3..5000`` and ``T = 0..1e6``: error <= 1.8e-14
  of the peak value ``Sigma'(g, 0)`` for ``g <= 55`` (float64), and float32 equals float64 to
  2e-5 relative for ``g`` up to 1e15 (sigma0 up to 1e6 um). This replaces the rough-surface
  asymptote ``e^(-T/g)/g`` (Beckmann 1963) that BBM and Westin blend in, whose relative error
  is ``O(1/g)``; the series needs no large-``g`` switch: it reproduces ``g^2 Sigma'(T = 0) =
  1 + 1/g + O(g^-2)`` to 1e-13 at ``g = 1e8..1e12`` (float64).

**Effective roughness** (eq. 81): ``x e^(x^2/2) = y`` is solved by a fixed number of Newton
steps (``NEWTON_STEPS = 6``) without gradient, ``f(x) = x e^(x^2/2) - y`` from ``x0 = y`` for
``y <= 1`` (convex, monotone from above) and ``h(x) = log x + x^2/2 - log y`` from
``x0 = max(1, sqrt(2 log y))`` for ``y > 1``; one last Newton step with gradient gives the
implicit-function derivative ``dx/dy = 1/((1 + x^2) e^(x^2/2))`` exactly.

Sampling (fallback; there is no analytic sampler): with probability ``p_c`` a cosine-weighted
direction, otherwise a Beckmann half-vector lobe about the mirror direction of the rough-limit
width ``alpha_s = sqrt((2 sigma0/tau)^2 + (lam_mean/(2 pi tau))^2)`` (clamped to [1e-3, 1]):
``2 sigma0/tau`` is the width of ``D`` for large ``g`` (``e^(-T/g)`` is the Beckmann lobe of slope
``2 sigma/tau``), ``lam/(2 pi tau)`` that of the ``m = 1`` term for smooth surfaces. ``pdf`` is the
exact mixture ``p_c cl/pi + (1 - p_c) D_B(h) (n.h)/(4 v.h)``; lobe samples with ``v.m <= 0`` or
below the horizon fail (pdf 0, weight 0). ``p_c = 0.1 + 0.8 max(a)/(max(a) + F0_max)``.

Units: ``sigma0``, ``tau`` and ``wavelength`` in micrometres (only their ratios matter: scaling
all three by the same factor leaves the BRDF unchanged, which is why the registry entry keeps
the wavelengths fixed).
"""

from __future__ import annotations

import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax.scipy.special import erf, erfc, gammaln

from brdf_fit.core.frame import split
from brdf_fit.core.fresnel import conductor, f0_from_ior
from brdf_fit.core.numerics import INV_PI, safe_div, safe_log, safe_sqrt
from brdf_fit.core.params import Channels, Entry, Param, Scalar, bounded
from brdf_fit.core.validate import ParameterError, check_param, check_scalar
from brdf_fit.models._base import AbstractBRDF, QuadratureLobe, expand_channels
from brdf_fit.models._fallback import cosine_beckmann_pdf, cosine_beckmann_sample
from brdf_fit.models._lobes import max_over_channels, sanitize, sanitize_pair, upper

__all__ = ["HTSG", "registry_entries", "N_TERMS", "G_SERIES"]

SQRT_PI = math.sqrt(math.pi)
HALF_LOG_2PI = 0.5 * math.log(2.0 * math.pi)
#: terms of the series of :func:`_bd0_over_g` (|v| <= 1/3: remainder < (1/3)^33/33 of D)
BD0_TERMS = 16
#: number of series nodes (fixed trip count), see the module docstring for the error bound
N_TERMS = 128
#: largest g summed as the exact partial series m = 1..N_TERMS (tail <= 1.4e-17 of the peak)
G_SERIES = 55.0
#: window of the strided (trapezoid) regime, in units of sqrt(g), left and right of g
WINDOW_LEFT = 9.0
WINDOW_RIGHT = 14.0
#: Newton steps for x e^(x^2/2) = y (quadratic convergence: 4 suffice from both starts, measured;
#: 6 leaves a margin)
NEWTON_STEPS = 6
#: a = tau cot(theta)/(2 sigma0) is clamped here: erf(30) = 1, erfc(30) = exp(-900) = 0 in both
#: float32 and float64, so the clamp only avoids overflow of a^2 near the normal
A_MAX = 30.0
#: sine of theta below which a direction is treated as the normal (a = A_MAX): s^2 < 1e-30
SIN_EPS = 1e-15
#: clamp of the sampling lobe's Beckmann width (a narrower lobe would need > 1e6 samples to see)
SAMPLER_ALPHA_MIN = 1e-3

_HE_1991 = (
    "X. D. He, K. E. Torrance, F. X. Sillion, D. P. Greenberg, A comprehensive physical model "
    "for light reflection, SIGGRAPH 1991, Computer Graphics 25(4):175-186; errata: R. "
    "Pacanowski, N. Holzschuch, Demystifying the He, Torrance, Sillion and Greenberg BRDF"
)


def _solve_x_exp_half_x2(y):
    """``x >= 0`` with ``x exp(x^2/2) = y`` (eq. 81 in the variable ``x = z0/sigma0``)."""
    lo = y <= 1.0
    ylo = jnp.where(lo, y, 0.5)
    yhi = jnp.where(lo, 2.0, y)
    ys_lo = jax.lax.stop_gradient(ylo)
    ys_hi = jax.lax.stop_gradient(yhi)
    lyh = jnp.log(ys_hi)
    xl = ys_lo
    xh = jnp.maximum(1.0, jnp.sqrt(2.0 * lyh))
    for _ in range(NEWTON_STEPS):
        e = jnp.exp(0.5 * xl * xl)
        xl = xl - (xl * e - ys_lo) / ((1.0 + xl * xl) * e)
        xh = xh - (jnp.log(xh) + 0.5 * xh * xh - lyh) / (1.0 / xh + xh)
    # one differentiable step: exact implicit derivative dx/dy = 1/((1 + x^2) e^(x^2/2))
    e = jnp.exp(0.5 * xl * xl)
    xl = xl - (xl * e - ylo) / ((1.0 + xl * xl) * e)
    xh = xh - (jnp.log(xh) + 0.5 * xh * xh - jnp.log(yhi)) / (1.0 / xh + xh)
    return jnp.where(lo, xl, xh)


def _bd0_over_g(u):
    """``D(u) = (1 + u) log(1 + u) - u`` (``u > -1``) without cancellation: ``g D(u)`` is Loader's
    ``bd0(x, g) = x log(x/g) + g - x`` at ``x = g (1 + u)`` (C. Loader, "Fast and accurate
    computation of binomial probabilities", 2000). For ``|v| <= 1/3``, ``v = u/(2 + u)``, the
    series ``D = u v + 2 (1 + u) sum_{j>=1} v^(2j+1)/(2j+1)`` (16 terms: remainder < 1e-16 of
    ``D``); otherwise the direct form, whose two terms are then within a factor 4 of ``D``."""
    v = u / (2.0 + u)
    small = jnp.abs(v) <= 1.0 / 3.0
    vs = jnp.where(small, v, 0.0)
    v2 = vs * vs
    acc = jnp.zeros_like(v2) + 1.0 / (2 * BD0_TERMS + 1)
    for j in range(BD0_TERMS - 1, 0, -1):
        acc = acc * v2 + 1.0 / (2 * j + 1)
    series = u * vs + 2.0 * (1.0 + u) * vs * v2 * acc
    ub = jnp.where(small, 1.0, u)
    direct = (1.0 + ub) * jnp.log1p(ub) - ub
    return jnp.where(small, series, direct)


def _stirlerr(x):
    """``log Gamma(x + 1) - (x + 1/2) log x + x - log(2 pi)/2`` for real ``x >= 1``: Stirling's
    series (5 terms, error < 2e-14 for ``x >= 10``), below 10 the difference itself (terms
    ``< 30``, so its absolute round-off stays ``< 30 eps``)."""
    big = x >= 10.0
    xb = jnp.where(big, x, 10.0)
    r = 1.0 / xb
    r2 = r * r
    series = r * (1.0 / 12 - r2 * (1.0 / 360 - r2 * (1.0 / 1260 - r2 * (1.0 / 1680
                                                                         - r2 / 1188))))
    xs = jnp.where(big, 1.0, x)
    direct = gammaln(xs + 1.0) - (xs + 0.5) * jnp.log(xs) + xs - HALF_LOG_2PI
    return jnp.where(big, series, direct)


def _series(log_g, g, T, dtype):
    """``Sigma' = sum_m g^(m-1) e^-g e^(-T/m)/(m! m)`` on the fixed node set (module docstring)."""
    rough = g > G_SERIES
    # smooth regime: the exact partial sum m = 1..N_TERMS (integer nodes)
    m = jnp.arange(1, N_TERMS + 1, dtype=dtype)
    lgs = jnp.where(rough, math.log(G_SERIES), log_g)[..., None]
    gs = jnp.where(rough, G_SERIES, g)[..., None]
    Ts = jnp.where(rough, 0.0, T)[..., None]
    lt = (m - 1.0) * lgs - gs - gammaln(m + 1.0) - jnp.log(m) - Ts / m
    smooth = jnp.sum(jnp.exp(lt), axis=-1)
    # rough regime: trapezoid rule in t = (x - g)/sqrt(g) on [max(-9, (1 - g)/sqrt(g)), 14];
    # Poisson log-weights in Loader's saddle-point form (no term of size g log g)
    gr = jnp.where(rough, g, 2.0 * G_SERIES)
    lgr = jnp.where(rough, log_g, math.log(2.0 * G_SERIES))
    sq = jnp.sqrt(gr)
    t0 = jnp.maximum(-WINDOW_LEFT, (1.0 - gr) / sq)
    h = (WINDOW_RIGHT - t0) / (N_TERMS - 1)
    j = jnp.arange(N_TERMS, dtype=dtype)
    t = t0[..., None] + h[..., None] * j
    u = t / sq[..., None]
    opu = 1.0 + u
    x = gr[..., None] * opu
    Tg = jnp.where(rough, T, 0.0) / gr
    lw = (-gr[..., None] * _bd0_over_g(u) - _stirlerr(x) - Tg[..., None] / opu
          - 1.5 * jnp.log(opu) - HALF_LOG_2PI)
    # Sigma' = (h/g^2) sum_j exp(lw_j): the 1/g^2 in log space (g^2 overflows float32 at 2e19)
    rsum = h * jnp.sum(jnp.exp(lw), axis=-1) * jnp.exp(-2.0 * lgr)
    return jnp.where(rough, rsum, smooth)


def _shadow_parts(wx, wy, wz, tau, sigma0):
    """``S^ = S/cos`` (Smith form of eq. 24/25, see the module docstring) and ``K`` (eq. 82)."""
    s = safe_sqrt(wx * wx + wy * wy)
    sok = s > SIN_EPS
    ss = jnp.where(sok, s, 1.0)
    a = jnp.where(sok, tau * wz * (0.5 / (sigma0 * ss)), A_MAX)
    a = jnp.minimum(a, A_MAX)
    one_p_erf = 1.0 + erf(a)
    S_hat = tau * one_p_erf / (tau * wz * one_p_erf + 2.0 * sigma0 * s * jnp.exp(-a * a) / SQRT_PI)
    K = safe_div(s, wz) * erfc(a)
    return S_hat, K


class HTSG(AbstractBRDF):
    """He-Torrance-Sillion-Greenberg directional-diffuse + uniform-diffuse BRDF (see the module
    docstring for the formulas, sources and choices).

    ``sigma0`` (RMS height), ``tau`` (autocorrelation length) and ``wavelength`` in micrometres;
    ``eta``, ``k`` (complex index ``eta + i k``) and ``albedo`` (the uniform-diffuse ``a``) may
    carry channels; ``wavelength`` is a static float or tuple with one wavelength per channel.
    """

    sigma0: Scalar = bounded(0.18, lo=0.0, lo_open=True)
    tau: Scalar = bounded(3.0, lo=0.0, lo_open=True)
    eta: Channels = bounded(1.6, lo=0.0, lo_open=True, channels=True)
    k: Channels = bounded(0.2, lo=0.0, channels=True)
    albedo: Channels = bounded(0.0, lo=0.0, hi=1.0, channels=True)
    wavelength: float | tuple[float, ...] = eqx.field(static=True, default=(0.55,))

    def __check_init__(self):
        owner = "HTSG"
        for name in ("sigma0", "tau"):
            check_param(name, getattr(self, name), lo=0.0, lo_open=True, owner=owner)
            check_scalar(name, getattr(self, name), owner)
        check_param("eta", self.eta, lo=0.0, lo_open=True, owner=owner)
        check_param("k", self.k, lo=0.0, owner=owner)
        check_param("albedo", self.albedo, lo=0.0, hi=1.0, owner=owner)
        lam = np.atleast_1d(np.asarray(self.wavelength, dtype=float))
        if lam.ndim != 1 or not np.all(np.isfinite(lam)) or np.any(lam <= 0):
            raise ParameterError(f"{owner}: parameter 'wavelength' must be positive, got "
                                 f"{lam.tolist()}")
        ch = self.channels()
        if lam.size != 1 and lam.size != (ch or 1):
            raise ParameterError(f"{owner}: parameter 'wavelength' needs 1 or {ch or 1} "
                                 f"entries (one per channel), got {lam.size}")

    # ------------------------------------------------------------------ helpers

    def _dtype(self):
        return jnp.result_type(*[x for x in (self.sigma0, self.tau, self.eta, self.k,
                                             self.albedo)])

    def _lam(self):
        lam = jnp.asarray(self.wavelength, dtype=self._dtype())
        if self.channels() is None or lam.size == 1:
            return lam.reshape(())
        return lam

    def _sampler_alpha(self):
        lam_mean = float(np.mean(np.asarray(self.wavelength, dtype=float)))
        a2 = (2.0 * self.sigma0 / self.tau) ** 2 + (lam_mean / (2.0 * math.pi * self.tau)) ** 2
        return jnp.clip(jnp.sqrt(a2), SAMPLER_ALPHA_MIN, 1.0)

    def _p_cos(self):
        a = jnp.max(jnp.asarray(self.albedo))
        f0 = jnp.max(f0_from_ior(jnp.asarray(self.eta), jnp.asarray(self.k)))
        return 0.1 + 0.8 * safe_div(a, a + f0)

    # ------------------------------------------------------------------ BRDF

    def directional_diffuse(self, wi, wo):
        """``rho_dd`` alone (1/sr; eqs. 76-84), 0 below the horizon."""
        valid, (ix, iy, iz), (ox, oy, oz) = sanitize_pair(wi, wo)
        ch = self.channels()
        E = lambda x: expand_channels(x, ch)  # noqa: E731
        sigma0, tau = self.sigma0, self.tau
        lam = self._lam()
        Hx, Hy, Hz = ix + ox, iy + oy, iz + oz
        Hxy2 = Hx * Hx + Hy * Hy
        H2 = Hxy2 + Hz * Hz
        d = 0.5 * jnp.sqrt(H2)  # l.h; H2 >= Hz^2 > 0 on valid lanes
        Si, Ki = _shadow_parts(ix, iy, iz, tau, sigma0)
        So, Ko = _shadow_parts(ox, oy, oz, tau, sigma0)
        x = _solve_x_exp_half_x2((Ki + Ko) / math.sqrt(8.0 * math.pi))
        sigma = sigma0 / jnp.sqrt(1.0 + x * x)
        kg = 2.0 * math.pi * E(sigma) / lam  # (2 pi sigma/lam)
        log_g = 2.0 * safe_log(kg * E(Hz))
        g = jnp.exp(log_g)
        T = (math.pi * tau / lam) ** 2 * E(Hxy2)
        dt = jnp.result_type(log_g)
        sig = _series(log_g, g, T, dt)
        F = conductor(E(jnp.minimum(d, 1.0)), self.eta, self.k)
        geo = E(Si * So * H2 * H2)
        val = F * geo * (0.5 * math.pi * tau / lam) ** 2 * kg * kg * sig * INV_PI
        return jnp.where(E(valid), val, 0.0)

    def eval(self, wi, wo):
        ch = self.channels()
        valid = upper(wi, wo)
        ud = self.albedo * INV_PI
        val = self.directional_diffuse(wi, wo) + ud
        return jnp.where(expand_channels(valid, ch), val, 0.0)

    def coherent_reflectance(self, wo):
        """Reflectance of the delta lobe ``rho_sp`` in the mirror direction (eq. 1 specular term:
        ``|F(cv)|^2 e^-g S(v)^2`` with ``g = (4 pi sigma cv/lam)^2``), not part of :meth:`eval`."""
        ox, oy, oz = split(wo)
        valid = oz > 0
        ox, oy, oz = sanitize(valid, ox, oy, oz)
        ch = self.channels()
        E = lambda x: expand_channels(x, ch)  # noqa: E731
        S_hat, K = _shadow_parts(ox, oy, oz, self.tau, self.sigma0)
        x = _solve_x_exp_half_x2(2.0 * K / math.sqrt(8.0 * math.pi))
        sigma = self.sigma0 / jnp.sqrt(1.0 + x * x)
        g = (4.0 * math.pi * E(sigma * oz) / self._lam()) ** 2
        S = S_hat * oz
        val = conductor(E(oz), self.eta, self.k) * jnp.exp(-g) * E(S * S)
        return jnp.where(E(valid), val, 0.0)

    def pdf(self, wi, wo):
        return cosine_beckmann_pdf(wi, wo, self._sampler_alpha(), self._p_cos())

    def sample(self, wo, uc, u):
        return cosine_beckmann_sample(self, wo, uc, u, self._sampler_alpha(), self._p_cos())

    def quadrature_lobe(self) -> QuadratureLobe:
        """Quadrature hint (:func:`brdf_fit.verify.albedo.lobe_rule`): a half-vector lobe of the
        sampler's Beckmann width (the directional-diffuse lobe's rough-limit width)."""
        return QuadratureLobe("half", self._sampler_alpha())

    def selection_hint(self):
        return max_over_channels(self.albedo) + max_over_channels(
            f0_from_ior(jnp.asarray(self.eta), jnp.asarray(self.k)))


# ----------------------------------------------------------------------------- registry

#: RGB wavelengths of the registry entry (micrometres): one per channel
RGB_WAVELENGTHS = (0.65, 0.55, 0.45)

_HTSG_FAILURES: dict[str, str] = {}


def registry_entries():
    """The ``htsg`` entry (wavelengths fixed at :data:`RGB_WAVELENGTHS`: with them free, sigma0,
    tau and the wavelength could all be scaled together without changing the BRDF)."""
    return [
        Entry(
            name="htsg",
            builder=lambda sigma0, tau, eta, k, albedo: HTSG(
                sigma0=sigma0, tau=tau, eta=eta, k=k, albedo=albedo,
                wavelength=RGB_WAVELENGTHS),
            params=(
                Param("sigma0", 0.18, lo=0.0, lo_open=True,
                      doc="RMS surface height sigma0 (micrometres)"),
                Param("tau", 3.0, lo=0.0, lo_open=True,
                      doc="autocorrelation length tau (micrometres)"),
                Param("eta", (1.6, 1.6, 1.6), lo=0.0, lo_open=True, channels=True,
                      doc="real part of the complex index of refraction"),
                Param("k", (0.2, 0.2, 0.2), lo=0.0, channels=True,
                      doc="extinction coefficient (imaginary part of the index)"),
                Param("albedo", (0.3, 0.2, 0.1), lo=0.0, hi=1.0, channels=True,
                      doc="uniform-diffuse albedo a(lambda) (rho_ud = a/pi)"),
            ),
            reference=_HE_1991,
            description=(
                "He-Torrance-Sillion-Greenberg 1991: physical-optics directional diffuse "
                "(Kirchhoff series, 128 fixed terms, effective roughness, Smith shadowing, "
                "complex Fresnel) + uniform diffuse a/pi at RGB wavelengths 0.65/0.55/0.45 um; "
                "the coherent specular delta lobe is not part of eval"
            ),
            aliases=("he", "he-torrance", "he-1991"),
            expected_failures=_HTSG_FAILURES,
            year=1991,
            catalogue="He-Torrance-Sillion-Greenberg",
            sampler="cosine + Beckmann half-vector mixture (exact pdf)",
        ),
    ]
