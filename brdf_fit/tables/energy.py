"""The energy-compensation tables of the Kulla & Conty (2017) multiple-scattering lobe of GGX
(:mod:`brdf_fit.models.kulla_conty`): ``E(mu, alpha)`` and ``E_avg(alpha)``.

``E = A + B`` is the directional albedo of the GGX lobe with height-correlated Smith masking and
``F = 1`` (:func:`brdf_fit.tables.dfg_values`, float64, the horizon-exact half-vector rule), and
``E_avg = 2 Int_0^1 E(mu) mu dmu``. :func:`ms_tables` computes both; the results are shipped as
package data (``brdf_fit/resources/tables``) because models (layer 1) may not import this module
(layer 3). Regenerate them with ``python -m brdf_fit.tables.energy`` (about 45 s on 2 CPU cores);
``tests/tables/test_ms_resources.py`` checks that the shipped files equal a regeneration.

**E table** (``ggx_ms_E.npz``, channel ``E``, 1 MB): 512 x 256 endpoint nodes of

* ``log10_alpha`` in ``[-4, 0]`` (``alpha`` in ``[1e-4, 1]``; ``dfg_values`` is accurate to
  < 1e-7 for ``alpha >= 1e-5`` at every ``mu`` and loses accuracy only below ``alpha = 1e-5``
  with ``mu < 1e-4``, which the grid avoids; models clamp ``alpha`` to ``1e-4``);
* ``sqrt_warped_mu = sqrt(log(1 + mu/alpha) / log(1 + 1/alpha))`` in ``[0, 1]``
  (:func:`brdf_fit.models.kulla_conty.warped_mu`): for small ``alpha``, ``E`` depends on
  ``mu / alpha`` only (the loss ``1 - E`` is a bump of height 0.11 at ``mu ~ alpha`` with an
  ``(alpha/mu)^2`` tail), which this coordinate resolves linearly below ``mu ~ alpha`` and
  logarithmically above, the same way for every ``alpha``; the square root resolves the
  ``mu log(1/mu)`` approach of wide lobes to ``E(0) = 1``; ``mu = 1`` is ``v = 1`` for every
  ``alpha``. Along ``alpha`` the log axis keeps adjacent rows within 1.8% in ``alpha``.

The lobe interpolates ``q = (1 - E)(1 + mu/alpha)^2``
(:func:`brdf_fit.models.kulla_conty.loss_table`). Measured linear-interpolation error
(:data:`E_TABLE_ERROR_MEASURED`): max |``1 - q_lookup / (1 + mu/alpha)^2`` - dfg_values| =
1.9e-5 over the 383 ``log10_alpha`` cell centres in ``[1e-3, 1]`` x 96 log-spaced ``mu`` in
``[1e-3, 1]`` (worst at alpha = 2.4e-3, mu = 1.0e-3); the same grid at 256 x 128: 7.5e-5, which
left the gold ``ggx-conductor-ms`` (red channel F = 1 - 5e-7) at albedo 1 + 9.6e-6 against the
energy check's 1 + 1e-5 (now 1 + 1.2e-7). Grids tried first (same measure, on ``E`` directly):
uniform in ``mu^(1/4)`` and ``alpha^(1/4)``, 64 x 64: 3.4e-3; ``sqrt(alpha)`` x
``sqrt(mu (1 + alpha)/(mu + alpha))``, 128 x 128: 7.1e-5, but it squeezes every ``mu > 60
alpha`` into the last cell, so the lobe's integral ``Int (1 - E_tab) 2 mu dmu`` was 4x ``1 -
E_avg`` at ``alpha = 1e-4``. The column ``mu = 0`` is the limit ``mu -> 0+`` (``dfg_values``).
``E`` is clamped to ``<= 1``: the quadrature overshoots 1 by up to 1.3e-8 at ``mu -> 0`` for
``alpha = 1e-4``, and a negative loss would make the lobe negative.

**E_avg table** (``ggx_ms_E_avg.npz``, channel ``E_avg``): 257 endpoint nodes of
``log10_alpha`` in ``[-4, 0]``, each computed from ``dfg_values`` directly (not from the
interpolated grid) as ``1 - E_avg = 2 Int_0^1 (1 - E(mu)) mu dmu`` by composite Gauss-Legendre
in ``mu`` (:data:`E_AVG_ORDER` = 6 nodes on each of :data:`E_AVG_PANELS` = 16 geometric panels
from ``1e-3 alpha`` to 1, and on ``[0, 1e-3 alpha]``): within 5.5e-8 relative (in ``1 -
E_avg``) of 40 panels x 10 nodes at alpha = 1e-4 ... 1 (plain Gauss-Legendre in ``mu`` or in the
warped coordinate, 64 nodes, missed by 13% at alpha = 1e-4: the ``(alpha/mu)^2`` tail carries
half of ``1 - E_avg`` spread over four decades of ``mu``). The loss is integrated, so it keeps its
relative precision where it is 1e-7. For small ``alpha``, ``1 - E_avg ~ alpha^2 (c_0 + c_1
log(1/alpha))``; it divides in the lobe, so its *relative* error matters, which the log axis
keeps uniform: linear interpolation in ``log10(alpha)`` is within :data:`E_AVG_ERROR_MEASURED` =
5.8e-4 relative at the cell midpoints (worst at alpha = 1e-4). The metadata records
``grid_consistency``: the largest relative difference between this ``1 - E_avg`` and the one the
lobe integrates from the interpolated ``E`` table (its albedo is ``F_ms (1 - E(mu_o))`` times
``1 +`` that difference): 8.5e-5 (3.4e-4 with the 256 x 128 grid).
"""

