"""Poulin-Fournier parallel-cylinder BRDF (brdf_fit.models.poulin_fournier).

Independent reference: a NumPy implementation in spherical angles that finds the lit-and-seen arc
by explicit 2-D ray casting against the neighbouring circles (grid scan, then bisection of each
boundary), builds the facet mirror vector explicitly, and integrates with scipy's adaptive
``quad``; it shares no code or formula for the visibility limits with the model.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from _helpers import assert_gradient_matches_fd, vec
from _helpers import eval_jit as _eval
from scipy import integrate

from brdf_fit.core.validate import ParameterError
from brdf_fit.models._base import astype
from brdf_fit.models.poulin_fournier import PoulinFournier, registry_entries, visible_interval

# ----------------------------------------------------------------------------- NumPy reference


def _ray_hits_neighbour(a, th, d, n_neigh=4):
    """Does the ray from the arc point at angle(s) ``a`` (cylinder centred at 0, radius 1) in the
    2-D direction ``(sin th, cos th)`` hit a neighbouring circle centred at ``(k d, 0)``?"""
    a = np.atleast_1d(a)
    px, pz = np.sin(a), np.cos(a)
    ux, uz = math.sin(th), math.cos(th)
    hit = np.zeros(a.shape, bool)
    for k in range(-n_neigh, n_neigh + 1):
        if k == 0:
            continue
        qx, qz = px - k * d, pz
        b = qx * ux + qz * uz
        c = qx * qx + qz * qz - 1.0
        disc = b * b - c
        inside = c < -1e-13
        t_far = -b + np.sqrt(np.maximum(disc, 0.0))
        hit |= inside | ((disc > 0) & (t_far > 1e-13) & (-b - np.sqrt(np.maximum(disc, 0.0)) > 0))
    return hit


def _seen(a, th, d):
    return (np.cos(np.atleast_1d(a) - th) > 0) & ~_ray_hits_neighbour(a, th, d)


def _ray_cast_interval(th, d, n_grid=513, n_bisect=60):
    """The visible arc for projected angle ``th``, by ray casting: scan, then bisect the ends."""
    half = math.asin(d / 2)
    grid = np.linspace(-half, half, n_grid + 2)[1:-1]  # the meeting points are on two circles
    vis = _seen(grid, th, d)
    idx = np.flatnonzero(vis)
    if idx.size == 0:
        return 0.0, 0.0
    assert np.all(np.diff(idx) == 1), "visible set is not one interval"

    def bisect(inside, outside):
        for _ in range(n_bisect):
            m = 0.5 * (inside + outside)
            if _seen(m, th, d)[0]:
                inside = m
            else:
                outside = m
        return 0.5 * (inside + outside)

    lo = bisect(grid[idx[0]], -half if idx[0] == 0 else grid[idx[0] - 1])
    hi = bisect(grid[idx[-1]], half if idx[-1] == n_grid - 1 else grid[idx[-1] + 1])
    return lo, hi


def _direction(theta, phi):
    return np.array([math.sin(theta) * math.cos(phi), math.sin(theta) * math.sin(phi),
                     math.cos(theta)])


def _reference(theta_i, phi_i, theta_o, phi_o, kd, ks, e, d):
    """f_r from spherical angles, ray-cast limits and adaptive quadrature."""
    wi, wo = _direction(theta_i, phi_i), _direction(theta_o, phi_o)
    th_i = math.atan(math.tan(theta_i) * math.sin(phi_i))  # projection onto the (b, n) plane
    th_o = math.atan(math.tan(theta_o) * math.sin(phi_o))
    lo_i, hi_i = _ray_cast_interval(th_i, d)
    lo_o, hi_o = _ray_cast_interval(th_o, d)
    lo, hi = max(lo_i, lo_o), min(hi_i, hi_o)
    if hi <= lo:
        return np.zeros_like(np.asarray(kd, float))

    def facet(a, part):
        m = np.array([0.0, math.sin(a), math.cos(a)])
        r = 2.0 * (m @ wo) * m - wo  # facet mirror of wo
        proj = max(m @ wi, 0.0) * max(m @ wo, 0.0)
        if part == "d":
            return proj
        return (e + 2) / (2 * math.pi) * max(r @ wi, 0.0) ** e * proj

    peak = min(max(0.5 * (th_i + th_o), lo), hi)
    kw = dict(points=[peak], epsabs=0.0, epsrel=1e-13, limit=200)
    i_d = integrate.quad(facet, lo, hi, args=("d",), **kw)[0]
    i_s = integrate.quad(facet, lo, hi, args=("s",), **kw)[0]
    return (np.asarray(kd) / math.pi * i_d + np.asarray(ks) * i_s) / (d * wi[2] * wo[2])


def _random_angles(n, seed):
    rng = np.random.default_rng(seed)
    th = np.arccos(rng.uniform(0.02, 1.0, size=(n, 2)))
    ph = rng.uniform(0, 2 * math.pi, size=(n, 2))
    return th, ph


def _to_dirs(th, ph):
    return jnp.asarray(vec(th, ph))


# ----------------------------------------------------------------------------- tests

def test_visibility_limits_match_ray_casting():
    rng = np.random.default_rng(0)
    cases = [(rng.uniform(0.05, 2.0), rng.uniform(-1.55, 1.55)) for _ in range(120)]
    d, th = (np.array(c) for c in zip(*cases, strict=True))
    # the closed form, batched and jitted (120 eager scalar calls cost ~10 s of dispatch)
    lo, hi = (np.asarray(v) for v in jax.jit(visible_interval)(jnp.asarray(th), jnp.asarray(d)))
    worst = 0.0
    for k in range(len(cases)):
        ref = _ray_cast_interval(th[k], d[k])
        worst = max(worst, abs(lo[k] - ref[0]), abs(hi[k] - ref[1]))
    assert worst < 1e-9, worst  # measured 7.8e-16


@pytest.mark.parametrize("kd,ks,e,d", [((0.3, 0.25, 0.2), (0.5, 0.5, 0.5), 10.0, 1.5),
                                       (0.1, 0.8, 60.0, 2.0), (0.6, 0.3, 2.5, 0.4)])
def test_eval_matches_independent_reference(kd, ks, e, d):
    th, ph = _random_angles(80, seed=int(10 * e))
    model = PoulinFournier(kd=jnp.asarray(kd), ks=jnp.asarray(ks), exponent=jnp.asarray(e),
                           spacing=jnp.asarray(d))
    got = np.asarray(_eval(model, _to_dirs(th[:, 0], ph[:, 0]), _to_dirs(th[:, 1], ph[:, 1])))
    ref = np.array([_reference(th[k, 0], ph[k, 0], th[k, 1], ph[k, 1], kd, ks, e, d)
                    for k in range(len(th))]).reshape(got.shape)
    rel = np.max(np.abs(got - ref) / np.maximum(np.abs(ref), 1e-300))
    assert rel < 1e-10, rel  # measured 4e-15, 1.1e-14, 1.1e-12 (150 pairs)


def test_quadrature_error_against_fine_rule():
    th, ph = _random_angles(500, seed=5)
    wi, wo = _to_dirs(th[:, 0], ph[:, 0]), _to_dirs(th[:, 1], ph[:, 1])
    for e, d in ((10.0, 1.5), (100.0, 2.0), (100.0, 1.0)):
        f = _eval(PoulinFournier(exponent=e, spacing=d), wi, wo)
        ref = _eval(PoulinFournier(exponent=e, spacing=d, n_nodes=1024), wi, wo)
        rel = float(jnp.max(jnp.abs(f - ref) / jnp.maximum(ref, 1e-300)))
        assert rel < 1e-11, (e, d, rel)  # measured 4.2e-15, 2.2e-14, 3.0e-14


def test_flat_limit_is_the_facet_brdf():
    """spacing -> 0: the visible arc shrinks to the top of the cylinder, m -> n."""
    th, ph = _random_angles(200, seed=7)
    wi, wo = _to_dirs(th[:, 0], ph[:, 0]), _to_dirs(th[:, 1], ph[:, 1])
    kd, ks, e = 0.3, 0.6, 20.0
    f = _eval(PoulinFournier(kd=kd, ks=ks, exponent=e, spacing=1e-4), wi, wo)
    r = 2 * wi[:, 2] * wo[:, 2] - jnp.sum(wi * wo, -1)
    phong = kd / math.pi + ks * (e + 2) / (2 * math.pi) * jnp.maximum(r, 0.0) ** e
    rel = float(jnp.max(jnp.abs(f - phong) / phong))
    assert rel < 1e-5, rel  # measured 8.1e-8 (O(spacing^2))


def test_reciprocal_and_anisotropic():
    th, ph = _random_angles(300, seed=9)
    wi, wo = _to_dirs(th[:, 0], ph[:, 0]), _to_dirs(th[:, 1], ph[:, 1])
    model = registry_entries()[0].build()
    f, g = _eval(model, wi, wo), _eval(model, wo, wi)
    assert float(jnp.max(jnp.abs(f - g) / f)) < 1e-13
    rot = jnp.asarray([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    fr = _eval(model, wi @ rot.T, wo @ rot.T)
    assert float(jnp.max(jnp.abs(fr - f) / f)) > 0.1  # rotating about n changes f
    assert type(model).anisotropic and "anisotropic" in registry_entries()[0].tags


_PAIRS = _to_dirs(np.array([[0.3, 0.9], [1.2, 0.5], [0.7, 0.75]]).T,
                  np.array([[0.2, 3.0], [1.4, -1.0], [2.0, 5.0]]).T)


@jax.jit
def _loss(p):
    model = PoulinFournier(kd=p[0], ks=p[1], exponent=p[2], spacing=p[3])
    return jnp.sum(model.eval(_PAIRS[0], _PAIRS[1]))


def test_gradients_match_finite_differences():
    p0 = jnp.asarray([0.3, 0.5, 12.0, 1.3])
    g = np.asarray(jax.grad(_loss)(p0))
    # |g - fd| <= 1e-6 max(|fd|, 1e-3)
    assert_gradient_matches_fd(_loss, g, p0, rel=1e-6, abs=1e-9, h=1e-5, relative_step=True)


def test_hard_directions_finite_gradients():
    eps = 1e-7
    dirs = jnp.asarray([[1.0, 0.0, eps], [0.0, 1.0, eps], [0.0, -1.0, eps], [0.6, 0.8, eps],
                        [0.0, 0.0, 1.0], [0.3, 0.4, 0.866], [1.0, 0.0, 0.0]])
    dirs = dirs / jnp.linalg.norm(dirs, axis=-1, keepdims=True)
    wi = jnp.repeat(dirs, len(dirs), 0)
    wo = jnp.tile(dirs, (len(dirs), 1))
    wo = jnp.concatenate([wo, wi * jnp.asarray([-1.0, -1.0, 1.0])])  # add l = -v reflected
    wi = jnp.concatenate([wi, wi])

    def loss(p, wi, wo):
        return jnp.sum(PoulinFournier(kd=p[0], ks=p[1], exponent=p[2], spacing=p[3]).eval(wi, wo))

    value_and_grads = jax.jit(jax.value_and_grad(loss, argnums=(0, 1, 2)))
    for p in ([0.3, 0.5, 10.0, 1.5], [0.0, 1.0, 0.0, 2.0], [1.0, 0.0, 100.0, 0.05]):
        val, grads = value_and_grads(jnp.asarray(p), wi, wo)
        assert np.isfinite(float(val))
        assert all(np.all(np.isfinite(np.asarray(x))) for x in grads)


def test_float32_and_vmap():
    model = astype(registry_entries()[0].build(), jnp.float32)
    th, ph = _random_angles(16, seed=3)
    wi = _to_dirs(th[:, 0], ph[:, 0]).astype(jnp.float32)
    wo = _to_dirs(th[:, 1], ph[:, 1]).astype(jnp.float32)
    f32 = _eval(model, wi, wo)
    assert f32.dtype == jnp.float32 and f32.shape == (16, 3)
    f64 = _eval(registry_entries()[0].build(), wi.astype(jnp.float64), wo.astype(jnp.float64))
    assert float(jnp.max(jnp.abs(f32.astype(jnp.float64) - f64) / f64)) < 1e-4
    spacing = jnp.asarray([0.5, 1.0, 2.0])
    out = jax.jit(jax.vmap(lambda s: PoulinFournier(spacing=s).eval(
        wi[0].astype(jnp.float64), wo[0].astype(jnp.float64))))(spacing)
    assert out.shape == (3,)


@pytest.mark.parametrize("kwargs,name", [({"spacing": -1.0}, "spacing"),
                                         ({"spacing": 0.0}, "spacing"),
                                         ({"spacing": 2.5}, "spacing"),
                                         ({"exponent": -1.0}, "exponent"),
                                         ({"kd": 1.5}, "kd"), ({"ks": -0.1}, "ks")])
def test_bad_parameters(kwargs, name):
    with pytest.raises(ParameterError, match=repr(name)):
        PoulinFournier(**kwargs)
    with pytest.raises(ParameterError, match=repr(name)):
        registry_entries()[0].build(**kwargs)
