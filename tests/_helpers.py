"""Helpers shared by the test files: jitted model wrappers, directions, finite differences and
the "finite at the extremes" harness.

The jitted wrappers are module-level objects, so every test module that uses them reuses one
compilation per model type and argument shapes (a fresh ``jax.jit(lambda ...)`` per test or per
file compiles again); eager calls (``model.eval(...)`` outside ``jit``) dispatch op by op and
were the largest cost of several tests.

Random data: every helper that draws takes a seeded ``numpy.random.Generator`` and draws in a
documented order, so a test's data is fixed by its seed (see also :func:`seed_of`).
"""

from __future__ import annotations

import contextlib
import math
import zlib
from collections.abc import Mapping

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest


@jax.jit
def eval_jit(model, wi, wo):
    return model.eval(wi, wo)


@jax.jit
def pdf_jit(model, wi, wo):
    return model.pdf(wi, wo)


@jax.jit
def eval_cos_jit(model, wi, wo):
    return model.eval_cos(wi, wo)


@jax.jit
def sample_jit(model, wo, uc, u):
    """``model.sample`` (a ``BRDFSample``), ``wo`` broadcast to the batch of ``u``."""
    return model.sample(jax.numpy.broadcast_to(wo, u.shape[:-1] + (3,)), uc, u)


@jax.jit
def draw_jit(model, wo, uc, u):
    """``(wi, pdf, weight)`` of :func:`sample_jit`."""
    s = model.sample(jax.numpy.broadcast_to(wo, u.shape[:-1] + (3,)), uc, u)
    return s.wi, s.pdf, s.weight


#: JAX's events for one program compiled by XLA, or loaded from the persistent compilation cache
#: instead (each reported once per program, with its duration)
COMPILE_EVENTS = ("/jax/core/compile/backend_compile_duration",
                  "/jax/compilation_cache/cache_retrieval_time_sec")


@contextlib.contextmanager
def counting_compiles():
    """Yield a list that holds one entry per program XLA compiles (or loads from the persistent
    cache) inside the block (``jax.monitoring``'s backend compile events: whatever compiled
    the program, it is counted)."""
    seen: list[float] = []
    active = [True]

    def listener(name, secs, **kw):
        if active[0] and name in COMPILE_EVENTS:
            seen.append(secs)

    jax.monitoring.register_event_duration_secs_listener(listener)
    try:
        yield seen
    finally:
        active[0] = False  # JAX has no public way to remove a listener: it goes quiet


def seed_of(*key) -> int:
    """A seed fixed by ``key`` (e.g. the test's name and parameters): CRC-32 of ``repr(key)``.

    The same in every process and on every platform, unlike Python's ``hash`` of a ``str``
    (salted per process unless ``PYTHONHASHSEED`` is set)."""
    return zlib.crc32(repr(key).encode())


def vec(theta, phi):
    """Unit vectors from polar angle ``theta`` and azimuth ``phi`` (NumPy, broadcasting)."""
    theta, phi = np.asarray(theta), np.asarray(phi)
    return np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)], -1)


def dir_from_cos(cos_theta, phi=0.0):
    """The unit vector ``(3,)`` (NumPy) with polar cosine ``cos_theta`` and azimuth ``phi``:
    ``(s cos(phi), s sin(phi), cos_theta)`` with ``s = sqrt(max(0, 1 - cos_theta^2))``."""
    s = math.sqrt(max(0.0, 1.0 - cos_theta * cos_theta))
    return np.array([s * math.cos(phi), s * math.sin(phi), cos_theta])


def random_dirs(rng, n, lo=1e-3):
    """``(n, 3)`` unit vectors (NumPy) with cosines uniform in ``[lo, 1]`` (drawn first) and
    azimuths uniform in ``[0, 2 pi)`` (drawn second); ``lo = -1``: uniform on the sphere."""
    mu = rng.uniform(lo, 1.0, n)
    phi = rng.uniform(0, 2 * np.pi, n)
    s = np.sqrt(1 - mu * mu)
    return np.stack([s * np.cos(phi), s * np.sin(phi), mu], -1)


