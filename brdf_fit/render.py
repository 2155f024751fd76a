"""Previews: a sphere shaded with a model under a directional light or an environment, or a
plane at a grazing view, as a linear image; dense measured data (MERL, RGL) rendered from
themselves; NVIDIA's FLIP between two renders (issue 46).

The scene, and Mitsuba 3's equivalent (``tests/test_render.py`` renders it there too):

- a unit sphere at the origin, seen by an orthographic camera on the +z axis looking down -z
  (``+y`` up, ``+x`` to the right of the image); the image covers ``[-FRAME_HALF_WIDTH,
  FRAME_HALF_WIDTH]`` in x and y, one ray per pixel through its centre;
- a directional light of irradiance ``E`` (W/m^2 on a surface facing it) arriving from
  zenith ``theta`` and azimuth ``phi`` (``(sin theta cos phi, sin theta sin phi, cos theta)``
  points toward it);
- direct illumination only: ``L = f(wi, wo) cos(theta_i) E`` at every pixel on the sphere
  (a convex sphere casts no shadow on itself), 0 elsewhere. ``wi`` is the light's direction and
  ``wo`` the camera's (``(0, 0, 1)``), both in the shading frame of the hit point: the normal
  ``n``, the tangent along the sphere's azimuth ``s = normalize(-n_y, n_x, 0)`` (Mitsuba's
  ``sphere`` shape: the direction of ``dp/du``; ``(1, 0, 0)`` at the pole, the image centre)
  and ``t = n x s``.

With the default ``E = pi`` a white Lambertian surface facing the light renders 1.

**A plane at a grazing view** (:func:`render_plane`), where grazing behaviour shows (Fresnel's
rise, a lobe's off-specular peak, a masking term's fall-off): the square ``|x|, |y| <=``
:data:`PLANE_HALF_WIDTH` of the plane ``z = 0`` (normal ``+z``, shading frame the world's
axes: Mitsuba's ``rectangle`` scaled by it), seen by a pinhole camera
:data:`PLANE_CAMERA_DISTANCE` from the origin at ``view_zenith_deg`` from the normal, on the
``-y`` side, looking at the origin with ``+z`` up (Mitsuba's ``perspective`` sensor with that
``look_at`` and a horizontal field of view ``fov_deg``; one ray per pixel through its centre):
the view direction changes across the image, up to the horizon, above which nothing is drawn.
The same directional light, ``L = f(wi, wo) cos(theta_i) E``; its default, at the view's zenith
on the far side (azimuth 90 degrees, toward ``+y``), puts the mirror glint at the image centre.

Under a constant environment of radiance ``L`` (:func:`render_sphere_environment`) a pixel is
``L`` times the directional albedo at its view direction, estimated at the pixel centre by
multiple importance sampling (Veach 1997, ch. 9) of the model's own sampler and the
environment's (uniform on the sphere), with each pixel's standard error. The sRGB
PNG is ``clip(L 2^exposure, 0, 1)`` encoded with the sRGB transfer function (IEC 61966-2-1,
through colour-science), 8 bits; the OpenEXR file keeps ``L`` linear (float32).
"""

from __future__ import annotations

import dataclasses
import functools
import math
import pathlib

import numpy as np

__all__ = ["FLIP_EXTRA", "FRAME_HALF_WIDTH", "HEURISTICS", "IRRADIANCE", "EnvironmentImage",
           "MerlTable", "RGLData", "dense_data", "PLANE_CAMERA_DISTANCE", "PLANE_HALF_WIDTH",
           "SphereImage", "flip_error", "plane_geometry", "render_plane", "render_sphere",
           "render_sphere_environment", "write_image", "write_png"]

#: half the width of the square the image covers, in sphere radii (a 10% margin)
FRAME_HALF_WIDTH = 1.1
#: default irradiance: a white Lambertian surface facing the light renders 1
IRRADIANCE = math.pi
#: half the side of the square of the plane :func:`render_plane` draws: at the default view
#: (camera 0.69 above the plane) only rays within 0.4 degrees of the horizon pass beyond it
PLANE_HALF_WIDTH = 100.0
#: distance of :func:`render_plane`'s camera from the origin (the plane's point at the image
#: centre)
PLANE_CAMERA_DISTANCE = 4.0
#: how to install NVIDIA's FLIP (an optional dependency, imported when a difference is asked)
FLIP_EXTRA = "pip install flip-evaluator (or pip install 'brdf_fit[render]')"


