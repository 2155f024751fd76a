"""The mirror-lobe quadrature rule: nodes over ``wi`` for power-cosine lobes ``(r.wi)^n`` about
the mirror direction ``r`` of ``wo`` (the Phong family), in ``u = r.wi`` with the exact arc of
the upper hemisphere at each ``u``, panels graded toward the peak, the horizon tangencies and
their square-root tails (measured errors: docs/quadrature.md and
benchmarks/bench_phong_normaliser.py). A :class:`~brdf_fit.core.quadrature.Rule` like the others of
:mod:`brdf_fit.core.quadrature`; :func:`brdf_fit.verify.albedo.directional_albedo` takes it for a
lobe that declares ``("mirror", n)``.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np

from brdf_fit.core.quadrature import Rule, _float_dtype, _gl01, _is_tracer, gauss_legendre_interval

__all__ = ["MIRROR_N_PHI", "MIRROR_N_U", "mirror_lobe_rule"]

#: Gauss-Legendre nodes per panel in ``u = r.wi`` and per ring in azimuth of
#: :func:`mirror_lobe_rule` (32 panel slots, 16384 nodes; panels of zero width carry no weight:
#: measured 2048 weighted nodes at normal view to 15360 at cos(theta_o) = 1e-4). Measured on
#: the exactly normalised Phong lobe, n in [0, 1e6], cos(theta_o) in [1e-4, 1]: relative error
#: <= 4e-9 (12 nodes per panel: 1.2e-8; 10 x 24: 3e-7 with finer lobe breaks).
MIRROR_N_U = 16
MIRROR_N_PHI = 32
#: Breaks of the mirror-lobe rule toward the peak, in units of the lobe scale ``1/(n+1)`` of
#: ``u^n ~ exp(-n (1 - u))``: beyond ``1 - u = 60/(n+1)`` the lobe is below ``e^-60``; the
#: ratio ~3 between breaks keeps each panel within a few e-folds of the integrand.
_MIRROR_LOBE_BREAKS = (60.0, 20.0, 7.0, 2.5, 0.8, 0.25, 0.06)


#: Breaks of the mirror-lobe rule near the horizon tangencies ``u = +-s``, where
#: ``sqrt(1 - u^2) = q cos(theta_o)``: the arc of the upper hemisphere opens over this range.
_MIRROR_TANGENCY_BREAKS = (1.5, 3.0)
#: Decade breaks in ``v = 1 - |u|``: the arc length approaches its far value like
#: ``sqrt(v_s / v)`` (``v_s = 1 - s ~ c^2/2``), a tail over ``log10(1/v_s)`` decades that each
#: panel must see only a decade of; 1e-9 covers grazing views down to cos(theta_o) ~ 1e-4.
_MIRROR_DECADE_BREAKS = tuple(10.0 ** -k for k in range(1, 10))


def _cubic_map(n: int):
    """Gauss-Legendre on [0, 1] pushed through ``t -> 3t^2 - 2t^3`` (zero derivative at both
    ends): a panel whose integrand has a square-root kink at an end becomes smooth in ``t``."""
    t, w = _gl01(n)
    return 3.0 * t * t - 2.0 * t**3, w * 6.0 * t * (1.0 - t)


def _mirror_nodes(xp, wo, exponent, n_u: int, n_phi: int):
    """Nodes of :func:`mirror_lobe_rule` with the array module ``xp`` (numpy or jax.numpy).

    The panels are laid out in ``v = 1 - |u|`` (distance to the nearer pole of ``r``), computed
    from accurately formed breaks, so that ``1 - u^2 = v (2 - v)`` keeps its relative precision
    where it is ~ cos^2(theta_o) (grazing views: the tangencies sit at ``1 - |u| ~ c^2/2``)."""
    c = xp.clip(wo[..., 2], 0.0, 1.0)
    s = xp.sqrt((1.0 - c) * (1.0 + c))
    n = xp.maximum(exponent, 0.0) * xp.ones_like(c)
    one = xp.ones_like(c)
    # v of the tangency u = +-s, and of the boundary-layer breaks sqrt(1 - u^2) = q c, formed
    # without cancellation: 1 - sqrt(1 - x) = x / (1 + sqrt(1 - x))
    v_s = c * c / (1.0 + s)
    tang = []
    for q in _MIRROR_TANGENCY_BREAKS:
        x = xp.clip((q * c) ** 2, 0.0, 1.0)
        tang.append(x / (1.0 + xp.sqrt(1.0 - x)))
    lobe = [xp.clip(k / (n + 1.0), 0.0, 1.0) for k in _MIRROR_LOBE_BREAKS]
    # the arc length decays like sqrt(v_s / v) away from a tangency, all the way to v = 1:
    # geometric (decade) breaks in v, clipped to [v_s, 1] so that none is wasted below v_s
    decades = [xp.clip(d * one, v_s, 1.0) for d in _MIRROR_DECADE_BREAKS]
    # upper half u in [0, 1]: v = 1 - u in [0, 1]; lower half u in [-s, 0]: v = 1 + u in [v_s, 1]
    up = xp.sort(xp.stack([0.0 * one, v_s, one, *lobe, *tang, *decades], axis=-1), axis=-1)
    lw = xp.sort(xp.clip(xp.stack([v_s, one, *tang, *decades], axis=-1), v_s[..., None], 1.0),
                 axis=-1)
    t, wt = _cubic_map(n_u)

    def panels(br):
        lo, hi = br[..., :-1], br[..., 1:]
        v = lo[..., None] + (hi - lo)[..., None] * t
        wv = (hi - lo)[..., None] * wt
        return v.reshape(v.shape[:-2] + (-1,)), wv.reshape(wv.shape[:-2] + (-1,))

    v_up, w_up = panels(up)
    v_lw, w_lw = panels(lw)
    u = xp.concatenate([1.0 - v_up, v_lw - 1.0], axis=-1)
    v = xp.concatenate([v_up, v_lw], axis=-1)
    wu = xp.concatenate([w_up, w_lw], axis=-1)
    su = xp.sqrt(xp.clip(v * (2.0 - v), 0.0, 1.0))
    # above-horizon arc |p| < p0 where z.wi = c u + s su cos p > 0, i.e. cos p0 = -c u/(s su);
    # as an angle from its sine and cosine (arccos loses sqrt(eps) near the tangencies):
    # (s su)^2 - (c u)^2 = s^2 - u^2 = (s - |u|)(s + |u|), and s - |u| = v - v_s accurately
    full = xp.concatenate([v_up <= v_s[..., None], xp.zeros_like(v_lw, dtype=bool)], axis=-1)
    full = full | (s[..., None] <= 0.0)
    gap = xp.clip(v - v_s[..., None], 0.0, None) * (s[..., None] + xp.abs(u))
    p0 = xp.where(full, math.pi, xp.arctan2(xp.sqrt(gap), -c[..., None] * u))
    xg, wg = gauss_legendre_interval(n_phi, -1.0, 1.0)
    p = p0[..., None] * xg  # (..., U, n_phi)
    w = (wu * p0)[..., None] * wg
    # frame of r = mirror(wo): t1 in the plane of r and the normal, toward the normal
    r = xp.stack([-wo[..., 0], -wo[..., 1], c], axis=-1)
    ez = xp.zeros_like(r) + xp.asarray([0.0, 0.0, 1.0])
    has_s = s > 1e-300
    t1 = xp.where(has_s[..., None], (ez - c[..., None] * r) / xp.where(has_s, s, 1.0)[..., None],
                  xp.zeros_like(r) + xp.asarray([1.0, 0.0, 0.0]))
    t2 = xp.cross(r, t1)
    cp, sp = xp.cos(p)[..., None], xp.sin(p)[..., None]
    ex = (su[..., None, None] * (cp * t1[..., None, None, :] + sp * t2[..., None, None, :]))
    dirs = u[..., None, None] * r[..., None, None, :] + ex
    dirs = dirs.reshape(dirs.shape[:-3] + (-1, 3))
    w = w.reshape(w.shape[:-2] + (-1,))
    # nodes that rounding puts on or below the horizon carry no weight
    w = xp.where(dirs[..., 2] > 0, w, 0.0)
    w = xp.where((wo[..., 2] > 0)[..., None], w, 0.0)
    return dirs, w


def mirror_lobe_rule(
    wo, exponent, n_u: int = MIRROR_N_U, n_phi: int = MIRROR_N_PHI, dtype=None
) -> Rule:
    """Rule over ``wi`` in the upper hemisphere for power-cosine lobes ``max(0, r.wi)^n`` about
    the mirror direction ``r = (-wo_x, -wo_y, wo_z)`` (Phong and its variants), exact in its
    domain: it covers the whole upper hemisphere, so diffuse terms are integrated too.

    Coordinates: ``u = r.wi`` and the azimuth ``p`` about ``r`` from the plane of ``r`` and the
    normal; ``dwi = du dp`` and ``z.wi = c u + s sqrt(1 - u^2) cos p`` (``c = wo_z``,
    ``s = sqrt(1 - c^2)``). For each ``u`` in ``[-s, 1]`` the part above the horizon is the exact
    arc ``|p| < arccos(-c u / (s sqrt(1 - u^2)))`` (all of it for ``u >= s``), integrated by
    Gauss-Legendre in ``p``. In ``u``, Gauss-Legendre panels with breaks at the horizon
    tangencies ``u = -s`` and ``u = s`` (where the arc length has a square-root kink), at ``u = 0``
    (the edge of ``max(0, u)^n``) and graded toward the peak at ``1 - k/(n+1)``, ``k`` in
    :data:`_MIRROR_LOBE_BREAKS`; every panel is mapped by ``t -> 3t^2 - 2t^3`` so that the kinks
    at its ends become smooth. Convergence and accuracy: tests/test_quadrature_mirror.py and
    docs/quadrature.md (relative error <= 4e-9 on the exactly normalised Phong lobe for n in
    [0, 1e6] and cos(theta_o) in [1e-4, 1] at the defaults).

    ``wo`` of shape ``(3,)`` or ``(..., 3)`` (batched rule), ``exponent`` a scalar or
    broadcasting with ``wo[..., 0]``. ``n_u`` nodes per panel (32 panels, some empty), ``n_phi``
    per ring. Tracers (under ``jit``/``grad``) build the rule in ``jax.numpy`` under
    ``stop_gradient``.
    """
    if n_u < 1 or n_phi < 1:
        raise ValueError(f"need n_u, n_phi >= 1, got {n_u}, {n_phi}")
    dt = _float_dtype(dtype)
    if _is_tracer(wo, exponent):
        wdt = jnp.result_type(float)
        wo_, n_ = (jax.lax.stop_gradient(jnp.asarray(a).astype(wdt)) for a in (wo, exponent))
        dirs, w = _mirror_nodes(jnp, wo_, n_, n_u, n_phi)
        return Rule(directions=dirs.astype(dt), weights=w.astype(dt))
    wo_ = np.asarray(wo, dtype=np.float64)
    if wo_.shape[-1:] != (3,):
        raise ValueError(f"wo must have shape (..., 3), got {wo_.shape}")
    n_ = np.asarray(exponent, dtype=np.float64)
    if np.any(n_ < 0) or not np.all(np.isfinite(n_)):
        raise ValueError(f"exponent must be finite and >= 0, got {exponent}")
    with np.errstate(divide="ignore", invalid="ignore"):
        dirs, w = _mirror_nodes(np, wo_, n_, n_u, n_phi)
    return Rule(directions=jnp.asarray(dirs, dtype=dt), weights=jnp.asarray(w, dtype=dt))
