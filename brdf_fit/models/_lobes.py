"""Lobe kernels the models share (DESIGN.md section 3), written once:

* sanitising directions: lanes at or below the horizon see the normal ``(0, 0, 1)`` before any
  singular formula does, and are masked afterwards (the double-where idiom of
  :mod:`brdf_fit.core.numerics`): :func:`sanitize`, :func:`sanitize_direction`,
  :func:`sanitize_wo`, :func:`sanitize_pair`, :func:`upper`, :func:`scaled_where`;
* the half vector ``h = normalize(wi + wo)`` with its validity flag: raw (:func:`half_vector`),
  sanitised with both directions for microfacet-type lobes (:func:`half_geometry`, ``wo.h``) or
  for half-vector Phong-type lobes (:func:`half_angles`, ``wi.h``); reflecting ``wo`` about a
  sampled ``h`` (:func:`reflect_about_half`);
* the power-cosine lobe (Lafortune & Willems 1994, section 3) about an axis
  (:func:`power_cosine_local`, :func:`sample_power_cosine_about`) and about the mirror direction
  ``r_o = 2 (n.wo) n - wo``: ``cos(alpha_r)`` (:func:`cos_alpha_r`), the whole-sphere density
  ``(n+1)/(2 pi) cos^n(alpha_r)`` (:func:`power_cosine_pdf`, :func:`mirror_lobe_pdf`) and the
  samplers (:func:`sample_lobe_about_mirror`, :func:`sample_mirror_lobe`);
* the cosine-weighted fallback sampler (:func:`cosine_pdf`, :func:`sample_cosine`) and the
  one-sample choice between a cosine-weighted diffuse lobe and a specular one (probability
  :func:`lobe_probability`; the mirror lobe: :func:`diffuse_mirror_pdf`,
  :func:`sample_diffuse_or_mirror`; a sampled half vector: :func:`sample_diffuse_or_half`);
* the sample weight ``f cos / pdf`` with the failed-sample convention (:func:`sample_weight`) and
  the :class:`~brdf_fit.models.BRDFSample` a sampler returns (:func:`finish_sample`).

Every kernel is the formula its models had written by hand, operation for operation, so the
models' values and gradients are unchanged (bit for bit).
"""
from __future__ import annotations

import math
from typing import NamedTuple

import jax
import jax.numpy as jnp

from brdf_fit.core.frame import frame_from_normal, join, mirror, split, to_world
from brdf_fit.core.numerics import (
    INV_PI,
    INV_TWO_PI,
    safe_div,
    safe_normalize3,
    safe_sqrt,
)
from brdf_fit.core.validate import check_param, check_scalar
from brdf_fit.core.warp import sample_cosine_hemisphere
from brdf_fit.models._base import AbstractBRDF, BRDFSample, expand_channels

__all__ = [
    "EXPONENT_MAX",
    "HalfGeometry",
    "check_exponent",
    "cos_alpha_r",
    "cos_alpha_r_pow",
    "cosine_pdf",
    "diffuse_mirror_pdf",
    "finish_sample",
    "half_angles",
    "half_geometry",
    "half_vector",
    "lobe_probability",
    "max_over_channels",
    "mirror_lobe_pdf",
    "normalize_direction",
    "power_cosine_local",
    "power_cosine_pdf",
    "reflect_about_half",
    "sample_cosine",
    "sample_diffuse_or_half",
    "sample_diffuse_or_mirror",
    "sample_lobe_about_mirror",
    "sample_mirror_lobe",
    "sample_power_cosine_about",
    "sample_weight",
    "sanitize",
    "sanitize_direction",
    "sanitize_pair",
    "sanitize_wo",
    "scaled_where",
    "upper",
]

#: Largest Phong exponent the models declare (and the registry entries admit): up to 1e6 the
#: power underflows to 0 in float32, never to NaN (:func:`brdf_fit.core.numerics.safe_pow`).
EXPONENT_MAX = 1e6


# ----------------------------------------------------------------------------- samples


def sample_weight(model: AbstractBRDF, wi, wo, pdf):
    """``f cos / pdf`` with the failed-sample convention (0 where ``pdf = 0``)."""
    ok = pdf > 0
    f = model.eval_cos(wi, wo)
    ch = model.channels()
    okc = expand_channels(ok, ch)
    pdfc = expand_channels(jnp.where(ok, pdf, 1.0), ch)
    return jnp.where(okc, f / pdfc, 0.0)


