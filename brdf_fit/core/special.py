"""Special functions with the derivatives JAX lacks.

:func:`betainc` is the regularised incomplete beta function

    I_x(a, b) = B(x; a, b) / B(a, b),   B(x; a, b) = Int_0^x t^(a-1) (1 - t)^(b-1) dt,

with derivatives with respect to ``a``, ``b`` **and** ``x`` (a ``jax.custom_jvp``).
``jax.scipy.special.betainc`` differentiates only in ``x`` (JAX issues #15487, #38610).

Method
------
Value: the continued fraction of I_x(a, b) (Abramowitz & Stegun 26.5.8; evaluated with the modified
Lentz algorithm as in Press et al., *Numerical Recipes*, 3rd ed., sec. 6.4, ``betacf``), used for
``x < (a + 1)/(a + b + 2)`` where it converges fast, and the symmetry
``I_x(a, b) = 1 - I_(1-x)(b, a)`` otherwise. The prefactor ``x^a (1-x)^b / (a B(a, b))`` is formed
in logarithms with a cancellation-free ``log B`` (:func:`betaln`) and the logarithm of whichever
of ``x``, ``1 - x`` is near 1 taken as ``log1p`` of minus the other (both are passed), so ``a`` up
to 1e6 keeps its precision even in float32.

Derivatives in ``a`` and ``b``: forward-mode differentiation of the same continued fraction,
carried by hand inside the Lentz loop (dual numbers for the partial numerators and the Lentz
``C``, ``D`` ratios), the approach of R. J. Boik and J. F. Robison-Cox, "Derivatives of the
incomplete beta function", *Journal of Statistical Software* 3(1), 1998. The loop stops when the
value *and* both derivatives of the continued fraction have converged (relative increment below
the dtype's epsilon), or after :data:`CF_MAX_ITER` steps. The derivative of the prefactor is
analytic: ``d/da log(prefactor) = log x - 1/a + psi(a + b) - psi(a)`` (and likewise for ``b``),
with the digamma difference formed without cancellation (:func:`_digamma_diff`).

Derivative in ``x``: ``x^(a-1) (1-x)^(b-1) / B(a, b)`` in logarithms.

Ranges validated (tests/test_special.py, float64, against SciPy values and central differences):
``a, b`` in [1e-8, 1e6] (the Mallett-Yuksel normaliser needs ``a = n/2`` in [0, 5e5] with
``b = 1/2``), ``x`` in [0, 1]. The continued fraction needs O(sqrt(max(a, b))) steps near the
mean ``a/(a+b)`` (Numerical Recipes sec. 6.4): about 2000 at a = 5e5, well below
:data:`CF_MAX_ITER`.

Edges: ``I_0 = 0``, ``I_1 = 1``, with zero ``a``/``b`` derivatives there. ``dI/dx`` at ``x = 0``
(``x = 1``) is ``x^(a-1)/B`` resp. ``(1-x)^(b-1)/B``, infinite for ``a < 1`` (``b < 1``): there it
is returned as 0 (the one-sided limit does not exist as a finite number; 0 keeps gradients finite).
``a`` and ``b`` are clamped below at :data:`PARAM_MIN`.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jax.scipy.special import digamma, gammaln

__all__ = ["betainc", "betaln", "betainc_complement", "lgamma_diff", "PARAM_MIN", "CF_MAX_ITER"]

#: ``a`` and ``b`` are clamped below at 1e-30: ``I_x(0, b) = 1`` for x > 0 is the limit a -> 0+,
#: reached to within ``a * |log stuff|`` ~ 1e-28; 1e-30 is a normal float32 number, and
#: ``gammaln(1e-30)`` = 69 stays finite.
PARAM_MIN = 1e-30
#: Hard cap on continued-fraction steps (the loop normally stops at convergence; ~2000 steps are
#: needed at a = 5e5 with x at the mean, the worst case of the Phong normaliser).
CF_MAX_ITER = 20000
#: Lentz's guard against a zero denominator (Numerical Recipes' FPMIN): 1e-30 is far below any
#: partial denominator met for a, b > 0 and still a normal float32 number.
_LENTZ_TINY = 1e-30
#: Switch to the asymptotic (Stirling) forms of log-gamma and digamma differences at z >= 10:
#: the truncated series (terms to z^-9) is accurate to 1e-14 there.
_ASYMPTOTIC_Z = 10.0


def _stirling_corr(z):
    """``lgamma(z) - [(z - 1/2) log z - z + log(2 pi)/2]`` for z >= 10 (Abramowitz & Stegun
    6.1.41, terms to z^-9)."""
    iz = 1.0 / z
    iz2 = iz * iz
    return iz * (1 / 12 - iz2 * (1 / 360 - iz2 * (1 / 1260 - iz2 * (1 / 1680 - iz2 / 1188))))


def _digamma_tail(z):
    """``psi(z) - log z + 1/(2z)`` for z >= 10 (Abramowitz & Stegun 6.3.18, terms to z^-10)."""
    iz2 = 1.0 / (z * z)
    return -iz2 * (1 / 12 - iz2 * (1 / 120 - iz2 * (1 / 252 - iz2 * (1 / 240 - iz2 / 132))))


def lgamma_diff(z, w):
    """``log Gamma(z + w) - log Gamma(z)`` for z > 0, w >= 0 without the cancellation of two
    large log-gammas when z is large (Stirling differences for z >= 10)."""
    big = z >= _ASYMPTOTIC_Z
    zb = jnp.where(big, z, _ASYMPTOTIC_Z)
    asym = (
        (zb - 0.5) * jnp.log1p(w / zb)
        + w * jnp.log(zb + w)
        - w
        + (_stirling_corr(zb + w) - _stirling_corr(zb))
    )
    zs = jnp.where(big, 1.0, z)
    direct = gammaln(zs + w) - gammaln(zs)
    return jnp.where(big, asym, direct)


def _digamma_diff(z, w):
    """``psi(z + w) - psi(z)`` for z > 0, w >= 0, cancellation-free for large z."""
    big = z >= _ASYMPTOTIC_Z
    zb = jnp.where(big, z, _ASYMPTOTIC_Z)
    asym = (
        jnp.log1p(w / zb)
        + 0.5 * (w / (zb * (zb + w)))
        + (_digamma_tail(zb + w) - _digamma_tail(zb))
    )
    zs = jnp.where(big, 1.0, z)
    direct = digamma(zs + w) - digamma(zs)
    return jnp.where(big, asym, direct)


def betaln(a, b):
    """``log B(a, b)`` = ``lgamma(min) - [lgamma(max + min) - lgamma(max)]``, accurate for one or
    both arguments large (``a = 5e5, b = 1/2`` keeps full precision in float32)."""
    lo = jnp.minimum(a, b)
    hi = jnp.maximum(a, b)
    return gammaln(lo) - lgamma_diff(hi, lo)


def _cf_dual(a, b, x):
    """Continued fraction ``h`` of NR ``betacf`` and ``d log h / da``, ``d log h / db``.

    ``I_x(a, b) = x^a (1-x)^b / (a B(a, b)) * h``. Each step ``m`` applies the even partial
    numerator ``m (b - m) x / ((a + 2m - 1)(a + 2m))`` and the odd one
    ``-(a + m)(a + b + m) x / ((a + 2m)(a + 2m + 1))`` (A&S 26.5.8).
    """
    dtype = jnp.result_type(a, b, x)
    eps = jnp.finfo(dtype).eps

    def guard(v):
        return jnp.where(jnp.abs(v) < _LENTZ_TINY, _LENTZ_TINY, v)

    # initial D = 1 / (1 - (a + b) x / (a + 1))
    q = 1.0 - (a + b) * x / (a + 1.0)
    q_a = -x * (1.0 - b) / (a + 1.0) ** 2
    q_b = -x / (a + 1.0)
    q = guard(q)
    d = 1.0 / q
    d_a = -q_a * d * d
    d_b = -q_b * d * d
    c = jnp.ones_like(d)
    c_a = jnp.zeros_like(d)
    c_b = jnp.zeros_like(d)
    log_h = jnp.log(jnp.abs(d))
    sign = jnp.sign(d)
    lh_a = d_a / d
    lh_b = d_b / d

    def step(aa, aa_a, aa_b, d, d_a, d_b, c, c_a, c_b):
        dn = guard(1.0 + aa * d)
        dn_a = aa_a * d + aa * d_a
        dn_b = aa_b * d + aa * d_b
        dinv = 1.0 / dn
        d2_a = -dn_a * dinv * dinv
        d2_b = -dn_b * dinv * dinv
        cinv = 1.0 / c
        cn = guard(1.0 + aa * cinv)
        cn_a = aa_a * cinv - aa * c_a * cinv * cinv
        cn_b = aa_b * cinv - aa * c_b * cinv * cinv
        delta = dinv * cn
        dl_a = d2_a / dinv + cn_a / cn
        dl_b = d2_b / dinv + cn_b / cn
        return dinv, d2_a, d2_b, cn, cn_a, cn_b, delta, dl_a, dl_b

    def body(state):
        old = state
        m, d, d_a, d_b, c, c_a, c_b, log_h, sign, lh_a, lh_b, done_before = state
        mf = m.astype(dtype)
        m2 = 2.0 * mf
        # even step
        den1 = a - 1.0 + m2
        den2 = a + m2
        aa = mf * (b - mf) * x / (den1 * den2)
        aa_a = aa * (-1.0 / den1 - 1.0 / den2)
        aa_b = mf * x / (den1 * den2)
        d, d_a, d_b, c, c_a, c_b, de1, l1a, l1b = step(aa, aa_a, aa_b, d, d_a, d_b, c, c_a, c_b)
        # odd step
        den3 = a + 1.0 + m2
        aa = -(a + mf) * (a + b + mf) * x / (den2 * den3)
        aa_a = aa * (1.0 / (a + mf) + 1.0 / (a + b + mf) - 1.0 / den2 - 1.0 / den3)
        aa_b = -(a + mf) * x / (den2 * den3)
        d, d_a, d_b, c, c_a, c_b, de2, l2a, l2b = step(aa, aa_a, aa_b, d, d_a, d_b, c, c_a, c_b)
        delta = de1 * de2
        log_h = log_h + jnp.log(jnp.abs(delta))
        sign = sign * jnp.sign(delta)
        inc_a = l1a + l2a
        inc_b = l1b + l2b
        lh_a = lh_a + inc_a
        lh_b = lh_b + inc_b
        tol = 2.0 * eps
        done = (
            (jnp.abs(delta - 1.0) <= tol)
            & (jnp.abs(inc_a) <= tol * (1.0 + jnp.abs(lh_a)))
            & (jnp.abs(inc_b) <= tol * (1.0 + jnp.abs(lh_b)))
        )
        # converged elements are frozen: an element's value does not depend on how long the
        # slowest element of its batch keeps the loop running (batch-independent results)
        new = (d, d_a, d_b, c, c_a, c_b, log_h, sign, lh_a, lh_b)
        kept = tuple(jnp.where(done_before, o, v) for o, v in zip(old[1:-1], new, strict=True))
        return (m + 1, *kept, done_before | done)

    def cond(state):
        return (state[0] <= CF_MAX_ITER) & ~jnp.all(state[-1])

    state = (jnp.asarray(1, jnp.int32), d, d_a, d_b, c, c_a, c_b, log_h, sign, lh_a, lh_b,
             jnp.zeros(jnp.shape(d), bool))
    state = jax.lax.while_loop(cond, body, state)
    _, _, _, _, _, _, _, log_h, sign, lh_a, lh_b, _ = state
    return log_h, sign, lh_a, lh_b


def _log_pair(x, y):
    """``(log x, log y)`` for ``x + y = 1`` given both: the logarithm of the one near 1 is
    ``log1p`` of minus the other, which is exact where ``x`` itself is only rounded to 1. At
    ``a = 5e5``, ``y = 1e-6`` in float32, ``a log x`` from the rounded ``x`` is off by up to 6%
    of its value (the spacing of float32 near 1 is 6e-8); via ``log1p(-y)`` it keeps float32
    precision (the Phong normaliser at n = 1e6, cos 1e-3: 2.1e-3 relative error before)."""
    log_x = jnp.where(x > 0.5, jnp.log1p(-jnp.where(x > 0.5, y, 0.0)), jnp.log(x))
    log_y = jnp.where(y > 0.5, jnp.log1p(-jnp.where(y > 0.5, x, 0.0)), jnp.log(y))
    return log_x, log_y


def _front_cf(a, b, x, y):
    """``I_x(a, b)`` by the continued fraction for 0 < x, y = 1 - x, and its a/b partials."""
    log_h, sign, lh_a, lh_b = _cf_dual(a, b, x)
    log_x, log_y = _log_pair(x, y)
    log_front = a * log_x + b * log_y - jnp.log(a) - betaln(a, b)
    val = sign * jnp.exp(log_front + log_h)
    dlog_a = log_x - 1.0 / a + _digamma_diff(a, b) + lh_a
    dlog_b = log_y + _digamma_diff(b, a) + lh_b
    return val, val * dlog_a, val * dlog_b


def _betainc_parts(a, b, x, y):
    """``(I, dI/da, dI/db, dI/dx)`` for ``x = 1 - y`` given both (no cancellation near x = 1)."""
    a = jnp.maximum(a, PARAM_MIN)
    b = jnp.maximum(b, PARAM_MIN)
    interior = (x > 0) & (y > 0)
    xs = jnp.where(interior, x, 0.5)
    ys = jnp.where(interior, y, 0.5)
    direct = xs < (a + 1.0) / (a + b + 2.0)
    # direct: CF at (a, b, x); complement: 1 - CF at (b, a, y), with the partials swapped
    p = jnp.where(direct, a, b)
    q = jnp.where(direct, b, a)
    u = jnp.where(direct, xs, ys)
    v = jnp.where(direct, ys, xs)
    val, dp, dq = _front_cf(p, q, u, v)
    i_val = jnp.where(direct, val, 1.0 - val)
    i_a = jnp.where(direct, dp, -dq)
    i_b = jnp.where(direct, dq, -dp)
    log_xs, log_ys = _log_pair(xs, ys)
    i_x = jnp.exp((a - 1.0) * log_xs + (b - 1.0) * log_ys - betaln(a, b))
    # edges: I_0 = 0, I_1 = 1; dI/dx there is its limit where finite, else 0
    at0 = x <= 0
    lim0 = jnp.where(a == 1.0, jnp.exp(-betaln(a, b)), 0.0)
    lim1 = jnp.where(b == 1.0, jnp.exp(-betaln(a, b)), 0.0)
    i_val = jnp.where(interior, i_val, jnp.where(at0, 0.0, 1.0))
    i_a = jnp.where(interior, i_a, 0.0)
    i_b = jnp.where(interior, i_b, 0.0)
    i_x = jnp.where(interior, i_x, jnp.where(at0, lim0, lim1))
    return i_val, i_a, i_b, i_x


@jax.custom_jvp
def betainc_complement(a, b, x, y):
    """``I_x(a, b)`` given ``x`` and ``y = 1 - x`` separately (pass ``y = cos^2`` when
    ``x = sin^2`` is within rounding of 1). Callers keep ``x + y = 1``; the jvp uses
    ``dI = dI/dx (dx - dy)/2``, exact for any tangent pair with ``dy = -dx``."""
    a, b, x, y = jnp.broadcast_arrays(a, b, x, y)
    return _betainc_parts(a, b, x, y)[0]


@betainc_complement.defjvp
def _betainc_complement_jvp(primals, tangents):
    a, b, x, y = jnp.broadcast_arrays(*primals)
    ta, tb, tx, ty = (jnp.broadcast_to(t, a.shape) for t in tangents)
    val, ia, ib, ix = _betainc_parts(a, b, x, y)
    # x and y move together along x + y = 1: the x-derivative is split half and half so that a
    # consistent pair (tx, ty = -tx) gives exactly ix * tx.
    return val, ia * ta + ib * tb + 0.5 * ix * (tx - ty)


def betainc(a, b, x):
    """Regularised incomplete beta ``I_x(a, b)``, differentiable in ``a``, ``b`` and ``x``.

    ``a, b > 0`` (clamped at :data:`PARAM_MIN`), ``0 <= x <= 1``. See the module docstring for the
    method, the validated ranges and the edge conventions.
    """
    return betainc_complement(a, b, x, 1.0 - x)

