"""Quadrature rules on the hemisphere and the sphere of directions, as plain data.

A :class:`Rule` is a set of unit directions and solid-angle weights such that

    integral of g(w) dw  ~=  sum_k weights[k] * g(directions[k]).

Product rules (smooth integrands) in the coordinates (mu, phi), mu = cos(theta), for which the
solid-angle element is simply ``dw = dmu dphi``:

* In mu: Gauss-Legendre quadrature. With ``n`` nodes it integrates polynomials of degree
  ``2 n - 1`` exactly, and it converges geometrically for integrands analytic on the interval
  (P. J. Davis and P. Rabinowitz, *Methods of Numerical Integration*, 2nd ed., Academic Press
  1984, sec. 2.7). The nodes are those of :func:`numpy.polynomial.legendre.leggauss`, affinely
  mapped to the requested interval.
* In phi: the periodic trapezoid rule, ``n_phi`` equally spaced nodes offset by half a step,
  all with weight ``2 pi / n_phi``. It integrates the trigonometric polynomials of degree
  ``< n_phi`` exactly, and converges geometrically for smooth periodic integrands
  (L. N. Trefethen and J. A. C. Weideman, "The exponentially convergent trapezoidal rule",
  *SIAM Review* 56(3):385-458, 2014).

Gauss-Legendre only converges fast for smooth integrands: an integrand with a kink or a jump at a
known ``mu`` (the horizon cut of a lobe, a total-internal-reflection edge) should use
:func:`composite_gauss_legendre_hemisphere` with a panel break at that ``mu``.

Lobe-adapted rules (sharp lobes): :func:`halfvector_rule` places the nodes in the half-vector
parameterisation ``wi = 2 (wo.h) h - wo``, ``dwi = 4 (wo.h) dw_h`` (B. Walter, S. Marschner, H. Li,
K. Torrance, "Microfacet models for refraction through rough surfaces", EGSR 2007, eq. 14), in the
slope plane of ``h``, where the half vectors reflecting ``wo`` above the horizon form a disk: the
horizon is the exact boundary of the domain, the lobe is resolved by sinh-graded Gauss-Legendre
panels (construction and convergence tables: docs/quadrature.md).
:func:`brdf_fit.core.mirror_rule.mirror_lobe_rule` does the same for power-cosine lobes about
the mirror direction (the Phong family).
:func:`brdf_fit.verify.albedo.directional_albedo` integrates any model lobe by lobe with the rule
suited to each; this module knows no model.

Node arrays are built with NumPy in float64 and converted to JAX arrays only at the end, at the
requested ``dtype`` (default: JAX's default float dtype, i.e. float64 when ``jax_enable_x64`` is
on and float32 otherwise).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

__all__ = [
    "HALFVECTOR_N_PHI",
    "HALFVECTOR_N_THETA",
    "Rule",
    "composite_gauss_legendre_hemisphere",
    "cosine_rule",
    "gauss_legendre_hemisphere",
    "gauss_legendre_interval",
    "gauss_legendre_sphere",
    "halfvector_rule",
    "integrate",
    "periodic_trapezoid",
    "AZIMUTHAL_N_PHI",
    "azimuthal_rule",
]


class Rule(eqx.Module):
    """A quadrature rule on (part of) the sphere of directions.

    Attributes:
        directions: ``(N, 3)`` unit vectors (local frame, z = normal).
        weights: ``(N,)`` solid-angle weights: ``integral g dw ~= sum(weights * g(directions))``.
    """

    directions: jax.Array
    weights: jax.Array

    @property
    def n(self) -> int:
        """Number of nodes (per direction, for the batched rules of :func:`halfvector_rule`)."""
        return int(self.weights.shape[-1])


def _float_dtype(dtype) -> np.dtype:
    """The requested float dtype, or JAX's default float dtype (respects ``jax_enable_x64``)."""
    return jax.dtypes.canonicalize_dtype(np.float64 if dtype is None else dtype)


