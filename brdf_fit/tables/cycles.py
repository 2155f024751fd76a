"""The lookup tables Blender's Cycles reads for its Principled BSDF's GGX lobes, rebuilt by this
package's own quadrature (issue 42), and their difference from Cycles' own.

Cycles 4.5 (``src/app/cycles_precompute.cpp``, which prints ``src/scene/shader.tables``)
estimates these by quasi-Monte Carlo over its visible-normal sampler; the model that reads them
(:mod:`brdf_fit.models.blender_principled`) needs the same quantities on the same grids, and
interpolates them as Cycles does (``kernel/util/lookup_table.h``: clamped, linear along each
axis). Grids: ``rough = i / (n - 1)`` and ``mu = j / (n - 1)``, each clamped to ``[1e-4, 1]``;
GGX width ``alpha = rough^2``; incidence ``z = k / 15`` clamped to ``[1e-4, 0.99]`` with
``ior = (1 + z^2) / (1 - z^2)`` (``ior_parametrization``: ``F0 = z^4``).

* ``ggx_E`` (32 x 32, ``[mu, rough]``): the directional albedo of the GGX lobe with
  height-correlated Smith masking (Heitz 2014, eq. 99) and no Fresnel, at the view cosine
  ``mu``: :func:`brdf_fit.tables.dfg_values` (``A + B``), the horizon-exact half-vector rule in
  float64. At ``rough = 0`` (clamped to 1e-4: ``alpha^2 = 1e-16``, below Cycles' 2e-10 the lobe
  is a mirror, ``BSDF_ROUGHNESS_SQ_THRESH``) Cycles' sampler returns exactly 1; so does this.
* ``ggx_Eavg`` (32, ``[rough]``): ``2 Int_0^1 E(mu) mu dmu``
  (:func:`brdf_fit.tables.energy.e_avg_values`); 1 at ``rough = 0``.
* ``ggx_gen_schlick_ior_s`` (16 x 16 x 16, ``[z, mu, rough]``): the factor ``s`` such that the
  albedo of a reflection lobe with the Principled BSDF's remapped Fresnel ``mix(F0, 1,
  s_real(h))``, ``s_real = clamp((F(v.h; ior) - F0_real) / (1 - F0_real), 0, 1)`` (``F`` the
  exact dielectric Fresnel, ``F0_real = ((ior - 1)/(ior + 1))^2``), is estimated as
  ``mix(F0, 1, s)`` (``bsdf_microfacet_estimate_albedo``). Cycles averages
  ``eval.x / eval.y = s_real(v.h)`` over visible normals drawn from ``v``, a reflection below
  the horizon counting 0, so ``s`` is that mean, not a Fresnel-weighted albedo ratio::

      s(mu) = Int_{H+} D_v(h) [2 (v.h) h - v above the horizon] s_real(v.h) dh
            = Int_{wi in H+} D(h) G1(v) / (4 mu) s_real(v.h) dwi,

  (the visible-normal density ``D_v(h) = G1(v) (v.h) D(h) / mu``, Heitz & d'Eon 2014, eq. 2,
  and ``dh = dwi / (4 v.h)``, Walter et al. 2007, eq. 14), integrated with the same
  horizon-exact half-vector rule as ``ggx_E`` (at a higher order, :data:`S_ORDER`). At
  ``rough = 0`` it is ``s_real(mu)``. The slice ``z = 1e-4`` is 0: Cycles computes
  ``ior = 1 + 2e-8`` in float32, which is 1, where the remapped Fresnel is 0.

:func:`compare` reads Cycles' printed tables (a ``shader.tables`` file, e.g. from a Cycles
checkout) and reports the largest difference per table; ``benchmarks/bench_cycles_tables.py``
writes ``benchmarks/results/cycles_tables.md``. Cycles' own values carry the noise of their
estimator (``2^23``, ``2^26`` and ``2^20`` samples) and six printed decimals.

The sheen's LTC table is not rebuilt but transcribed from Cycles (:func:`write_sheen_table`,
``cycles_sheen_ltc.npz``): it is Zeltner et al.'s (2022) fit of a volumetric sheen.

The tables are shipped as package data (``brdf_fit/resources/tables/cycles_ggx.npz``; models
may not import this module). Regenerate with ``python -m brdf_fit.tables.cycles
[SHADER_TABLES]``;
``tests/tables/test_cycles_tables.py`` recomputes sample nodes and compares.
"""

