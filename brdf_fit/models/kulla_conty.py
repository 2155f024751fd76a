"""Multiple-scattering energy compensation of GGX: the Kulla & Conty (2017) lobe, from packaged
tables.

A single-scattering microfacet lobe reflects ``E(mu_o) < 1`` of the light even with ``F = 1``:
the light that would scatter again between microfacets is lost (69% at ``alpha = 1``, ``mu = 1``).
Kulla & Conty add the missing energy as a second, diffuse-like lobe

    f_ms(wi, wo) = F_ms (1 - E(mu_o)) (1 - E(mu_i)) / (pi (1 - E_avg)),
    E_avg = 2 Int_0^1 E(mu) mu dmu,
    F_ms  = F_avg^2 E_avg / (1 - F_avg (1 - E_avg)),   F_avg = 2 Int_0^1 F(mu) mu dmu,

with ``E(mu, alpha)`` the directional albedo of the GGX lobe (height-correlated Smith masking)
with ``F = 1``. Its albedo is ``Int f_ms cos dwi = F_ms (1 - E(mu_o))``, so with ``F = 1``
(``F_avg = F_ms = 1``) single + multiple scattering reflect 1 (the white furnace; measured
``|E - 1| <= 3.9e-5`` for ``alpha`` and ``mu_o`` in ``[1e-3, 1]``, the tables' error), and
with ``F < 1`` the factor ``F_ms`` accounts for the absorption at every further bounce (a
geometric series in ``F_avg (1 - E_avg)``). The lobe is symmetric in ``(mu_i, mu_o)`` (reciprocal
by construction), depends on ``wi`` only through ``mu_i``, and is smooth in it, so it is sampled
from the cosine-weighted hemisphere with its exact pdf ``mu_i / pi``. In a model it is the
second lobe of a :class:`~brdf_fit.models.Mixture` with the GGX lobe
(``registry.get("ggx-ms")``), which picks it with probability proportional to its mean albedo
``F_ms (1 - E_avg)`` (:meth:`KullaContyLobe.selection_hint`).

**Tables.** ``E`` and ``E_avg`` are computed once by ``brdf_fit.tables.energy.ms_tables`` (layer
3; the split-sum quadrature of :mod:`brdf_fit.tables.dfg`, float64) and shipped as package data
(``brdf_fit/resources/tables/ggx_ms_E.npz`` and ``ggx_ms_E_avg.npz``), read here with
:func:`brdf_fit.core.table.load_packaged_table`; ``tests/tables/test_ms_resources.py`` holds the
files equal to a regeneration. Both lookups are linear (differentiable in ``alpha``):

* ``E`` on the 512 x 256 grid of ``log10_alpha`` in ``[-4, 0]`` and ``sqrt_warped_mu =
  sqrt(log(1 + mu/alpha) / log(1 + 1/alpha))`` in ``[0, 1]`` (endpoint nodes; see
  :func:`warped_mu`). For small ``alpha``, ``E`` is a function of ``mu / alpha`` (the loss
  ``1 - E`` is a bump of height 0.11 at ``mu ~ alpha`` with an ``(alpha/mu)^2`` tail), which
  this coordinate resolves linearly below ``alpha`` and logarithmically above; the square root
  resolves the ``mu log(1/mu)`` approach of wide lobes to ``E(0) = 1``, and ``mu = 1`` maps to 1
  for every ``alpha``. Measured linear-interpolation error against direct
  :func:`brdf_fit.tables.dfg_values`: :data:`E_TABLE_INTERPOLATION_ERROR`.
* ``E_avg`` on 257 nodes of ``log10_alpha`` in ``[-4, 0]``: for small ``alpha``,
  ``1 - E_avg ~ alpha^2 (c_0 + c_1 log(1/alpha))`` is tiny and only its *relative* error
  matters (it divides), which a log axis keeps uniform.

The model interpolates the losses, not ``E``: ``q = (1 - E)(1 + mu/alpha)^2`` on the ``E`` grid
(:func:`loss_table`, which says why the factor) and ``1 - E_avg``, both computed in float64 when
the tables are loaded, so nothing cancels in float32 where the loss is 1e-9.

**Below the grid** (``alpha < ALPHA_MIN = 1e-4``) both lookups use ``alpha = ALPHA_MIN``, as the
GGX distribution itself does (:data:`brdf_fit.core.numerics.ALPHA_MIN`); the lobe then reflects
at most ``0.11 F_ms`` at ``mu_o ~ 1e-4`` and about ``1e-8`` elsewhere (``E -> 1`` as
``alpha -> 0``, so ``f_ms -> 0``).

References
----------
- C. Kulla, A. Conty, "Revisiting Physically Based Shading at Imageworks", SIGGRAPH 2017 course
  "Physically Based Shading in Theory and Practice" (the ``E``/``E_avg`` lobe, and ``F_ms``).
- E. Heitz, "Understanding the masking-shadowing function in microfacet-based BRDFs", JCGT 3(2),
  2014 (height-correlated Smith ``G2``).
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

from brdf_fit.core.fresnel import AbstractFresnel, SchlickFresnel
from brdf_fit.core.numerics import ALPHA_MIN, INV_PI, safe_div, safe_sqrt
from brdf_fit.core.params import Scalar, bounded
from brdf_fit.core.table import Table, load_packaged_table
from brdf_fit.core.validate import check_param, check_scalar
from brdf_fit.models._base import AbstractBRDF, QuadratureLobe, expand_channels
from brdf_fit.models._lobes import cosine_pdf, max_over_channels, sample_cosine, upper

__all__ = [
    "E_AVG_TABLE_FILE",
    "E_TABLE_FILE",
    "E_TABLE_INTERPOLATION_ERROR",
    "KullaContyLobe",
    "MU_RULE_NODES_PER_CELL",
    "dmu_dwarped",
    "fresnel_ms",
    "interpolate_loss",
    "loss_table",
    "loss_weight",
    "mu_from_warped",
    "ms_loss",
    "ms_loss_avg",
    "warped_mu",
]

#: the packaged tables (``brdf_fit/resources/tables``), written by ``brdf_fit.tables.energy``
E_TABLE_FILE = "ggx_ms_E.npz"
E_AVG_TABLE_FILE = "ggx_ms_E_avg.npz"
#: measured max |(1 - ms_loss) - dfg_values| at off-grid points with alpha and mu in [1e-3, 1]
#: (``brdf_fit.tables.energy.E_TABLE_ERROR_MEASURED``, recorded in the table's metadata as
#: ``interpolation_error``)
E_TABLE_INTERPOLATION_ERROR = 1.9e-5
#: Gauss-Legendre nodes per cell of the ``E`` table in the lobe's own quadrature rule
#: (:meth:`KullaContyLobe.quadrature_lobe`): inside a cell the integrand is ``q`` (linear in the
#: cell's coordinate ``v``) times a smooth function of ``v``, so 4 nodes per cell integrate the
#: interpolated lobe to round-off (measured: 4 and 8 nodes per cell agree to 3e-16 relative)
MU_RULE_NODES_PER_CELL = 4


# ----------------------------------------------------------------------------- the warp


def warped_mu(mu, alpha):
    """The ``E`` table's second coordinate ``v = sqrt(log(1 + mu/alpha) / log(1 + 1/alpha))``
    (``v(0) = 0``, ``v(1) = 1`` for every ``alpha > 0``): linear in ``mu/alpha`` below
    ``mu ~ alpha``, logarithmic above, square-rooted to resolve ``mu -> 0``. ``jax.numpy``;
    gradient finite at ``mu = 0``."""
    return safe_sqrt(jnp.log1p(mu / alpha) / jnp.log1p(1.0 / alpha))


def mu_from_warped(v, alpha):
    """The inverse of :func:`warped_mu`: ``mu = alpha expm1(v^2 log(1 + 1/alpha))`` (NumPy)."""
    return alpha * np.expm1(v * v * np.log1p(1.0 / alpha))


def dmu_dwarped(v, alpha):
    """``d mu / d v = 2 alpha L v exp(v^2 L)``, ``L = log(1 + 1/alpha)`` (NumPy)."""
    L = np.log1p(1.0 / alpha)
    return 2.0 * alpha * L * v * np.exp(v * v * L)


# ----------------------------------------------------------------------------- tables


def loss_weight(mu, alpha):
    """``(1 + mu / alpha)^2``: the loss ``1 - E`` times it is what the lobe interpolates (see
    :func:`loss_table`). Arithmetic only (NumPy or ``jax.numpy``)."""
    x = 1.0 + mu / alpha
    return x * x


def loss_table(e_table: Table) -> Table:
    """The table the lobe interpolates, from an ``E`` table on the axes ``(log10_alpha,
    sqrt_warped_mu)``: channel ``q = (1 - E) (1 + mu/alpha)^2`` at the nodes (float64 NumPy).

    Why not ``1 - E`` itself: for ``mu >> alpha`` the loss falls like ``(alpha/mu)^2``, i.e.
    exponentially along the logarithmic warped axis, and the lobe's integral weights it with
    ``mu dmu`` (half of ``1 - E_avg`` at ``alpha = 1e-4`` comes from ``mu > 10 alpha``): a linear
    interpolant of the loss overestimates that tail (measured: ``Int (1 - E_tab) 2 mu dmu`` off
    ``1 - E_avg`` by 3.3e-3 relative at ``alpha = 1.2e-4`` on a 256 x 128 grid; with ``q``,
    which tends to a constant there, 3.4e-4; 8.5e-5 on the shipped 512 x 256 grid)."""
    ax_a, ax_v = e_table.axes
    alpha = (10.0 ** ax_a.nodes())[:, None]
    mu = np.clip(mu_from_warped(ax_v.nodes()[None, :], alpha), 0.0, 1.0)
    mu = np.where(ax_v.nodes()[None, :] >= 1.0, 1.0, mu)
    loss = 1.0 - np.asarray(e_table.channel("E"), dtype=np.float64)
    return Table((loss * loss_weight(mu, alpha))[..., None], e_table.axes, ("q",), e_table.meta)


def interpolate_loss(q_table: Table, mu, alpha):
    """``1 - E(mu, alpha)`` from a :func:`loss_table` (linear lookup of ``q`` at
    ``(log10(alpha), warped_mu(mu, alpha))``, divided by :func:`loss_weight`); ``jax.numpy``, in
    the table's dtype; ``alpha`` is used as given (clamp it first)."""
    dt = jnp.asarray(q_table.values).dtype
    a, mu = jnp.asarray(alpha, dt), jnp.asarray(mu, dt)
    q = q_table.lookup(jnp.log10(a), warped_mu(mu, a))[..., 0]
    return q / loss_weight(mu, a)