class MerlTable:
    """Dense MERL data as something :func:`render_sphere` shades with: ``eval`` interpolates
    trilinearly between the bin centres (:func:`brdf_fit.io.merl.merl_interpolate`; the
    nearest bin would draw the bins' edges across a highlight); a missing bin renders 0."""

    def __init__(self, table):
        self.table = np.asarray(table, float)

    def eval(self, wi, wo):
        from brdf_fit.io.merl import merl_interpolate

        v = merl_interpolate(self.table, np.asarray(wi, float), np.asarray(wo, float))
        return np.where(v < 0.0, 0.0, v)


class RGLData:
    """A dense RGL-EPFL material (``.bsdf``) as something :func:`render_sphere` shades with:
    its own evaluation (:meth:`brdf_fit.io.rgl.RGLMaterial.eval`, the interpolation of
    Mitsuba 3's ``measured`` plugin), in NumPy; 0 below the surface."""

    def __init__(self, material):
        self.material = material

    def eval(self, wi, wo):
        return self.material.eval(np.asarray(wi, float), np.asarray(wo, float))


def dense_data(path):
    """Dense measured data that can be rendered from themselves: a MERL ``.binary`` file
    (:class:`MerlTable`) or an RGL ``.bsdf`` file (:class:`RGLData`); None for any other
    file (sparse data: a gonioreflectometer's samples cannot be rendered from themselves).
    A file of either kind that cannot be read raises :class:`~brdf_fit.data.DataError` naming
    it."""
    import os

    from brdf_fit.io.merl import is_merl_file, read_merl_table

    if is_merl_file(path):
        return MerlTable(read_merl_table(path))
    if os.fspath(path).lower().endswith(".bsdf"):
        from brdf_fit.io.rgl import RGLMaterial, read_tensor_file

        return RGLData(RGLMaterial(read_tensor_file(path), os.fspath(path)))
    return None


@dataclasses.dataclass
class SphereImage:
    """A rendered sphere: ``radiance`` ``(size, size, C)`` (linear, C = the model's channels,
    at least 3), ``mask`` ``(size, size)`` (pixels on the sphere), ``cos_view`` (``n . wo``
    per pixel; 0 off the sphere: how far from the silhouette), the light's direction and
    irradiance."""

    radiance: np.ndarray
    mask: np.ndarray
    cos_view: np.ndarray
    light: np.ndarray
    irradiance: np.ndarray


def light_direction(zenith_deg: float, azimuth_deg: float = 0.0) -> np.ndarray:
    """The unit vector toward a light at ``zenith_deg`` from +z and ``azimuth_deg`` from +x."""
    t, p = math.radians(zenith_deg), math.radians(azimuth_deg)
    return np.array([math.sin(t) * math.cos(p), math.sin(t) * math.sin(p), math.cos(t)])


def _sphere_pixels(size: int):
    """``(frames, mask)``: each pixel centre's shading frame on the unit sphere, ``(size^2, 3,
    3)`` flattened row-major (row 0 at the top), its rows the local axes ``s, t, n`` in world
    coordinates (module docstring: ``s`` along the sphere's azimuth, Mitsuba's ``dp/du``; off
    the sphere the normal of ``(x, y, 0)`` clipped to the disc), and the pixels on it."""
    c = (np.arange(size) + 0.5) / size * 2.0 - 1.0
    x = FRAME_HALF_WIDTH * c[None, :].repeat(size, 0)
    y = -FRAME_HALF_WIDTH * c[:, None].repeat(size, 1)
    r2 = x * x + y * y
    n = np.stack([x, y, np.sqrt(np.maximum(1.0 - r2, 0.0))], -1).reshape(-1, 3)
    s = np.stack([-n[:, 1], n[:, 0], np.zeros(len(n))], -1)
    norm = np.linalg.norm(s, axis=-1, keepdims=True)
    s = np.where(norm > 0.0, s / np.where(norm > 0.0, norm, 1.0), [1.0, 0.0, 0.0])
    return np.stack([s, np.cross(n, s), n], 1), (r2 < 1.0).reshape(-1)


def _masked(wi, wo, m, cos_view):
    """The ``(wi, wo, cos_i, mask, cos_view)`` of a geometry (:func:`sphere_geometry`,
    :func:`plane_geometry`): the normal incidence pair where nothing is drawn, the light's
    cosine (0 below the surface), ``cos_view`` 0 off the mask."""
    up = np.array([0.0, 0.0, 1.0])
    wi = np.where(m[:, None], wi, up)
    wo = np.where(m[:, None], wo, up)
    cos_i = np.where(m, np.maximum(wi[:, 2], 0.0), 0.0)
    return wi, wo, cos_i, m, np.where(m, cos_view, 0.0)


