"""Batch fitting: B independent problems sharing one registry model and one sample count.

    res = fit_batch(wi, wo, values, "ggx")       # wi, wo: (B, M, 3); values: (B, M, C)

The residual of problem ``b`` is :meth:`brdf_fit.fit._Problem.residuals` (same metric,
weights, sigma, ``cos_weight``, relative floor, parameter transforms) as :func:`brdf_fit.fit.fit`
builds it for that problem alone, up to rounding, so the two agree at the optimum. It is
evaluated as :meth:`~brdf_fit.fit._Problem.residuals_prepared`: the data side of the metric
(for ``log``, ``log1p(f cos)``) is computed once, not at every iteration.

**Cost of one iteration.** The residual, its Jacobian and the normal equations come from one
forward-mode pass per shared parameter plus one per *channel* parameter, not per channel
(:func:`directions`: a channel's residuals depend only on its own entry of an RGB ``f0``), and
only the ``p x p`` normal equations are kept. The data (directions and prepared metric terms)
is placed on the device once per call, and every group gathers its own lanes from it.

**The straggler problem.** Under ``vmap`` a ``while_loop`` runs until its slowest member stops:
members that have converged are masked, but still computed. In 10,000 GGX fits the median
problem needs ~9 steps and the slowest ~100 (an ``f0`` channel running to its bound of 1), so
one vmapped solve pays ``B x max(steps)`` instead of ``sum(steps)``. Three things bound it here:

- *groups*: the lanes are taken in groups of ``group`` (:data:`GROUP` = 8) problems, one group
  after another (``lax.map``), and each group runs its own while_loop, which stops when *its*
  members are done. This is also faster per step: one vmapped step over thousands of lanes
  materialises every intermediate of the residual and its tangents as a (B, M C) array, far
  larger than the caches (measured: 147 us per problem-step vmapped over 2,000 problems, 62-67
  us in groups of 8-32, see :func:`_grouped`);
- *chunks*: the solve runs ``chunk_steps`` iterations at a time; after each chunk the converged
  problems are kept and only the stragglers are gathered into a compact batch and solved on from
  where they stopped;
- *blocks*: every call takes a fixed number of lanes (the batch's bucket ``16 * 2**k``, at most
  :data:`MAX_BLOCK`), so one shape is compiled per batch-size class and the chunk length is data,
  not a static argument; padding lanes are marked done, so a group of padding costs nothing.

``benchmarks/bench_fit_batch.py`` measures this against one plain vmapped solve
(``chunk_steps=None, group=None``).

**Initial guess.** ``guess="grid"`` (default) starts the parameters without an ``init`` value
from the best of a coarse design evaluated on a subsample (:mod:`brdf_fit.guess`).

**Solvers.** ``solver="batch-lm"`` (the default) is the Levenberg-Marquardt method written here
for batches: Marquardt scaling by the running maximum of ``diag(J^T J)`` (as MINPACK), the
damping update of H. B. Nielsen ("Damping parameter in Marquardt's method", IMM-REP-1999-05,
DTU, 1999: ``lam *= max(1/3, 1 - (2 rho - 1)^3)`` on success, ``lam *= nu; nu *= 2`` on failure),
the residual and Jacobian from one forward-mode pass, the normal equations (``p x p``)
solved by Cholesky, and no step longer than ``STEP_MAX`` = 2 in the unconstrained space
(without that cap a first step from the registry default drove a logistic parameter far past
its bound, onto a plateau of zero gradient: 7-18% of 300 problems ended worse than scipy's
``least_squares``, measured; with it none, and the mean step count fell from ~26 to ~11). Its
whole state (``u``, ``lam``, ``nu``, the scaling) is carried across chunks, so chunking and
compaction do not change a single iterate. It stops when an accepted step satisfies
optimistix's Cauchy test, ``max|du / (atol + rtol |u|)| < 1`` and
``|d loss| < atol + rtol * loss``, or when the next, undamped Gauss-Newton step from the new
iterate would pass the same two tests by its quadratic model (so the step that would only
confirm convergence is not taken); or when the damping has grown past ``LAM_MAX`` (every step
rejected at machine precision), counted as converged only if the residual is orthogonal to the
Jacobian columns (cosine < 10 sqrt(eps), MINPACK's gtol test).

Any name in :data:`brdf_fit.fit.SOLVERS` (``"lm"``, ...) runs that optimistix solver through
:func:`brdf_fit.fit.solve`, the solver of :func:`fit`; optimistix keeps its state inside one
solve, so there each chunk restarts the solver from the last iterate (the damping restarts; the
optimum is the same). Measured on this 2-core CPU, one optimistix LM step cost ~4x a batch-lm
step (it linearises and evaluates the residual separately and solves by QR).

**Sharding.** With ``shard=True`` the batch axis is laid out over a 1-D
:class:`jax.sharding.Mesh` of ``jax.devices()`` with ``NamedSharding(mesh, P("batch"))`` and
every call runs under ``jax.shard_map``: each device iterates its own groups, so a device stops
when *its* members are done. Blocks are multiples of ``group x`` the device count. On a CPU,
``XLA_FLAGS=--xla_force_host_platform_device_count=N`` (set before JAX starts) gives N host
devices, one per core: the groups of one device run one after another on one core, so this is
how a batch uses all cores. The default ``shard=None`` shards whenever more than one device is
visible.

History: before the groups (one vmapped while_loop over the whole shard), batches of 2,000 and
10,000 problems hung on 2 host devices of the 2-core development VM (every thread in a futex
wait) and 256 problems disagreed with the unsharded run (max |f0| difference 0.96); with the
grouped loops 10,000 problems run sharded and agree with the unsharded results to 3e-9 (the
last digits differ because the two compile to different fusions; see the benchmark).
"""

from __future__ import annotations

import dataclasses
import math
import time
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh, NamedSharding
from jax.sharding import PartitionSpec as P

from brdf_fit import registry
from brdf_fit.fitting import guess as _guess
from brdf_fit.fitting.single import (
    METRICS,
    RELATIVE_FLOOR,
    SOLVERS,
    FitError,
    _Problem,
    _transform,
    at_bound,
    covariance_normal,
    solve,
)

