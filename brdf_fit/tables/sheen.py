"""The packaged directional-albedo table of the KHR_materials_sheen "Charlie" sheen lobe
(:mod:`brdf_fit.models.gltf_pbr`): ``E(mu, sheenRoughness)``, the extension's ``E(x)`` of its
albedo-scaling technique for the Charlie visibility.

``E(mu_o, sr) = Int_H+ f_s(wi, wo) (n.wi) dwi`` with ``f_s`` = :func:`brdf_fit.models.gltf_pbr
.charlie_sheen` (sheen colour 1), ``wo = (sqrt(1 - mu_o^2), 0, mu_o)``, integrated in float64 by
a product rule of the package's Gauss-Legendre rules (:func:`brdf_fit.core.quadrature
.gauss_legendre_interval`): in ``mu_i`` a composite rule with panels split at :data:`MU_BREAKS`
(graded towards the horizon, where the lobe of a small sheen roughness lives, on the scale
``mu ~ sqrt(r)``, and where ``E`` grows for ``mu_o -> 0``), :data:`N_PER_PANEL` nodes each; in
``phi`` Gauss-Legendre on ``[0, pi]`` with :data:`PHI_BREAKS` (the lobe is even in ``phi``, so
the rule doubles the half circle; its nodes cluster at ``phi = 0`` and ``pi``, where the lobe of
two grazing directions changes fastest).

Grid (endpoint nodes, :mod:`brdf_fit.models.gltf_pbr`): axis 0 ``log10_sheen_roughness`` in
``[log10 SHEEN_ROUGHNESS_MIN, 0] = [-2, 0]`` (129 nodes), axis 1 ``log10_mu`` in
``[log10 SHEEN_TABLE_MU_MIN, 0] = [-6, 0]`` (193 nodes); the model interpolates cubically
(:meth:`brdf_fit.core.table.Table.lookup` with ``order=3``). Log axes because ``E`` varies on the
scale of ``mu ~ sr`` (a lobe that is 0 beyond ``mu ~ 5 sr`` at small ``sr``) and tends to a
finite value only down to ``mu ~ 1e-6``, below which it grows like ``1/(mu Lambda(0))``.

The metadata records ``accuracy``: ``interpolation`` (the largest ``|lookup - quadrature|`` at
every cell centre of the grid, both axes at once), ``quadrature`` (the largest change of the
quadrature when every panel's node count is doubled, on a subgrid) and ``max_abs``, their sum;
tests/models/test_gltf_pbr.py compares spot values with an independent ``scipy.integrate``
double integral. Regenerate with ``python -m brdf_fit.tables.sheen`` (6 minutes on two busy
cores: 50,000 ``(mu, sr)`` pairs of 52,000 nodes each).
"""

from __future__ import annotations

import math
import pathlib

import jax
import jax.numpy as jnp
import numpy as np

from brdf_fit._version import __version__
from brdf_fit.core.quadrature import gauss_legendre_interval
from brdf_fit.core.table import Axis, Table
from brdf_fit.models.charlie_sheen import (
    SHEEN_ROUGHNESS_MIN,
    SHEEN_TABLE_FILE,
    SHEEN_TABLE_MU_MIN,
    SHEEN_TABLE_N_MU,
    SHEEN_TABLE_N_ROUGHNESS,
    charlie_sheen,
)
from brdf_fit.tables._stream import run_blocks
from brdf_fit.tables.export import write_table

__all__ = ["MU_BREAKS", "N_PER_PANEL", "PHI_BREAKS", "albedo", "sheen_table", "table_axes"]

#: Panel ends in ``mu_i`` (graded towards the horizon).
MU_BREAKS = (0.0, 1e-7, 1e-6, 1e-5, 1e-4, 1e-3, 3e-3, 0.01, 0.02, 0.04, 0.08, 0.16, 0.3, 0.5,
             0.75, 1.0)