from __future__ import annotations

import pathlib

import jax
import jax.numpy as jnp
import numpy as np

from brdf_fit._version import __version__
from brdf_fit.core.table import Axis, Table
from brdf_fit.models.kulla_conty import (
    E_AVG_TABLE_FILE,
    E_TABLE_FILE,
    dmu_dwarped,
    interpolate_loss,
    loss_table,
    mu_from_warped,
)
from brdf_fit.tables.dfg import dfg_values
from brdf_fit.tables.export import write_table

__all__ = [
    "E_AVG_AXIS",
    "E_AVG_ERROR_MEASURED",
    "E_AVG_ORDER",
    "E_TABLE_AXES",
    "E_TABLE_ERROR_MEASURED",
    "e_avg_values",
    "e_grid_values",
    "ms_tables",
    "resource_dir",
    "write_ms_resources",
]

MASKING = "height-correlated"
#: the axes of the E table (log10(alpha), the warped mu), endpoint nodes
E_TABLE_AXES = (Axis("log10_alpha", -4.0, 0.0, 512, centres=False),
                Axis("sqrt_warped_mu", 0.0, 1.0, 256, centres=False))
#: the axis of the E_avg table, endpoint nodes
E_AVG_AXIS = Axis("log10_alpha", -4.0, 0.0, 257, centres=False)
#: the rule of :func:`e_avg_values`: Gauss-Legendre of E_AVG_ORDER nodes on E_AVG_PANELS
#: geometric panels of mu from E_AVG_MU_LO * alpha to 1, and on [0, E_AVG_MU_LO * alpha]
#: (accuracy measured: module docstring)
E_AVG_PANELS = 16
E_AVG_ORDER = 6
E_AVG_MU_LO = 1e-3
#: max |linear lookup - dfg_values| of the E table over alpha, mu in [1e-3, 1] (module docstring)
E_TABLE_ERROR_MEASURED = 1.9e-5
#: max relative error of 1 - E_avg from linear interpolation in log10(alpha), at the cell
#: midpoints of E_AVG_AXIS (measured; module docstring)
E_AVG_ERROR_MEASURED = 5.8e-4