def gauss_legendre_interval(n: int, a: float = -1.0, b: float = 1.0) -> tuple[np.ndarray, ...]:
    """Gauss-Legendre nodes and weights on ``[a, b]`` as float64 NumPy arrays.

    Exact for polynomials of degree ``2 n - 1``; nodes are strictly inside ``(a, b)``.
    """
    if n < 1:
        raise ValueError(f"need at least one node, got n={n}")
    x, w = np.polynomial.legendre.leggauss(int(n))
    half = 0.5 * (float(b) - float(a))
    mid = 0.5 * (float(b) + float(a))
    return mid + half * x, half * w


def periodic_trapezoid(n_phi: int) -> tuple[np.ndarray, np.ndarray]:
    """Periodic trapezoid rule on ``[0, 2 pi)``: nodes ``(j + 1/2) 2 pi / n_phi``, equal weights.

    Exact for trigonometric polynomials of degree ``< n_phi`` (float64 NumPy arrays).
    """
    if n_phi < 1:
        raise ValueError(f"need at least one node, got n_phi={n_phi}")
    step = 2.0 * np.pi / int(n_phi)
    phi = (np.arange(int(n_phi), dtype=np.float64) + 0.5) * step
    return phi, np.full(int(n_phi), step)


def _product_rule(mu, w_mu, phi, w_phi, dtype) -> Rule:
    """Tensor product of a rule in mu and one in phi, as directions (mu-major order)."""
    mu = np.asarray(mu, dtype=np.float64)
    sin_t = np.sqrt(np.clip(1.0 - mu * mu, 0.0, None))
    m, p = np.meshgrid(mu, phi, indexing="ij")
    s, _ = np.meshgrid(sin_t, phi, indexing="ij")
    dirs = np.stack([s * np.cos(p), s * np.sin(p), m], axis=-1).reshape(-1, 3)
    w = np.outer(w_mu, w_phi).reshape(-1)
    dt = _float_dtype(dtype)
    return Rule(directions=jnp.asarray(dirs, dtype=dt), weights=jnp.asarray(w, dtype=dt))


def gauss_legendre_hemisphere(
    n_mu: int, n_phi: int, mu_range: tuple[float, float] = (0.0, 1.0), dtype=None
) -> Rule:
    """Gauss-Legendre in ``mu = cos(theta)`` on ``mu_range`` times the periodic trapezoid in phi.

    Exact for ``P(mu) * T(phi)`` with ``P`` a polynomial of degree ``<= 2 n_mu - 1`` and ``T`` a
    trigonometric polynomial of degree ``< n_phi``. Total weight = ``2 pi (mu_1 - mu_0)``.

    Args:
        n_mu: Gauss-Legendre nodes in mu.
        n_phi: equally spaced azimuth nodes (offset by half a step).
        mu_range: ``(mu_0, mu_1)`` with ``-1 <= mu_0 < mu_1 <= 1``; default the upper hemisphere.
        dtype: float dtype of the returned arrays (default: JAX's default float dtype).
    """
    mu0, mu1 = float(mu_range[0]), float(mu_range[1])
    if not -1.0 <= mu0 < mu1 <= 1.0:
        raise ValueError(f"mu_range must satisfy -1 <= mu_0 < mu_1 <= 1, got {mu_range}")
    mu, w_mu = gauss_legendre_interval(n_mu, mu0, mu1)
    phi, w_phi = periodic_trapezoid(n_phi)
    return _product_rule(mu, w_mu, phi, w_phi, dtype)


def gauss_legendre_sphere(n_mu: int, n_phi: int, dtype=None) -> Rule:
    """The product rule of :func:`gauss_legendre_hemisphere` on the whole sphere, mu in (-1, 1).

    For densities that may spill below the horizon (total weight ``4 pi``). A density with a jump
    at the horizon converges slowly with this rule; use a composite rule with a break at 0,
    ``composite_gauss_legendre_hemisphere((0.0,), n, n_phi, mu_range=(-1, 1))``, instead.
    """
    return gauss_legendre_hemisphere(n_mu, n_phi, mu_range=(-1.0, 1.0), dtype=dtype)