@functools.cache
def _loss_tables() -> tuple[Table, Table]:
    """``(q, 1 - E_avg)`` as float64 NumPy tables (loaded once)."""
    e = load_packaged_table(E_TABLE_FILE)
    ea = load_packaged_table(E_AVG_TABLE_FILE)
    loss_avg = 1.0 - np.asarray(ea.channel("E_avg"), dtype=np.float64)
    return loss_table(e), Table(loss_avg[..., None], ea.axes, ("loss_avg",), ea.meta)


@functools.cache
def _typed_tables(dtype_name: str) -> tuple[Table, Table]:
    q, loss_avg = _loss_tables()
    dt = np.dtype(dtype_name)
    return (Table(np.asarray(q.values, dt), q.axes, q.channels),
            Table(np.asarray(loss_avg.values, dt), loss_avg.axes, loss_avg.channels))


def _float_dtype(*xs):
    dts = [jnp.asarray(x).dtype for x in xs]
    dts = [d for d in dts if jnp.issubdtype(d, jnp.floating)]
    return jax.dtypes.canonicalize_dtype(dts[0] if dts else float)


def _clamped(alpha):
    return jnp.maximum(alpha, ALPHA_MIN)


def ms_loss(mu, alpha):
    """``1 - E(mu, alpha)`` from the packaged table (:func:`interpolate_loss`; ``alpha`` clamped
    below at ``ALPHA_MIN``), in the dtype of ``mu``. ``mu`` in [0, 1]."""
    q, _ = _typed_tables(str(_float_dtype(mu, alpha)))
    dt = q.values.dtype
    return interpolate_loss(q, jnp.asarray(mu, dt), _clamped(jnp.asarray(alpha, dt)))