__all__ = ["BatchFitResult", "fit_batch", "BATCH_SOLVERS"]

BATCH_SOLVERS = ("batch-lm", *SOLVERS)
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
#: Longest step of batch-lm in the unconstrained space (see _lm_chunk).
STEP_MAX = 2.0
#: Smallest straggler bucket; buckets grow by BUCKET_GROWTH (16, 32, 64, ...): a lane costs the
#: same whether it is active or padding, so a coarse ladder (x4) paid up to 4x for a chunk.
MIN_BUCKET = 16
BUCKET_GROWTH = 2
#: Largest number of lanes in one compiled call: a batch is solved in blocks of this many
#: lanes (10,000 problems: 10 blocks of 1024), so one shape is compiled per batch size class.
MAX_BLOCK = 1024
#: Iterations per chunk for ``chunk_steps="auto"``: short chunks first (a chunk costs its lane
#: count times its slowest member's steps; from the grid guess the median GGX problem needs 5
#: steps, the p90 7 and the p99 12, measured on 10,000), then longer ones for the few
#: stragglers. Measured against (6, 3, 3, 4, 8, 16, 32): 61,900 lane-steps instead of 67,900.
CHUNK_SCHEDULE = (5, 2, 2, 4, 8, 16, 32)
#: Lanes per group (see _grouped): each group of problems is stepped by its own while_loop.
GROUP = 8


@dataclasses.dataclass
class BatchFitResult:
    """Outcome of :func:`fit_batch`; every array has a leading batch axis ``B``."""

    model_name: str
    params: dict[str, np.ndarray]  # (B, ...) per registry parameter (fixed ones included)
    stderr: dict[str, np.ndarray]  # (B, ...) per free parameter
    converged: np.ndarray  # (B,) bool
    steps: np.ndarray  # (B,) int: solver iterations (summed over chunks)
    loss: np.ndarray  # (B,) 0.5 * sum of squared residuals (as FitResult.loss)
    residual_rms: np.ndarray  # (B,)
    n_samples: np.ndarray  # (B,) samples used (weight > 0 in some channel)
    n_params: int
    metric: str
    solver: str
    seconds: float
    rounds: list = dataclasses.field(default_factory=list)  # per chunk: lanes, active, seconds
    n_devices: int = 1
    #: per free parameter, (B, ...) bool: the fitted value sits at an end of its interval
    #: (:func:`brdf_fit.fit.at_bound`; its standard error means nothing there)
    at_bound: dict = dataclasses.field(default_factory=dict)

    @property
    def batch_size(self) -> int:
        return int(self.converged.shape[0])

    def lane_steps(self) -> int:
        """Solver iterations paid for: per group, its lane count times the iterations its
        while_loop ran, summed over groups and chunks (padding included)."""
        return int(sum(r["lane_steps"] for r in self.rounds))

    def to_dict(self) -> dict:
        return {
            "model": self.model_name,
            "params": {k: np.asarray(v).tolist() for k, v in self.params.items()},
            "stderr": {k: np.asarray(v).tolist() for k, v in self.stderr.items()},
            "converged": self.converged.tolist(),
            "steps": self.steps.tolist(),
            "loss": self.loss.tolist(),
            "residual_rms": self.residual_rms.tolist(),
            "n_samples": self.n_samples.tolist(),
            "n_params": self.n_params,
            "metric": self.metric,
            "solver": self.solver,
            "seconds": round(self.seconds, 4),
            "rounds": self.rounds,
            "n_devices": self.n_devices,
            "at_bound": {k: np.asarray(v).tolist() for k, v in self.at_bound.items()},
        }


# ----------------------------------------------------------------------------- batch-lm


def directions(problem, n_channels: int):
    """Tangent directions of the structured forward-mode Jacobian of ``problem`` and the map
    ``Q`` (C, k, p) from directions to the columns of the flat parameter vector.

    A channel parameter (registry ``channels``, shape (C,)) acts on each channel's residuals
    only through its own entry (the assumption :mod:`brdf_fit.guess` also makes; tested for
    every registry model in ``tests/test_fit_batch.py``), so its C Jacobian columns are block
    diagonal and *one* tangent of ones gives all of them: tangent ``a`` of residual ``(m, c)``
    is column ``Q[c, a]``. A shared parameter takes one direction per entry. GGX with RGB f0:
    2 forward-mode passes instead of jacfwd's 4, and the f0 pass carries no tangent through D
    and G (the other parameters are closed over, so their tangents are symbolic zeros).
    Measured on this CPU (GGX, 300 samples, RGB, groups of 8): residual, Jacobian and normal
    equations 36 us per problem against 62 us with jacfwd on the flattened residual.

    Returns ``(dirs, Q)``: ``dirs`` a tuple of ``(name, j)``, ``j`` None for a channel
    parameter's tangent of ones, else the flat entry of a shared parameter."""
    dirs, cols = [], []
    k = 0
    for name, shape in zip(problem.free, problem.shapes, strict=True):
        size = int(np.prod(shape)) if shape else 1
        if problem.entry.param(name).channels and tuple(shape) == (n_channels,):
            dirs.append((name, None))
            cols.append([k + c for c in range(n_channels)])
        else:
            for j in range(size):
                dirs.append((name, j))
                cols.append([k + j] * n_channels)
        k += size
    Q = np.zeros((n_channels, len(dirs), k))
    for a, cs in enumerate(cols):
        for c, col in enumerate(cs):
            Q[c, a, col] = 1.0
    return tuple(dirs), Q


