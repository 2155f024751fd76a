"""Cycles' closure helpers that Blender's Principled BSDF (:mod:`brdf_fit.models
.blender_principled`) is built from, transcribed from Cycles 4.5 (Blender's release branch of
the Cycles repository): its lookup tables and their interpolation (``kernel/util/lookup_table
.h``), the Fresnel helpers of ``kernel/closure/bsdf_util.h``, the multiple-scattering
compensation and albedo estimate of ``kernel/closure/bsdf_microfacet.h``, and the sheen lobe of
``kernel/closure/bsdf_sheen.h``. Each function names the Cycles function it transcribes; the
formulas are in the model module's docstring."""

from __future__ import annotations

import functools
import importlib.resources

import jax.numpy as jnp
import numpy as np

from brdf_fit.core.fresnel import dielectric
from brdf_fit.core.numerics import INV_PI, safe_div, safe_sqrt

__all__ = ["CLOSURE_WEIGHT_CUTOFF", "CYCLES_TABLE_FILE", "ROUGHNESS_SQ_THRESH",
           "SAMPLER_ALPHA_FLOOR", "SHEEN_INVALID", "SHEEN_ROUGHNESS_MIN", "SHEEN_TABLE_FILE",
           "compensation", "estimated_s", "f0_from_ior", "fresnel_dielectric_fss", "ior_from_f0",
           "lookup_1d", "lookup_2d", "lookup_3d", "remapped_fresnel", "sheen_lobe", "tables"]

#: ``CLOSURE_WEIGHT_CUTOFF`` (kernel/svm/types.h): a coat or metallic weight at or below is skipped
CLOSURE_WEIGHT_CUTOFF = 1e-5
#: ``BSDF_ROUGHNESS_SQ_THRESH`` (kernel/svm/types.h): ``alpha_x alpha_y`` at or below: a mirror
ROUGHNESS_SQ_THRESH = 2e-10
#: the narrowest GGX width the sampler draws from: a lobe at roughness 0 (a mirror, which
#: ``eval`` does not see) is still drawn as a very narrow one, so its pdf stays finite
SAMPLER_ALPHA_FLOOR = 1e-7
#: the shipped tables (brdf_fit.tables.cycles)
CYCLES_TABLE_FILE = "cycles_ggx.npz"
#: ``bsdf_sheen_setup``: the sheen roughness is clamped to [1e-3, 1]; an LTC whose ``A`` or
#: albedo interpolates below 1e-5 is no closure (the table's invalid corner: smooth sheen at
#: grazing views)
SHEEN_ROUGHNESS_MIN = 1e-3
SHEEN_INVALID = 1e-5
#: the transcribed sheen table (brdf_fit.tables.cycles.write_sheen_table)
SHEEN_TABLE_FILE = "cycles_sheen_ltc.npz"


@functools.lru_cache(maxsize=1)
def tables() -> dict[str, np.ndarray]:
    """The shipped tables as float64 NumPy arrays (loaded once)."""
    out = {}
    for name, keys in ((CYCLES_TABLE_FILE, ("ggx_E", "ggx_Eavg", "ggx_gen_schlick_ior_s")),
                       (SHEEN_TABLE_FILE, ("sheen_ltc",))):
        ref = importlib.resources.files("brdf_fit") / "resources" / "tables" / name
        with importlib.resources.as_file(ref) as p, np.load(p) as z:
            out.update({k: np.asarray(z[k], np.float64) for k in keys})
    return out


def _lerp_axis(x, n: int):
    """``lookup_table_read`` along one axis of ``n`` nodes ``i / (n - 1)``: ``x`` clamped to
    [0, 1]; ``(i, f)`` with the value ``(1 - f) v[i] + f v[i + 1]``."""
    t = jnp.clip(x, 0.0, 1.0) * (n - 1)
    fi = jnp.minimum(jnp.floor(t), n - 2)
    return fi.astype(jnp.int32), t - fi


def lookup_1d(table, x, dtype=None):
    """``lookup_table_read(x)`` (the table in ``dtype``, default ``x``'s)."""
    i, f = _lerp_axis(x, table.shape[0])
    t = jnp.asarray(table, jnp.result_type(x) if dtype is None else dtype)
    return (1 - f) * t[i] + f * t[i + 1]


def lookup_2d(table, x, y):
    """``lookup_table_read_2D(x, y)`` of a ``[y, x]`` table (or of ``table[k]`` for each ``k``
    of a leading index array: ``table`` ``[z, y, x]`` with ``k`` given)."""
    ny, nx = table.shape[-2:]
    ix, fx = _lerp_axis(x, nx)
    iy, fy = _lerp_axis(y, ny)
    t = jnp.asarray(table, jnp.result_type(x, y))
    v00, v01 = t[..., iy, ix], t[..., iy, ix + 1]
    v10, v11 = t[..., iy + 1, ix], t[..., iy + 1, ix + 1]
    return (1 - fy) * ((1 - fx) * v00 + fx * v01) + fy * ((1 - fx) * v10 + fx * v11)


