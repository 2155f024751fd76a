"""Environments that light a preview (:mod:`brdf_fit.render`): a constant one, and a
latitude-longitude map (an OpenEXR file the user gives), each able to say its radiance in a
direction, draw directions, and give their density, so that the renderer can weigh its samples
against the model's own (multiple importance sampling, Veach 1997, ch. 9).

**The lat-long convention is Mitsuba 3's** ``envmap`` (its default ``to_world``, ``+y`` up), so
that a scene lit by a map renders the same in both (``tests/test_render.py``): a world direction
``d`` is at ``u = atan2(d_x, -d_z) / (2 pi)`` (wrapped into [0, 1)) and ``v = acos(d_y) / pi``;
the texel ``(row j, column i)`` of an ``H x W`` map sits at ``u = (i + 1/2) / W`` (the columns
wrap around) and ``v = j / (H - 1)`` (the first row at the zenith ``+y``, the last at the nadir),
and the radiance between texels is bilinear. This was measured against Mitsuba 3.9.1's
``envmap`` ``eval`` at 200 random directions of an 6 x 8 map: agreement to 1.3e-6 (float32),
where the other half-texel and row conventions differ by 0.38 or more.

**Sampling.** The map's bilinear patches (between neighbouring texel columns, wrapping, and
rows: ``W x (H - 1)`` of them) are drawn with probability proportional to their corners' mean
channel value times their solid angle, a point uniform in ``(u, v)`` within the patch, and the
density per solid angle is ``p_patch W (H - 1) / (2 pi^2 sin(theta))`` (the Jacobian of the
lat-long map, as Mitsuba's and pbrt's). A patch with a non-zero corner has a non-zero
probability, so every direction the map lights is drawn (the estimate is unbiased); a patch of
four zero corners is dark throughout and never drawn. The constant environment draws uniformly
on the sphere (density ``1 / (4 pi)``).
"""

from __future__ import annotations

import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

__all__ = ["ConstantEnvironment", "LatLongEnvironment", "read_latlong", "sky_texels",
           "BUILT_IN"]


class ConstantEnvironment(eqx.Module):
    """The same radiance ``L`` (one value per channel) from every direction."""

    radiance_value: jax.Array

    def radiance(self, d):
        """``(..., C)``: ``L`` in every direction ``d`` ``(..., 3)``."""
        return jnp.broadcast_to(self.radiance_value, (*d.shape[:-1], self.radiance_value.size))

    def sample(self, u):
        """``(d, pdf)``: a direction uniform on the sphere from ``u`` ``(..., 2)`` in [0, 1)^2
        (Archimedes: ``z`` uniform in [-1, 1])."""
        z = 1.0 - 2.0 * u[..., 0]
        r = jnp.sqrt(jnp.maximum(1.0 - z * z, 0.0))
        phi = 2.0 * jnp.pi * u[..., 1]
        d = jnp.stack([r * jnp.cos(phi), r * jnp.sin(phi), z], -1)
        return d, jnp.full(z.shape, 1.0 / (4.0 * jnp.pi), u.dtype)

    def pdf(self, d):
        return jnp.full(d.shape[:-1], 1.0 / (4.0 * jnp.pi), d.dtype)