def normal_dirs(rng, n, lo=1e-2):
    """``(n, 3)`` unit vectors (JAX) from normalised Gaussian draws folded into the upper
    hemisphere, the cosine raised to at least ``lo`` and the vector renormalised (the draws of
    the table-model tests, tests/models/test_kajiya.py and test_westin.py)."""
    v = rng.normal(size=(n, 3))
    v[:, 2] = np.abs(v[:, 2])
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    v[:, 2] = np.maximum(v[:, 2], lo)
    return jnp.asarray(v / np.linalg.norm(v, axis=1, keepdims=True))


def random_angles(rng, n, lo=1e-3, phi_range=(0.0, 2 * np.pi)):
    """``(theta, phi)``: cosines uniform in ``[lo, 1]``, azimuths uniform in ``phi_range``."""
    return np.arccos(rng.uniform(lo, 1.0, n)), rng.uniform(*phi_range, n)


# ----------------------------------------------------------------------------- finite differences


def fd_central(fn, x, h):
    """Second-order central difference ``(fn(x + h) - fn(x - h)) / (2 h)`` (``x``, ``h`` may be
    arrays: elementwise steps of an elementwise ``fn``)."""
    return (fn(x + h) - fn(x - h)) / (2 * h)


def fd_central4(fn, x, h):
    """Fourth-order central difference
    ``(8 (fn(x + h) - fn(x - h)) - (fn(x + 2h) - fn(x - 2h))) / (12 h)``."""
    return (8.0 * (fn(x + h) - fn(x - h)) - (fn(x + 2 * h) - fn(x - 2 * h))) / (12.0 * h)


def _select(value, name):
    """``value[name]`` for a mapping of per-parameter values, else ``value``."""
    return value[name] if isinstance(value, Mapping) else value


def central_differences(f, params, h=1e-6, relative_step=False, names=None):
    """Central differences of the scalar ``f(params)`` with respect to every entry of every leaf of
    ``params`` (a dict of NumPy-convertible arrays, nested dicts, or one array), as a dict
    ``{path: array}`` (``path``: the leaf's key path, e.g. ``('alpha',)`` or ``('ward', 'rho_s')``).

    ``f`` receives ``params`` with every leaf as a float64 NumPy array, one entry moved by
    ``+-step``; the step is ``h``, or ``h max(1, |x|)`` with ``relative_step``. ``names``: only the
    leaves under these top-level keys (default: all)."""
    flat, tree = jax.tree_util.tree_flatten_with_path(params)
    leaves = [np.asarray(v, float) for _, v in flat]
    out = {}
    for i, (path, _) in enumerate(flat):
        key = tuple(getattr(k, "key", getattr(k, "idx", k)) for k in path)
        if names is not None and (not key or key[0] not in names):
            continue
        v = leaves[i]
        fd = np.zeros(v.shape)
        for idx in np.ndindex(v.shape):
            step = h * max(1.0, abs(float(v[idx]))) if relative_step else h
            up, dn = v.copy(), v.copy()
            up[idx] += step
            dn[idx] -= step
            p_up = jax.tree_util.tree_unflatten(tree, leaves[:i] + [up] + leaves[i + 1:])
            p_dn = jax.tree_util.tree_unflatten(tree, leaves[:i] + [dn] + leaves[i + 1:])
            fd[idx] = (float(f(p_up)) - float(f(p_dn))) / (2 * step)
        out[key] = fd
    return out


#: step of the central differences through Fdr_int. Fdr_int is Mitsuba's 16,384-node
#: Gauss-Legendre sum of an integrand with a kink (total internal reflection: the Fresnel
#: factor reaches 1 with an infinite slope at the critical angle), so as alpha or eta moves,
#: nodes cross the kink: the sum is continuous but its slope changes at points ~1e-6 apart in
#: alpha (measured: central differences at h = 1e-5, 1e-6 are off by 0.1-1.5%, at h = 1e-7 by
#: 1e-5, at h = 1e-8 and 1e-9 by < 2e-7; rounding adds only ~1e-8 at h = 1e-8). The control
#: (tests/models/test_mitsuba_native.py): the same rows without total internal reflection
#: (eta > 1) agree at h = 1e-5. Used by every finite-difference test of a model that holds
#: these tables (brdf_fit.models.mitsuba.MitsubaPlasticDiffuse).
H_KINKED = 1e-8