def finish_sample(model: AbstractBRDF, wi, wo, ok=None) -> BRDFSample:
    """The :class:`~brdf_fit.models.BRDFSample` of a drawn ``wi``: ``pdf = model.pdf(wi, wo)``
    (0 where ``ok`` is False: a failed sample) and :func:`sample_weight`."""
    pdf = model.pdf(wi, wo) if ok is None else jnp.where(ok, model.pdf(wi, wo), 0.0)
    return BRDFSample(wi=wi, pdf=pdf, weight=sample_weight(model, wi, wo, pdf))


def scaled_where(ok, scale, value, channels):
    """``scale * value`` where ``ok``, 0 elsewhere: ``ok`` and ``value`` per direction, ``scale``
    (a model parameter) may carry the channel axis of ``channels``."""
    return jnp.where(expand_channels(ok, channels), scale * expand_channels(value, channels), 0.0)


def check_exponent(exponent, owner: str):
    """A lobe exponent: a scalar >= 0 (validated for concrete values)."""
    check_param("exponent", exponent, lo=0.0, owner=owner)
    check_scalar("exponent", exponent, owner)


def max_over_channels(x):
    """The largest value over the channel axis (a scalar's own value)."""
    return jnp.max(jnp.asarray(x))


# ----------------------------------------------------------------------------- sanitising


def upper(wi, wo):
    """Both directions strictly above the horizon."""
    return (wi[..., 2] > 0) & (wo[..., 2] > 0)


def sanitize(valid, x, y, z):
    """Components ``(x, y, z)`` where ``valid``, the normal ``(0, 0, 1)`` elsewhere."""
    return jnp.where(valid, x, 0.0), jnp.where(valid, y, 0.0), jnp.where(valid, z, 1.0)


def sanitize_direction(w, ok):
    """``w`` (..., 3) where ``ok``, the normal elsewhere."""
    n = jnp.zeros_like(w).at[..., 2].set(1.0)
    return jnp.where(ok[..., None], w, n)


def sanitize_wo(wo):
    """``wo`` where it is above the horizon, the normal elsewhere (and the flag)."""
    ok = wo[..., 2] > 0
    return sanitize_direction(wo, ok), ok


def sanitize_pair(wi, wo):
    """``(valid, (ix, iy, iz), (ox, oy, oz))``: ``valid`` where both directions are above the
    horizon, the components of both sanitised to the normal elsewhere."""
    ix, iy, iz = split(wi)
    ox, oy, oz = split(wo)
    valid = (iz > 0) & (oz > 0)
    return valid, sanitize(valid, ix, iy, iz), sanitize(valid, ox, oy, oz)


# ----------------------------------------------------------------------------- cosine lobe


def cosine_pdf(wi, wo):
    """``cos(theta_i)/pi`` on the upper hemisphere, 0 elsewhere: the density of
    :func:`sample_cosine` for a model that samples nothing else."""
    return jnp.where(upper(wi, wo), wi[..., 2] * INV_PI, 0.0)


def sample_cosine(model: AbstractBRDF, wo, u) -> BRDFSample:
    """A cosine-weighted hemisphere sample with ``model.pdf`` (e.g. :func:`cosine_pdf`): the
    sampler of models without a lobe-adapted one (``weight = pi f``)."""
    return finish_sample(model, sample_cosine_hemisphere(u), wo)


# ----------------------------------------------------------------------------- half vector


def half_vector(wi, wo):
    """``((ix, iy, iz), (ox, oy, oz), (hx, hy, hz), hok)``: the components of both directions
    and of ``h = normalize(wi + wo)``, with ``hok`` False where ``wi + wo`` vanishes
    (``wi = -wo``)."""
    ix, iy, iz = split(wi)
    ox, oy, oz = split(wo)
    hx, hy, hz, hok = safe_normalize3(ix + ox, iy + oy, iz + oz)
    return (ix, iy, iz), (ox, oy, oz), (hx, hy, hz), hok


class HalfGeometry(NamedTuple):
    """Sanitised half-vector geometry (:func:`half_geometry`)."""

    valid: jax.Array
    i: tuple
    o: tuple
    h: tuple
    #: ``wo.h`` (1 on invalid lanes)
    d: jax.Array