def ms_loss_avg(alpha):
    """``1 - E_avg(alpha)`` from the packaged table (linear in ``log10(alpha)``; ``alpha``
    clamped below at ``ALPHA_MIN``)."""
    _, loss_avg = _typed_tables(str(_float_dtype(alpha)))
    dt = loss_avg.values.dtype
    a = _clamped(jnp.asarray(alpha, dt))
    return loss_avg.lookup(jnp.log10(a))[..., 0]


def fresnel_ms(f_avg, e_avg):
    """Kulla & Conty's ``F_ms = F_avg^2 E_avg / (1 - F_avg (1 - E_avg)) = F_avg sum_{k >= 0}
    F_avg E_avg (F_avg (1 - E_avg))^k``: the fraction of the multiply scattered energy that
    leaves when every further bounce multiplies by ``F_avg`` (their geometric series). Equals 1
    for ``F_avg = 1``; the denominator is at least ``E_avg > 0``."""
    return f_avg * f_avg * e_avg / (1.0 - f_avg * (1.0 - e_avg))


# ----------------------------------------------------------------------------- the lobe


class KullaContyLobe(AbstractBRDF):
    """The Kulla & Conty (2017) multiple-scattering lobe of a GGX lobe of width ``alpha`` with
    Fresnel part ``fresnel`` (see the module docstring). ``F_avg`` is
    ``fresnel.average()``: closed form for Schlick, Gauss-Legendre in ``mu`` otherwise."""

    alpha: Scalar = bounded(0.5, lo=0.0, hi=1.0, lo_open=True)
    fresnel: AbstractFresnel = SchlickFresnel(0.04)

    def __check_init__(self):
        check_param("alpha", self.alpha, lo=0.0, hi=1.0, lo_open=True, owner="KullaContyLobe")
        check_scalar("alpha", self.alpha, "KullaContyLobe")

    def _factor(self, dtype=None):
        """``F_ms / (pi (1 - E_avg))`` (channels) and ``F_ms (1 - E_avg)`` (the mean albedo)."""
        alpha = self.alpha if dtype is None else jnp.asarray(self.alpha, dtype)
        loss_avg = ms_loss_avg(alpha)
        f_ms = fresnel_ms(self.fresnel.average(), 1.0 - loss_avg)
        return f_ms * safe_div(INV_PI, loss_avg), f_ms * loss_avg

    def eval(self, wi, wo):
        ok = upper(wi, wo)
        ch = self.channels()
        # sanitised lanes (below the horizon) look up mu = 1 and are masked afterwards
        mu_i = jnp.where(ok, wi[..., 2], 1.0)
        mu_o = jnp.where(ok, wo[..., 2], 1.0)
        dt = _float_dtype(wi)
        li = ms_loss(mu_i, jnp.asarray(self.alpha, dt))
        lo = ms_loss(mu_o, jnp.asarray(self.alpha, dt))
        factor, _ = self._factor(dt)
        return jnp.where(expand_channels(ok, ch), factor * expand_channels(li * lo, ch), 0.0)

    def pdf(self, wi, wo):
        return cosine_pdf(wi, wo)

    def sample(self, wo, uc, u):
        return sample_cosine(self, wo, u)

    def albedo(self, wo):
        """The directional albedo ``F_ms (1 - E(mu_o))`` the lobe is built to have. The quadrature
        of :func:`brdf_fit.verify.albedo.directional_albedo` (exact for the interpolated lobe)
        differs from it by the consistency of the ``E_avg`` table with the interpolated ``E``
        table: 8.5e-5 relative at the ``E_avg`` nodes, up to 4.9e-4 between them (measured at
        alpha = 1e-4, 3e-3, 0.3, 1), i.e. at most 5e-5 absolute (the loss is <= 0.11 where
        ``1 - E_avg`` is small)."""
        mu_o = jnp.clip(wo[..., 2], 0.0, 1.0)
        dt = _float_dtype(wo)
        loss_avg = ms_loss_avg(jnp.asarray(self.alpha, dt))
        f_ms = fresnel_ms(self.fresnel.average(), 1.0 - loss_avg)
        lo = jnp.where(wo[..., 2] > 0, ms_loss(mu_o, jnp.asarray(self.alpha, dt)), 0.0)
        return f_ms * expand_channels(lo, self.channels())

    def selection_hint(self):
        """The lobe's cosine-weighted mean albedo ``F_ms (1 - E_avg)``, largest over channels."""
        _, mean_albedo = self._factor(_float_dtype(self.alpha))
        return max_over_channels(mean_albedo)

    def quadrature_lobe(self) -> QuadratureLobe:
        """``("mu", (mu, w))``: the lobe depends on ``wi`` through ``mu_i`` only; the rule in
        ``mu`` is composite Gauss-Legendre over the cells of the ``E`` table in its warped
        coordinate ``v`` (:data:`MU_RULE_NODES_PER_CELL` nodes per cell, mapped to ``mu`` at this
        lobe's ``alpha``), which integrates the linearly interpolated table to round-off (the
        nodes depend on ``alpha`` only through ``stop_gradient``). 255 x 4 nodes in ``mu``."""
        loss, _ = _loss_tables()
        ax = loss.axis("sqrt_warped_mu")
        edges = np.linspace(ax.lo, ax.hi, ax.n)
        x, w = np.polynomial.legendre.leggauss(MU_RULE_NODES_PER_CELL)
        half = 0.5 * np.diff(edges)[:, None]
        u = (0.5 * (edges[:-1] + edges[1:])[:, None] + half * x[None, :]).ravel()
        wu = (half * w[None, :]).ravel()
        a = _clamped(jax.lax.stop_gradient(jnp.asarray(self.alpha)))
        L = jnp.log1p(1.0 / a)
        u, wu = jnp.asarray(u, a.dtype), jnp.asarray(wu, a.dtype)
        e = jnp.exp(u * u * L)
        mu = jnp.clip(a * jnp.expm1(u * u * L), 0.0, 1.0)
        return QuadratureLobe("mu", (mu, wu * 2.0 * a * L * u * e))