def assert_gradient_matches_fd(f, grad, params, rel, abs, h=1e-6, relative_step=False,
                               names=None):
    """Every entry of the gradient ``grad`` (same structure as ``params``) equals the central
    difference of ``f`` (:func:`central_differences`) to ``pytest.approx(rel=rel, abs=abs)``, i.e.
    ``|g - fd| <= max(rel |fd|, abs)``. ``rel`` and ``abs`` may be dicts keyed by the top-level
    parameter name."""
    fd = central_differences(f, params, h=h, relative_step=relative_step, names=names)
    for key, d in fd.items():
        gk = grad
        for k in key:
            gk = gk[k]
        gk = np.asarray(gk, float).reshape(d.shape)
        r = _select(rel, key[0]) if key else rel
        a = _select(abs, key[0]) if key else abs
        for idx in np.ndindex(d.shape):
            assert float(gk[idx]) == pytest.approx(d[idx], rel=r, abs=a), (key, idx)


def eval_cos_and_pdf(model, wi, wo):
    """``sum(eval_cos) + 1e-2 sum(pdf)``: an objective of
    :func:`assert_model_gradient_matches_fd` that also differentiates the pdf."""
    return jnp.sum(model.eval_cos(wi, wo)) + 1e-2 * jnp.sum(model.pdf(wi, wo))


def assert_model_gradient_matches_fd(build, wi, wo, params, rel, abs, h=1e-6,
                                     relative_step=False, weights=None, objective=None):
    """The gradient of ``objective(build(**p), wi, wo)`` (default: ``sum(eval(wi, wo) * weights)``)
    with respect to every entry of every parameter equals its central differences
    (:func:`assert_gradient_matches_fd`). One jitted ``value_and_grad`` gives both (the parameters
    go in as float64 NumPy arrays, so it compiles once)."""

    @jax.jit
    def value_and_grad(p):
        def total(q):
            m = build(**q)
            if objective is not None:
                return objective(m, wi, wo)
            f = m.eval(wi, wo)
            return jnp.sum(f if weights is None else f * weights)

        return jax.value_and_grad(total)(p)

    p0 = {k: np.asarray(v, float) for k, v in params.items()}
    grad = value_and_grad(p0)[1]
    assert_gradient_matches_fd(lambda p: value_and_grad(p)[0], grad, p0, rel=rel, abs=abs, h=h,
                               relative_step=relative_step)


# ----------------------------------------------------------------------------- finite at extremes


def assert_finite(tree, what=""):
    """Every entry of every leaf of ``tree`` is finite (the message names the leaf's path)."""
    for path, leaf in jax.tree_util.tree_leaves_with_path(tree):
        bad = ~np.isfinite(np.asarray(leaf))
        assert not bad.any(), f"{what}: {bad.sum()} non-finite entries at {path}"


def values_pdfs_grads(build, grid, wi, wo):
    """``(eval, pdf, grads)`` of ``build(**p)`` at ``(wi, wo)`` for every parameter set ``p`` of
    ``grid`` (dict of equal-length arrays; one jitted ``vmap``): ``grads`` is the gradient of
    ``sum(eval) + sum(pdf)`` with respect to ``(p, wi, wo)``."""

    def total(p, wi, wo):
        m = build(**p)
        return jnp.sum(m.eval(wi, wo)) + jnp.sum(m.pdf(wi, wo))

    def one(p):
        m = build(**p)
        return m.eval(wi, wo), m.pdf(wi, wo), jax.grad(total, argnums=(0, 1, 2))(p, wi, wo)

    return jax.jit(jax.vmap(one))(grid)


#: uniforms of :func:`assert_sampling_finite`: both ends of [0, 1) and near them
EXTREME_UNIFORMS = (0.0, 1e-7, 0.5, 1 - 1e-7)