#: Panel ends in ``phi`` on ``[0, pi]``.
PHI_BREAKS = (0.0, 0.5, 1.5, 2.5, 2.9, 3.05, math.pi)
#: Gauss-Legendre nodes per panel (both coordinates); the accuracy estimate doubles it.
N_PER_PANEL = 24
#: ``(mu_o, sr)`` pairs per compiled call.
PAIRS_PER_CALL = 8


def _rule(n: int):
    """``(mu_i, phi, weights)`` of the product rule (float64 NumPy, flat), the factor 2 of the
    half circle included."""
    mu = [gauss_legendre_interval(n, a, b) for a, b in zip(MU_BREAKS[:-1], MU_BREAKS[1:],
                                                           strict=True)]
    ph = [gauss_legendre_interval(n, a, b) for a, b in zip(PHI_BREAKS[:-1], PHI_BREAKS[1:],
                                                           strict=True)]
    m, wm = (np.concatenate(x) for x in zip(*mu, strict=True))
    p, wp = (np.concatenate(x) for x in zip(*ph, strict=True))
    M, P = np.meshgrid(m, p, indexing="ij")
    return M.ravel(), P.ravel(), 2.0 * np.outer(wm, wp).ravel()


@jax.jit
def _albedo_block(mu_o, sr, mu_i, phi, w):
    """``E`` at pairs ``(mu_o, sr)`` (P,) by the rule ``(mu_i, phi, w)`` (N,)."""
    s_i = jnp.sqrt(jnp.clip(1.0 - mu_i * mu_i, 0.0, None))
    wi = jnp.stack([s_i * jnp.cos(phi), s_i * jnp.sin(phi), mu_i], -1)[None, :, :]
    s_o = jnp.sqrt(jnp.clip(1.0 - mu_o * mu_o, 0.0, None))
    wo = jnp.stack([s_o, jnp.zeros_like(mu_o), mu_o], -1)[:, None, :]
    f = charlie_sheen(wi, wo, sr[:, None])
    return jnp.sum(w[None, :] * f * mu_i[None, :], axis=-1)


def albedo(mu, sheen_roughness, n_per_panel: int = N_PER_PANEL) -> np.ndarray:
    """``E(mu, sheenRoughness)`` by quadrature (float64, the module docstring's rule), at the
    broadcast of ``mu`` and ``sheen_roughness``; streamed in blocks on every core."""
    mu, sr = np.broadcast_arrays(np.asarray(mu, np.float64), np.asarray(sheen_roughness,
                                                                        np.float64))
    shape = mu.shape
    mu, sr = mu.ravel(), sr.ravel()
    out = np.empty(mu.size)
    with jax.enable_x64(True):
        rule = tuple(jnp.asarray(a, jnp.float64) for a in _rule(n_per_panel))

    def compute(start: int, stop: int) -> None:
        pad = PAIRS_PER_CALL - (stop - start)
        m = np.concatenate([mu[start:stop], np.full(pad, mu[start])])
        s = np.concatenate([sr[start:stop], np.full(pad, sr[start])])
        e = _albedo_block(jnp.asarray(m), jnp.asarray(s), *rule)
        out[start:stop] = np.asarray(e)[: stop - start]

    run_blocks(compute, mu.size, PAIRS_PER_CALL)
    return out.reshape(shape)


def table_axes() -> tuple[Axis, Axis]:
    """The grid of the packaged table (module docstring)."""
    return (Axis("log10_sheen_roughness", math.log10(SHEEN_ROUGHNESS_MIN), 0.0,
                 SHEEN_TABLE_N_ROUGHNESS, centres=False),
            Axis("log10_mu", math.log10(SHEEN_TABLE_MU_MIN), 0.0, SHEEN_TABLE_N_MU,
                 centres=False))