from __future__ import annotations

import functools
import math
import pathlib
import re

import jax
import jax.numpy as jnp
import numpy as np

from brdf_fit._version import __version__
from brdf_fit.core.fresnel import dielectric
from brdf_fit.core.quadrature import HALFVECTOR_N_PHI, HALFVECTOR_N_THETA, halfvector_rule
from brdf_fit.tables.dfg import dfg_values
from brdf_fit.tables.energy import e_avg_values

__all__ = ["CYCLES_TABLE_FILE", "GRID_CLAMP", "IOR_Z_CLAMP", "SHEEN_TABLE_FILE", "compare",
           "cycles_tables", "ior_from_z", "read_cycles_tables", "s_values", "write_cycles_tables",
           "write_sheen_table"]

#: the resource file (also named in brdf_fit.models.blender_principled)
CYCLES_TABLE_FILE = "cycles_ggx.npz"
#: the transcribed sheen table (also named in brdf_fit.models.blender_principled)
SHEEN_TABLE_FILE = "cycles_sheen_ltc.npz"
#: ``cycles_precompute``: roughness and cosine nodes clamped to ``[1e-4, 1]``
GRID_CLAMP = 1e-4
#: ``cycles_precompute``: the IOR coordinate clamped to ``[1e-4, 0.99]``
IOR_Z_CLAMP = (1e-4, 0.99)
#: ``BSDF_ROUGHNESS_SQ_THRESH`` (kernel/svm/types.h): ``alpha_x alpha_y`` at or below is a mirror
ROUGHNESS_SQ_THRESH = 2e-10
#: texels per compiled call of :func:`_s_block`
_BLOCK = 64
#: the half-vector rule of the ``s`` table (``n_theta, n_phi``): at the grazing ``mu = 1e-4``
#: the default 48 x 64 was 1.9e-4 from a 2-million-sample estimate (0.061499 against 0.061680
#: +- 0.000023 at ``rough = 4/15``, ``z = 13/15``); 192 x 256 gives 0.061683, Cycles 0.061686
S_ORDER = (192, 256)


def ior_from_z(z):
    """``ior_parametrization`` of ``cycles_precompute``: ``ior_from_F0(z^4)`` =
    ``(1 + z^2) / (1 - z^2)``."""
    z2 = np.asarray(z, np.float64) ** 2
    return (1.0 + z2) / (1.0 - z2)


def _grid(n: int) -> np.ndarray:
    return np.clip(np.arange(n) / (n - 1), GRID_CLAMP, 1.0)


def _s_real(c, ior):
    """``clamp((F(c; ior) - F0) / (1 - F0), 0, 1)``: the Principled BSDF's remapped Fresnel."""
    f0 = ((ior - 1.0) / (ior + 1.0)) ** 2
    return jnp.clip((dielectric(c, ior) - f0) / (1.0 - f0), 0.0, 1.0)


@functools.partial(jax.jit, static_argnames=("n_theta", "n_phi"))
def _s_block(mu, alpha, ior, n_theta: int, n_phi: int):
    """``s`` (module docstring) for texels ``(mu[k], alpha[k], ior[k])``, ``alpha > 0``."""
    so = jnp.sqrt(jnp.maximum(1.0 - mu * mu, 0.0))
    v = jnp.stack([so, jnp.zeros_like(mu), mu], axis=-1)
    rule = halfvector_rule(v, alpha, n_theta=n_theta, n_phi=n_phi, dtype=jnp.float64)
    ix, iy, iz = (rule.directions[..., c] for c in range(3))
    a, co, so_, eta = alpha[:, None], mu[:, None], so[:, None], ior[:, None]
    hx, hy, hz = ix + so_, iy, iz + co
    t2 = (hx * hx + hy * hy) / (hz * hz)
    s2 = hx * hx + hy * hy + hz * hz
    cos_h2 = hz * hz / s2
    a2 = a * a
    d = a2 / (math.pi * cos_h2 * cos_h2 * (a2 + t2) ** 2)  # GGX D (Walter et al. 2007, eq. 33)
    p_v = jnp.sqrt(co * co + a2 * so_ * so_)  # mu (1 + 2 Lambda(v)): G1(v) = 2 mu / (mu + p_v)
    vh = 0.5 * jnp.sqrt(s2)
    return jnp.sum(rule.weights * d / (2.0 * (co + p_v)) * _s_real(vh, eta), axis=-1)


