"""The batched solvers of :func:`brdf_fit.fitting.batch.fit_batch`: ``batch-lm``, a
Levenberg-Marquardt method written for batches (one step: :func:`lm_chunk`), the optimistix
solvers restarted chunk by chunk (:func:`optx_chunk`), the structured forward-mode Jacobian
they share (:func:`directions`, :func:`tangents`) and the final standard errors
(:func:`finalise_one`, :func:`finalise_state`). The solver state is an :class:`LMState`.

Everything here acts on a batch of lanes with a leading axis; how lanes are grouped, chunked,
blocked and sharded is :mod:`brdf_fit.fitting._schedule`. See :mod:`brdf_fit.fitting.batch` for
the method and its measurements.

**batch-lm**: Marquardt scaling by the running maximum of ``diag(J^T J)`` (as MINPACK: J. J.
Moré, "The Levenberg-Marquardt algorithm: implementation and theory", Numerical Analysis, LNM
630, 1978), the damping update of H. B. Nielsen ("Damping parameter in Marquardt's method",
IMM-REP-1999-05, DTU, 1999: ``lam *= max(1/3, 1 - (2 rho - 1)^3)`` on success,
``lam *= nu; nu *= 2`` on failure), the residual and Jacobian from one forward-mode pass, the
normal equations (``p x p``) solved by Cholesky, and no step entry longer than
:data:`STEP_MAX` in the unconstrained space.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from brdf_fit.fitting import solvers as _solvers
from brdf_fit.fitting.problem import stderr_codes
from brdf_fit.fitting.solvers import covariance_normal, hc3_weights, pinv_or_stand_in, solve

__all__ = ["LMState", "gather", "data_axes", "lanes", "directions", "tangents", "normal",
           "quad", "quad_pairs", "tangent_list", "lm_init", "lm_step", "lm_propose", "lm_update",
           "gauss_newton_step",
           "newton_converged", "lm_chunk", "optx_chunk",
           "finalise_one", "finalise_state", "grouped"]

#: Initial damping of batch-lm relative to max(diag(J^T J)) (Madsen, Nielsen & Tingleff,
#: "Methods for non-linear least squares problems", DTU 2004, section 3.2: 1e-6 for a good start,
#: 1e-3 otherwise; registry defaults are not good starts).
LM_TAU = 1e-3
#: Floor of the Marquardt scaling diag(J^T J), relative to its largest entry: a parameter whose
#: column vanishes (f0 at its logistic bound) must still be damped, not divided by zero.
SCALE_FLOOR = 1e-12
#: Marquardt's scaling of the damping by diag(J^T J) (running maximum, as MINPACK) or none.
MARQUARDT_SCALING = True
#: Growth of the damping factor nu after each rejected step (Nielsen: 2).
NU_GROWTH = 2.0
#: Damping beyond LAM_MAX * max(diag(J^T J)): every step is rejected at machine precision; stop
#: (not converged).
LAM_MAX = 1e16
#: Longest step of batch-lm in the unconstrained space, per entry (see :func:`lm_propose`).
STEP_MAX = 2.0
#: Smallest denominator of the step-length cap and of the gradient cosine (a zero step or a zero
#: residual would divide by zero there).
DIV_FLOOR = 1e-300
#: MINPACK's gtol test: a stuck iterate is a minimum when the largest cosine between the
#: residual and a Jacobian column is below this many sqrt(eps).
GTOL_SQRT_EPS = 10.0
#: The rounding floor, in units of ``eps * loss``: a lane whose step was rejected where the
#: Gauss-Newton decrement ``0.5 g^T A^-1 g`` (the decrease of the undamped step, by the quadratic
#: model) is at most this is at machine precision (no step can show a decrease the loss
#: resolves): it takes that undamped step without a loss test and stops, as at LAM_MAX,
#: converged if MINPACK's gtol test passes. 1: below one rounding unit of the loss itself (its
#: sum over samples rounds by more).
ROUNDING_FLOOR = 1.0
#: Stall: a lane stops, not converged, after this many consecutive accepted steps that each
#: changed the loss by less than the Cauchy tolerance ``atol + rtol * loss`` (the loss half of
#: the convergence test passed) while the step itself stayed long (the parameter half failed).
#: The iterate is then sliding along a direction in which the loss is flat to the tolerance: a
#: Jacobian column vanishing as a logistic parameter runs onto the plateau of its transform
#: (an all-black file drives alpha and f0 to their bounds, ``f = 1000`` f0 to 1), where only
#: LAM_MAX or max_steps ended it (71-256 steps, issue 16). Near a minimum where ``J^T J`` is
#: non-singular the step shrinks with the loss change and the Newton test passes within a
#: few steps: measured on 10,000 GGX fits (benchmarks/bench_fit_batch.py), every lane that
#: converged at an interior minimum had at most 5 such steps in a row; the 24 that ran an f0
#: channel onto its bound of 1 had 44-56 and now stop at 16, their parameters moved by at most
#: 4e-9 and their losses by 1e-8 relative. Rejected steps neither count nor reset the streak
#: (the damping's own stop, LAM_MAX, handles a run of them).
STALL_STEPS = 16


class LMState(eqx.Module):
    """The solver state of every lane (leading batch axis on every field), carried across
    chunks (host side: NumPy arrays, updated in place between chunks). ``cost``, ``A``, ``g``
    and ``meat`` (batch-lm's carried quantities, :func:`quad`) are None for the optimistix
    solvers; ``budget`` (iterations of this chunk per lane) is set only for a chunk call."""

    u: Any  # (B, p) unconstrained iterate
    lam: Any  # (B,) damping; < 0: not set yet (set from the first J^T J)
    nu: Any  # (B,) Nielsen's damping growth factor
    scale: Any  # (B, p) Marquardt scaling: running maximum of diag(J^T J)
    steps: Any  # (B,) int32 iterations so far (all chunks)
    done: Any  # (B,) bool: stopped (converged or stuck)
    ok: Any  # (B,) bool: converged
    cost: Any = None  # (B,) 0.5 |r|^2 at u
    A: Any = None  # (B, p, p) J^T J at u
    g: Any = None  # (B, p) J^T r at u
    meat: Any = None  # (B, p, p) J^T diag(r^2) J at u (zeros unless the sandwich is used)
    budget: Any = None  # (B,) int32: the chunk's length, carried with the lanes
    #: (B,) int32: the most iterations of each lane (fit_batch's max_steps), data rather than a
    #: static argument, so that one compilation serves every max_steps
    limit: Any = None
    #: (B, 2): batch-lm's ``rtol, atol`` per lane (data, like ``limit``: one compilation for
    #: every tolerance)
    tol: Any = None
    #: (B,) int32: consecutive accepted steps of negligible loss change (see STALL_STEPS)
    stall: Any = None

    @classmethod
    def start(cls, u, dtype, max_steps: int, rtol: float = 0.0, atol: float = 0.0) -> LMState:
        """The state before the first iteration at the starts ``u`` (B, p) (NumPy)."""
        B, p = u.shape
        return cls(u=u.astype(dtype), lam=np.full(B, -1.0, dtype), nu=np.full(B, 2.0, dtype),
                   scale=np.zeros((B, p), dtype), steps=np.zeros(B, np.int32),
                   done=np.zeros(B, bool), ok=np.zeros(B, bool),
                   limit=np.full(B, max_steps, np.int32), stall=np.zeros(B, np.int32),
                   tol=np.broadcast_to(np.asarray([rtol, atol], dtype), (B, 2)).copy())

    def with_quad(self, q) -> LMState:
        """The state with batch-lm's carried ``(cost, A, g, meat)`` set (NumPy copies)."""
        cost, A, g, meat = (np.array(x) for x in q)
        return dataclasses.replace(self, cost=cost, A=A, g=g, meat=meat)

    def with_budget(self, budget) -> LMState:
        return dataclasses.replace(self, budget=budget)


# ----------------------------------------------------------------------------- Jacobian


def directions(problem, n_channels: int):
    """Tangent directions of the structured forward-mode Jacobian of ``problem`` and the map
    ``Q`` (C, k, p) from directions to the columns of the flat parameter vector.

    A channel parameter (declared ``channels``, shape (C,)) acts on each channel's residuals
    only through its own entry (the assumption :mod:`brdf_fit.fitting.guess` also makes; tested
    for every registry model in ``tests/fitting/test_fit_batch.py``), so its C Jacobian columns
    are block diagonal and *one* tangent of ones gives all of them: tangent ``a`` of residual
    ``(m, c)`` is column ``Q[c, a]``. A shared parameter takes one direction per entry. GGX with
    RGB f0: 2 forward-mode passes instead of jacfwd's 4, and the f0 pass carries no tangent
    through D and G (the other parameters are closed over, so their tangents are symbolic
    zeros). Measured on this CPU (GGX, 300 samples, RGB, groups of 8): residual, Jacobian and
    normal equations 36 us per problem against 62 us with jacfwd on the flattened residual.

    Returns ``(dirs, Q)``: ``dirs`` a tuple of ``(name, j)``, ``j`` None for a channel
    parameter's tangent of ones, else the flat entry of a shared parameter."""
    lay = problem.layout
    dirs, cols = [], []
    for name, size, sl, chan in zip(lay.names, lay.sizes, lay.slices,
                                    lay.structured(n_channels), strict=True):
        if chan:
            dirs.append((name, None))
            cols.append([sl.start + c for c in range(n_channels)])
        else:
            for j in range(size):
                dirs.append((name, j))
                cols.append([sl.start + j] * n_channels)
    Q = np.zeros((n_channels, len(dirs), lay.size))
    for a, cs in enumerate(cols):
        for c, col in enumerate(cs):
            Q[c, a, col] = 1.0
    return tuple(dirs), Q


def tangents(problem, dirs, x, prep, fixed, physical=False):
    """Residuals ``r`` (M, C) at the flat ``x`` (unconstrained, or physical with ``physical``)
    and their tangents ``T`` (k, M, C) along :func:`directions`."""
    r, T = tangent_list(problem, dirs, x, prep, fixed, physical)
    T = jnp.stack(T) if T else jnp.zeros((0, *r.shape), r.dtype)
    return r, T


def tangent_list(problem, dirs, x, prep, fixed, physical=False):
    """:func:`tangents` with the tangents as a list of ``k`` arrays (M, C), not stacked."""
    prob = problem.with_fixed(fixed)
    parts = prob.split(x)

    def res(pp):
        params = {**prob.fixed, **pp} if physical else prob.physical(pp)
        return prob.residuals_prepared(params, prep)

    r, T = None, []
    for name, j in dirs:
        v = parts[name]
        t = (jnp.ones_like(v) if j is None
             else jnp.zeros(v.size, v.dtype).at[j].set(1.0).reshape(v.shape))
        rj, tj = jax.jvp(lambda z, name=name: res({**parts, name: z}), (v,), (t,))
        # r from a JVP's primal: the model's value where its derivatives come from (a model
        # with a separate value form, as MicrofacetBRDF in float32, would otherwise be
        # evaluated twice per step, once in each form)
        r = rj if r is None else r
        T.append(tj)
    if r is None:
        r = res(parts)
    return r, T


def normal(T, r, Q):
    """``J^T J`` and ``J^T r`` from the tangents (:func:`directions`).

    In float32 the per-channel sums over the samples are formed with the sample axis last
    (``(k, C, M)``, products summed over the contiguous axis): XLA's CPU code for the (M, C)
    layout's strided reductions made the normal equations cost more than the residual and its
    tangents together in float32 (measured on GGX, 300 samples x RGB, groups of 8 lanes:
    residual + 2 tangents 6.7 us per lane, with the normal equations 21.3 us; sample axis
    last 13.5 us; float64 16.1 us either way, so float64 keeps the einsum and its numbers)."""
    Q = jnp.asarray(Q, r.dtype)
    if r.dtype == jnp.float32:
        Tt = jnp.swapaxes(T, 1, 2)  # (k, C, M)
        rt = r.T  # (C, M)
        G = jnp.moveaxis(jnp.sum(Tt[:, None] * Tt[None], -1), -1, 0)  # (C, k, k)
        h = jnp.sum(Tt * rt[None], -1).T  # (C, k)
    else:
        G = jnp.einsum("amc,bmc->cab", T, T)
        h = jnp.einsum("amc,mc->ca", T, r)
    return jnp.einsum("cap,cab,cbq->pq", Q, G, Q), jnp.einsum("cap,ca->p", Q, h)


def quad(problem, dq, u, prep, fx, sandwich):
    """Loss and the normal-equation quantities ``(0.5 |r|^2, J^T J, J^T r, J^T diag(r^2) J)``
    at ``u`` (the last, the sandwich estimator's meat, zeros unless ``sandwich``): only these
    ``p x p`` quantities are carried between iterations, never the ``(M C, p)`` Jacobian
    (copying it every step made the loop memory-bound), and the standard errors come from the
    carried ones at the end (:func:`finalise_state`). ``dq``: :func:`directions`."""
    dirs, Q = dq
    r, T = tangents(problem, dirs, u, prep, fx)
    A, g = normal(T, r, Q)
    meat = normal(T * r, r, Q)[0] if sandwich else jnp.zeros_like(A)
    return 0.5 * jnp.sum(r * r), A, g, meat


def quad_pairs(problem, dq, u, prep, fx, sandwich):
    """:func:`quad` for one large block of samples (the chunked fit's chunk): the same sums,
    formed pair by pair of tangents (``sum_m T_a T_b`` per channel, ``a <= b``) instead of from
    the stacked ``(k, M, C)`` tangents. Stacked, XLA fused every tangent's computation into one
    concatenate fusion, which took over half of a chunk's time (XLA's CPU profile). Pair by
    pair, one pass of the chunked sums over a whole MERL file (1.1 million samples of Mitsuba's
    GGX conductor, RGB eta and k: 3 tangents, in chunks of 16,384) took 0.35-0.39 s against
    0.44-0.45 s stacked (issue 44). Agrees with :func:`quad` to rounding
    (tests/fitting/test_fit_chunked.py)."""
    dirs, Q = dq
    r, T = tangent_list(problem, dirs, u, prep, fx)
    k = len(T)
    Q = jnp.asarray(Q, r.dtype)

    def gram(w):  # (C, k, k): sum over samples of T_a T_b w per channel
        rows = [[None] * k for _ in range(k)]
        for a in range(k):
            for b in range(a, k):
                t = T[a] * T[b] if w is None else T[a] * T[b] * w
                rows[a][b] = rows[b][a] = jnp.sum(t, axis=0)
        return jnp.stack([jnp.stack(row, -1) for row in rows], -2)

    def to_params(G):
        return jnp.einsum("cap,cab,cbq->pq", Q, G, Q)

    if not k:
        A = jnp.zeros((Q.shape[-1],) * 2, r.dtype)
        return 0.5 * jnp.sum(r * r), A, jnp.zeros(Q.shape[-1], r.dtype), A
    h = jnp.stack([jnp.sum(t * r, axis=0) for t in T], -1)  # (C, k)
    A = to_params(gram(None))
    meat = to_params(gram(r * r)) if sandwich else jnp.zeros_like(A)
    return 0.5 * jnp.sum(r * r), A, jnp.einsum("cap,ca->p", Q, h), meat


# ----------------------------------------------------------------------------- groups


def gather(data, idx):
    """The problems ``idx`` of every leaf of the prepared ``data`` (leaves (B, M, k)). A leaf
    with a leading axis of 1 is shared by all problems (one geometry ``wi, wo`` for the whole
    batch, and the terms prepared from it alone, e.g. ``log``'s ``cos``): it is returned
    without a lane axis, (M, k), and vmapped with ``in_axes=None`` (:func:`data_axes`), so the
    geometry-only part of the model (half vectors, cosines, the Fresnel factor's
    ``(1 - cos)^5``) is computed once per group and step, not once per lane. (With one
    problem every index is 0, and the two agree.)"""
    return jax.tree.map(lambda x: x[0] if x.shape[0] == 1 else x[idx], data)


def data_axes(a):
    """``in_axes`` of gathered data (:func:`gather`): 0 for per-lane leaves (3-D), None for
    shared ones (2-D)."""
    return jax.tree.map(lambda x: None if x.ndim == 2 else 0, a)


def lanes(fn, data_pos: int, args):
    """``jax.vmap(fn)(*args)`` with the gathered data at ``args[data_pos]`` mapped by
    :func:`data_axes`."""
    axes = tuple(data_axes(x) if i == data_pos else 0 for i, x in enumerate(args))
    return jax.vmap(fn, in_axes=axes)(*args)


def grouped(fn, tree, group, idx=None, data=None):
    """Apply ``fn`` (which takes a batch of ``group`` lanes) to consecutive groups of ``group``
    lanes of ``tree`` (leading axis a multiple of ``group``), one group after another
    (``lax.map``), and return the results with the leading axis restored. With ``data``, ``fn``
    is called as ``fn(t, a)``, ``a`` the problems ``idx`` (one per lane) of ``data`` (leading
    axis: all B problems), gathered inside the group: the batch's data is never copied whole.

    Why groups: one vmapped step over all B lanes materialises every intermediate of the
    residual and its forward-mode tangents as a (B, M C) array (14 MB per array for 2,000
    problems of 300 x 3 values): far larger than the caches, so the step was memory-bound.
    Measured on this 2-core CPU (GGX, 300 samples, RGB): residual + Jacobian + normal equations
    cost 147 us per problem vmapped over 2,000 problems, 62-67 us in groups of 8-32 and 110 us
    one problem at a time (loop overhead)."""
    lead = jax.tree.leaves(tree)[0].shape[0]
    group = lead if group is None else group
    k = lead // group

    def rows(x):
        return x.reshape((k, group, *x.shape[1:]))

    split = jax.tree.map(rows, tree)
    if data is None:
        out = jax.lax.map(fn, split)
    else:
        out = jax.lax.map(lambda t: fn(t[0], gather(data, t[1])), (split, rows(idx)))
    return jax.tree.map(lambda x: x.reshape((k * group, *x.shape[2:])), out)


# ----------------------------------------------------------------------------- batch-lm


def lm_init(problem, group, sandwich, idx, data, u, fixed):
    """The carried quad (see :func:`quad`) at the starting point of every lane."""
    dq = directions(problem, data[3].shape[-1])

    def g(t, a):
        uu, fx = t
        return lanes(lambda x, y, z: quad(problem, dq, x, y, z, sandwich), 1, (uu, a, fx))
    return grouped(g, (u, fixed), group, idx, data)


def lm_step(problem, dq, sandwich, s: LMState, a, fx) -> LMState:
    """One batch-lm iteration of one lane (vmapped by :func:`lm_chunk`); a lane that is done
    or out of steps keeps its state.

    It stops when an accepted step satisfies optimistix's Cauchy test,
    ``max|du / (atol + rtol |u|)| < 1`` and ``|d loss| < atol + rtol * loss``, or when the next,
    undamped Gauss-Newton step from the new iterate would pass the same two tests by its
    quadratic model; or when the damping has grown past :data:`LAM_MAX` (every step rejected
    at machine precision), counted as converged only if the residual is orthogonal to the
    Jacobian columns (MINPACK's gtol test, :data:`GTOL_SQRT_EPS`); or, not converged, after
    :data:`STALL_STEPS` accepted steps in a row that changed the loss by less than the tolerance
    while the step stayed long (a parameter sliding onto the plateau of its transform)."""
    du, u_new, lam, scale = lm_propose(s)
    return lm_update(s, du, u_new, lam, scale, quad(problem, dq, u_new, a, fx, sandwich))


def lm_propose(s: LMState):
    """The first half of :func:`lm_step`: the damped step ``du`` from the carried normal
    equations, the trial point ``u_new = u + du``, the damping ``lam`` and the Marquardt
    ``scale`` it used. No model evaluation (the caller evaluates :func:`quad` at ``u_new``)."""
    A, g = s.A, s.g
    d = jnp.diagonal(A)
    if MARQUARDT_SCALING:
        scale = jnp.maximum(s.scale, d)
        scale = jnp.maximum(scale, SCALE_FLOOR * jnp.max(scale))
    else:
        scale = jnp.ones_like(d)
    lam = jnp.where(s.lam < 0, LM_TAU * jnp.max(d) / jnp.max(scale), s.lam)
    M = A + jnp.diag(lam * scale)
    L = jnp.linalg.cholesky(M)
    du = -jax.scipy.linalg.cho_solve((L, True), g)
    du = jnp.where(jnp.all(jnp.isfinite(du)), du, jnp.zeros_like(du))
    # safeguard: no entry of the step longer than STEP_MAX in the unconstrained space (a
    # logistic parameter pushed far past its bound lands on a plateau with zero gradient). Per
    # entry, not on the step's length: a parameter already on such a plateau (its column ~0,
    # its Gauss-Newton component unbounded) took the whole length, and the others crawled:
    # ggx-plastic on a MERL silver (chunked) ran its albedo's u to -290 in 256 steps while
    # alpha and f0 moved by ~1e-6 a step, "did not converge"; clipped per entry, 80 steps,
    # converged (the albedo at 0, f0 at 1)
    du = jnp.clip(du, -STEP_MAX, STEP_MAX)
    return du, s.u + du, lam, scale


def gauss_newton_step(A, g):
    """The undamped Gauss-Newton step ``-A^-1 g`` (Cholesky; NaN where ``A`` is not positive
    definite)."""
    return -jax.scipy.linalg.cho_solve((jnp.linalg.cholesky(A), True), g)


def newton_converged(u, cost, A, g, rtol, atol):
    """True where the undamped Gauss-Newton step ``-A^-1 g`` from ``u`` would pass the Cauchy
    test by its quadratic model: ``max|dn / (atol + rtol |u|)| < 1`` and the Gauss-Newton
    decrement ``0.5 g^T A^-1 g < atol + rtol * cost`` (:func:`lm_update`'s second test)."""
    dn = gauss_newton_step(A, g)
    return (jnp.all(jnp.isfinite(dn))
            & (jnp.max(jnp.abs(dn) / (atol + rtol * jnp.abs(u))) < 1.0)
            & (-0.5 * jnp.dot(g, dn) < atol + rtol * cost))


def lm_update(s: LMState, du, u_new, lam, scale, q_new) -> LMState:
    """The second half of :func:`lm_step`: accept or reject the trial point ``u_new`` of
    :func:`lm_propose` from its loss and normal equations ``q_new`` (:func:`quad`), test
    convergence, and update the damping (:func:`lm_step`'s docstring says how)."""
    dtype = s.u.dtype
    rtol, atol = s.tol[0], s.tol[1]
    active = ~s.done & (s.steps < s.limit)
    cost, A, g = s.cost, s.A, s.g
    d = jnp.diagonal(A)
    cost_new, A_new, g_new, meat_new = q_new
    pred = -jnp.dot(g, du) - 0.5 * jnp.dot(du, A @ du)
    actual = cost - cost_new
    rho = jnp.where(pred > 0, actual / jnp.where(pred > 0, pred, 1.0), -1.0)
    accept = jnp.isfinite(cost_new) & (actual >= 0) & (rho > 0)
    small_step = jnp.max(jnp.abs(du) / (atol + rtol * jnp.abs(s.u))) < 1.0
    small_df = jnp.abs(actual) < atol + rtol * cost
    # the same two tests on the *next*, undamped Gauss-Newton step from u_new, predicted by
    # its quadratic model (the Gauss-Newton decrement 0.5 g^T A^-1 g estimates how far the
    # loss is above the local minimum; Boyd & Vandenberghe 2004, section 9.5.1): when that
    # step would pass, u_new is converged and the step that would only confirm it is not
    # taken (measured, 10,000 GGX fits: mean 8.2 -> 5.6 steps, losses equal to 6e-12)
    newton = newton_converged(u_new, cost_new, A_new, g_new, rtol, atol)
    conv = (accept & ((small_step & small_df) | newton)) | (cost == 0)
    # stuck: damped past LAM_MAX, or at the rounding floor (ROUNDING_FLOOR), where even the
    # undamped Gauss-Newton step dn (the best decrease the quadratic model offers, its decrement
    # 0.5 g^T A^-1 g) would lower the loss by less than one rounding unit of it: no step can
    # show a decrease there, and each rejection only multiplied lam until LAM_MAX (a chunked fit
    # of a MERL plastic with GGX took 5 such passes over the whole file). The gradient is still
    # exact where the loss's differences are not, so the lane takes dn without a loss test and
    # stops; its loss and normal equations stay those of u (the loss at u + dn differs by less
    # than its rounding). Without that step the lane stopped up to 1e-8 from the optimum
    dn = gauss_newton_step(A, g)
    floor = ~accept & jnp.all(jnp.isfinite(dn)) & (
        -0.5 * jnp.dot(g, dn) <= ROUNDING_FLOOR * jnp.finfo(dtype).eps * cost)
    stuck = (~accept & (lam * s.nu > LAM_MAX * jnp.max(d))) | floor
    # stuck at machine precision: a minimum if the residual is orthogonal to the Jacobian
    # columns (MINPACK's gtol test, cosine below 10 sqrt(eps))
    cosine = jnp.abs(g) / jnp.maximum(jnp.sqrt(d * 2.0 * cost), DIV_FLOOR)
    conv = conv | (stuck & (jnp.max(cosine) < GTOL_SQRT_EPS * jnp.sqrt(jnp.finfo(dtype).eps)))
    # stall (STALL_STEPS): accepted steps that leave the loss unchanged to the tolerance while
    # the iterate still moves; a step that changes the loss by more resets the count
    stall = jnp.where(accept, jnp.where(small_df & ~conv, s.stall + 1, 0), s.stall)
    stalled = ~conv & (stall >= STALL_STEPS)
    fac = jnp.maximum(1.0 / 3.0, 1.0 - (2.0 * rho - 1.0) ** 3)
    keep = accept & active
    new = LMState(
        u=jnp.where(accept, u_new, jnp.where(floor, s.u + dn, s.u)),
        lam=jnp.where(accept, lam * fac, lam * s.nu),
        nu=jnp.where(accept, jnp.asarray(2.0, dtype), NU_GROWTH * s.nu),
        scale=scale,
        steps=s.steps + 1,
        done=conv | stuck | stalled,
        ok=conv,
        cost=jnp.where(keep, cost_new, cost),
        A=jnp.where(keep, A_new, A),
        g=jnp.where(keep, g_new, g),
        meat=jnp.where(keep, meat_new, s.meat),
        budget=s.budget,
        limit=s.limit,
        tol=s.tol,
        stall=stall,
    )
    return jax.tree.map(lambda n, o: jnp.where(active, n, o), new, s)


def lm_chunk(problem, n_steps, group, sandwich, idx, data,
             state: LMState, fixed) -> LMState:
    """Up to ``n_steps`` batch-lm iterations on a batch (leading axis on every leaf; None: each
    lane's ``state.budget``). The batch is taken in groups of ``group`` lanes (see
    :func:`grouped`); each group runs its own while_loop, which stops as soon as all of *its*
    members are done: a converged problem costs iterations only until the slowest member of its
    group stops, not of the whole batch."""
    dq = directions(problem, data[3].shape[-1])

    def one_b(s, a, fx):
        return lanes(lambda s, a, fx: lm_step(problem, dq, sandwich, s, a, fx), 1, (s, a, fx))

    def run_group(t, a):
        s, fx = t

        def cond(c):
            k, s = c
            # the chunk length travels with the lanes (every leaf is batch-sharded), so one
            # compiled chunk serves every length of the schedule
            limit = jnp.max(s.budget) if n_steps is None else n_steps
            return (k < limit) & jnp.any(~s.done & (s.steps < s.limit))

        def body(c):
            k, s = c
            return k + 1, one_b(s, a, fx)

        return jax.lax.while_loop(cond, body, (jnp.asarray(0), s))[1]

    return grouped(run_group, (state, fixed), group, idx, data)


def optx_chunk(problem, solver, rtol, atol, n_steps, idx, data, state: LMState,
               fixed) -> LMState:
    """``n_steps`` of an optimistix solver (:func:`brdf_fit.fitting.solvers.solve`), restarted
    from the current iterate (optimistix does not expose its state between solves)."""

    def one(s, a, fx):
        prob = problem.with_fixed(fx)
        u, ok, k = solve(prob, s.u, a, solver, rtol, atol, n_steps, residuals=lambda v, aa:
                         prob.residuals_prepared(prob.unflatten(v), aa).reshape(-1))
        active = ~s.done & (s.steps < s.limit)
        new = dataclasses.replace(s, u=u, steps=s.steps + k.astype(jnp.int32), done=ok, ok=ok)
        return jax.tree.map(lambda n, o: jnp.where(active, n, o), new, s)

    return lanes(one, 1, (state, gather(data, idx), fixed))


# ----------------------------------------------------------------------------- finalisation


def finalise_one(problem, u, prep, m_eff, fixed, sandwich):
    """Physical parameters, standard errors (fit()'s estimator: pooled s^2 with sigma, the
    :data:`~brdf_fit.fitting.solvers.SANDWICH` estimator without), loss and residual rms at the
    final ``u``. The residual and its Jacobian come from one structured forward-mode pass
    (:func:`directions`) in the physical parameters; HC3's leverage of residual ``(m, c)`` is
    ``T_mc^T Q_c (J^T J)^+ Q_c^T T_mc`` (its Jacobian row through the direction map ``Q``)."""
    prob = problem.with_fixed(fixed)
    phys = prob.unflatten(u)
    flat = prob.layout.join(phys, dtype=u.dtype)
    dirs, Q = directions(problem, prep[3].shape[-1])
    r, T = tangents(problem, dirs, flat, prep, fixed, physical=True)
    if flat.shape[0]:
        A, _ = normal(T, r, Q)
        hc3 = sandwich and _solvers.SANDWICH == "HC3"  # (read when traced)
        if hc3:
            Qd = jnp.asarray(Q, r.dtype)
            bread = pinv_or_stand_in(A, jnp)
            h = jnp.einsum("amc,cap,pq,cbq,bmc->mc", T, Qd, bread, Qd, T)
            w = hc3_weights(r, h, jnp)
            meat = normal(T * w, w, Q)[0]
        else:
            bread = None
            meat = normal(T * r, r, Q)[0] if sandwich else None
        cov = covariance_normal(A, meat, jnp.sum(r * r), m_eff.astype(u.dtype),
                                dof_factor=not hc3, bread=bread)
        se = jnp.sqrt(jnp.maximum(jnp.diagonal(cov), 0.0))
        code = stderr_codes(A, jnp.all(jnp.isfinite(A)) & jnp.all(jnp.isfinite(r)), jnp)
    else:
        se = jnp.zeros(0, u.dtype)
        code = jnp.zeros(0, jnp.int32)
    loss = 0.5 * jnp.sum(r * r)
    rms = jnp.sqrt(jnp.mean(r * r))
    return phys, se, loss, rms, code


def finalise_state(problem, u, cost, A, meat, m_eff, n_res, fixed, sandwich, with_cov=False):
    """:func:`finalise_one` from batch-lm's carried quantities at the final ``u`` (no model
    evaluation): the transforms act entry by entry, ``x_i = t_i(u_i)``, so the physical
    Jacobian is ``J_u D^-1`` with ``D = diag(dx/du)`` and ``J_x^T J_x = D^-1 (J_u^T J_u) D^-1``
    (likewise the sandwich's meat), exactly; ``D`` is the forward-mode derivative of the
    transforms. A parameter pushed so far onto its bound that ``D`` underflows to 0 has a zero
    column (code 2 of :func:`~brdf_fit.fitting.problem.stderr_codes`; fit_batch reports it at
    bound, standard error NaN). The loss is
    the carried one and ``rms = sqrt(2 loss / n_res)``, ``n_res = M C``. The sandwich here is
    HC1 (no leverages without a pass over the data): the estimator of the chunked path, whose
    leverages are ~p/m (:data:`~brdf_fit.fitting.solvers.SANDWICH`). ``with_cov``: the
    covariance of the physical parameters (p, p) is returned last as well."""
    prob = problem.with_fixed(fixed)
    phys = prob.unflatten(u)
    cov = jnp.zeros((u.shape[0], u.shape[0]), u.dtype)
    if u.shape[0]:
        def flat(v):
            return prob.layout.join(prob.unflatten(v))

        D = jax.jvp(flat, (u,), (jnp.ones_like(u),))[1]
        inv = jnp.where(D != 0, 1.0 / jnp.where(D != 0, D, 1.0), 0.0)
        S = inv[:, None] * inv[None, :]
        cov = covariance_normal(A * S, meat * S if sandwich else None, 2.0 * cost, m_eff)
        se = jnp.sqrt(jnp.maximum(jnp.diagonal(cov), 0.0))
        code = stderr_codes(A * S, jnp.all(jnp.isfinite(A * S)) & jnp.isfinite(cost), jnp)
    else:
        se = jnp.zeros(0, u.dtype)
        code = jnp.zeros(0, jnp.int32)
    out = (phys, se, cost, jnp.sqrt(2.0 * cost / n_res), code)
    return (*out, cov) if with_cov else out