def _tangents(problem, dirs, x, prep, fixed, physical=False):
    """Residuals ``r`` (M, C) at the flat ``x`` (unconstrained, or physical with ``physical``)
    and their tangents ``T`` (k, M, C) along :func:`directions`."""
    prob = dataclasses.replace(problem, fixed=fixed)
    parts = prob.split(x)

    def res(pp):
        params = {**prob.fixed, **pp} if physical else prob.physical(pp)
        return prob.residuals_prepared(params, prep)

    r = res(parts)
    T = []
    for name, j in dirs:
        v = parts[name]
        t = (jnp.ones_like(v) if j is None
             else jnp.zeros(v.size, v.dtype).at[j].set(1.0).reshape(v.shape))
        T.append(jax.jvp(lambda z, name=name: res({**parts, name: z}), (v,), (t,))[1])
    T = jnp.stack(T) if T else jnp.zeros((0, *r.shape), r.dtype)
    return r, T


def _normal(T, r, Q):
    """``J^T J`` and ``J^T r`` from the tangents (:func:`directions`)."""
    Q = jnp.asarray(Q, r.dtype)
    G = jnp.einsum("amc,bmc->cab", T, T)
    h = jnp.einsum("amc,mc->ca", T, r)
    return jnp.einsum("cap,cab,cbq->pq", Q, G, Q), jnp.einsum("cap,ca->p", Q, h)


def _quad(problem, dq, u, prep, fx, sandwich):
    """Loss and the normal-equation quantities ``(0.5 |r|^2, J^T J, J^T r, J^T diag(r^2) J)``
    at ``u`` (the last, the sandwich estimator's meat, zeros unless ``sandwich``): only these
    ``p x p`` quantities are carried between iterations, never the ``(M C, p)`` Jacobian
    (copying it every step made the loop memory-bound), and the standard errors come from the
    carried ones at the end (:func:`_finalise_state`). ``dq``: :func:`directions`."""
    dirs, Q = dq
    r, T = _tangents(problem, dirs, u, prep, fx)
    A, g = _normal(T, r, Q)
    meat = _normal(T * r, r, Q)[0] if sandwich else jnp.zeros_like(A)
    return 0.5 * jnp.sum(r * r), A, g, meat


def _grouped(fn, tree, group, idx=None, data=None):
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
        out = jax.lax.map(lambda t: fn(t[0], jax.tree.map(lambda x: x[t[1]], data)),
                          (split, rows(idx)))
    return jax.tree.map(lambda x: x.reshape((k * group, *x.shape[2:])), out)


def _lm_init(problem, group, sandwich, idx, data, u, fixed):
    """The carried quad (see :func:`_quad`) at the starting point of every lane."""
    dq = directions(problem, data[3].shape[-1])

    def g(t, a):
        uu, fx = t
        return jax.vmap(lambda x, y, z: _quad(problem, dq, x, y, z, sandwich))(uu, a, fx)
    return _grouped(g, (u, fixed), group, idx, data)


def _lm_chunk(problem, rtol, atol, max_steps, n_steps, group, sandwich, idx, data, state,
              fixed):
    """Up to ``n_steps`` batch-lm iterations on a batch (leading axis on every leaf). The batch
    is taken in groups of ``group`` lanes (see :func:`_grouped`); each group runs its own
    while_loop, which stops as soon as all of *its* members are done: a converged problem costs
    iterations only until the slowest member of its group stops, not of the whole batch."""
    dtype = state["u"].dtype
    dq = directions(problem, data[3].shape[-1])

    def quad(u, a, fx):
        return _quad(problem, dq, u, a, fx, sandwich)

    def one(s, a, fx):
        active = ~s["done"] & (s["steps"] < max_steps)
        cost, A, g = s["cost"], s["A"], s["g"]
        d = jnp.diagonal(A)
        if MARQUARDT_SCALING:
            scale = jnp.maximum(s["scale"], d)
            scale = jnp.maximum(scale, SCALE_FLOOR * jnp.max(scale))
        else:
            scale = jnp.ones_like(d)
        lam = jnp.where(s["lam"] < 0, LM_TAU * jnp.max(d) / jnp.max(scale), s["lam"])
        M = A + jnp.diag(lam * scale)
        L = jnp.linalg.cholesky(M)
        du = -jax.scipy.linalg.cho_solve((L, True), g)
        du = jnp.where(jnp.all(jnp.isfinite(du)), du, jnp.zeros_like(du))
        # safeguard: no step longer than STEP_MAX in the unconstrained space (a logistic
        # parameter pushed far past its bound lands on a plateau with zero gradient)
        du = du * jnp.minimum(1.0, STEP_MAX / jnp.maximum(jnp.sqrt(jnp.sum(du * du)), 1e-300))
        u_new = s["u"] + du
        cost_new, A_new, g_new, meat_new = quad(u_new, a, fx)
        pred = -jnp.dot(g, du) - 0.5 * jnp.dot(du, A @ du)
        actual = cost - cost_new
        rho = jnp.where(pred > 0, actual / jnp.where(pred > 0, pred, 1.0), -1.0)
        accept = jnp.isfinite(cost_new) & (actual >= 0) & (rho > 0)
        small_step = jnp.max(jnp.abs(du) / (atol + rtol * jnp.abs(s["u"]))) < 1.0
        small_df = jnp.abs(actual) < atol + rtol * cost
        # the same two tests on the *next*, undamped Gauss-Newton step from u_new, predicted by
        # its quadratic model (the Gauss-Newton decrement 0.5 g^T A^-1 g estimates how far the
        # loss is above the local minimum; Boyd & Vandenberghe 2004, section 9.5.1): when that
        # step would pass, u_new is converged and the step that would only confirm it is not
        # taken (measured, 10,000 GGX fits: mean 8.2 -> 5.6 steps, losses equal to 6e-12)
        dn = -jax.scipy.linalg.cho_solve((jnp.linalg.cholesky(A_new), True), g_new)
        newton = (jnp.all(jnp.isfinite(dn))
                  & (jnp.max(jnp.abs(dn) / (atol + rtol * jnp.abs(u_new))) < 1.0)
                  & (-0.5 * jnp.dot(g_new, dn) < atol + rtol * cost_new))
        conv = (accept & ((small_step & small_df) | newton)) | (cost == 0)
        stuck = ~accept & (lam * s["nu"] > LAM_MAX * jnp.max(d))
        # stuck at machine precision: a minimum if the residual is orthogonal to the Jacobian
        # columns (MINPACK's gtol test, cosine below 10 sqrt(eps))
        cosine = jnp.abs(g) / jnp.maximum(jnp.sqrt(d * 2.0 * cost), 1e-300)
        conv = conv | (stuck & (jnp.max(cosine) < 10.0 * jnp.sqrt(jnp.finfo(dtype).eps)))
        fac = jnp.maximum(1.0 / 3.0, 1.0 - (2.0 * rho - 1.0) ** 3)
        keep = accept & active
        new = {
            "u": jnp.where(accept, u_new, s["u"]),
            "lam": jnp.where(accept, lam * fac, lam * s["nu"]),
            "nu": jnp.where(accept, jnp.asarray(2.0, dtype), NU_GROWTH * s["nu"]),
            "scale": scale,
            "steps": s["steps"] + 1,
            "done": conv | stuck,
            "ok": conv,
            "cost": jnp.where(keep, cost_new, cost),
            "A": jnp.where(keep, A_new, A),
            "g": jnp.where(keep, g_new, g),
            "meat": jnp.where(keep, meat_new, s["meat"]),
        }
        if "budget" in s:
            new["budget"] = s["budget"]
        return jax.tree.map(lambda n, o: jnp.where(active, n, o), new, s)

    one_b = jax.vmap(one)

    def run_group(t, a):
        s, fx = t

        def cond(c):
            k, s = c
            # the chunk length travels with the lanes (every leaf is batch-sharded), so one
            # compiled chunk serves every length of the schedule
            limit = jnp.max(s["budget"]) if n_steps is None else n_steps
            return (k < limit) & jnp.any(~s["done"] & (s["steps"] < max_steps))

        def body(c):
            k, s = c
            return k + 1, one_b(s, a, fx)

        return jax.lax.while_loop(cond, body, (jnp.asarray(0), s))[1]

    return _grouped(run_group, (state, fixed), group, idx, data)


