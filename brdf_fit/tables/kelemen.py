"""The packaged specular-albedo table of the Kelemen & Szirmay-Kalos (2001) coupled model
(:mod:`brdf_fit.models.kelemen`): ``A_k(alpha)``, ``B_k(alpha)`` at the model's Chebyshev nodes
``mu_k``, on :data:`~brdf_fit.models.kelemen.ALBEDO_TABLE_N_ALPHA` endpoint nodes of
``log10(alpha)`` in ``[log10(ALPHA_MIN), 0] = [-4, 0]``.

Each row is the quadrature of :func:`brdf_fit.models.kelemen.albedo_nodes` (float64), so the model's
lookup reproduces it exactly at the nodes; between them the model interpolates cubically in
``log10(alpha)`` (:meth:`brdf_fit.core.table.Table.lookup` with ``order=3``). The metadata
records ``interpolation_error``: the largest difference between that lookup and the quadrature
at every cell midpoint (each of ``A``, ``B`` and every ``mu_k``). The table ships as package data
(``brdf_fit/resources/tables/kelemen_AB.npz``) because models (layer 1) may not import this module
(layer 3); regenerate it with ``python -m brdf_fit.tables.kelemen``.
"""

from __future__ import annotations

import pathlib

import jax
import jax.numpy as jnp
import numpy as np

from brdf_fit._version import __version__
from brdf_fit.core.numerics import ALPHA_MIN
from brdf_fit.core.table import Axis, Table
from brdf_fit.models.kelemen import (
    ALBEDO_TABLE_FILE,
    ALBEDO_TABLE_N_ALPHA,
    TABLE_N_PHI,
    TABLE_N_THETA,
    TABLE_NODES,
    albedo_nodes,
)
from brdf_fit.tables._stream import run_blocks
from brdf_fit.tables.export import write_table

__all__ = ["ALPHAS_PER_CALL", "kelemen_albedo_table", "node_values"]

#: ``alpha`` values per compiled call (each holds 32 x 4096 quadrature nodes)
ALPHAS_PER_CALL = 4


def node_values(alpha) -> np.ndarray:
    """``[A_0..A_31, B_0..B_31]`` at each ``alpha`` (float64, shape ``alpha.shape + (64,)``), by
    :func:`brdf_fit.models.kelemen.albedo_nodes`, streamed in blocks."""
    alpha = np.asarray(alpha, np.float64).ravel()
    out = np.empty((alpha.size, 2 * TABLE_NODES))
    fn = jax.jit(jax.vmap(albedo_nodes))

    def compute(start: int, stop: int) -> None:
        a = np.concatenate([alpha[start:stop],
                            np.full(ALPHAS_PER_CALL - (stop - start), alpha[start])])
        A, B = fn(jnp.asarray(a))
        out[start:stop] = np.concatenate([np.asarray(A), np.asarray(B)], -1)[: stop - start]

    run_blocks(compute, alpha.size, ALPHAS_PER_CALL)
    return out


def kelemen_albedo_table(n_alpha: int = ALBEDO_TABLE_N_ALPHA) -> Table:
    """The table :mod:`brdf_fit.models.kelemen` ships (module docstring), with its measured
    interpolation error in the metadata."""
    axis = Axis("log10_alpha", float(np.log10(ALPHA_MIN)), 0.0, n_alpha, centres=False)
    x = axis.nodes()
    values = node_values(10.0**x)
    channels = tuple(f"A_{k}" for k in range(TABLE_NODES)) + tuple(
        f"B_{k}" for k in range(TABLE_NODES))
    table = Table(values, (axis,), channels)
    mid = 0.5 * (x[1:] + x[:-1])
    exact = node_values(10.0**mid)
    with jax.enable_x64(True):
        looked = np.asarray(table.lookup(jnp.asarray(mid), order=3))
    err = float(np.abs(looked - exact).max())
    meta = {
        "kind": "kelemen_specular_albedo",
        "model": "kelemen",
        "description": "A_k, B_k: a_s(mu_k) = f0 A_k + (1 - f0) B_k at the Chebyshev nodes "
                       "mu_k of brdf_fit.models.kelemen (s = sqrt(mu))",
        "quadrature": {"rule": "halfvector_rule", "n_theta": TABLE_N_THETA,
                       "n_phi": TABLE_N_PHI, "dtype": "float64"},
        "lookup": "cubic Lagrange in log10_alpha (Table.lookup order=3)",
        "interpolation_error": {"max_abs": err, "method": "cubic lookup against the quadrature "
                                f"at the {mid.size} cell midpoints, every channel"},
        "brdf_fit_version": __version__,
    }
    return Table(values, (axis,), channels, meta)


def main() -> None:
    table = kelemen_albedo_table()
    out = pathlib.Path(__file__).resolve().parents[1] / "resources" / "tables"
    for p in write_table(table, out / ALBEDO_TABLE_FILE):
        print(f"wrote {p}")
    print(f"interpolation error {table.meta['interpolation_error']['max_abs']:.3g}")


if __name__ == "__main__":
    main()
