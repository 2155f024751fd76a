"""Local shading frame helpers: z is the normal, x the tangent (anisotropy axis), y the bitangent.

Directions are unit vectors of shape ``(..., 3)`` pointing away from the surface. Kernels unpack
components once (:func:`split`) and work on the scalars (DESIGN.md section 5).
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np


def split(w):
    """``(x, y, z)`` components of ``w`` (..., 3)."""
    return w[..., 0], w[..., 1], w[..., 2]


def join(x, y, z):
    """Stack components back into a ``(..., 3)`` array."""
    return jnp.stack(jnp.broadcast_arrays(x, y, z), axis=-1)


def mirror(w):
    """Mirror direction about the shading normal: ``(-x, -y, z)``."""
    return w * jnp.asarray([-1.0, -1.0, 1.0], dtype=w.dtype)


def frame_from_normal(n, t=None):
    """Orthonormal frame ``(t, b, n)`` from a normal and an optional tangent hint.

    Without a tangent, the branch-free construction of Duff et al., "Building an orthonormal basis,
    revisited", JCGT 6(1), 2017 is used. With one, ``t`` is Gram-Schmidt-orthogonalised to ``n``.
    """
    nx, ny, nz = split(n)
    if t is None:
        sign = jnp.where(nz >= 0, 1.0, -1.0)
        a = -1.0 / (sign + nz)
        b = nx * ny * a
        t = join(1.0 + sign * nx * nx * a, sign * b, -sign * nx)
    else:
        t = t - jnp.sum(t * n, axis=-1, keepdims=True) * n
        t = t / jnp.linalg.norm(t, axis=-1, keepdims=True)
    bvec = jnp.cross(n, t)
    return t, bvec, n


def to_world(w, t, b, n):
    x, y, z = split(w)
    return x[..., None] * t + y[..., None] * b + z[..., None] * n


# ------------------------------------------------------- angle grids in degrees (file/CLI boundary)


def unit_from_angles(theta_deg, phi_deg) -> np.ndarray:
    """Unit vectors ``(..., 3)`` (NumPy, float64) from zenith and azimuth angles in degrees."""
    t = np.radians(np.asarray(theta_deg, dtype=np.float64))
    p = np.radians(np.asarray(phi_deg, dtype=np.float64))
    st = np.sin(t)
    return np.stack([st * np.cos(p), st * np.sin(p), np.cos(t)], axis=-1)


def zenith_states_deg(n_theta: int, n_phi: int, max_zenith: float, phi0: float = 0.0):
    """Directions of a (theta, phi) grid in degrees with one state at the pole: theta on
    ``linspace(0, max_zenith, n_theta)`` (just the normal if ``n_theta == 1``), phi on
    ``phi0 + 360 k / n_phi``."""
    thetas = np.linspace(0.0, max_zenith, n_theta) if n_theta > 1 else np.zeros(1)
    phis = phi0 + 360.0 * np.arange(n_phi) / n_phi
    t, p = [], []
    for th in thetas:
        if th == 0.0:
            t.append(0.0)
            p.append(phi0)
        else:
            t.extend([th] * n_phi)
            p.extend(phis.tolist())
    return unit_from_angles(np.asarray(t), np.asarray(p))
