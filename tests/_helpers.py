"""Helpers shared by the catalogue model test files.

The jitted wrappers are module-level objects, so every test module that uses them reuses one
compilation per model type and argument shapes (a fresh ``jax.jit(lambda ...)`` per test or per
file compiles again); eager calls (``model.eval(...)`` outside ``jit``) dispatch op by op and
were the largest cost of several tests.
"""

from __future__ import annotations

import jax
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


def vec(theta, phi):
    """Unit vectors from polar angle ``theta`` and azimuth ``phi`` (NumPy, broadcasting)."""
    theta, phi = np.asarray(theta), np.asarray(phi)
    return np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)], -1)


def random_angles(rng, n, lo=1e-3, phi_range=(0.0, 2 * np.pi)):
    """``(theta, phi)``: cosines uniform in ``[lo, 1]``, azimuths uniform in ``phi_range``."""
    return np.arccos(rng.uniform(lo, 1.0, n)), rng.uniform(*phi_range, n)


def central_differences(f, params, h=1e-6, relative_step=False):
    """``{name: array}`` of central differences of the scalar ``f(params)`` with respect to every
    entry of every parameter (``params``: dict of NumPy-convertible arrays). The step is ``h``,
    or ``h max(1, |x|)`` with ``relative_step``."""
    p0 = {k: np.asarray(v, float) for k, v in params.items()}
    out = {}
    for k, v in p0.items():
        fd = np.zeros(v.shape)
        for idx in np.ndindex(v.shape):
            step = h * max(1.0, abs(float(v[idx]))) if relative_step else h
            up, dn = v.copy(), v.copy()
            up[idx] += step
            dn[idx] -= step
            fd[idx] = (float(f({**p0, k: up})) - float(f({**p0, k: dn}))) / (2 * step)
        out[k] = fd
    return out


def assert_gradient_matches_fd(f, grad, params, rel, abs, h=1e-6, relative_step=False):
    """Every entry of ``grad[name]`` equals the central difference of ``f`` (see
    :func:`central_differences`) to ``pytest.approx(rel=rel, abs=abs)``."""
    fd = central_differences(f, params, h=h, relative_step=relative_step)
    for k, d in fd.items():
        gk = np.asarray(grad[k], float).reshape(d.shape)
        for idx in np.ndindex(d.shape):
            assert float(gk[idx]) == pytest.approx(d[idx], rel=rel, abs=abs), (k, idx)