def sphere_geometry(size: int, light) -> tuple[np.ndarray, ...]:
    """``(wi, wo, cos_i, mask, cos_view)`` per pixel, flattened row-major (row 0 at the top):
    the light and camera directions in each hit point's shading frame (the normal incidence
    pair off the sphere, where nothing is drawn), the light's cosine (0 below the surface)."""
    frames, m = _sphere_pixels(size)
    light = np.asarray(light, float)
    # the camera's direction (0, 0, 1) in each frame is the frame's third column
    return _masked(frames @ (light / np.linalg.norm(light)), frames[:, :, 2], m,
                   frames[:, 2, 2])


def render_sphere(model, size: int = 256, light_zenith_deg: float = 45.0,
                  light_azimuth_deg: float = 0.0, irradiance=IRRADIANCE) -> SphereImage:
    """The sphere shaded with ``model`` (a built model) under a directional light (module
    docstring). One call of ``model.eval`` on every pixel: one compiled program per model
    type and image size, whatever the parameter values. ``irradiance``: a number or one per
    channel."""
    if size < 1:
        raise ValueError(f"render: size must be >= 1, got {size}")
    light = light_direction(light_zenith_deg, light_azimuth_deg)
    return _shade(model, int(size), light, irradiance, sphere_geometry(int(size), light))


def plane_geometry(size: int, light, view_zenith_deg: float, fov_deg: float):
    """``(wi, wo, cos_i, mask, cos_view)`` per pixel of :func:`render_plane`'s view, flattened
    row-major (row 0 at the top), as :func:`sphere_geometry` gives them for the sphere; the
    normal incidence pair where a ray misses the square."""
    t = math.radians(view_zenith_deg)
    origin = PLANE_CAMERA_DISTANCE * np.array([0.0, -math.sin(t), math.cos(t)])
    forward = -origin / np.linalg.norm(origin)
    left = np.cross([0.0, 0.0, 1.0], forward)  # Mitsuba's look_at: up x dir
    left /= np.linalg.norm(left)
    up = np.cross(forward, left)
    half = math.tan(math.radians(fov_deg) / 2.0)
    c = ((np.arange(size) + 0.5) / size * 2.0 - 1.0) * half
    d = (forward[None, None] - c[None, :, None] * left[None, None]
         - c[:, None, None] * up[None, None]).reshape(-1, 3)
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    down = d[:, 2] < 0.0
    dist = np.where(down, -origin[2] / np.where(down, d[:, 2], -1.0), 0.0)
    p = origin[None] + dist[:, None] * d
    m = down & (np.abs(p[:, 0]) <= PLANE_HALF_WIDTH) & (np.abs(p[:, 1]) <= PLANE_HALF_WIDTH)
    light = np.asarray(light, float)
    wi = np.broadcast_to(light / np.linalg.norm(light), d.shape)
    return _masked(wi, -d, m, -d[:, 2])


def render_plane(model, size: int = 256, view_zenith_deg: float = 80.0, fov_deg: float = 30.0,
                 light_zenith_deg: float | None = None, light_azimuth_deg: float = 90.0,
                 irradiance=IRRADIANCE) -> SphereImage:
    """The plane at a grazing view (module docstring) shaded with ``model`` under a
    directional light, as a :class:`SphereImage` (``mask``: the pixels that see the plane;
    ``cos_view``: ``n . wo`` there, small toward the horizon). ``light_zenith_deg`` defaults to
    ``view_zenith_deg`` (with azimuth 90 degrees: the mirror glint at the centre). One call of
    ``model.eval`` on every pixel, as :func:`render_sphere`."""
    if size < 1:
        raise ValueError(f"render: size must be >= 1, got {size}")
    if not 0.0 < view_zenith_deg < 90.0:
        raise ValueError(f"render: view zenith {view_zenith_deg} must be in (0, 90) degrees")
    if not 0.0 < fov_deg < 180.0:
        raise ValueError(f"render: field of view {fov_deg} must be in (0, 180) degrees")
    zenith = view_zenith_deg if light_zenith_deg is None else light_zenith_deg
    light = light_direction(zenith, light_azimuth_deg)
    geometry = plane_geometry(int(size), light, view_zenith_deg, fov_deg)
    return _shade(model, int(size), light, irradiance, geometry)


