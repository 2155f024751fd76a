"""The sheen lobe of KHR_materials_sheen: Estevez and Kulla's "Charlie" microfacet sheen (A. Conty
Estevez, C. Kulla, "Production Friendly Microfacet Sheen BRDF", SIGGRAPH 2017) with their fitted
``Lambda`` and its packaged directional-albedo table. The formulas, the epsilons and their reasons
are in :mod:`brdf_fit.models.gltf_pbr`'s docstring (the glTF model that layers this lobe over
its base; OpenPBR's and Blender's sheen are other lobes); :mod:`brdf_fit.tables.sheen` writes
the table.
"""

from __future__ import annotations

import functools
import math

import jax.numpy as jnp
import numpy as np

from brdf_fit.core.numerics import ALPHA_MIN, INV_TWO_PI, safe_div, safe_pow
from brdf_fit.core.table import Table, load_packaged_table
from brdf_fit.models._lobes import half_geometry

__all__ = [
    "CHARLIE_L_R0",
    "CHARLIE_L_R1",
    "SHEEN_ROUGHNESS_MIN",
    "SHEEN_TABLE_ERROR",
    "SHEEN_TABLE_FILE",
    "SHEEN_TABLE_MU_MIN",
    "SHEEN_TABLE_N_MU",
    "SHEEN_TABLE_N_ROUGHNESS",
    "charlie_lambda",
    "charlie_lobe",
    "charlie_sheen",
    "sheen_albedo",
]

#: Estevez & Kulla 2017's fitted ``l(x) = a/(1 + b x^c) + d x + e`` at ``r = 0``: ``(a, b, c, d,
#: e)`` (the extension's ``l(x, alphaG)`` at ``oneMinusAlphaSq = 1``).
CHARLIE_L_R0 = (25.3245, 3.32435, 0.16801, -1.27393, -4.85967)
#: The same at ``r = 1`` (``oneMinusAlphaSq = 0``); between them ``p_1 + (p_0 - p_1)(1 - r)^2``.
CHARLIE_L_R1 = (21.5473, 3.82987, 0.19823, -1.97760, -4.32054)
#: Sheen roughness whose square is ``ALPHA_MIN``: the sheen ``r`` is ``max(sr^2, ALPHA_MIN)``, so
#: everything below it evaluates as it (and the albedo table starts there).
SHEEN_ROUGHNESS_MIN = math.sqrt(ALPHA_MIN)
#: The sheen albedo table's smallest ``mu`` (:mod:`brdf_fit.models.gltf_pbr`'s docstring,
#: epsilons).
SHEEN_TABLE_MU_MIN = 1e-6
#: Endpoint nodes of the sheen albedo table: ``log10(sheenRoughness)`` in ``[-2, 0]`` and
#: ``log10(mu)`` in ``[-6, 0]`` (64 and 32 nodes per decade). Measured cubic-lookup errors at
#: half this density: 2.1e-4 (97 ``mu`` nodes, sheenRoughness 0.01) and 1.4e-4 (65 roughness
#: nodes); at this one 1.3e-5 and 6.7e-6 (the h^4 of a cubic).
SHEEN_TABLE_N_ROUGHNESS = 129
SHEEN_TABLE_N_MU = 193
#: The packaged ``E(mu, sheenRoughness)`` table (``brdf_fit/resources/tables``), written by
#: ``python -m brdf_fit.tables.sheen``.
SHEEN_TABLE_FILE = "charlie_sheen_E.npz"
#: Largest absolute error of :func:`sheen_albedo` measured by ``brdf_fit.tables.sheen`` (cubic
#: lookup against the quadrature at every cell centre, plus the quadrature's own error; recorded
#: in the table's metadata, ``accuracy.max_abs``).
SHEEN_TABLE_ERROR = 3e-5


def charlie_lambda(mu, r):
    """Estevez & Kulla's fitted ``Lambda(mu)`` at sheen roughness ``r``
    (:mod:`brdf_fit.models.gltf_pbr`'s docstring):
    ``exp(l(mu))`` below ``mu = 0.5``, ``exp(2 l(0.5) - l(1 - mu))`` above. ``mu`` in [0, 1]."""
    t = (1.0 - r) * (1.0 - r)
    a, b, c, d, e = (p1 + (p0 - p1) * t for p0, p1 in zip(CHARLIE_L_R0, CHARLIE_L_R1,
                                                          strict=True))

    def ell(x):
        return a / (1.0 + b * safe_pow(x, c)) + d * x + e

    return jnp.where(mu < 0.5, jnp.exp(ell(mu)), jnp.exp(2.0 * ell(0.5) - ell(1.0 - mu)))


