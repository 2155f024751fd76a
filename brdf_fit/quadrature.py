"""Quadrature rules on the hemisphere and the sphere of directions, as plain data.

A :class:`Rule` is a set of unit directions and solid-angle weights such that

    integral of g(w) dw  ~=  sum_k weights[k] * g(directions[k]).

All rules here are *product rules* in the coordinates (mu, phi), mu = cos(theta), for which the
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
    "Rule",
    "composite_gauss_legendre_hemisphere",
    "gauss_legendre_hemisphere",
    "gauss_legendre_interval",
    "gauss_legendre_sphere",
    "integrate",
    "periodic_trapezoid",
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
        """Number of nodes."""
        return int(self.weights.shape[0])


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
