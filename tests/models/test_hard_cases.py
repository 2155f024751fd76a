"""No NaN or Inf in values or gradients on the hard-case grid, for every registry entry.

Grid (issue "Foundation", Done means): cos(theta) in {1e-7, 1e-4, 1e-2, 0.5, 1} for both
directions, in generic position, with wi == wo, wi == mirror(wo), and both directions grazing at
opposite azimuths (the half vector vanishes in the limit; exactly on the horizon it does vanish),
grazing near-mirror pairs unit only to rounding (length 1 +- 1e-6, or float32-normalised) and the
grazing mirror pair wi = (-1, 0, 1e-8), wo = (1, 0, 1e-8);
alpha in {1e-4, 1e-3, 0.05, 0.5, 1}, k in {0, 1, 100}, eta in {1, 1.5, 1/1.5}; Blinn-Phong
exponents up to 1e6; every other parameter (the catalogue's sigma, nu, tau, lobe coefficients,
...) at the ends of its interval, one at a time. Gradients are taken with respect to both
directions and every parameter, in float64 and in float32.
"""

import itertools
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from _helpers import assert_finite, values_pdfs_grads
from _helpers import dir_from_cos as direction

from brdf_fit import registry
from brdf_fit.verify.checks import hard_case_params

COS = [1e-7, 1e-4, 1e-2, 0.5, 1.0]
HARD = {
    "alpha": [1e-4, 1e-3, 0.05, 0.5, 1.0],
    "alpha_x": [1e-4, 1e-3, 0.05, 0.5, 1.0],
    "alpha_y": [1e-4, 0.05, 1.0],
    "eta": [1.0, 1.5, 1 / 1.5],
    "k": [0.0, 1.0, 100.0],
    "exponent": [0.0, 1.0, 100.0, 1e4, 1e6],
    "f0": [0.0, 1.0],
    "rho": [0.0, 1.0],
    "rho_d": [0.0, 1.0],
    "kd": [0.0, 1.0],
    "ks": [0.0, 1.0],
}


def _float32_normalised(w):
    w = np.asarray(w, np.float32)
    return (w / np.sqrt(np.sum(w * w, dtype=np.float32))).astype(np.float64)


def direction_pairs():
    wi, wo = [], []
    for ci, co in itertools.product(COS, COS):
        wi.append(direction(ci, 0.3))  # generic azimuths
        wo.append(direction(co, 2.1))
        wi.append(direction(ci, 1.0))  # same azimuth
        wo.append(direction(co, 1.0))
        wi.append(direction(ci, 0.0))  # opposite azimuths (grazing pairs: h -> 0)
        wo.append(direction(co, math.pi))
    for c in COS:
        w = direction(c, 0.7)
        wi.append(w)  # wi == wo
        wo.append(w)
        wi.append([-w[0], -w[1], w[2]])  # wi == mirror(wo)
        wo.append(w)
    # directions unit only to rounding (issue 16): grazing near-mirror pairs with one direction
    # of length 1 +- 1e-6, and both normalised in float32 (negative wo.h gave negative values)
    for c in COS[:3]:
        w = np.asarray(direction(c, 0.4))
        m = np.asarray([-w[0], -w[1], w[2]])
        for scale in (1 + 1e-6, 1 - 1e-6):
            wi.append(m * scale)
            wo.append(w)
            wi.append(m)
            wo.append(w * scale)
        wi.append(_float32_normalised(m))
        wo.append(_float32_normalised(w))
    # a grazing mirror pair below the COS grid (float32 gradients were NaN at alpha = 1e-4 in
    # the V-cavity models and kelemen, issue 16)
    wi.append([-1.0, 0.0, 1e-8])
    wo.append([1.0, 0.0, 1e-8])
    # exactly on the horizon, opposite: wi == -wo, the half vector is exactly zero
    wi.append([1.0, 0.0, 0.0])
    wo.append([-1.0, 0.0, 0.0])
    wi.append([0.0, 0.0, 1.0])
    wo.append([1.0, 0.0, 0.0])
    return np.asarray(wi), np.asarray(wo)


WI, WO = direction_pairs()


def param_grid(entry):
    """The named hard values (product) plus every other parameter at its interval ends, one at a
    time (:func:`brdf_fit.verify.checks.hard_case_params`)."""
    grid = hard_case_params(entry, HARD)
    return grid, next(iter(grid.values())).shape[0] if grid else 1


@pytest.mark.parametrize("dtype", [jnp.float64, jnp.float32], ids=["f64", "f32"])
@pytest.mark.parametrize("entry", registry.entries(), ids=registry.names())
def test_values_and_gradients_are_finite(entry, dtype):
    grid, n = param_grid(entry)
    grid = {k: jnp.asarray(v, dtype) for k, v in grid.items()}
    wi = jnp.asarray(WI, dtype)
    wo = jnp.asarray(WO, dtype)
    vals, pdfs, grads = values_pdfs_grads(entry.build, grid, wi, wo)
    assert vals.dtype == dtype
    assert_finite(vals, f"{entry.name} eval")
    assert_finite(pdfs, f"{entry.name} pdf")
    assert_finite(grads, f"{entry.name} gradient")
    assert np.all(np.asarray(vals) >= 0) and np.all(np.asarray(pdfs) >= 0)
    # the exactly-opposite horizon pair and horizon directions evaluate to 0
    assert np.all(np.asarray(vals)[:, -2:] == 0)


@pytest.mark.parametrize("dtype", [jnp.float64, jnp.float32], ids=["f64", "f32"])
@pytest.mark.parametrize("entry", registry.entries(), ids=registry.names())
def test_sampling_is_finite_on_hard_cases(entry, dtype):
    grid, n = param_grid(entry)
    grid = {k: jnp.asarray(v, dtype) for k, v in grid.items()}
    us = [0.0, 1e-7, 0.5, 1.0 - 1e-7]
    uu = jnp.asarray(list(itertools.product(us, us)), dtype)
    wo = jnp.asarray([direction(c, 0.4) for c in COS], dtype)
    wo_b = jnp.repeat(wo, uu.shape[0], axis=0)
    u_b = jnp.tile(uu, (wo.shape[0], 1))
    uc = jnp.linspace(0.0, 1.0 - 1e-7, u_b.shape[0], dtype=dtype)

    def one(p):
        s = entry.build(**p).sample(wo_b, uc, u_b)
        return s.wi, s.pdf, s.weight

    wi, pdf, weight = jax.jit(jax.vmap(one))(grid)
    assert_finite((wi, pdf, weight), f"{entry.name} sample")
    assert np.all(np.asarray(pdf) >= 0)
    assert np.all(np.asarray(weight)[np.asarray(pdf) == 0] == 0)