def half_geometry(wi, wo) -> HalfGeometry:
    """The half-vector geometry of a microfacet-type lobe: ``valid`` where both directions are
    above the horizon and ``h`` exists; on the other lanes ``wi``, ``wo`` and ``h`` are replaced
    by the normal before any formula sees them (so ``d = wo.h = 1`` there).

    ``d`` is clamped at 0: for unit directions ``wo.h = |wi + wo|/2 >= 0``, but directions unit
    only to rounding (length 1 +- 1e-6) at a grazing, near-mirror pair make ``1 + wi.wo``, hence
    ``wo.h``, negative (-5e-3 at cos = 1e-4), which gave negative V-cavity values and
    half-vector pdfs (issue 16). Consumers read ``d = 0`` as the limit ``wo.h -> 0+``."""
    (ix, iy, iz), (ox, oy, oz), (hx, hy, hz), hok = half_vector(wi, wo)
    valid = (iz > 0) & (oz > 0) & hok
    i = sanitize(valid, ix, iy, iz)
    o = sanitize(valid, ox, oy, oz)
    h = sanitize(valid, hx, hy, hz)
    d = jnp.maximum(o[0] * h[0] + o[1] * h[1] + o[2] * h[2], 0.0)
    return HalfGeometry(valid, i, o, h, d)


def half_angles(wi, wo):
    """``(ok, hx, hy, hz, d, cl, cv)`` of a half-vector Phong-type lobe: the components of ``h``,
    ``d = wi.h`` and the cosines ``cl = n.wi``, ``cv = n.wo``. ``ok`` where both directions are
    above the horizon, ``h`` exists and ``d, n.h > 0``; elsewhere every value is that of
    ``wi = wo = n`` (``h = n``, ``d = cl = cv = 1``), so no formula sees a singular input."""
    (ix, iy, iz), (_, _, oz), (hx, hy, hz), hok = half_vector(wi, wo)
    d = ix * hx + iy * hy + iz * hz
    ok = (iz > 0) & (oz > 0) & hok & (d > 0) & (hz > 0)
    return (ok, jnp.where(ok, hx, 0.0), jnp.where(ok, hy, 0.0), jnp.where(ok, hz, 1.0),
            jnp.where(ok, d, 1.0), jnp.where(ok, iz, 1.0), jnp.where(ok, oz, 1.0))


def reflect_about_half(wo, h):
    """``(2 (wo.h) h - wo, wo.h)`` with ``wo.h`` of shape ``(..., 1)``: the reflection of
    ``wo`` about a sampled half vector ``h`` (both ``(..., 3)``)."""
    d = jnp.sum(wo * h, axis=-1, keepdims=True)
    return 2.0 * d * h - wo, d


def normalize_direction(w):
    """``w / |w|`` (..., 3) (guarded: a vanishing ``w`` stays 0)."""
    x, y, z, _ = safe_normalize3(w[..., 0], w[..., 1], w[..., 2])
    return join(x, y, z)


# ----------------------------------------------------------------------------- power-cosine lobe


def cos_alpha_r(wi, wo):
    """``max(0, r_o.wi) = max(0, 2 (n.wi)(n.wo) - wi.wo)`` (symmetric in wi and wo)."""
    ix, iy, iz = split(wi)
    ox, oy, oz = split(wo)
    return jnp.maximum(2.0 * iz * oz - (ix * ox + iy * oy + iz * oz), 0.0)


def cos_alpha_r_pow(wi, wo, exponent):
    """``max(0, r_o.wi)^n`` with ``1 - cos(alpha_r) = |r_o - wi|^2/2 = ((ix + ox)^2 + (iy + oy)^2
    + (iz - oz)^2)/2`` (unit vectors): near the peak ``r_o.wi`` itself rounds to a multiple of
    eps, i.e. to an angle of ``sqrt(2 eps)`` (3.5e-4 rad in float32), and ``n`` = 1e6 turned that
    into a 5% error; the chord keeps the relative precision of ``1 - cos``. Then
    ``exp(n log1p(-d))``, 0 where ``cos <= 0``; ``d/dn`` finite (as
    :func:`brdf_fit.core.numerics.safe_pow`). Symmetric in wi and wo."""
    ix, iy, iz = split(wi)
    ox, oy, oz = split(wo)
    sx, sy, dz = ix + ox, iy + oy, iz - oz
    d = 0.5 * (sx * sx + sy * sy + dz * dz)
    ok = d < 1.0
    ds = jnp.where(ok, d, 0.0)
    return jnp.where(ok, jnp.exp(exponent * jnp.log1p(-ds)), 0.0)