def _optx_chunk(problem, solver, rtol, atol, max_steps, n_steps, idx, data, state, fixed):
    """``n_steps`` of an optimistix solver (:func:`brdf_fit.fit.solve`), restarted from the
    current iterate (optimistix does not expose its state between solves)."""

    def one(s, a, fx):
        prob = dataclasses.replace(problem, fixed=fx)
        u, ok, k = solve(prob, s["u"], a, solver, rtol, atol, n_steps, residuals=lambda v, aa:
                         prob.residuals_prepared(prob.unflatten(v), aa).reshape(-1))
        active = ~s["done"] & (s["steps"] < max_steps)
        new = {**s, "u": u, "steps": s["steps"] + k.astype(jnp.int32), "done": ok, "ok": ok}
        return jax.tree.map(lambda n, o: jnp.where(active, n, o), new, s)

    return jax.vmap(one)(state, jax.tree.map(lambda x: x[idx], data), fixed)


def _candidate_losses(problem, cands, prep, fixed, lay, chan_of):
    """Per-channel losses ``(n', C)`` (``0.5 sum r^2`` over the samples) of the candidate
    vectors ``cands`` (n', p) of :func:`brdf_fit.guess.design` on prepared data ``prep``.

    For a product design (``lay = (n_shared, n_level)``) one model evaluation per shared point
    serves all its channel levels: level ``l`` of channel ``c`` becomes the pseudo-channel
    ``l C + c`` (every channel parameter and the per-channel data tiled ``n_level`` times). It
    rests on the channel separability of :func:`directions` (tested for every registry model
    against candidate-by-candidate evaluation); the shared part of the model (a microfacet
    model's D and G) is then computed ``n_shared`` times instead of ``n_shared n_level``
    (measured: 1.02 s -> 0.66 s for 10,000 GGX problems, 24 candidates x 64 samples)."""
    prob = dataclasses.replace(problem, fixed=fixed)

    def each():
        return 0.5 * jax.vmap(lambda uu: jnp.sum(
            prob.residuals_prepared(prob.unflatten(uu), prep) ** 2, axis=0))(cands)

    if lay is None:
        return each()
    try:
        return _pseudo_channel_losses(problem, cands, prep, fixed, lay, chan_of)
    except (TypeError, ValueError):
        # a model with per-channel constants of its own (HTSG's wavelengths) cannot take
        # n_level C channels: its shapes do not broadcast, which fails here, at trace time
        return each()


def _pseudo_channel_losses(problem, cands, prep, fixed, lay, chan_of):
    C = prep[3].shape[-1]
    ns, nl = lay
    c3 = cands.reshape(ns, nl, -1)
    chan = np.asarray(chan_of) >= 0
    wi, wo, mul, gf, scale = prep
    def tile(x):
        return x if x is None or x.shape[-1] != C else jnp.tile(x, (1, nl))

    prep_t = (wi, wo, tile(mul), tile(gf), tile(scale))
    fixed_t = {k: (jnp.tile(v, nl) if problem.entry.param(k).channels and v.shape == (C,)
                   else v) for k, v in fixed.items()}
    prob_t = dataclasses.replace(problem, fixed=fixed_t)

    is_chan = {n: bool(np.ravel(v)[0]) for n, v in problem.split(chan).items()}

    def one(rows):  # (nl, p): one shared point, its nl levels
        levels = jax.vmap(prob_t.split)(rows)  # {name: (nl, ...)}
        # a channel parameter's (nl, C) levels become the pseudo-channels l C + c; a shared
        # one is the same in every level
        parts = {n: v.reshape(-1) if is_chan[n] else v[0] for n, v in levels.items()}
        r = prob_t.residuals_prepared(prob_t.physical(parts), prep_t)
        return 0.5 * jnp.sum(r * r, axis=0).reshape(nl, C)

    return jax.vmap(one)(c3).reshape(ns * nl, C)


# ----------------------------------------------------------------------------- finalisation