class LatLongEnvironment(eqx.Module):
    """A latitude-longitude map (module docstring): ``texels`` ``(H, W, C)`` (linear radiance,
    ``H >= 2``), and the patch distribution made from them by :meth:`of`."""

    texels: jax.Array
    patch_cdf: jax.Array  # (H - 1) * W cumulative probabilities, row-major over the patches
    patch_prob: jax.Array  # (H - 1, W)

    @classmethod
    def of(cls, texels) -> LatLongEnvironment:
        """The environment of ``texels`` ``(H, W, C)`` (NumPy or JAX; finite, non-negative, not
        all zero, ``H >= 2``); raises ValueError naming what is wrong."""
        t = np.asarray(texels, float)
        if t.ndim == 2:
            t = t[..., None]
        if t.ndim != 3 or t.shape[0] < 2 or t.shape[1] < 1:
            raise ValueError(f"an environment map is (H, W, C) with H >= 2, got {t.shape}")
        if not np.all(np.isfinite(t)) or np.any(t < 0.0):
            raise ValueError("an environment map's values must be finite and >= 0")
        H, W = t.shape[:2]
        level = t.mean(-1)  # the channels' mean: positive wherever any channel is
        corners = 0.25 * (level[:-1] + level[1:] + np.roll(level[:-1], -1, 1)
                          + np.roll(level[1:], -1, 1))
        theta = np.pi * np.arange(H) / (H - 1)
        solid = (2.0 * np.pi / W) * (np.cos(theta[:-1]) - np.cos(theta[1:]))
        weight = corners * solid[:, None]
        total = weight.sum()
        if not total > 0.0:
            raise ValueError("an environment map must not be black everywhere")
        prob = weight / total
        cdf = np.cumsum(prob.reshape(-1))
        cdf[-1] = 1.0
        return cls(jnp.asarray(t), jnp.asarray(cdf), jnp.asarray(prob))

    @property
    def shape(self) -> tuple[int, int]:
        return self.texels.shape[0], self.texels.shape[1]

    @staticmethod
    def _uv(d):
        u = jnp.arctan2(d[..., 0], -d[..., 2]) / (2.0 * jnp.pi)
        u = u - jnp.floor(u)
        v = jnp.arccos(jnp.clip(d[..., 1], -1.0, 1.0)) / jnp.pi
        return u, v

    def radiance(self, d):
        """``(..., C)``: the map's bilinear radiance in the world directions ``d`` (unit)."""
        H, W = self.shape
        u, v = self._uv(d)
        x = u * W - 0.5
        y = v * (H - 1)
        x0 = jnp.floor(x)
        y0 = jnp.clip(jnp.floor(y), 0, H - 2)
        fx, fy = (x - x0)[..., None], jnp.clip(y - y0, 0.0, 1.0)[..., None]
        i0 = x0.astype(jnp.int32) % W
        i1 = (i0 + 1) % W
        j0 = y0.astype(jnp.int32)
        j1 = j0 + 1
        t = self.texels
        return ((1 - fx) * (1 - fy) * t[j0, i0] + fx * (1 - fy) * t[j0, i1]
                + (1 - fx) * fy * t[j1, i0] + fx * fy * t[j1, i1])

    def sample(self, u):
        """``(d, pdf)``: a world direction drawn from ``u`` ``(..., 2)`` in [0, 1)^2 (module
        docstring) and its density per solid angle."""
        H, W = self.shape
        k = jnp.clip(jnp.searchsorted(self.patch_cdf, u[..., 0], side="right"), 0,
                     (H - 1) * W - 1)
        j, i = k // W, k % W
        uu = ((i.astype(u.dtype) + 0.5) + u[..., 1]) / W
        # the second coordinate within the patch: the first one's leftover, rescaled
        lo = jnp.where(k > 0, self.patch_cdf[jnp.maximum(k - 1, 0)], 0.0)
        width = self.patch_cdf[k] - lo
        s = jnp.clip((u[..., 0] - lo) / jnp.where(width > 0, width, 1.0), 0.0, 1.0)
        vv = (j.astype(u.dtype) + s) / (H - 1)
        theta, phi = jnp.pi * vv, 2.0 * jnp.pi * (uu - jnp.floor(uu))
        st = jnp.sin(theta)
        d = jnp.stack([st * jnp.sin(phi), jnp.cos(theta), -st * jnp.cos(phi)], -1)
        return d, self._pdf(j, i, st)

    def _pdf(self, j, i, sin_theta):
        H, W = self.shape
        p = self.patch_prob[j, i] * W * (H - 1) / (2.0 * jnp.pi ** 2)
        return jnp.where(sin_theta > 0, p / jnp.where(sin_theta > 0, sin_theta, 1.0), 0.0)

    def pdf(self, d):
        """The density per solid angle of :meth:`sample` at world directions ``d``."""
        H, W = self.shape
        u, v = self._uv(d)
        i = jnp.floor(u * W - 0.5).astype(jnp.int32) % W
        j = jnp.clip(jnp.floor(v * (H - 1)).astype(jnp.int32), 0, H - 2)
        return self._pdf(j, i, jnp.sqrt(jnp.maximum(1.0 - d[..., 1] ** 2, 0.0)))


def sky_texels(height: int = 64, width: int = 128) -> np.ndarray:
    """A procedural lat-long map shipped with the package (``--environment-map sky``), in the
    convention above: a sky of radiance 1 at the zenith falling to 0.3 at the horizon (as
    ``0.3 + 0.7 cos(theta)``, slightly blue: RGB 0.8, 0.9, 1), a ground of 0.1, and a sun of
    400 (3 x 3 texels, 30 degrees above the horizon, at azimuth ``u = 1/4``: toward ``+x``)."""
    v = np.arange(height) / (height - 1)
    sky = np.where(v < 0.5, 0.3 + 0.7 * np.cos(np.pi * v), 0.1)
    tex = np.repeat(sky[:, None, None], width, 1).repeat(3, 2) * np.array([0.8, 0.9, 1.0])
    j = int(round((1.0 / 3.0) * (height - 1)))
    tex[j - 1:j + 2, width // 4 - 1:width // 4 + 2] = 400.0
    return tex


#: the maps a name gives instead of a file (``--environment-map NAME``)
BUILT_IN = {"sky": sky_texels}


def read_latlong(path, scale: float = 1.0) -> LatLongEnvironment:
    """A lat-long OpenEXR file (its R, G, B channels, linear radiance) as an environment, times
    ``scale``; a file that cannot be read or is not such a map raises ValueError naming it.
    A name of :data:`BUILT_IN` (``sky``) gives that procedural map instead."""
    from brdf_fit.io.exr import read_exr

    if str(path) in BUILT_IN:
        return LatLongEnvironment.of(BUILT_IN[str(path)]() * scale)
    pixels, channels, _ = read_exr(path)  # (its errors name the file)
    names = [c.upper() for c in channels]
    if all(c in names for c in "RGB"):
        pixels = np.stack([pixels[..., names.index(c)] for c in "RGB"], -1)
    elif len(names) == 1:
        pixels = pixels[..., :1]
    else:
        raise ValueError(f"{path}: an environment map needs R, G, B channels (or one), "
                         f"found {', '.join(channels)}")
    if not (math.isfinite(scale) and scale >= 0.0):
        raise ValueError(f"environment scale {scale}: must be finite and >= 0")
    try:
        return LatLongEnvironment.of(np.asarray(pixels, float) * scale)
    except ValueError as e:
        raise ValueError(f"{path}: {e}") from None