def resource_dir() -> pathlib.Path:
    """``brdf_fit/resources/tables`` in the source tree this module belongs to."""
    return pathlib.Path(__file__).resolve().parents[1] / "resources" / "tables"


def e_grid_values(log10_alpha, v) -> np.ndarray:
    """``min(E, 1)`` at ``log10_alpha`` x ``v`` (1-D node vectors of the two axes; float64, shape
    ``(len(log10_alpha), len(v))``): the E table's values at those nodes."""
    alpha = 10.0 ** np.asarray(log10_alpha, np.float64)[:, None]
    v = np.asarray(v, np.float64)[None, :]
    mu = np.where(v >= 1.0, 1.0, np.clip(mu_from_warped(v, alpha), 0.0, 1.0))
    A, B = dfg_values(mu, np.broadcast_to(alpha, mu.shape), MASKING)
    return np.minimum(A + B, 1.0)


def _e_avg_rule(alpha, panels: int, order: int):
    """Nodes and weights in mu (shape ``(len(alpha), n)``) of the E_avg rule: Gauss-Legendre of
    ``order`` on ``panels`` geometric panels from ``E_AVG_MU_LO * alpha`` to 1 and on
    ``[0, E_AVG_MU_LO * alpha]`` (where the loss is linear in mu)."""
    x, w = np.polynomial.legendre.leggauss(order)
    a = np.asarray(alpha, np.float64).reshape(-1, 1, 1)
    t = np.linspace(0.0, 1.0, panels + 1)
    lo = E_AVG_MU_LO * a
    edges = np.concatenate([np.zeros_like(a), lo * (1.0 / lo) ** t[None, None, :]], axis=-1)
    left, right = edges[..., :-1, None], edges[..., 1:, None]
    half = 0.5 * (right - left)
    mu = (0.5 * (left + right) + half * x).reshape(a.shape[0], -1)
    wmu = (half * w).reshape(a.shape[0], -1)
    return np.clip(mu, 0.0, 1.0), wmu


def e_avg_values(alpha, panels: int = E_AVG_PANELS, order: int = E_AVG_ORDER) -> np.ndarray:
    """``E_avg(alpha) = 1 - 2 Int_0^1 (1 - E(mu)) mu dmu`` (float64, shape of ``alpha``), ``E`` from
    ``dfg_values`` (clamped to <= 1), by composite Gauss-Legendre in ``mu``: ``order`` nodes on
    each of ``panels`` geometric panels from ``1e-3 alpha`` to 1, and on ``[0, 1e-3 alpha]``.
    The loss is integrated, so it keeps its relative precision where it is 1e-8."""
    shape = np.shape(np.asarray(alpha))
    alpha = np.atleast_1d(np.asarray(alpha, np.float64)).ravel()
    mu, wmu = _e_avg_rule(alpha, panels, order)
    A, B = dfg_values(mu, np.broadcast_to(alpha[:, None], mu.shape), MASKING)
    loss = 1.0 - np.minimum(A + B, 1.0)
    return (1.0 - 2.0 * np.sum(wmu * loss * mu, axis=-1)).reshape(shape)


def _grid_loss_avg(e_table: Table, alpha) -> np.ndarray:
    """``1 - E_avg`` integrated from the interpolated E table as the lobe interpolates it
    (:func:`brdf_fit.models.kulla_conty.interpolate_loss`), by composite Gauss-Legendre with 4
    nodes per cell of the warped axis (the lobe's own quadrature rule)."""
    ax = e_table.axes[1]
    edges = np.linspace(ax.lo, ax.hi, ax.n)
    x, w = np.polynomial.legendre.leggauss(4)
    half = 0.5 * np.diff(edges)[:, None]
    u = (0.5 * (edges[:-1] + edges[1:])[:, None] + half * x).ravel()
    wu = (half * w).ravel()
    a = np.asarray(alpha, np.float64).reshape(-1, 1)
    mu = np.clip(mu_from_warped(u[None, :], a), 0.0, 1.0)
    with jax.enable_x64(True):
        loss = np.asarray(interpolate_loss(loss_table(e_table), jnp.asarray(mu), jnp.asarray(a)))
    return 2.0 * np.sum(wu * loss * mu * dmu_dwarped(u[None, :], a), axis=-1)