def composite_gauss_legendre_hemisphere(
    mu_breaks: Sequence[float],
    n_per_panel: int | Sequence[int],
    n_phi: int,
    mu_range: tuple[float, float] = (0.0, 1.0),
    dtype=None,
) -> Rule:
    """Composite Gauss-Legendre in mu (panels split at ``mu_breaks``) times the trapezoid in phi.

    Use it for integrands with a kink, a jump or a sharp peak at a known ``mu``: each panel is
    integrated by its own Gauss-Legendre rule, so the rule converges as fast as for a smooth
    integrand if the breaks sit on the singularities.

    Args:
        mu_breaks: panel boundaries inside ``mu_range``; the ends of ``mu_range`` are added if
            missing, duplicates are removed, so ``(0.3,)`` and ``(0, 0.3, 1)`` are equivalent on
            the hemisphere.
        n_per_panel: Gauss-Legendre nodes per panel, one int for all or one per panel.
        n_phi: equally spaced azimuth nodes.
        mu_range: the interval covered (default the upper hemisphere ``(0, 1)``).
        dtype: float dtype of the returned arrays (default: JAX's default float dtype).
    """
    lo, hi = float(mu_range[0]), float(mu_range[1])
    if not -1.0 <= lo < hi <= 1.0:
        raise ValueError(f"mu_range must satisfy -1 <= mu_0 < mu_1 <= 1, got {mu_range}")
    inner = np.asarray(mu_breaks, dtype=np.float64).reshape(-1)
    if np.any(inner < lo) or np.any(inner > hi):
        raise ValueError(f"mu_breaks {list(inner)} outside mu_range {mu_range}")
    edges = np.unique(np.concatenate([[lo], inner, [hi]]))
    n_panels = edges.size - 1
    counts = (
        [int(n_per_panel)] * n_panels
        if np.ndim(n_per_panel) == 0
        else [int(c) for c in n_per_panel]  # type: ignore[union-attr]
    )
    if len(counts) != n_panels:
        raise ValueError(f"{len(counts)} node counts given for {n_panels} panels {list(edges)}")
    panels = zip(counts, edges[:-1], edges[1:], strict=True)
    parts = [gauss_legendre_interval(c, a, b) for c, a, b in panels]
    mu = np.concatenate([p[0] for p in parts])
    w_mu = np.concatenate([p[1] for p in parts])
    phi, w_phi = periodic_trapezoid(n_phi)
    return _product_rule(mu, w_mu, phi, w_phi, dtype)


def integrate(fn: Callable[[jax.Array], jax.Array], rule: Rule) -> jax.Array:
    """``sum_k w_k fn(d_k)``: the rule applied to ``fn``.

    ``fn`` maps the ``(N, 3)`` directions to ``(N,)`` values (returns a scalar) or ``(N, C)``
    values (returns ``(C,)``). The weights and the values are promoted to a common dtype first, so
    a float32 integrand works with a float64 rule under strict dtype promotion.
    """
    vals = jnp.asarray(fn(rule.directions))
    if vals.shape[:1] != rule.weights.shape:
        raise ValueError(f"fn returned shape {vals.shape}; expected ({rule.n},) or ({rule.n}, C)")
    with jax.numpy_dtype_promotion("standard"):  # explicit, deliberate promotion
        dt = jnp.promote_types(rule.weights.dtype, vals.dtype)
    return jnp.tensordot(rule.weights.astype(dt), vals.astype(dt), axes=1)


# ------------------------------------------------------------------------------- smooth lobes


#: azimuth nodes of :func:`azimuthal_rule` by default: its lobes do not depend on the azimuth
#: (4 keeps any ``cos(k phi)`` term with ``k < 4`` exact)
AZIMUTHAL_N_PHI = 4