def _shade(model, size: int, light, irradiance, geometry) -> SphereImage:
    """``f(wi, wo) cos_i E`` at every pixel of ``geometry`` (:func:`sphere_geometry` or
    :func:`plane_geometry`), 0 off the mask: one ``model.eval`` call."""
    import jax.numpy as jnp

    wi, wo, cos_i, m, cos_view = geometry
    dtype = jnp.zeros(()).dtype
    f = np.asarray(model.eval(jnp.asarray(wi, dtype), jnp.asarray(wo, dtype)), float)
    f = f.reshape(len(wi), -1)
    channels = max(3, f.shape[1])
    E = np.broadcast_to(np.asarray(irradiance, float).reshape(-1), (channels,))
    L = np.broadcast_to(f, (len(wi), channels)) * cos_i[:, None] * E
    L = np.where(m[:, None], L, 0.0)
    return SphereImage(radiance=L.reshape(size, size, channels),
                       mask=m.reshape(size, size), cos_view=cos_view.reshape(size, size),
                       light=light, irradiance=np.array(E))


@dataclasses.dataclass
class EnvironmentImage(SphereImage):
    """A sphere under a constant environment (:func:`render_sphere_environment`): besides the
    radiance, ``stderr`` ``(size, size, C)``, each pixel's standard error (the spread of its
    per-sample estimates over the square root of their number), and the estimator's settings."""

    stderr: np.ndarray | None = None
    samples_per_pixel: int = 0
    heuristic: str = "balance"


#: the multiple-importance-sampling weights :func:`render_sphere_environment` offers (Veach
#: 1997, ch. 9, eq. 9.13 and the power heuristic of eq. 9.14 with beta = 2)
HEURISTICS = ("balance", "power")


def _environment_estimates(model, wo, frames, environment, key, spp: int, power: bool):
    """``(mean, stderr)`` per pixel of ``int f(wi, wo) cos(theta_i) L(wi) dwi`` by multiple
    importance sampling of two strategies, one sample each per pass: the model's own sampler
    (``sample``, density ``pdf``), and the environment's (:mod:`brdf_fit.envmap`: uniform on
    the sphere for a constant one, the map's patches for a lat-long map; its samples below the
    surface add 0). Each sample's weight is the balance or the power heuristic of the two
    densities (Veach 1997, eqs. 9.13-9.14). ``wo`` ``(P, 3)`` is local to each pixel's shading
    frame, ``frames`` ``(P, 3, 3)`` its rows the local axes in world coordinates (the
    environment's directions are the world's)."""
    import jax
    import jax.numpy as jnp

    P = wo.shape[0]
    k1, k2, k3 = jax.random.split(key, 3)
    wo_s = jnp.broadcast_to(wo[:, None, :], (P, spp, 3))
    uc = jax.random.uniform(k1, (P, spp), wo.dtype)
    u = jax.random.uniform(k2, (P, spp, 2), wo.dtype)
    v = jax.random.uniform(k3, (P, spp, 2), wo.dtype)

    def weight(p_self, p_other):
        if power:
            return p_self * p_self / (p_self * p_self + p_other * p_other)
        return p_self / (p_self + p_other)

    def contribution(wi, world, p_self, p_other):
        f = model.eval(wi, wo_s).reshape(P, spp, -1)
        cos = jnp.maximum(wi[..., 2], 0.0)
        ok = (cos > 0.0) & (p_self > 0.0) & jnp.isfinite(p_self)
        w = jnp.where(ok, weight(p_self, p_other) * cos / jnp.where(ok, p_self, 1.0), 0.0)
        return f * w[..., None] * environment.radiance(world)

    s = model.sample(wo_s, uc, u)
    world_b = jnp.einsum("pij,psi->psj", frames, s.wi)  # local -> world
    p_e_at_b = jnp.where(s.wi[..., 2] > 0.0, environment.pdf(world_b), 0.0)
    c_b = contribution(s.wi, world_b, s.pdf, p_e_at_b)
    world_e, p_e = environment.sample(v)
    wi_e = jnp.einsum("pij,psj->psi", frames, world_e)  # world -> local
    p_b_at_e = jnp.where(wi_e[..., 2] > 0.0, model.pdf(wi_e, wo_s), 0.0)
    c_e = contribution(wi_e, world_e, p_e, p_b_at_e)
    x = c_b + c_e  # one estimate per pass
    mean = jnp.mean(x, 1)
    stderr = jnp.std(x, 1, ddof=1) / jnp.sqrt(spp)
    return mean, stderr