def power_cosine_local(u, exponent):
    """Power-cosine lobe about +z: ``cos = u0^(1/(n+1))`` (Lafortune & Willems 1994, section 3),
    with ``1 - cos`` from ``expm1`` so narrow lobes (n = 1e4..1e6) keep their width in float32."""
    u0 = u[..., 0]
    ok = u0 > 0
    lu = jnp.log(jnp.where(ok, u0, 1.0)) / (exponent + 1.0)
    one_minus = jnp.where(ok, -jnp.expm1(lu), 1.0)  # 1 - cos; cos = 0 when u0 = 0
    z = 1.0 - one_minus
    r = safe_sqrt(one_minus * (2.0 - one_minus))
    phi = 2.0 * math.pi * u[..., 1]
    return join(r * jnp.cos(phi), r * jnp.sin(phi), z)


def sample_power_cosine_about(axis, u, exponent):
    """Power-cosine sample about the unit ``axis`` (..., 3) (:func:`power_cosine_local` turned
    into the frame of Duff et al. 2017 about the axis); ``u0 = 0`` gives a direction orthogonal
    to the axis."""
    t, b, nn = frame_from_normal(axis)
    return normalize_direction(to_world(power_cosine_local(u, exponent), t, b, nn))


def sample_lobe_about_mirror(wo, u, exponent):
    """Power-cosine sample about ``r_o = mirror(wo)`` (``wo`` assumed above the horizon)."""
    return sample_power_cosine_about(mirror(wo), u, exponent)


def power_cosine_pdf(wi, wo, exponent):
    """``(n+1)/(2 pi) max(0, r_o.wi)^n`` (the power-cosine density, whole-sphere normalised)."""
    return (exponent + 1.0) * INV_TWO_PI * cos_alpha_r_pow(wi, wo, exponent)


def mirror_lobe_pdf(wi, wo, exponent):
    """:func:`power_cosine_pdf` on the upper hemisphere, 0 elsewhere: the density of
    :func:`sample_mirror_lobe`."""
    return jnp.where(upper(wi, wo), power_cosine_pdf(wi, wo, exponent), 0.0)


def sample_mirror_lobe(model: AbstractBRDF, wo, u, exponent) -> BRDFSample:
    """A power-cosine sample about ``r_o`` with ``model.pdf`` (e.g. :func:`mirror_lobe_pdf`);
    fails (pdf 0, weight 0) for ``wo`` at or below the horizon."""
    wos, ok = sanitize_wo(wo)
    return finish_sample(model, sample_lobe_about_mirror(wos, u, exponent), wo, ok)


# ----------------------------------------------------------------------------- lobe choice


def sample_diffuse_or_half(model: AbstractBRDF, wo, uc, u, h, p_d=None) -> BRDFSample:
    """One-sample choice between the cosine hemisphere (``uc < p_d``) and ``wo`` reflected about
    the sampled half vector ``h`` (..., 3) (``p_d=None``: the half-vector lobe alone); the
    returned pdf is ``model.pdf``, 0 for ``wo`` at or below the horizon."""
    wos, ok = sanitize_wo(wo)
    ws = normalize_direction(reflect_about_half(wos, h)[0])
    if p_d is not None:
        ws = jnp.where((uc < p_d)[..., None], sample_cosine_hemisphere(u), ws)
    return finish_sample(model, ws, wo, ok)


def lobe_probability(hint_d, hint_s):
    """``p_d = hint_d / (hint_d + hint_s)`` (1 when both vanish: then nothing reflects)."""
    tot = hint_d + hint_s
    return jnp.where(tot > 0, safe_div(hint_d, tot), 1.0)


def diffuse_mirror_pdf(wi, wo, exponent, p_d):
    """``p_d cos(theta_i)/pi + (1 - p_d) (n+1)/(2 pi) cos^n(alpha_r)`` on the upper hemisphere:
    the density of :func:`sample_diffuse_or_mirror`."""
    diff = jnp.maximum(wi[..., 2], 0.0) * INV_PI
    spec = power_cosine_pdf(wi, wo, exponent)
    return jnp.where(upper(wi, wo), p_d * diff + (1.0 - p_d) * spec, 0.0)


def sample_diffuse_or_mirror(model: AbstractBRDF, wo, uc, u, exponent, p_d) -> BRDFSample:
    """Classic one-sample lobe choice: ``uc < p_d``: cosine hemisphere, else the power-cosine lobe
    about ``r_o``; the returned pdf is ``model.pdf`` (the mixture density, e.g.
    :func:`diffuse_mirror_pdf`)."""
    wos, ok = sanitize_wo(wo)
    wd = sample_cosine_hemisphere(u)
    ws = sample_lobe_about_mirror(wos, u, exponent)
    wi = jnp.where((uc < p_d)[..., None], wd, ws)
    return finish_sample(model, wi, wo, ok)