def assert_sampling_finite(model, dtype, cos=(1e-7, 0.5, 1.0), phi=0.4,
                           failed_weight_zero=True):
    """``model.sample`` at ``wo`` of each cosine in ``cos`` (azimuth ``phi``) and the 4 x 4 grid of
    :data:`EXTREME_UNIFORMS` (with 16 lobe uniforms from 0 to ``1 - 1e-7``), in ``dtype``: wi, pdf
    and weight finite; with ``failed_weight_zero`` also weight 0 where pdf is 0."""
    us = jnp.asarray(EXTREME_UNIFORMS, dtype)
    u = jnp.stack(jnp.meshgrid(us, us), -1).reshape(-1, 2)
    uc = jnp.linspace(0.0, 1 - 1e-7, 16, dtype=dtype)
    for c in cos:
        w = jnp.broadcast_to(jnp.asarray(vec(np.array(math.acos(c)), np.array(phi)), dtype),
                             (16, 3))
        s = sample_jit(model, w, uc, u)
        for x in (s.wi, s.pdf, s.weight):
            assert np.all(np.isfinite(np.asarray(x))), (c, x)
        if failed_weight_zero:
            assert np.all(np.asarray(s.weight)[np.asarray(s.pdf) == 0] == 0), c


def cli_one_error(capsys, argv, fragment):
    """``brdf-fit ARGV`` ends in one ``brdf-fit: error:`` line naming ``fragment``, exit status
    2, no traceback (argparse's usage errors exit through SystemExit(2))."""
    from brdf_fit.cli import main

    try:
        code = main(argv)
    except SystemExit as e:
        code = e.code
    err = capsys.readouterr().err
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert code == 2 and "Traceback" not in err, err
    assert sum("error:" in ln for ln in lines) == 1 and fragment in lines[-1], err


class SampleOnePdfOther(eqx.Module):
    """Negative control for chi-square tests: the sampler of ``inner`` reported with the pdf of
    ``other`` (a pdf that does not describe the sampler must be rejected)."""

    inner: eqx.Module
    other: eqx.Module

    def sample(self, wo, uc, u):
        return self.inner.sample(wo, uc, u)

    def pdf(self, wi, wo):
        return self.other.pdf(wi, wo)


#: Python source that prints a child process's own peak resident memory, in KiB, on a line
#: ``PEAK_KIB <n>`` of stderr: VmHWM of /proc/self/status, the high-water mark of the memory
#: map that exec gave the child. Not ``resource.getrusage(...).ru_maxrss``: Linux carries the
#: forking parent's high-water mark across exec into it, so a child of a pytest worker holding
#: 700 MB reported 700 MB whatever it did (measured).
PEAK_RSS_CODE = ("import sys as _s\n"
                 "def _peak():\n"
                 "    for line in open('/proc/self/status'):\n"
                 "        if line.startswith('VmHWM:'):\n"
                 "            print('PEAK_KIB', line.split()[1], file=_s.stderr)\n")


def peak_kib(stderr: str) -> int:
    """The ``PEAK_KIB`` figure a child printed (:data:`PEAK_RSS_CODE`)."""
    return int(stderr.split("PEAK_KIB")[1].split()[0])