def _finalise_one(problem, u, prep, m_eff, fixed, sandwich):
    """Physical parameters, standard errors (fit()'s estimator: pooled s^2 with sigma, HC1
    sandwich without), loss and residual rms at the final ``u``. The residual and its Jacobian
    come from one structured forward-mode pass (:func:`directions`) in the physical
    parameters."""
    prob = dataclasses.replace(problem, fixed=fixed)
    phys = prob.unflatten(u)
    free = prob.free
    flat = jnp.concatenate([jnp.ravel(phys[n]) for n in free]) if free else jnp.zeros(0, u.dtype)
    dirs, Q = directions(problem, prep[3].shape[-1])
    r, T = _tangents(problem, dirs, flat, prep, fixed, physical=True)
    if flat.shape[0]:
        A, _ = _normal(T, r, Q)
        meat = _normal(T * r, r, Q)[0] if sandwich else None
        cov = covariance_normal(A, meat, jnp.sum(r * r), m_eff.astype(u.dtype))
        se = jnp.sqrt(jnp.maximum(jnp.diagonal(cov), 0.0))
    else:
        se = jnp.zeros(0, u.dtype)
    loss = 0.5 * jnp.sum(r * r)
    rms = jnp.sqrt(jnp.mean(r * r))
    return phys, se, loss, rms


def _finalise_state(problem, u, cost, A, meat, m_eff, n_res, fixed, sandwich):
    """:func:`_finalise_one` from batch-lm's carried quantities at the final ``u`` (no model
    evaluation): the transforms act entry by entry, ``x_i = t_i(u_i)``, so the physical
    Jacobian is ``J_u D^-1`` with ``D = diag(dx/du)`` and ``J_x^T J_x = D^-1 (J_u^T J_u) D^-1``
    (likewise the sandwich's meat), exactly; ``D`` is the forward-mode derivative of the
    transforms. A parameter pushed so far onto its bound that ``D`` underflows to 0 gets the
    standard error 0 (it is flagged ``at_bound``; its error means nothing there). The loss is
    the carried one and ``rms = sqrt(2 loss / n_res)``, ``n_res = M C``."""
    prob = dataclasses.replace(problem, fixed=fixed)
    phys = prob.unflatten(u)
    if u.shape[0]:
        def flat(v):
            x = prob.unflatten(v)
            return jnp.concatenate([jnp.ravel(x[n]) for n in prob.free])

        D = jax.jvp(flat, (u,), (jnp.ones_like(u),))[1]
        inv = jnp.where(D != 0, 1.0 / jnp.where(D != 0, D, 1.0), 0.0)
        S = inv[:, None] * inv[None, :]
        cov = covariance_normal(A * S, meat * S if sandwich else None, 2.0 * cost, m_eff)
        se = jnp.sqrt(jnp.maximum(jnp.diagonal(cov), 0.0))
    else:
        se = jnp.zeros(0, u.dtype)
    return phys, se, cost, jnp.sqrt(2.0 * cost / n_res)


# ----------------------------------------------------------------------------- driver


def _bucket(n: int, unit: int) -> int:
    b = MIN_BUCKET
    while b < n:
        b *= BUCKET_GROWTH
    return int(math.ceil(b / unit) * unit)


class _Runner:
    """Jitted (optionally shard_mapped) chunk and finalise functions, cached per shape."""

    def __init__(self, problem, solver, rtol, atol, max_steps, shard, group, sigma):
        self.devices = jax.devices() if shard else jax.devices()[:1]
        self.ndev = len(self.devices)
        self.mesh = Mesh(np.asarray(self.devices), ("batch",)) if self.ndev > 1 else None
        self.group = group
        self.solver = solver
        #: lane counts are multiples of this (every device holds whole groups)
        self.unit = (group or 1) * self.ndev
        if solver == "batch-lm":
            def chunk(n_steps, i, d, s, fx):
                return _lm_chunk(problem, rtol, atol, max_steps, n_steps, group, not sigma,
                                 i, d, s, fx)
        else:
            def chunk(n_steps, i, d, s, fx):
                return _optx_chunk(problem, solver, rtol, atol, max_steps, n_steps, i, d, s, fx)

        def fin(i, d, u, m_eff, fx):
            sandwich = not sigma

            def one(t, a):
                uu, mm, ff = t
                return jax.vmap(lambda x, y, z, w: _finalise_one(
                    problem, x, y, z, w, sandwich))(uu, a, mm, ff)
            return _grouped(one, (u, m_eff, fx), group, i, d)

        def init(i, d, u, fx):
            return _lm_init(problem, group, not sigma, i, d, u, fx)

        def fin_state(u, cost, A, meat, m_eff, n_res, fx):
            return jax.vmap(lambda *t: _finalise_state(problem, *t, not sigma))(
                u, cost, A, meat, m_eff, n_res, fx)
        self._fin_state = jax.jit(fin_state)

        self._guess = {}
        self._problem = problem
        self._sigma = sigma
        self._prepare = self._sub = None

        self._chunk = {}
        self._raw_chunk = chunk
        self._fin = self._compile(fin, 5)
        self._init = self._compile(init, 4)

    def _compile(self, fn, n_args):
        """jit ``fn(idx, data, *lanes)``; on a mesh under shard_map with ``data`` replicated
        and every other argument split along the batch."""
        if self.mesh is None:
            return jax.jit(fn)
        spec = P("batch")
        specs = (spec, P(), *[spec] * (n_args - 2))
        return jax.jit(jax.shard_map(fn, mesh=self.mesh, in_specs=specs, out_specs=spec,
                                     check_vma=False))

    def chunk(self, n_steps):
        if self.solver == "batch-lm":  # the length is data (state["budget"]), not static
            n_steps = None
        fn = self._chunk.get(n_steps)
        if fn is None:
            fn = self._chunk[n_steps] = self._compile(
                lambda i, d, s, fx: self._raw_chunk(n_steps, i, d, s, fx), 4)
        return fn

    def put(self, tree):
        if self.mesh is None:
            return jax.tree.map(jnp.asarray, tree)
        sh = NamedSharding(self.mesh, P("batch"))
        return jax.tree.map(lambda x: jax.device_put(x, sh), tree)

    def prepare(self, raw):
        """The batch's data (numpy ``(wi, wo, f, w, sigma, floor)``), prepared on the device
        once (:meth:`brdf_fit.fit._Problem.prepare`; replicated over the mesh): every call
        gathers its lanes from it inside its groups (:func:`_grouped`)."""
        sh = None if self.mesh is None else NamedSharding(self.mesh, P())
        raw = jax.tree.map(lambda x: jax.device_put(x, sh), raw)
        if self._prepare is None:  # (wi and wo pass through: not copied by the jit)
            self._prepare = jax.jit(lambda t: self._problem.prepare(t, jnp)[2:],
                                    out_shardings=sh)
        return (*raw[:2], *self._prepare(raw))

    def subsample(self, data, sub):
        """The samples ``sub`` of every problem of prepared ``data`` (the guess's subsample)."""
        if self._sub is None:
            sh = None if self.mesh is None else NamedSharding(self.mesh, P())
            self._sub = jax.jit(lambda t, i: jax.tree.map(lambda x: x[:, i], t),
                                out_shardings=sh)
        return self._sub(data, jnp.asarray(sub))

    def finalise(self, *args):
        return self._fin(*args)

    def init(self, *args):
        return self._init(*args)

    def guess(self, lay, chan_of):
        """Compiled: per lane, the start :func:`brdf_fit.guess.pick` chooses from its
        candidates (losses per channel on the subsample ``d[0]``) and, for batch-lm, the
        carried quantities there on the full data ``d[1]`` (:func:`_quad`), in the same pass
        over each group (the same work as two calls, one compilation fewer)."""
        key = (lay, tuple(int(c) for c in chan_of))
        fn = self._guess.get(key)
        if fn is None:
            problem, group = self._problem, self.group
            lm = self.solver == "batch-lm"
            sandwich = not self._sigma

            def best(c, a, fx):
                L = _candidate_losses(problem, c, a, fx, lay, chan_of)
                return _guess.pick(jnp, c, L, lay, chan_of)

            def one(t, a):
                c, fx = t
                u = jax.vmap(best)(c, a[0], fx)
                if not lm:
                    return u, ()
                dq = directions(problem, a[1][3].shape[-1])
                return u, jax.vmap(lambda x, y, z: _quad(problem, dq, x, y, z, sandwich))(
                    u, a[1], fx)

            def guess(i, d, c, fx):
                return _grouped(one, (c, fx), group, i, d)

            fn = self._guess[key] = self._compile(guess, 4)
        return fn