def azimuthal_rule(mu, w_mu, n_phi: int = AZIMUTHAL_N_PHI, dtype=None) -> Rule:
    """A given rule in ``mu = cos(theta)`` (nodes ``mu``, weights ``w_mu``, NumPy or JAX arrays,
    possibly traced) times the periodic trapezoid in phi: the rule of a lobe that declares its
    own ``mu`` nodes (``quadrature_lobe() == ("mu", (mu, w_mu))``, e.g. the tabulated
    multiple-scattering lobe of :mod:`brdf_fit.models.kulla_conty`). Directions mu-major."""
    dt = _float_dtype(dtype)
    mu = jnp.asarray(mu, dt).reshape(-1)
    w_mu = jnp.asarray(w_mu, dt).reshape(-1)
    phi, w_phi = periodic_trapezoid(n_phi)
    phi, w_phi = jnp.asarray(phi, dt), jnp.asarray(w_phi, dt)
    s = jnp.sqrt(jnp.clip(1.0 - mu * mu, 0.0, None))[:, None]
    dirs = jnp.stack([s * jnp.cos(phi)[None, :], s * jnp.sin(phi)[None, :],
                      jnp.broadcast_to(mu[:, None], (mu.size, phi.size))], axis=-1)
    return Rule(directions=dirs.reshape(-1, 3), weights=(w_mu[:, None] * w_phi[None, :]).ravel())


def cosine_rule(n_mu: int = 8, n_phi: int = 4, dtype=None) -> Rule:
    """Gauss-Legendre in ``mu = cos(theta)`` on (0, 1) times the periodic trapezoid in phi.

    The rule for smooth lobes. It is exact for ``P(mu) T(phi)`` with ``P`` of degree
    ``<= 2 n_mu - 1`` and ``T`` trigonometric of degree ``< n_phi``, so a Lambertian integrand
    ``rho/pi * mu`` is integrated exactly by any rule (even ``cosine_rule(1, 1)``), and a
    cosine-power lobe ``mu^k`` by ``n_mu >= (k + 1)/2``. Same nodes as
    :func:`gauss_legendre_hemisphere` on the upper hemisphere.
    """
    return gauss_legendre_hemisphere(n_mu, n_phi, dtype=dtype)


# ------------------------------------------------------------------- lobe-adapted (half vector)

#: Default node counts of :func:`halfvector_rule` (``n_theta`` along each ray, ``n_phi`` rays):
#: 48 x 64 = 3072 evaluations reach 3e-8 absolute on the GGX albedo for alpha and cos(theta_o)
#: in [1e-3, 1] (docs/quadrature.md).
HALFVECTOR_N_THETA = 48
HALFVECTOR_N_PHI = 64
#: Pole on the boundary when the lobe centre is closer than this many lobe widths to the horizon
#: cut (in the stretched slope plane), otherwise the pole is the lobe centre.
_POLE_SWITCH = 3.0
#: Beyond this distance (in lobe widths) the boundary-pole rule gets a central angular panel
#: ``|psi - psi_lobe| < atan(_CENTRE_WIDTH / d)`` with ``_CENTRE_FRACTION`` of the rays, clipped
#: to ``_CENTRE_CLIP`` of the way to either end of the half-range of ray directions.
_SPLIT_SWITCH = 1.0
_CENTRE_WIDTH = 4.0
_CENTRE_FRACTION = 0.375
_CENTRE_CLIP = 0.85
#: Largest grading factor of the circle map of the lobe-centred rule (anisotropic lobes).
_CIRCLE_MAP_MAX = 2.0
#: Nearest boundary point in the stretched metric: coarse grid in the boundary angle, then
#: safeguarded Newton steps (exact in one step for isotropic lobes, where it is the grid node 0).
_NEAREST_GRID = 64
_NEAREST_NEWTON = 12


def _is_tracer(*xs) -> bool:
    return any(isinstance(x, jax.core.Tracer) for x in xs)


def _gl01(n: int) -> tuple[np.ndarray, np.ndarray]:
    """Gauss-Legendre nodes and weights on [0, 1] (float64 NumPy)."""
    return gauss_legendre_interval(n, 0.0, 1.0)