def float32_spread(model, wi, wo, roundings, draws=8, seed=0):
    """How much ``model``'s value moves under float32 rounding, per pair (the largest relative
    change over the channels): over ``draws`` random perturbations of the directions by
    ``roundings`` float32 epsilons per component (absolute: a unit vector's rounding is
    relative to its length, not to a small component), and the model's own float32 arithmetic
    (at a near-mirror grazing pair ``h = wi + wo`` keeps 5e-5 of its tangential components after
    cancellation, which float32 resolves to 0.2%; a sharp lobe turns that into a percent of
    ``D``). The parity tests against float32 renderers (Cycles, MaterialX's GLSL) allow a few
    times this where a value is ill-conditioned."""
    from brdf_fit.models import astype

    eps32 = float(np.finfo(np.float32).eps)
    rng = np.random.default_rng(seed)
    base = np.asarray(model.eval(wi, wo))
    worst = np.zeros(base.shape[0])
    for _ in range(draws):
        def jitter(w):
            w = w + roundings * eps32 * rng.uniform(-1.0, 1.0, w.shape)
            return w / np.linalg.norm(w, axis=-1, keepdims=True)

        moved = np.asarray(model.eval(jitter(wi), jitter(wo)))
        rel = np.abs(moved - base) / np.maximum(np.abs(base), 1e-300)
        worst = np.maximum(worst, rel.max(axis=-1))
    m32 = astype(model, jnp.float32)
    v32 = np.asarray(m32.eval(jnp.asarray(wi, jnp.float32), jnp.asarray(wo, jnp.float32)))
    rel = np.abs(v32 - base) / np.maximum(np.abs(base), 1e-300)
    return np.maximum(worst, rel.max(axis=-1))


def direction_sensitivity(model, wi, wo):
    """Per pair, the relative change of ``model``'s value (its largest channel) per unit change
    of each direction component, to first order: ``sum_k |d f / d w_k| / f`` over the
    tangential gradients (the part along ``w`` is no physical change of a unit direction) of
    both ``wi`` and ``wo``. Times a component's rounding error, a bound on the value's error
    from rounded directions that a random perturbation (:func:`float32_spread`) can miss at an
    ill-conditioned pair (a narrow lobe at grazing)."""

    def peak(a, b):
        return jnp.max(model.eval(a[None], b[None]))

    grad = jax.vmap(jax.grad(peak, argnums=(0, 1)))
    gi, go = (np.asarray(g) for g in grad(jnp.asarray(wi), jnp.asarray(wo)))
    value = np.asarray(jax.vmap(peak)(jnp.asarray(wi), jnp.asarray(wo)))

    def tangential(g, w):
        return g - np.sum(g * w, axis=-1, keepdims=True) * w

    total = np.abs(tangential(gi, wi)).sum(-1) + np.abs(tangential(go, wo)).sum(-1)
    return total / np.maximum(np.abs(value), 1e-300)


def parity_pairs(n, seed, lo=1e-2):
    """``n`` random ``(wi, wo)`` pairs (:func:`random_dirs`, seeded): the random half of the
    renderer parity tests (Cycles, MaterialX)."""
    rng = np.random.default_rng(seed)
    return random_dirs(rng, n, lo), random_dirs(rng, n, lo)


def grazing_pairs():
    """36 pairs with both directions at cos 1e-3 .. 0.05 (the view at 1e-3 .. 0.3), near-mirror,
    near-retro and crossed azimuths: the grazing half of the renderer parity tests."""
    out_i, out_o = [], []
    for ci in (1e-3, 0.01, 0.05):
        for co in (1e-3, 0.02, 0.3):
            for dphi in (0.0, 0.5 * math.pi, math.pi - 0.05, math.pi):
                si, so = math.sqrt(1 - ci * ci), math.sqrt(1 - co * co)
                out_i.append((si * math.cos(dphi), si * math.sin(dphi), ci))
                out_o.append((-so, 0.0, co))
    return np.array(out_i), np.array(out_o)


def write_model_data(path, entry: str, params: dict, n: int = 400, seed: int = 0,
                     noise: float = 0.01, lo: float = 0.05):
    """Write registry ``entry`` at ``params`` as RGB gonioreflectometer data (``.npz``): ``n``
    random pairs with cosines in ``[lo, 1]``, multiplicative Gaussian noise of ``noise``
    (the target CLI tests' materials). Returns ``path``."""
    from brdf_fit import registry
    from brdf_fit.data import GonioData
    from brdf_fit.io.npz import write_npz

    rng = np.random.default_rng(seed)
    wi, wo = random_dirs(rng, n, lo), random_dirs(rng, n, lo)
    f = np.asarray(registry.get(entry).build(**params).eval(wi, wo))
    f = f * (1.0 + noise * rng.standard_normal(f.shape))
    write_npz(GonioData(wi=wi, wo=wo, value=f, channels=("R", "G", "B")), path)
    return path