def ms_tables() -> tuple[Table, Table]:
    """``(E table, E_avg table)`` as shipped (module docstring for grids and accuracy)."""
    ax_a, ax_v = E_TABLE_AXES
    E = e_grid_values(ax_a.nodes(), ax_v.nodes())
    coords = {
        "log10_alpha": "log10(alpha)",
        "sqrt_warped_mu": "v = sqrt(log(1 + mu/alpha) / log(1 + 1/alpha)); "
                          "mu = alpha expm1(v^2 log(1 + 1/alpha))",
    }
    common = {"masking": MASKING, "fresnel": "F = 1", "brdf_fit_version": __version__,
              "reference": "C. Kulla, A. Conty, Revisiting Physically Based Shading at "
                           "Imageworks, SIGGRAPH 2017 course notes"}
    e_table = Table(E[..., None], E_TABLE_AXES, ("E",), {
        **common, "kind": "ggx_ms_E", "coordinates": coords,
        "quantity": "E(mu, alpha) = A + B, directional albedo of GGX with F = 1, clamped <= 1",
        "quadrature": "brdf_fit.tables.dfg_values (halfvector_rule 48 x 64, float64)",
        "limits": {"mu=0": "the limit mu -> 0+ (dfg_values)",
                   "alpha<1e-4": "models clamp alpha to 1e-4 (ALPHA_MIN)"},
        "interpolation_error": {
            "max_abs": E_TABLE_ERROR_MEASURED,
            "method": "bilinear lookup (of q, brdf_fit.models.kulla_conty.interpolate_loss) vs "
                      "dfg_values at the log10_alpha cell centres in [1e-3, 1] x 96 log-spaced "
                      "mu in [1e-3, 1]"},
    })
    alpha = 10.0 ** E_AVG_AXIS.nodes()
    e_avg = e_avg_values(alpha)
    grid = _grid_loss_avg(e_table, alpha)
    rel = np.abs(grid - (1.0 - e_avg)) / (1.0 - e_avg)
    e_avg_table = Table(e_avg[:, None], (E_AVG_AXIS,), ("E_avg",), {
        **common, "kind": "ggx_ms_E_avg",
        "coordinates": {"log10_alpha": "log10(alpha)"},
        "quantity": "E_avg(alpha) = 2 Int_0^1 E(mu) mu dmu",
        "quadrature": (f"Gauss-Legendre, {E_AVG_ORDER} nodes on each of {E_AVG_PANELS} geometric "
                       f"panels of mu from {E_AVG_MU_LO} alpha to 1 and on [0, {E_AVG_MU_LO} "
                       "alpha], over dfg_values"),
        "grid_consistency": {
            "max_rel": float(rel.max()),
            "method": "|1 - E_avg - Int (1 - E_table) 2 mu dmu| / (1 - E_avg), the E table "
                      "interpolated at each node's alpha"},
    })
    return e_table, e_avg_table


def write_ms_resources(directory=None) -> list[pathlib.Path]:
    """Compute :func:`ms_tables` and write them (``.npz`` + ``.json`` sidecar) to ``directory``
    (default: :func:`resource_dir`); returns the paths written."""
    d = resource_dir() if directory is None else pathlib.Path(directory)
    d.mkdir(parents=True, exist_ok=True)
    e_table, e_avg_table = ms_tables()
    return write_table(e_table, d / E_TABLE_FILE) + write_table(e_avg_table, d / E_AVG_TABLE_FILE)


if __name__ == "__main__":
    for p in write_ms_resources():
        print(p)