def sheen_table() -> Table:
    """The table :mod:`brdf_fit.models.gltf_pbr` ships, with its measured accuracy in the
    metadata (module docstring)."""
    ax_r, ax_mu = table_axes()
    xr, xm = ax_r.nodes(), ax_mu.nodes()
    R, M = np.meshgrid(10.0**xr, 10.0**xm, indexing="ij")
    values = albedo(M, R)[..., None]
    table = Table(values, (ax_r, ax_mu), ("E",))
    # interpolation error at every cell centre
    cr, cm = 0.5 * (xr[1:] + xr[:-1]), 0.5 * (xm[1:] + xm[:-1])
    CR, CM = np.meshgrid(cr, cm, indexing="ij")
    exact = albedo(10.0**CM, 10.0**CR)
    with jax.enable_x64(True):
        looked = np.asarray(table.lookup(jnp.asarray(CR), jnp.asarray(CM), order=3))[..., 0]
    interp = float(np.abs(looked - exact).max())
    # quadrature error: the rule with doubled nodes on every 8th node of each axis
    sub = (slice(None, None, 8), slice(None, None, 8))
    fine = albedo(M[sub], R[sub], 2 * N_PER_PANEL)
    quad = float(np.abs(fine - values[..., 0][sub]).max())
    meta = {
        "kind": "charlie_sheen_E",
        "model": "gltf-pbr-sheen",
        "quantity": ("E(mu, sheenRoughness) = Int f_sheen (n.wi) dwi with sheenColor 1: the "
                     "directional albedo of the KHR_materials_sheen Charlie lobe (D of Estevez "
                     "& Kulla 2017 eq. 2, their fitted Lambda, r = max(sheenRoughness^2, 1e-4), "
                     "no Fresnel, no visibility clamp, no terminator softening)"),
        "coordinates": {"log10_sheen_roughness": "log10(sheenRoughness), clamped to [-2, 0]",
                        "log10_mu": "log10(N.V), clamped to [-6, 0]"},
        "lookup": "cubic Lagrange in both axes (Table.lookup order=3)",
        "quadrature": {"rule": "Gauss-Legendre panels (brdf_fit.core.quadrature."
                               "gauss_legendre_interval) in mu_i and phi in [0, pi] (x 2)",
                       "mu_breaks": list(MU_BREAKS), "phi_breaks": list(PHI_BREAKS),
                       "n_per_panel": N_PER_PANEL, "dtype": "float64"},
        "accuracy": {"interpolation": interp, "quadrature": quad, "max_abs": interp + quad,
                     "method": (f"interpolation: |cubic lookup - quadrature| at all {CR.size} "
                                "cell centres; quadrature: |rule - rule with doubled nodes| on "
                                f"{fine.size} nodes (every 8th per axis)")},
        "limits": {"sheenRoughness < 0.01": "evaluated as 0.01 (r = ALPHA_MIN)",
                   "mu < 1e-6": "E(1e-6) (E grows like 1/(mu Lambda(0)) as mu -> 0)",
                   "E > 1": ("at grazing views for small sheenRoughness (the fitted Lambda "
                             "underestimates masking there); the model clamps the albedo "
                             "scaling at 0")},
        "reference": ("KhronosGroup/glTF extensions/2.0/Khronos/KHR_materials_sheen/README.md "
                      "(albedo-scaling technique); A. Conty Estevez, C. Kulla, Production "
                      "Friendly Microfacet Sheen BRDF, SIGGRAPH 2017"),
        "brdf_fit_version": __version__,
    }
    return Table(values, (ax_r, ax_mu), ("E",), meta)


def main() -> None:
    table = sheen_table()
    out = pathlib.Path(__file__).resolve().parents[1] / "resources" / "tables"
    for p in write_table(table, out / SHEEN_TABLE_FILE):
        print(f"wrote {p}")
    acc = table.meta["accuracy"]
    print(f"interpolation error {acc['interpolation']:.3g}, quadrature error "
          f"{acc['quadrature']:.3g}")


if __name__ == "__main__":
    main()