def charlie_lobe(hx, hy, iz, oz, sheen_roughness):
    """``D_s(H) / ((1 + Lambda(mu_o) + Lambda(mu_i)) 4 mu_o mu_i)`` on sanitised components
    (``iz, oz > 0``): the sheen lobe per unit sheen colour."""
    r = jnp.maximum(sheen_roughness * sheen_roughness, ALPHA_MIN)
    inv_r = 1.0 / r
    s2 = hx * hx + hy * hy  # sin^2(theta_H) without the cancellation of 1 - (N.H)^2
    D = (2.0 + inv_r) * INV_TWO_PI * safe_pow(s2, 0.5 * inv_r)
    lam = charlie_lambda(jnp.stack(jnp.broadcast_arrays(oz, iz)), r)  # one program for both
    g = 1.0 + lam[0] + lam[1]
    # 1/(4 mu_o mu_i) as a product of reciprocals (their product underflows nothing at 1e-7)
    return D * (safe_div(0.5, iz) * safe_div(0.5, oz)) / g


def charlie_sheen(wi, wo, sheen_roughness):
    """The sheen lobe ``f_sheen / sheenColor`` of KHR_materials_sheen
    (:mod:`brdf_fit.models.gltf_pbr`'s docstring) at
    ``(..., 3)`` directions: ``D_s V_s``, 0 at or below the horizon. What the packaged albedo
    table integrates (:mod:`brdf_fit.tables.sheen`)."""
    valid, (_, _, iz), (_, _, oz), (hx, hy, _), _ = half_geometry(wi, wo)
    return jnp.where(valid, charlie_lobe(hx, hy, iz, oz, sheen_roughness), 0.0)


@functools.lru_cache(maxsize=1)
def _packaged_table() -> Table:
    return load_packaged_table(SHEEN_TABLE_FILE)


@functools.lru_cache(maxsize=4)
def _typed_tables(dtype_name: str) -> tuple[Table, Table]:
    """The packaged table in ``dtype``, and the same values as a 1-D table over the roughness
    axis whose channels are the ``mu`` nodes (:func:`sheen_albedo`)."""
    t = _packaged_table()
    values = np.asarray(t.values, np.dtype(dtype_name))
    ax_r, ax_mu = t.axes
    rows = Table(values[..., 0], (ax_r,), tuple(f"mu_{k}" for k in range(ax_mu.n)))
    return Table(values, t.axes, t.channels), rows


def sheen_albedo(mu, sheen_roughness):
    """``E(mu, sheenRoughness)``: the directional albedo of :func:`charlie_sheen`, looked up in
    the packaged table (cubic in ``log10(sheenRoughness)`` on ``[log10 SHEEN_ROUGHNESS_MIN, 0]``
    and in ``log10(mu)`` on ``[log10 SHEEN_TABLE_MU_MIN, 0]``, both clamped to the grid).
    Differentiable in both; in ``mu``'s float dtype.

    The tensor-product cubic of :meth:`~brdf_fit.core.table.Table.lookup` is separable: for one
    (scalar) roughness, as in a model, the 4 table rows around it are interpolated once into a
    column over the ``mu`` nodes, which each direction then interpolates (4 gathers per
    direction instead of 16: the same values to rounding, and half the compilation time under
    ``grad``, measured)."""
    mu = jnp.asarray(mu)
    dt = mu.dtype if jnp.issubdtype(mu.dtype, jnp.floating) else jnp.result_type(float)
    full, rows = _typed_tables(jnp.dtype(dt).name)
    sr = jnp.asarray(sheen_roughness).astype(dt)
    x_r = jnp.log10(jnp.maximum(sr, SHEEN_ROUGHNESS_MIN))
    x_mu = jnp.log10(jnp.maximum(mu.astype(dt), SHEEN_TABLE_MU_MIN))
    if x_r.ndim:
        return full.lookup(x_r, x_mu, order=3)[..., 0]
    column = rows.lookup(x_r, order=3)
    return Table(column[:, None], full.axes[1:], ("E",)).lookup(x_mu, order=3)[..., 0]