_RUNNERS: dict = {}
#: Runners (and so their compiled chunks) kept for reuse by later calls with the same static
#: problem; the oldest is dropped beyond this many.
MAX_RUNNERS = 8


def _runner(problem, solver, rtol, atol, max_steps, shard, group, sigma):
    key = (problem.entry.name, problem.free, problem.shapes, problem.transforms, problem.metric,
           problem.cos_weight, solver, float(rtol), float(atol), int(max_steps), shard,
           len(jax.devices()), group, sigma)
    r = _RUNNERS.get(key)
    if r is None:
        if len(_RUNNERS) >= MAX_RUNNERS:
            _RUNNERS.pop(next(iter(_RUNNERS)))
        r = _RUNNERS[key] = _Runner(problem, solver, rtol, atol, max_steps, shard, group, sigma)
    return r


def _take(tree, idx):
    return jax.tree.map(lambda x: x[idx], tree)


def _batched_values(entry, spec, B, C, what):
    """Per-problem values (B, ...) of registry parameters from a dict of shared or per-problem
    values (a channel parameter: scalar or (C,) shared, (B, C) per problem; a scalar
    parameter: scalar shared, (B,) per problem)."""
    out = {}
    for name, v in spec.items():
        p = entry.param(name)
        a = np.asarray(v, float)
        per = (a.ndim == 2) if p.channels else (a.ndim == 1)
        if per:
            if a.shape[0] != B:
                raise FitError(f"{what}[{name!r}] has {a.shape[0]} rows for {B} problems")
            if p.channels and a.shape[1] != C:
                a = np.repeat(a.mean(axis=1, keepdims=True), C, axis=1)
        else:
            if p.channels:
                a = np.full(C, float(a)) if a.ndim == 0 else a
                if a.shape[0] != C:
                    a = np.full(C, float(np.mean(a)))
            a = np.broadcast_to(a, (B, *a.shape))
        for row in (a[0], a[-1]):
            p.validate(row, entry.name)
        out[name] = np.ascontiguousarray(a)
    return out


def _blocked(runner, fn, idx, block, inputs, data):
    """``fn`` on the lanes ``idx`` in consecutive blocks of ``block`` lanes (the last one padded
    by repeating a real lane), so that every call has the same shape and compiles once;
    ``inputs(pad, n)`` builds the (numpy) argument trees of a block from its lane indices
    ``pad`` of which the first ``n`` are real. Returns the outputs of the real lanes, in order,
    as numpy arrays. The blocks are dispatched before any result is read (JAX runs them
    asynchronously)."""
    outs = []
    for s0 in range(0, idx.size, block):
        part = idx[s0:s0 + block]
        n = part.size
        pad = np.concatenate([part, np.full(block - n, part[0])])
        outs.append((fn(runner.put(pad.astype(np.int32)), data,
                        *(runner.put(a) for a in inputs(pad, n))), n))
    res = [jax.tree.map(lambda x, n=n: np.asarray(x)[:n], o) for o, n in outs]
    return jax.tree.map(lambda *xs: np.concatenate(xs), *res)


