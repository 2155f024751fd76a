"""batch-lm at the rounding floor (brdf_fit.fitting._lm.lm_update, ROUNDING_FLOOR): a rejected
step where even the undamped Gauss-Newton step would lower the loss by less than one rounding
unit of it ends the lane, converged, at that Gauss-Newton step; a rejected step above the floor
only raises the damping, as before. On a linear least-squares problem, whose optimum is exact."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from brdf_fit.fitting import _lm

EPS = float(np.finfo(np.float64).eps)


def _problem(seed=2, m=400, p=4):
    rng = np.random.default_rng(seed)
    J = rng.normal(size=(m, p))
    y = rng.normal(size=m)  # far from the column space: a large residual, cost ~ m/2
    u_opt = np.linalg.lstsq(J, y, rcond=None)[0]

    def quad(u):
        r = J @ u - y
        return (0.5 * float(r @ r), J.T @ J, J.T @ r, np.zeros((p, p)))

    return J, u_opt, quad


def _state(u, quad):
    s = jax.tree.map(lambda x: jnp.asarray(x[0]), _lm.LMState.start(
        np.asarray(u)[None], np.float64, 50, 1e-10, 1e-10))
    cost, A, g, meat = (jnp.asarray(x) for x in quad(u))
    return _lm.LMState(**{**{f: getattr(s, f) for f in s.__dataclass_fields__},
                          "cost": cost, "A": A, "g": g, "meat": meat, "lam": jnp.asarray(1e-3)})


def _reject(s):
    """lm_update with a trial step whose loss came out one rounding unit above the current
    one (what rounding does to the loss differences of a step this small)."""
    du, u_new, lam, scale = _lm.lm_propose(s)
    cost, A, g, meat = s.cost, s.A, s.g, s.meat
    q = (cost * (1.0 + 2.0 * EPS), A, g, meat)
    return _lm.lm_update(s, du, u_new, lam, scale, q)


def test_floor_ends_the_lane_at_the_gauss_newton_step():
    J, u_opt, quad = _problem()
    A = J.T @ J
    cost = quad(u_opt)[0]
    # an offset whose Gauss-Newton decrement 0.5 d^T A d is a quarter of eps * cost
    d = np.random.default_rng(5).normal(size=u_opt.size)
    d *= np.sqrt(0.25 * EPS * cost / (0.5 * d @ A @ d))
    s = _reject(_state(u_opt + d, quad))
    assert bool(s.done) and bool(s.ok)
    # the undamped step lands on the optimum (to the rounding of the normal equations)
    np.testing.assert_allclose(np.asarray(s.u), u_opt, rtol=0, atol=1e-3 * np.abs(d).max())
    assert float(s.cost) == quad(u_opt + d)[0]  # the sums stay those of the last iterate


@pytest.mark.parametrize("factor", [1e2, 1e6])
def test_above_the_floor_a_rejection_only_damps(factor):
    J, u_opt, quad = _problem()
    A = J.T @ J
    cost = quad(u_opt)[0]
    d = np.random.default_rng(5).normal(size=u_opt.size)
    d *= np.sqrt(factor * EPS * cost / (0.5 * d @ A @ d))
    s0 = _state(u_opt + d, quad)
    s = _reject(s0)
    assert not bool(s.done)
    np.testing.assert_array_equal(np.asarray(s.u), np.asarray(s0.u))
    assert float(s.lam) > float(s0.lam)