#: samples (pixels x samples per pixel) per compiled call of the environment estimate
ENV_BLOCK_SAMPLES = 1 << 18


def render_sphere_environment(model, size: int = 128, radiance=1.0, samples_per_pixel: int = 64,
                              seed: int = 0, heuristic: str = "balance",
                              progress=None, environment=None) -> EnvironmentImage:
    """The sphere of :func:`render_sphere` lit by an environment from every direction above
    each point's surface (a convex sphere does not occlude itself): a constant one of
    ``radiance`` (a number or one per channel), or ``environment``, a
    :class:`~brdf_fit.envmap.LatLongEnvironment` (a lat-long map, Mitsuba 3's convention, ``+y``
    up: :mod:`brdf_fit.envmap`; ``radiance`` then scales it). Estimated at each pixel centre
    with ``samples_per_pixel`` passes of multiple importance sampling (the model's sampler and
    the environment's; ``heuristic``: :data:`HEURISTICS`). Under a constant environment the
    exact value is ``radiance`` times the model's directional albedo at the pixel's view
    direction; the image carries each pixel's standard error. Models with a delta lobe (a
    mirror) have no density to weigh and are refused. The pixels go in blocks of
    :data:`ENV_BLOCK_SAMPLES` samples; ``progress(done, total)`` is called after each block."""
    import jax
    import jax.numpy as jnp

    from brdf_fit.envmap import ConstantEnvironment

    if heuristic not in HEURISTICS:
        raise ValueError(f"render: heuristic must be one of {HEURISTICS}, got {heuristic!r}")
    if samples_per_pixel < 2:
        raise ValueError(f"render: samples_per_pixel must be >= 2, got {samples_per_pixel}")
    if getattr(model, "is_delta", False):
        raise ValueError("render: a model with a delta lobe has no density for an environment "
                         "estimate")
    frames, m = _sphere_pixels(int(size))
    wo = frames[:, :, 2]  # the camera's direction in each frame (read on the sphere only)
    cos_view = np.where(m, frames[:, 2, 2], 0.0)
    on = np.flatnonzero(m)
    dtype = jnp.zeros(()).dtype
    scale = np.asarray(radiance, float).reshape(-1)
    if environment is None:
        env = ConstantEnvironment(jnp.asarray(np.ones(1), dtype))
    else:
        env = jax.tree.map(lambda a: jnp.asarray(a, dtype), environment)
    estimate = _environment_program(heuristic == "power", int(samples_per_pixel))
    # pixels in blocks of one size (one compiled program; memory bounded by the block), each
    # block its own random stream (the seed folded with the block's index)
    # (a small image gets a block of its own size, to the next power of two, instead of
    # paying for a whole one: 0.9 s for a 16 x 16 sphere at 64 spp with the full block)
    block = max(1, min(ENV_BLOCK_SAMPLES // int(samples_per_pixel),
                       1 << max(0, len(on) - 1).bit_length()))
    n_blocks = -(-len(on) // block)
    means, ses = [], []
    for b in range(n_blocks):
        idx = on[b * block:(b + 1) * block]
        part, fr = wo[idx], frames[idx]
        pad = block - len(part)
        if pad:
            part = np.concatenate([part, np.broadcast_to([0.0, 0.0, 1.0], (pad, 3))])
            fr = np.concatenate([fr, np.broadcast_to(np.eye(3), (pad, 3, 3))])
        key = jax.random.fold_in(jax.random.key(seed), b)
        mean_b, se_b = estimate(model, jnp.asarray(part, dtype), jnp.asarray(fr, dtype), env,
                                key)
        means.append(np.asarray(mean_b, float)[: block - pad])
        ses.append(np.asarray(se_b, float)[: block - pad])
        if progress is not None:
            progress(b + 1, n_blocks)
    mean = np.concatenate(means).reshape(len(on), -1)
    se = np.concatenate(ses).reshape(len(on), -1)
    channels = max(3, mean.shape[1])
    L = np.broadcast_to(scale, (channels,))
    out = np.zeros((size * size, channels))
    err = np.zeros((size * size, channels))
    out[on] = np.broadcast_to(mean, (len(on), channels)) * L
    err[on] = np.broadcast_to(se, (len(on), channels)) * L
    return EnvironmentImage(radiance=out.reshape(size, size, channels),
                            mask=m.reshape(size, size), cos_view=cos_view.reshape(size, size),
                            light=np.zeros(3), irradiance=np.array(L),
                            stderr=err.reshape(size, size, channels),
                            samples_per_pixel=int(samples_per_pixel), heuristic=heuristic)


@functools.cache
def _environment_program(power: bool, spp: int):
    """The compiled estimate of one heuristic and sample count (one program per model type,
    environment kind and shape, and pixel count)."""
    import equinox as eqx

    return eqx.filter_jit(lambda model, wo, frames, env, key: _environment_estimates(
        model, wo, frames, env, key, spp, power))


def flip_error(reference: SphereImage, test: SphereImage) -> tuple[np.ndarray, float]:
    """NVIDIA's FLIP (Andersson et al. 2021, "Visualizing errors in rendered high dynamic range
    images", Eurographics short papers; the ``flip-evaluator`` package) between two renders of
    the scene, in its HDR mode on the linear RGB radiance (its own exposure range and tone
    mapper, 67 pixels per degree): ``(error map (H, W) in [0, 1], its mean over the
    reference's sphere)``. The mean leaves out the background, which both draw black and
    would only dilute it."""
    try:
        import flip_evaluator
    except ImportError:
        raise ImportError(f"a FLIP difference needs NVIDIA's FLIP: {FLIP_EXTRA}") from None
    ref = np.ascontiguousarray(reference.radiance[..., :3], np.float32)
    tst = np.ascontiguousarray(test.radiance[..., :3], np.float32)
    if ref.shape != tst.shape:
        raise ValueError(f"flip_error: images of shapes {ref.shape} and {tst.shape}")
    emap = np.asarray(flip_evaluator.evaluate(ref, tst, "HDR", applyMagma=False)[0], float)
    emap = emap.reshape(ref.shape[:2])
    return emap, float(emap[reference.mask].mean()) if reference.mask.any() else 0.0


def error_map_8bit(emap) -> np.ndarray:
    """A FLIP error map as ``(H, W, 3)`` uint8 through matplotlib's magma (FLIP's own colour
    map), 0 black to 1 light yellow."""
    from matplotlib import colormaps

    return np.round(colormaps["magma"](np.clip(emap, 0.0, 1.0))[..., :3] * 255).astype(np.uint8)


def srgb_8bit(radiance, exposure: float = 0.0) -> np.ndarray:
    """``(H, W, 3)`` uint8: ``clip(L 2^exposure, 0, 1)`` through the sRGB encoding
    (IEC 61966-2-1, colour-science's ``cctf_encoding``), rounded."""
    import colour

    v = np.clip(np.asarray(radiance, float)[..., :3] * 2.0 ** exposure, 0.0, 1.0)
    return np.round(colour.cctf_encoding(v, function="sRGB") * 255.0).astype(np.uint8)


def write_png(path, pixels) -> pathlib.Path:
    """``(H, W, 3)`` uint8 ``pixels`` as a PNG file, whole or not at all
    (:func:`brdf_fit.core.atomic.atomic_path`)."""
    import matplotlib.image

    from brdf_fit.core.atomic import atomic_path

    path = pathlib.Path(path)
    with atomic_path(path) as tmp:
        matplotlib.image.imsave(tmp, pixels, format="png")
    return path


def write_image(path, image: SphereImage, exposure: float = 0.0) -> pathlib.Path:
    """Write ``image`` as ``.png`` (sRGB, 8 bits, :func:`srgb_8bit`) or ``.exr`` (linear
    float32 R, G, B, and A = the sphere's mask), by the suffix; whole or not at all
    (:func:`brdf_fit.core.atomic.atomic_path`)."""
    from brdf_fit.core.atomic import atomic_path

    path = pathlib.Path(path)
    suffix = path.suffix.lower()
    if suffix not in (".png", ".exr"):
        raise ValueError(f"{path}: unknown image extension {path.suffix!r}; use .png or .exr")
    if suffix == ".png":
        write_png(path, srgb_8bit(image.radiance, exposure))
    else:
        from brdf_fit.io.exr import write_exr

        rgba = np.concatenate([image.radiance[..., :3], image.mask[..., None]], -1)
        with atomic_path(path) as tmp:
            write_exr(tmp, rgba.astype(np.float32), channels=("R", "G", "B", "A"))
    return path