def s_values(mu, rough, ior, *, n_theta: int = HALFVECTOR_N_THETA,
             n_phi: int = HALFVECTOR_N_PHI) -> np.ndarray:
    """``s(mu, rough, ior)`` (module docstring; float64, broadcast shape), Cycles' mirror limit
    where ``rough^4 <= 2e-10``."""
    mu, rough, ior = np.broadcast_arrays(*(np.asarray(x, np.float64) for x in (mu, rough, ior)))
    shape = mu.shape
    mu, rough, ior = mu.ravel(), rough.ravel(), ior.ravel()
    alpha = rough * rough
    out = np.empty(mu.shape)
    with jax.enable_x64(True):
        mirror = alpha * alpha <= ROUGHNESS_SQ_THRESH
        out[mirror] = np.asarray(_s_real(jnp.asarray(mu[mirror]), jnp.asarray(ior[mirror])))
        todo = np.flatnonzero(~mirror)
        for start in range(0, todo.size, _BLOCK):
            idx = todo[start:start + _BLOCK]
            pad = _BLOCK - idx.size
            take = np.concatenate([idx, np.full(pad, idx[0], int)])
            val = _s_block(jnp.asarray(mu[take]), jnp.asarray(alpha[take]),
                           jnp.asarray(ior[take]), n_theta, n_phi)
            out[idx] = np.asarray(val)[:idx.size]
    return out.reshape(shape)


def cycles_tables() -> dict[str, np.ndarray]:
    """``{"ggx_E": (32, 32), "ggx_Eavg": (32,), "ggx_gen_schlick_ior_s": (16, 16, 16)}`` on
    Cycles' grids and layouts (module docstring), clamped to ``[0, 1]`` as Cycles stores them."""
    rough32, mu32 = _grid(32), _grid(32)
    alpha = rough32 ** 2
    mirror = alpha * alpha <= ROUGHNESS_SQ_THRESH
    A, B = dfg_values(mu32[:, None], np.broadcast_to(alpha[None, :], (32, 32)))
    E = np.where(mirror[None, :], 1.0, A + B)
    e_avg = np.where(mirror, 1.0, e_avg_values(np.where(mirror, 0.5, alpha)))
    z = np.clip(np.arange(16) / 15, *IOR_Z_CLAMP)
    rough16, mu16 = _grid(16), _grid(16)
    S = s_values(mu16[None, :, None], rough16[None, None, :], ior_from_z(z)[:, None, None],
                 n_theta=S_ORDER[0], n_phi=S_ORDER[1])
    # z = 1e-4: Cycles' float32 ior_from_F0 rounds 1 + 2e-8 to 1, where F = F0 = 0: s = 0
    S[0] = 0.0
    return {"ggx_E": np.clip(E, 0.0, 1.0), "ggx_Eavg": np.clip(e_avg, 0.0, 1.0),
            "ggx_gen_schlick_ior_s": np.clip(S, 0.0, 1.0)}


def resource_path() -> pathlib.Path:
    return pathlib.Path(__file__).resolve().parents[1] / "resources" / "tables" / CYCLES_TABLE_FILE