def _run_chunks(runner, state, data, fixed, schedule, max_steps, solver, single, rounds,
                block, progress=None):
    """Solve chunk after chunk, compacting the unfinished problems between chunks (in blocks
    of ``block`` lanes); ``state`` (numpy arrays, leading axis B) is updated in place and one
    record per chunk is appended to ``rounds``."""
    B = state["u"].shape[0]
    idx = np.arange(B)
    k_chunk = 0
    while True:
        active = idx[~state["done"] & (state["steps"] < max_steps)]
        if active.size == 0:
            break
        n = active.size
        n_steps = schedule[min(k_chunk, len(schedule) - 1)]
        if solver != "batch-lm":  # restarted solves: never run past a member's budget
            n_steps = int(min(n_steps, max_steps - state["steps"][active].max()))
            n_steps = max(n_steps, 1)
        ts = time.perf_counter()
        before = state["steps"][active].copy()

        def inputs(pad, m, n_steps=n_steps):
            sub = _take(state, pad)
            sub["done"] = sub["done"].copy()
            sub["done"][m:] = True  # padding lanes: a group of padding alone stops at once
            sub["budget"] = np.full(pad.size, n_steps, np.int32)
            return sub, {k: v[pad] for k, v in fixed.items()}

        # without groups the whole block is one while_loop: shrink it to the stragglers'
        # bucket (one more compile per bucket), else compaction would save nothing
        blk = block if runner.group else min(block, _bucket(n, runner.unit))
        out = _blocked(runner, runner.chunk(n_steps), active, blk, inputs, data)
        for k in state:
            state[k][active] = out[k]
        lanes = int(math.ceil(n / blk) * blk)
        # iterations each group's while_loop ran (its slowest lane), paid by all its lanes
        ran = np.zeros(lanes, int)
        ran[:n] = state["steps"][active] - before
        g = runner.group or blk
        per_group = ran.reshape(-1, g).max(axis=1)
        rec = {"lanes": lanes, "active": int(n), "steps": int(per_group.max()),
               "lane_steps": int(per_group.sum() * g),
               "seconds": round(time.perf_counter() - ts, 4)}
        rounds.append(rec)
        k_chunk += 1
        if progress is not None:
            progress(int(np.sum(state["done"] | (state["steps"] >= max_steps))), B,
                     f"chunk {k_chunk}")
        if single:
            break


