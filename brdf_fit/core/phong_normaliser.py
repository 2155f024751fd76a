"""Energy normaliser of the modified-Phong lobe about the mirror direction.

For a view direction ``wo`` with ``cos_o = wo_z = c``, ``s = sqrt(1 - c^2)``, the mirror direction
``r = (-wo_x, -wo_y, wo_z)`` and an exponent ``n >= 0``,

    N(c, n) = Int_{H+} max(0, r.wi)^n (z . wi) dwi,

so that ``f = rho_s max(0, r.wi)^n / N(c, n)`` has directional albedo exactly ``rho_s`` for every
view (it is not reciprocal). At ``n = 0`` the lobe is the limit ``n -> 0+``: the indicator of
``r.wi > 0``, giving ``N(c, 0) = pi (1 + c)/2``. At normal incidence ``N(1, n) = 2 pi/(n + 2)``.

Derivation (written out here; it is the result of Mallett & Yuksel 2020, their ``I_M``)
-----------------------------------------------------------------------------------------
Put ``wi`` in the frame of ``r``: polar angle ``t`` from ``r``, azimuth ``p`` measured from the
plane of ``r`` and ``z``, ``u = cos t``. Then ``z . wi = c u + s sqrt(1 - u^2) cos p``. For
``u >= s`` the whole ring is above the horizon and contributes ``2 pi c u``; for ``u < s`` only
``cos p > -c u/(s sqrt(1 - u^2))`` is. Integrating ``u^n`` against these ring integrals and
substituting ``x = 1 - u^2`` into the clipped part gives (with ``B(x; a, b)`` the non-regularised
incomplete beta function and ``I_x(a, b)`` the regularised one)

    N = [2 pi c + sqrt(pi) G(n) (s^n - c (n/2) B(s^2; n/2, 1/2))] / (n + 2),
    G(n) = Gamma((n + 1)/2) / Gamma(n/2 + 1),

and since ``(n/2) B(s^2; n/2, 1/2) sqrt(pi) G(n) = pi I_{s^2}(n/2, 1/2)`` (``B(a, 1/2) =
sqrt(pi) Gamma(a)/Gamma(a + 1/2)``),

    N = [pi c (2 - I_{s^2}(n/2, 1/2)) + sqrt(pi) G(n) s^n] / (n + 2).          (MY)

Checks: c = 1 gives ``2 pi/(n + 2)``; n = 0 gives ``pi (1 + c)/2`` (``I_x(0+, 1/2) = 1``). The
formula is verified against an independent adaptive SciPy integration of the definition in
``tests/test_phong_norm.py`` (relative error < 1e-10 for n in {0, ..., 1000}, c in [1e-4, 1]);
this also verifies the ``I_M`` formula that ``shared/reference/models.md`` section 4.8 gives.

Methods
-------
``"mallett-yuksel"``: I. Mallett and C. Yuksel, "Constant-time energy-normalization for the Phong
specular BRDFs", *The Visual Computer* 36 (CGI 2020): the O(1) closed form (MY) for real
``n``, via the incomplete beta function (their ``I_M``, the normaliser of the modified Phong BRDF;
the paper's equation numbers could not be checked from here). :func:`brdf_fit.special.betainc`
supplies ``d/dn``; ``G(n)`` uses a cancellation-free log-gamma difference and ``s^n`` is
``exp(n/2 log1p(-c^2))``, so value and ``d/dn`` stay finite in float32 up to n = 1e6 and down to
c = 1e-4 (where ``s^2`` rounds to 1 in float32; ``y = c^2`` is passed to the incomplete beta
separately).

``"arvo"``: J. Arvo, "Applications of irradiance tensors to the simulation of non-Lambertian
phenomena", SIGGRAPH 1995: integer exponents by an O(n) recurrence in steps of 2. Arvo obtains
the axial moments of a cosine power over a region by a recurrence ``n -> n + 2`` (irradiance
tensors, his sections 3-5); for the hemisphere clipped by the horizon the same recurrence is the
integration-by-parts identity of the incomplete beta function

    B(x; a + 1, 1/2) = (a B(x; a, 1/2) - x^a sqrt(1 - x)) / (a + 1/2),
    B(s^2; 1/2, 1/2) = 2 theta_o,   B(s^2; 1, 1/2) = 2 (1 - c),

with ``G(a + 1) = G(a) (a + 1/2)/(a + 1)`` (``G(1/2) = 2/sqrt(pi)``, ``G(1) = sqrt(pi)/2``) and
``x^(a+1) = x^a x``; ``N`` then follows from the first form above. The loop is a
``jax.lax.fori_loop`` with the **static** trip count ``max_n // 2`` (masked steps beyond
``n``), so it is jit-, vmap- and reverse-differentiable in ``c``; the exponent is rounded to the
nearest integer and is not differentiated. Exponents above ``max_n`` give NaN. Forward error:
each step multiplies an existing error by ``a/(a + 1/2) < 1``, and the term it feeds is
``O(c/n)`` next to ``2 pi c/(n + 2)``: relative error ~ ``n * 1e-16``.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp

from brdf_fit.core.numerics import safe_sqrt
from brdf_fit.core.special import betainc_complement, lgamma_diff

__all__ = ["normaliser", "METHODS", "ARVO_MAX_N"]

METHODS = ("mallett-yuksel", "arvo")
#: Default static bound on the exponent for the Arvo recurrence (1024 loop steps).
ARVO_MAX_N = 2048

_SQRT_PI = math.sqrt(math.pi)


def _pow_s(c, n):
    """``s^n = (1 - c^2)^(n/2)`` via ``log1p``; 1 at n = 0 for c < 1, 0 at c >= 1 (the
    ``n -> 0+`` convention), finite gradients everywhere (double where)."""
    c2 = c * c
    ok = c2 < 1.0
    l1p = jnp.log1p(-jnp.where(ok, c2, 0.0))
    return jnp.where(ok, jnp.exp(0.5 * n * l1p), 0.0)


def _mallett_yuksel(c, n):
    a = 0.5 * n
    c2 = c * c
    x = jnp.clip(1.0 - c2, 0.0, 1.0)
    y = jnp.clip(c2, 0.0, 1.0)
    i_reg = betainc_complement(a, jnp.full_like(a, 0.5), x, y)
    g = jnp.exp(-lgamma_diff(a + 0.5, jnp.full_like(a, 0.5)))
    return (math.pi * c * (2.0 - i_reg) + _SQRT_PI * g * _pow_s(c, n)) / (n + 2.0)


def _arvo(c, n, max_n: int):
    n_int = jnp.round(jax.lax.stop_gradient(n))
    odd = jnp.mod(n_int, 2.0) == 1.0
    c2 = c * c
    x = jnp.clip(1.0 - c2, 0.0, 1.0)
    s = safe_sqrt(x)
    theta = jnp.arctan2(s, c)
    # start: a = 1/2 (n = 1) or a = 1 (n = 2)
    a0 = jnp.where(odd, 0.5, 1.0)
    beta = jnp.where(odd, 2.0 * theta, 2.0 * (1.0 - c))
    g = jnp.where(odd, 2.0 / _SQRT_PI, 0.5 * _SQRT_PI)
    xa = jnp.where(odd, s, x)  # x^a
    a_target = jnp.maximum(0.5 * n_int, a0)

    def body(_, st):
        a, beta, g, xa = st
        go = a < a_target
        nb = (a * beta - xa * c) / (a + 0.5)
        ng = g * (a + 0.5) / (a + 1.0)
        return (jnp.where(go, a + 1.0, a), jnp.where(go, nb, beta), jnp.where(go, ng, g),
                jnp.where(go, xa * x, xa))

    a, beta, g, xa = jax.lax.fori_loop(0, max_n // 2, body, (a0, beta, g, xa))
    n_pos = 2.0 * a
    val = (2.0 * math.pi * c + _SQRT_PI * g * (xa - c * a * beta)) / (n_pos + 2.0)
    # n = 0: the indicator lobe, N = pi (1 + c)/2 (and pi at c = 1)
    val0 = 0.5 * math.pi * (1.0 + c)
    val = jnp.where(n_int == 0, val0, val)
    return jnp.where(n_int > max_n, jnp.nan, val)


# Compiled once per shape and dtype: called outside jit, the incomplete beta's continued fraction
# and the Arvo loop would otherwise be traced and compiled anew on every call (a loop primitive
# run eagerly is compiled per trace); inside an enclosing jit these are inlined.
_mallett_yuksel_jit = jax.jit(_mallett_yuksel)
_arvo_jit = jax.jit(_arvo, static_argnums=2)


def normaliser(cos_o, n, method: str = "mallett-yuksel", max_n: int = ARVO_MAX_N):
    """``N(cos_o, n) = Int_{H+} max(0, r.wi)^n (z.wi) dwi`` (see the module docstring).

    ``cos_o`` in (0, 1], ``n >= 0``; arrays broadcast. ``method="mallett-yuksel"`` (real ``n``,
    O(1), differentiable in ``cos_o`` and ``n``) or ``"arvo"`` (integer ``n <= max_n``, O(max_n)
    with ``max_n`` static, differentiable in ``cos_o`` only).
    """
    cos_o, n = jnp.broadcast_arrays(jnp.asarray(cos_o), jnp.asarray(n))
    dtype = jnp.result_type(cos_o, n)
    if not jnp.issubdtype(dtype, jnp.floating):
        dtype = jnp.result_type(float)
    cos_o = cos_o.astype(dtype)
    n = n.astype(dtype)
    if method == "mallett-yuksel":
        return _mallett_yuksel_jit(cos_o, n)
    if method == "arvo":
        return _arvo_jit(cos_o, n, int(max_n))
    raise ValueError(f"unknown normaliser method {method!r}; valid: {', '.join(METHODS)}")