def lookup_3d(table, x, y, z):
    """``lookup_table_read_3D(x, y, z)`` of a ``[z, y, x]`` table."""
    nz, ny, nx = table.shape
    iz, fz = _lerp_axis(z, nz)
    ix, fx = _lerp_axis(x, nx)
    iy, fy = _lerp_axis(y, ny)
    t = jnp.asarray(table, jnp.result_type(x, y, z))

    def plane(k):
        v00, v01 = t[k, iy, ix], t[k, iy, ix + 1]
        v10, v11 = t[k, iy + 1, ix], t[k, iy + 1, ix + 1]
        return (1 - fy) * ((1 - fx) * v00 + fx * v01) + fy * ((1 - fx) * v10 + fx * v11)

    return (1 - fz) * plane(iz) + fz * plane(iz + 1)


def f0_from_ior(ior):
    """``F0_from_ior``: ``((ior - 1)/(ior + 1))^2``."""
    r = (ior - 1.0) / (ior + 1.0)
    return r * r


def ior_from_f0(f0):
    """``ior_from_F0``: ``(1 + sqrt(f0))/(1 - sqrt(f0))``, ``f0`` clamped to [0, 0.99]."""
    s = safe_sqrt(jnp.clip(f0, 0.0, 0.99))
    return (1.0 + s) / (1.0 - s)


def fresnel_dielectric_fss(eta):
    """``fresnel_dielectric_Fss`` for ``eta >= 1``: Kulla & Conty's (2017) fit of the
    cosine-weighted average Fresnel, ``(eta - 1)/(4.08567 + 1.00071 eta)``."""
    return (eta - 1.0) / (4.08567 + 1.00071 * eta)


def remapped_fresnel(c, eta):
    """``clamp((F_diel(c; eta) - F0(eta)) / (1 - F0(eta)), 0, 1)``: the Principled BSDF's
    interpolation factor between ``F0`` and 1 (``microfacet_fresnel``, negative exponent)."""
    f0 = f0_from_ior(eta)
    return jnp.clip(safe_div(dielectric(c, eta) - f0, 1.0 - f0), 0.0, 1.0)


def compensation(rough, mu, fss):
    """``(A, darkening)`` of ``microfacet_ggx_preserve_energy`` (module docstring): ``eval``
    carries ``A = energy_scale x darkening``, the closure's weight (hence its albedo, which
    layers the lobes below) only ``darkening = A / (1 + (1 - E)/E)``. ``rough`` and ``mu`` per
    direction, ``fss`` per channel."""
    tab = tables()
    E = lookup_2d(tab["ggx_E"], rough, mu)
    E_avg = lookup_1d(tab["ggx_Eavg"], rough, jnp.result_type(rough, mu))
    missing = (1.0 - E) / E
    f_ms = fss * E_avg / (1.0 - fss * (1.0 - E_avg))
    A = 1.0 + f_ms * missing
    return A, A / (1.0 + missing)


def sheen_lobe(ab, ix, iy, iz, ox, oy):
    """``bsdf_sheen_eval / cos(theta_i)``: the LTC ``(1/pi) (A / |M^-1 l|^2)^2`` with
    ``|M^-1 l|^2 = (A x + B z)^2 + (A y)^2 + z^2`` in the frame whose x axis is the view's
    tangential direction (``make_orthonormals_safe_tangent(N, wo)``; at normal view, where it
    has none, any frame: the lobe is then symmetric)."""
    a, b = ab
    t2 = ox * ox + oy * oy
    has = t2 > 1e-24
    inv = 1.0 / jnp.sqrt(jnp.where(has, t2, 1.0))
    tx, ty = jnp.where(has, ox * inv, 1.0), jnp.where(has, oy * inv, 0.0)
    x = ix * tx + iy * ty
    y = -ix * ty + iy * tx
    len2 = (a * x + b * iz) ** 2 + (a * y) ** 2 + iz * iz
    return INV_PI * (a / len2) ** 2


def estimated_s(rough, mu, eta):
    """``ggx_gen_schlick_ior_s`` at ``(rough, mu, z = sqrt((eta - 1)/(eta + 1)))``."""
    z = safe_sqrt(jnp.abs((eta - 1.0) / (eta + 1.0)))
    return lookup_3d(tables()["ggx_gen_schlick_ior_s"], rough, mu, z)