def fit_batch(
    wi,
    wo,
    values,
    model: str,
    weight=None,
    sigma=None,
    fix: dict | None = None,
    init: dict | None = None,
    metric: str = "log",
    solver: str = "batch-lm",
    cos_weight: bool = False,
    max_zenith_deg: float | None = None,
    max_steps: int = 256,
    rtol: float = 1e-10,
    atol: float = 1e-10,
    chunk_steps: int | str | None = "auto",
    group: int | None = GROUP,
    guess: str = "grid",
    shard: bool | None = None,
    progress=None,
    dtype: Any = None,
) -> BatchFitResult:
    """Fit registry model ``model`` to B datasets at once.

    ``wi``, ``wo``: (B, M, 3); ``values``, ``weight``, ``sigma``: (B, M, C) (or (B, M)).
    ``fix`` / ``init``: parameter values shared by all problems or per problem (leading axis
    B; see :func:`_batched_values`). ``max_zenith_deg`` masks samples (weight 0) instead of
    dropping them, so the sample count stays M. ``chunk_steps``: iterations per chunk before
    the stragglers are compacted (``"auto"``: the lengths of :data:`CHUNK_SCHEDULE`, then its
    last; None: one chunk of ``max_steps``). ``group``: lanes per while_loop (None: the whole
    block; with ``chunk_steps=None`` that is one plain vmapped solve). ``guess``: ``"grid"``
    or ``"none"`` (see :mod:`brdf_fit.guess`); ``max_steps=0`` returns the start itself.
    ``shard``: lay the batch over all ``jax.devices()`` (default: when there are several).
    ``progress``: called as ``progress(finished, B, stage)`` at the start and after every
    chunk (the CLI's progress bar). ``dtype``: of the arrays and the solve (default: JAX's
    default float).
    """

    t0 = time.perf_counter()
    entry = registry.get(model)
    if metric not in METRICS:
        raise FitError(f"unknown metric {metric!r}; valid metrics: {', '.join(METRICS)}")
    if solver not in BATCH_SOLVERS:
        raise FitError(f"unknown solver {solver!r}; valid solvers: {', '.join(BATCH_SOLVERS)}")
    if guess not in _guess.GUESSES:
        raise FitError(f"unknown guess {guess!r}; valid: {', '.join(_guess.GUESSES)}")
    dtype = jnp.zeros(()).dtype if dtype is None else jnp.dtype(dtype)
    wi = np.asarray(wi, float)
    wo = np.asarray(wo, float)
    f = np.asarray(values, float)
    if f.ndim == 2:
        f = f[..., None]
    if wi.ndim != 3 or wi.shape[-1] != 3 or wo.shape != wi.shape or f.shape[:2] != wi.shape[:2]:
        raise FitError(f"expected wi, wo (B, M, 3) and values (B, M, C); got {wi.shape}, "
                       f"{wo.shape}, {f.shape}")
    B, M, C = f.shape
    w = None if weight is None else np.broadcast_to(
        np.asarray(weight, float).reshape(f.shape[:2] + (-1,)), f.shape).copy()
    sg = None if sigma is None else np.broadcast_to(
        np.asarray(sigma, float).reshape(f.shape[:2] + (-1,)), f.shape).copy()
    if max_zenith_deg is not None:
        cz = math.cos(math.radians(max_zenith_deg))
        keep = (wi[..., 2] >= cz) & (wo[..., 2] >= cz)
        w = np.where(keep[..., None], 1.0 if w is None else w, 0.0)
    if not np.all(np.isfinite(f)) or (w is not None and np.any(w < 0)):
        raise FitError("values must be finite and weights non-negative")
    floor = RELATIVE_FLOOR * np.maximum(np.max(np.abs(f), axis=(1, 2)), 1e-300)
    fix = dict(fix or {})
    init = dict(init or {})
    for k in (*fix, *init):
        entry.param(k)
    defaults = entry.defaults()
    start = _batched_values(entry, {p.name: init.get(p.name, defaults[p.name])
                                    for p in entry.params if p.name not in fix}, B, C, "init")
    fixed = _batched_values(entry, fix, B, C, "fix")
    free = tuple(n for n in entry.param_names if n in start)
    problem = _Problem(
        entry=entry,
        free=free,
        shapes=tuple(start[n].shape[1:] for n in free),
        transforms=tuple(_transform(entry.param(n)) for n in free),
        fixed={},
        metric=metric,
        cos_weight=cos_weight,
    )
    u0 = (np.concatenate([tr.inverse(start[n]).reshape(B, -1)
                          for n, tr in zip(free, problem.transforms, strict=True)], axis=1)
          if free else np.zeros((B, 0)))
    raw = tuple(None if a is None else a.astype(dtype, copy=False)
                for a in (wi, wo, f, w, sg, floor))
    if w is None:
        m_eff, nused = np.full(B, M * C, dtype), np.full(B, M)
    else:
        m_eff = np.sum(w.reshape(B, -1) > 0, axis=1).astype(dtype)
        nused = np.sum(np.any(w > 0, axis=-1), axis=1)
    fixed = {k: v.astype(dtype) for k, v in fixed.items()}

    if shard is None:
        shard = len(jax.devices()) > 1
    p = u0.shape[1]
    state = {
        "u": u0.astype(dtype),
        "lam": np.full(B, -1.0, dtype),
        "nu": np.full(B, 2.0, dtype),
        "scale": np.zeros((B, p), dtype),
        "steps": np.zeros(B, np.int32),
        "done": np.zeros(B, bool),
        "ok": np.zeros(B, bool),
    }
    if chunk_steps == "auto":
        schedule = CHUNK_SCHEDULE
    elif chunk_steps is None:
        schedule = (max_steps,)
    elif isinstance(chunk_steps, int | np.integer) and not isinstance(chunk_steps, bool):
        schedule = (int(chunk_steps),)
    else:
        raise FitError(f"chunk_steps must be 'auto', None or an int, got {chunk_steps!r}")
    schedule = tuple(max(1, min(int(c), max_steps)) for c in schedule)
    rounds = []
    if group is not None and (not isinstance(group, int | np.integer) or group < 1):
        raise FitError(f"group must be a positive int or None, got {group!r}")
    runner = _runner(problem, solver, rtol, atol, max_steps, bool(shard),
                     None if group is None else int(group), sg is not None)
    ndev = runner.ndev
    unit = runner.unit
    # one block shape per call (compiled once): the whole batch without groups (a plain
    # vmapped solve), else the batch's bucket up to MAX_BLOCK lanes
    block = (int(math.ceil(B / unit) * unit) if group is None
             else min(_bucket(MAX_BLOCK, unit), _bucket(B, unit)))
    every = np.arange(B)

    # the data side of the metric once (brdf_fit.fit._metric_parts), on the device
    data = runner.prepare(raw)

    def whole(u, *extra):
        return lambda pad, n: (u[pad], *(x[pad] for x in extra),
                               {k: v[pad] for k, v in fixed.items()})

    vary = tuple(n for n in free if n not in init) if guess == "grid" else ()
    if vary:  # coarse design over the parameters without a start value (brdf_fit.guess)
        ts = time.perf_counter()
        cands = _guess.design(problem, state["u"], vary, defaults).astype(dtype)
        lay = _guess.layout(problem, vary)
        chan_of = _guess.channel_index(problem, C)
        sub = _guess.subsample(M)
        sub_data = runner.subsample(data, sub)
        state["u"], q = _blocked(runner, runner.guess(lay, chan_of), every, block,
                                 lambda pad, n: (cands[pad], {k: v[pad] for k, v in fixed.items()}),
                                 (sub_data, data))
        if q:
            state["cost"], state["A"], state["g"], state["meat"] = (np.array(x) for x in q)
        rounds.append({"lanes": int(math.ceil(B / block) * block), "active": B, "steps": 0,
                       "guess": True, "candidates": int(cands.shape[1]),
                       "samples": int(sub.size), "lane_steps": 0,
                       "seconds": round(time.perf_counter() - ts, 4)})
    if solver == "batch-lm" and "A" not in state:  # the carried quantities at the start
        ts = time.perf_counter()
        q = _blocked(runner, runner.init, every, block, whole(state["u"]), data)
        state["cost"], state["A"], state["g"], state["meat"] = (np.array(x) for x in q)
        rounds.append({"lanes": int(math.ceil(B / block) * block), "active": B, "steps": 0,
                       "init": True, "lane_steps": 0,
                       "seconds": round(time.perf_counter() - ts, 4)})
    if progress is not None:
        progress(0, B, "start")
    _run_chunks(runner, state, data, fixed, schedule, max_steps, solver,
                chunk_steps is None, rounds, block, progress)
    ts = time.perf_counter()
    if solver == "batch-lm":  # from the carried normal equations, no model evaluation
        out = runner._fin_state(state["u"], state["cost"], state["A"], state["meat"], m_eff,
                                np.full(B, M * C, dtype), fixed)
        phys, se, loss, rms = jax.tree.map(np.asarray, out)
    else:
        phys, se, loss, rms = _blocked(runner, runner.finalise, every, block,
                                       whole(state["u"], m_eff), data)
    stderr, k = {}, 0
    for name, shape in zip(free, problem.shapes, strict=True):
        size = int(np.prod(shape)) if shape else 1
        stderr[name] = se[:, k:k + size].reshape((B, *shape))
        k += size
    params = {name: (np.asarray(phys[name]) if name in phys else fixed[name])
              for name in entry.param_names}
    params = {name: np.broadcast_to(v, (B, *np.shape(v)[1:])) for name, v in params.items()}
    rounds.append({"lanes": int(math.ceil(B / block) * block), "active": B, "steps": 0,
                   "finalise": True, "lane_steps": 0,
                   "seconds": round(time.perf_counter() - ts, 4)})
    return BatchFitResult(
        model_name=entry.name,
        params=params,
        stderr=stderr,
        converged=state["ok"].astype(bool),
        steps=state["steps"].astype(int),
        loss=loss,
        residual_rms=rms,
        n_samples=nused.astype(int),
        n_params=p,
        metric=metric,
        solver=solver,
        seconds=time.perf_counter() - t0,
        rounds=rounds,
        n_devices=ndev,
        at_bound={n: at_bound(entry.param(n), params[n]) for n in free},
    )