def _nearest_boundary(xp, co, so, wx, wy, ax, ay):
    """Boundary angle offset ``delta`` of the point of the horizon circle nearest (in the metric
    stretched by the roughness) to the lobe centre, and that point ``(bx, by)`` in slope space.

    The horizon circle (see :func:`halfvector_rule`) has centre ``c0 = wo_xy / co`` and radius
    ``R = 1 / co``; its point at offset ``delta`` from the isotropic nearest point ``-d w`` is
    written without cancellation as ``b = -d w + R (2 sin^2(delta/2) w + sin(delta) w_perp)``.
    """
    R = 1.0 / co
    d = co / (1.0 + so)

    def point(delta, d, R, wx, wy):
        s2 = 2.0 * xp.sin(0.5 * delta) ** 2
        sn = xp.sin(delta)
        u = -d + R * s2  # along w
        v = R * sn  # along w_perp
        return u * wx - v * wy, u * wy + v * wx

    def cost(delta, d, R, wx, wy, ax, ay):
        bx, by = point(delta, d, R, wx, wy)
        return (bx / ax) ** 2 + (by / ay) ** 2

    grid = (np.arange(_NEAREST_GRID) - _NEAREST_GRID // 2) * (2.0 * np.pi / _NEAREST_GRID)
    g = xp.asarray(grid, dtype=co.dtype)
    per_dir = (d, R, wx, wy, ax, ay)
    f = cost(g, *(xp.expand_dims(a, -1) for a in per_dir))  # (..., G); g[G//2] = 0
    delta = g[xp.argmin(f, axis=-1)]
    step_max = 2.0 * np.pi / _NEAREST_GRID

    def newton(_, delta):
        bx, by = point(delta, d, R, wx, wy)
        c, s = xp.cos(delta), xp.sin(delta)
        dbx, dby = R * (s * wx - c * wy), R * (s * wy + c * wx)
        ddbx, ddby = R * (c * wx + s * wy), R * (c * wy - s * wx)
        g1 = 2.0 * (bx * dbx / ax**2 + by * dby / ay**2)
        g2 = 2.0 * ((dbx**2 + bx * ddbx) / ax**2 + (dby**2 + by * ddby) / ay**2)
        step = xp.where(g2 > 0, -g1 / xp.where(g2 > 0, g2, 1.0), -xp.sign(g1) * step_max)
        cand = delta + xp.clip(step, -step_max, step_max)
        return xp.where(cost(cand, *per_dir) < cost(delta, *per_dir), cand, delta)

    if xp is jnp:  # a loop, not 12 unrolled copies: keeps the compile time of jit low
        delta = jax.lax.fori_loop(0, _NEAREST_NEWTON, newton, delta)
    else:
        for i in range(_NEAREST_NEWTON):
            delta = newton(i, delta)
    return delta, point(delta, d, R, wx, wy)


def _angular_candidates(n_phi: int):
    """Gauss-Legendre / trapezoid reference nodes of the angular panels (float64 NumPy): the
    trapezoid of the lobe-centred rule, the end panels of the boundary-pole rule, and its central
    and end panels when it is split."""
    half = n_phi // 2
    nc = max(1, int(round(_CENTRE_FRACTION * half)))
    ne = half - nc
    return {
        "trap": (np.arange(n_phi) + 0.5) * (2.0 * np.pi / n_phi),
        "end": _gl01(half),
        "split_c": _gl01(nc),
        "split_e": _gl01(ne),
    }


def _halfvector_nodes(xp, wo, ax, ay, n_theta: int, n_phi: int):
    """Directions ``(..., n_phi * n_theta, 3)`` and weights ``(..., n_phi * n_theta)`` of
    :func:`halfvector_rule`, computed with the array module ``xp`` (NumPy or jax.numpy) in the
    float dtype of ``wo``. ``wo`` is ``(..., 3)``; ``ax``, ``ay`` broadcast against ``wo[..., 0]``.
    """
    dt = wo.dtype

    def const(a):
        return xp.asarray(np.asarray(a, dtype=np.float64), dtype=dt)

    ex = xp.expand_dims
    ox, oy, oz = wo[..., 0], wo[..., 1], wo[..., 2]
    ax, ay = xp.broadcast_to(ax, ox.shape), xp.broadcast_to(ay, ox.shape)
    up = oz > 0
    co = xp.where(up, oz, 1.0)
    so = xp.sqrt(ox * ox + oy * oy)
    has_az = so > 0
    sos = xp.where(has_az, so, 1.0)
    wx, wy = xp.where(has_az, ox / sos, 1.0), xp.where(has_az, oy / sos, 0.0)
    so = xp.where(up, so, 0.0)
    R = 1.0 / co
    cx, cy = ox / co, oy / co  # centre of the horizon circle in slope space

    # pole: boundary point nearest to the lobe centre in lobe widths (distance dp)
    delta, (bx, by) = _nearest_boundary(xp, co, so, wx, wy, ax, ay)
    dp = xp.sqrt((bx / ax) ** 2 + (by / ay) ** 2)
    nbx = -xp.cos(delta) * wx - xp.sin(delta) * wy  # outward normal of the circle at b
    nby = -xp.cos(delta) * wy + xp.sin(delta) * wx
    px, py = bx / ax, by / ay  # pole in the stretched plane
    tnx, tny = ax * nbx, ay * nby
    tn = xp.sqrt(tnx * tnx + tny * tny)
    e0x, e0y = -tnx / tn, -tny / tn  # centre of the admissible half-range of ray directions
    epx, epy = -e0y, e0x
    # angle from the ends of the half-range at which a ray is one lobe width long
    eps = ((ax * epx) ** 2 + (ay * epy) ** 2) / (2.0 * R * tn)

    cand = _angular_candidates(n_phi)

    # (a) pole at the lobe centre: trapezoid in an angle chi, with phi(chi) graded towards the
    # axis of the smaller width (the long axis of the stretched horizon ellipse) by the circle
    # map tan(phi) = tan(chi) / K, K = min(sqrt(alpha_max / alpha_min), _CIRCLE_MAP_MAX)
    chi = const(cand["trap"])
    kk = ex(xp.minimum(xp.sqrt(xp.maximum(ax, ay) / xp.minimum(ax, ay)), _CIRCLE_MAP_MAX), -1)
    den = xp.sqrt((kk * xp.cos(chi)) ** 2 + xp.sin(chi) ** 2)
    c_long, c_short = kk * xp.cos(chi) / den, xp.sin(chi) / den
    x_long = ex(ax <= ay, -1)
    trap_c = xp.where(x_long, c_long, c_short)
    trap_s = xp.where(x_long, c_short, c_long)
    trap_w = (2.0 * np.pi / n_phi) * kk / den**2

    # (b) pole on the boundary: the half-range psi in (-pi/2, pi/2) split at the direction psi_L
    # of the lobe centre, each part one Gauss-Legendre panel graded (sinh map) towards its end
    lx, ly = -px, -py
    ln = xp.maximum(xp.sqrt(lx * lx + ly * ly), 1e-300)
    cl, sl = (lx * e0x + ly * e0y) / ln, (lx * epx + ly * epy) / ln
    psi_l = xp.arctan2(sl, xp.maximum(cl, 0.0))

    def end_panel(nodes, length, sign):
        """Nodes psi = sign (pi/2 - t), t = eps sinh(y) in (0, length]."""
        y, wy_ = (const(a) for a in nodes)
        Y = xp.arcsinh(ex(length / eps, -1))
        t = ex(eps, -1) * xp.sinh(Y * y)
        w = ex(eps, -1) * Y * wy_ * xp.cosh(Y * y)
        return xp.sin(t), sign * xp.cos(t), w  # cos(psi), sin(psi), weight

    def gl_panel(nodes, a, b):
        y, wy_ = (const(c) for c in nodes)
        psi = ex(a, -1) + ex(b - a, -1) * y
        return xp.cos(psi), xp.sin(psi), ex(b - a, -1) * wy_

    def join(*parts):
        return tuple(xp.concatenate(c, axis=-1) for c in zip(*parts, strict=True))

    half = 0.5 * np.pi
    plain = join(
        end_panel(cand["end"], half - psi_l, 1.0), end_panel(cand["end"], half + psi_l, -1.0)
    )
    # (c) as (b) with two central Gauss-Legendre panels psi_L -+ psi_c around the lobe
    psi_c = xp.arctan(_CENTRE_WIDTH / xp.maximum(dp, 1e-300))
    lo = psi_l - xp.minimum(psi_c, _CENTRE_CLIP * (half + psi_l))
    hi = psi_l + xp.minimum(psi_c, _CENTRE_CLIP * (half - psi_l))
    central = join(
        gl_panel(cand["split_c"], psi_l, hi),
        end_panel(cand["split_e"], half - hi, 1.0),
        gl_panel(cand["split_c"], lo, psi_l),
        end_panel(cand["split_e"], half + lo, -1.0),
    )
    split = ex(dp > _SPLIT_SWITCH, -1)
    cpsi, spsi, wpsi = (xp.where(split, c, p) for c, p in zip(central, plain, strict=True))

    on_b = ex((dp < _POLE_SWITCH) & up, -1)
    exs = xp.where(on_b, ex(e0x, -1) * cpsi + ex(epx, -1) * spsi, trap_c)  # (..., n_phi)
    eys = xp.where(on_b, ex(e0y, -1) * cpsi + ex(epy, -1) * spsi, trap_s)
    wphi = xp.where(on_b, wpsi, trap_w)
    Px = xp.where(on_b, ex(px, -1), 0.0)
    Py = xp.where(on_b, ex(py, -1), 0.0)

    # extent of each ray: the horizon circle |p - c0| = R in slope space, p = S (P + r e)
    tex, tey = ex(ax, -1) * exs, ex(ay, -1) * eys
    A = tex * tex + tey * tey
    rmax_b = 2.0 * ex(R * tn, -1) * xp.where(on_b, cpsi, 1.0) / A
    B = -2.0 * (ex(cx, -1) * tex + ex(cy, -1) * tey)
    sq = xp.sqrt(B * B + 4.0 * A)
    rmax_o = xp.where(B <= 0, (sq - B) / (2.0 * A), 2.0 / xp.where(B <= 0, 1.0, B + sq))
    rmax = xp.where(on_b, rmax_b, rmax_o)
    rmin = xp.where(on_b, 0.0, -1.0 / (A * rmax_o))

    # radial sinh map centred on the closest approach of the ray to the lobe centre, scaled by
    # the lobe width there: 1 + |P + r e|^2 = (r - rc)^2 + wr^2
    rc = -(Px * exs + Py * eys)
    wr = xp.sqrt(1.0 + xp.maximum(Px * Px + Py * Py - rc * rc, 0.0))
    rc = xp.minimum(rc, rmax)
    x0 = xp.arcsinh(-rc / wr)
    x1 = xp.arcsinh((rmax - rc) / wr)
    xg, wg = (const(a) for a in _gl01(n_theta))
    x = ex(x0, -1) + ex(x1 - x0, -1) * xg  # (..., n_phi, n_theta)
    r = ex(rc, -1) + ex(wr, -1) * xp.sinh(x)
    wrad = ex(x1 - x0, -1) * wg * ex(wr, -1) * xp.cosh(x) * r

    # slope-space point -> half vector -> wi (mirror of wo), solid-angle weights
    tx2, ty2 = ex(ex(ax, -1), -1), ex(ex(ay, -1), -1)
    sx = tx2 * (ex(Px, -1) + r * ex(exs, -1))
    sy = ty2 * (ex(Py, -1) + r * ex(eys, -1))
    hz = 1.0 / xp.sqrt(1.0 + sx * sx + sy * sy)
    ox2, oy2, co2 = (ex(ex(a, -1), -1) for a in (ox, oy, co))
    woh = (sx * ox2 + sy * oy2 + co2) * hz
    k = 2.0 * woh * hz
    wix = k * sx - ox2
    wiy = k * sy - oy2
    wiz = co2 * hz * hz * ex(A, -1) * (ex(rmax, -1) - r) * (r - ex(rmin, -1))
    wgt = ex(wphi, -1) * wrad * tx2 * ty2 * hz**3 * 4.0 * woh
    up2 = ex(ex(up, -1), -1)
    wgt = xp.where(up2, wgt, 0.0)
    dirs = xp.stack([wix, wiy, xp.where(up2, wiz, 1.0)], axis=-1)
    shape = ox.shape + (n_phi * n_theta,)
    return dirs.reshape(shape + (3,)), wgt.reshape(shape)


def halfvector_rule(
    wo,
    alpha_x,
    alpha_y=None,
    n_theta: int = HALFVECTOR_N_THETA,
    n_phi: int = HALFVECTOR_N_PHI,
    dtype=None,
) -> Rule:
    """Rule over ``wi`` in the upper hemisphere for lobes around the mirror direction of ``wo``.

    Nodes are placed in the half-vector parameterisation ``wi = 2 (wo.h) h - wo`` with the
    Jacobian ``dwi = 4 (wo.h) dw_h`` (Walter et al. 2007, eq. 14), adapted to a microfacet lobe of
    widths ``(alpha_x, alpha_y)`` and with the horizon ``wi.z = 0`` as the exact boundary of the
    domain; see the section "Lobe-adapted rules" of docs/quadrature.md for the construction.
    ``n_theta * n_phi`` nodes; every node has ``wi.z > 0``. ``wo`` below the horizon gives
    all-zero weights.

    Args:
        wo: ``(3,)`` unit view direction (``(..., 3)`` gives a batched rule: directions
            ``(..., N, 3)``, weights ``(..., N)``; :func:`integrate` takes one direction only).
        alpha_x, alpha_y: lobe widths (microfacet roughness; ``alpha_y=None`` means isotropic).
            The rule is exact for no particular integrand; it is accurate for lobes of about this
            width (GGX, Beckmann, Blinn-Phong at its equivalent width); smooth cosine-weighted
            integrands are integrated to ~1e-7, but it is no rule for the whole hemisphere.
        n_theta: Gauss-Legendre nodes along each ray.
        n_phi: number of rays (even, >= 4).
        dtype: float dtype of the returned arrays (default: JAX's default float dtype).

    Concrete inputs are processed in float64 NumPy. If any input is a JAX tracer (inside ``jit``,
    ``grad`` or ``vmap``) the same construction runs in ``jax.numpy`` under ``stop_gradient``:
    the rule is then a fixed function of the lobe width, which is what differentiating a
    quadrature of a parameter-dependent integrand needs.
    """
    if n_theta < 1:
        raise ValueError(f"need n_theta >= 1, got {n_theta}")
    if n_phi < 4 or n_phi % 2:
        raise ValueError(f"n_phi must be even and >= 4, got {n_phi}")
    alpha_y = alpha_x if alpha_y is None else alpha_y
    dt = _float_dtype(dtype)
    if _is_tracer(wo, alpha_x, alpha_y):
        wdt = jnp.result_type(float)  # float64 under x64
        wo_, ax_, ay_ = (
            jax.lax.stop_gradient(jnp.asarray(a).astype(wdt)) for a in (wo, alpha_x, alpha_y)
        )
        dirs, w = _halfvector_nodes(jnp, wo_, ax_, ay_, n_theta, n_phi)
        return Rule(directions=dirs.astype(dt), weights=w.astype(dt))
    wo_ = np.asarray(wo, dtype=np.float64)
    if wo_.shape[-1:] != (3,):
        raise ValueError(f"wo must have shape (..., 3), got {wo_.shape}")
    ax_ = np.asarray(alpha_x, dtype=np.float64)
    ay_ = np.asarray(alpha_y, dtype=np.float64)
    if np.any(ax_ <= 0) or np.any(ay_ <= 0):
        raise ValueError(f"lobe widths must be positive, got {alpha_x}, {alpha_y}")
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        dirs, w = _halfvector_nodes(np, wo_, ax_, ay_, n_theta, n_phi)
    return Rule(directions=jnp.asarray(dirs, dtype=dt), weights=jnp.asarray(w, dtype=dt))