def write_cycles_tables(path=None) -> pathlib.Path:
    """Compute :func:`cycles_tables` and write them (``.npz``, float64, with a ``meta`` JSON
    string) to ``path`` (default: the package resource)."""
    import json

    path = resource_path() if path is None else pathlib.Path(path)
    tables = cycles_tables()
    meta = {"brdf_fit_version": __version__, "source": "brdf_fit.tables.cycles",
            "layout": {"ggx_E": "[mu, rough]", "ggx_Eavg": "[rough]",
                       "ggx_gen_schlick_ior_s": "[z, mu, rough]"},
            "quadrature": (f"E: dfg_values (halfvector_rule {HALFVECTOR_N_THETA} x "
                           f"{HALFVECTOR_N_PHI}); s: halfvector_rule {S_ORDER[0]} x "
                           f"{S_ORDER[1]}; float64")}
    np.savez(path, meta=np.array(json.dumps(meta)), **tables)
    return path


_ARRAY = re.compile(r"static const float table_(\w+)\[(\d+)\]\s*=\s*\{([^}]*)\};", re.S)


def read_cycles_tables(path) -> dict[str, np.ndarray]:
    """The float arrays of a Cycles ``shader.tables`` file, by name (flat, as printed)."""
    text = pathlib.Path(path).read_text(encoding="utf-8")
    out = {}
    for name, n, body in _ARRAY.findall(text):
        vals = np.array([float(x.strip().rstrip("f")) for x in body.split(",") if x.strip()])
        if vals.size != int(n):
            raise ValueError(f"{path}: table_{name} declares {n} values and holds {vals.size}")
        out[name] = vals
    return out


def compare(shader_tables, ours: dict[str, np.ndarray] | None = None) -> dict[str, dict]:
    """Per table: the largest and the mean absolute difference between Cycles' printed values
    and ours, and where the largest is (``(z,) mu, rough`` node indices)."""
    theirs = read_cycles_tables(shader_tables)
    ours = cycles_tables() if ours is None else ours
    out = {}
    for name, mine in ours.items():
        cyc = theirs[name].reshape(mine.shape)
        diff = np.abs(cyc - mine)
        k = np.unravel_index(int(np.argmax(diff)), diff.shape)
        out[name] = {"max_abs": float(diff.max()), "mean_abs": float(diff.mean()),
                     "at": [int(i) for i in k], "cycles": float(cyc[k]), "ours": float(mine[k])}
    return out


def write_sheen_table(shader_tables, path=None) -> pathlib.Path:
    """Transcribe Cycles' ``table_sheen_ltc`` (3 x 32 x 32: the LTC coefficients ``A``, ``B``
    and the albedo of the microfiber sheen, ``[roughness, cos]`` each) from a ``shader.tables``
    file into the package resource. Not rebuilt: the coefficients are T. Zeltner, B. Burley,
    M. J.-Y. Chiang's fit ("Practical Multiple-Scattering Sheen Using Linearly Transformed
    Cosines", SIGGRAPH 2022 talks) of a volumetric microflake sheen, as Cycles ships them
    (Blender 4.5, src/scene/shader.tables, Apache-2.0)."""
    import json

    table = read_cycles_tables(shader_tables)["sheen_ltc"].reshape(3, 32, 32)
    path = (resource_path().with_name(SHEEN_TABLE_FILE) if path is None
            else pathlib.Path(path))
    meta = {"source": "Cycles (Blender 4.5 release branch) src/scene/shader.tables, "
                      "table_sheen_ltc, transcribed",
            "reference": "T. Zeltner, B. Burley, M. J.-Y. Chiang, Practical Multiple-Scattering "
                         "Sheen Using Linearly Transformed Cosines, SIGGRAPH 2022 talks",
            "layout": "[A | B | albedo][roughness, cos_view], 32 x 32 endpoint nodes in [0, 1]"}
    np.savez(path, meta=np.array(json.dumps(meta)), sheen_ltc=table)
    return path


if __name__ == "__main__":
    import sys

    print(write_cycles_tables())
    if len(sys.argv) > 1:  # a Cycles shader.tables: transcribe the sheen table too
        print(write_sheen_table(sys.argv[1]))
