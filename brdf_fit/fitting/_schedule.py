"""How :func:`brdf_fit.fitting.batch.fit_batch` spends its iterations: the chunk schedule and
the compaction of stragglers between chunks (:func:`run_chunks`), blocks of a fixed lane count
(:func:`blocked`, :func:`bucket`), and the compiled, optionally sharded, functions that run on
them (:class:`Runner`, cached per static problem by :func:`runner`). The numerics (one solver
step, the Jacobian, the standard errors, the groups of lanes) are :mod:`brdf_fit.fitting._lm`;
the reasons and measurements are in :mod:`brdf_fit.fitting.batch`.
"""

from __future__ import annotations

import math
import time

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh, NamedSharding
from jax.sharding import PartitionSpec as P

from brdf_fit.fitting import guess as _guess
from brdf_fit.fitting import solvers as _solvers
from brdf_fit.fitting._lm import (
    LMState,
    directions,
    finalise_one,
    finalise_state,
    grouped,
    lanes,
    lm_chunk,
    lm_init,
    optx_chunk,
    quad,
)

__all__ = ["Runner", "runner", "blocked", "run_chunks", "bucket", "chunk_schedule",
           "CHUNK_SCHEDULE", "CHUNK_SCHEDULE_SHARED", "GROUP", "MAX_BLOCK", "MIN_BUCKET",
           "BUCKET_GROWTH", "MAX_RUNNERS",
           "block_lanes", "BLOCK_STEPS_PER_OCTAVE"]

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
#: The same after the shared-geometry guess (:data:`brdf_fit.fitting.guess.SHARED_CANDIDATES`
#: candidates on up to :data:`~brdf_fit.fitting.guess.SHARED_SAMPLES` samples), which leaves
#: fewer steps (16,384 GGX problems, 300 samples, 1% noise: median 4, p90 6, p99 9). Lane-steps
#: paid on them: 87,488 with CHUNK_SCHEDULE, 79,792 with (4, 2, 2, ...), 77,504 with this one
#: (103,856 after the 24-candidate guess with CHUNK_SCHEDULE).
CHUNK_SCHEDULE_SHARED = (4, 1, 2, 4, 8, 16, 32)
#: Lanes per group (see :func:`brdf_fit.fitting._lm.grouped`): each group of problems is
#: stepped by its own while_loop.
GROUP = 8
#: Runners (and so their compiled chunks) kept for reuse by later calls with the same static
#: problem; the oldest is dropped beyond this many.
MAX_RUNNERS = 8


def chunk_schedule(chunk_steps, max_steps: int, auto=CHUNK_SCHEDULE) -> tuple[int, ...]:
    """Iterations per chunk: ``"auto"`` the schedule ``auto`` (:data:`CHUNK_SCHEDULE`, or
    :data:`CHUNK_SCHEDULE_SHARED` after the shared-geometry guess), None one chunk of
    ``max_steps``, an int that many per chunk; each clipped to ``[1, max_steps]``. Raises
    ValueError for anything else."""
    if chunk_steps == "auto":
        schedule = tuple(auto)
    elif chunk_steps is None:
        schedule = (max_steps,)
    elif isinstance(chunk_steps, int | np.integer) and not isinstance(chunk_steps, bool):
        schedule = (int(chunk_steps),)
    else:
        raise ValueError(f"chunk_steps must be 'auto', None or an int, got {chunk_steps!r}")
    return tuple(max(1, min(int(c), max_steps)) for c in schedule)


#: Block sizes of a whole batch below MAX_BLOCK: 8 per octave (256, 288, 320, ...), so a batch
#: pays at most 1/8 more lanes than it has problems (the grid guess and the first chunk run every
#: lane of the block). With the power-of-two ladder a batch of 260 problems ran in 512 lanes,
#: 1.42-1.73x the time of 256 (the fault benchmark, issue 16). The stragglers' buckets keep the
#: coarse ladder: they are few lanes, and every distinct size is one more compilation.
BLOCK_STEPS_PER_OCTAVE = 8


def block_lanes(n: int, unit: int) -> int:
    """The block for a batch of ``n`` problems: the smallest of ``MIN_BUCKET``, then
    :data:`BLOCK_STEPS_PER_OCTAVE` sizes per octave, that holds ``n``, up to
    :data:`MAX_BLOCK`; rounded up to a multiple of ``unit``."""
    if n >= MAX_BLOCK:
        return bucket(MAX_BLOCK, unit)
    if n <= MIN_BUCKET:
        b = MIN_BUCKET
    else:
        step = max(1, 2 ** (int(math.floor(math.log2(n))) - int(math.log2(BLOCK_STEPS_PER_OCTAVE))))
        b = -(-n // step) * step
    return int(math.ceil(b / unit) * unit)


def bucket(n: int, unit: int) -> int:
    """The lane count for ``n`` lanes: the smallest ``MIN_BUCKET * BUCKET_GROWTH^k >= n``,
    rounded up to a multiple of ``unit``."""
    b = MIN_BUCKET
    while b < n:
        b *= BUCKET_GROWTH
    return int(math.ceil(b / unit) * unit)


class Runner:
    """Jitted (optionally shard_mapped) chunk, init, guess and finalise functions of one static
    problem, cached per shape by JAX. With ``shard`` the batch axis is laid out over a 1-D mesh
    of ``jax.local_devices()`` (this process's: a multi-process run shards within each) and
    every call runs under ``shard_map`` (the data replicated, every per-lane argument split
    along the batch)."""

    def __init__(self, problem, solver, rtol, atol, shard, group, sigma):
        self.devices = jax.local_devices() if shard else jax.local_devices()[:1]
        self.ndev = len(self.devices)
        self.mesh = Mesh(np.asarray(self.devices), ("batch",)) if self.ndev > 1 else None
        self.group = group
        self.solver = solver
        #: lane counts are multiples of this (every device holds whole groups)
        self.unit = (group or 1) * self.ndev
        sandwich = not sigma
        #: whether the standard errors come from batch-lm's carried normal equations
        #: (finalise_state: the pooled estimator, or HC1) rather than from a pass of their own
        #: (finalise_one: HC3 needs each residual's leverage); only then is the sandwich's meat
        #: summed at every step
        self.finalise_carried = solver == "batch-lm" and (
            not sandwich or _solvers.SANDWICH != "HC3")
        carry_meat = sandwich and self.finalise_carried
        self._carry_meat = carry_meat
        if solver == "batch-lm":
            def chunk(n_steps, i, d, s, fx):
                return lm_chunk(problem, n_steps, group, carry_meat,
                                i, d, s, fx)
        else:
            def chunk(n_steps, i, d, s, fx):
                return optx_chunk(problem, solver, rtol, atol, n_steps, i, d, s, fx)

        def fin(i, d, u, m_eff, fx):
            def one(t, a):
                uu, mm, ff = t
                return lanes(lambda x, y, z, w: finalise_one(
                    problem, x, y, z, w, sandwich), 1, (uu, a, mm, ff))
            return grouped(one, (u, m_eff, fx), group, i, d)

        def init(i, d, u, fx):
            return lm_init(problem, group, carry_meat, i, d, u, fx)

        def fin_state(u, cost, A, meat, m_eff, n_res, fx):
            return jax.vmap(lambda *t: finalise_state(problem, *t, carry_meat))(
                u, cost, A, meat, m_eff, n_res, fx)
        self.finalise_state = jax.jit(fin_state)

        self._guess = {}
        self._problem = problem
        self._sigma = sigma
        self._prepare = self._sub = None

        self._chunk = {}
        self._raw_chunk = chunk
        self._fin = self._compile(fin, 5)
        self._init = self._compile(init, 4)

    def _compile(self, fn, n_args, lanes_split=True):
        """jit ``fn(idx, data, *lanes)``; on a mesh under shard_map with ``data`` replicated
        and every other argument split along the batch (``lanes_split=False``: only ``idx``
        split, the arguments after ``data`` replicated too)."""
        if self.mesh is None:
            return jax.jit(fn)
        spec = P("batch")
        specs = (spec, P(), *[spec if lanes_split else P()] * (n_args - 2))
        return jax.jit(jax.shard_map(fn, mesh=self.mesh, in_specs=specs, out_specs=spec,
                                     check_vma=False))

    def chunk(self, n_steps):
        if self.solver == "batch-lm":  # the length is data (state.budget), not static
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
        once (:meth:`brdf_fit.fitting.problem.FitProblem.prepare`; replicated over the mesh):
        every call gathers its lanes from it inside its groups."""
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
        """Compiled: per lane, the start :func:`brdf_fit.fitting.guess.pick` chooses from its
        candidates (losses per channel on the subsample ``d[0]``) and, for batch-lm, the
        carried quantities there on the full data ``d[1]`` (:func:`~brdf_fit.fitting._lm.quad`),
        in the same pass over each group (the same work as two calls, one compilation fewer)."""
        key = (lay, tuple(int(c) for c in chan_of))
        fn = self._guess.get(key)
        if fn is None:
            problem, group = self._problem, self.group
            lm = self.solver == "batch-lm"
            carry_meat = self._carry_meat

            def best(c, a, fx):
                L = _guess.candidate_losses(problem, c, a, fx, lay)
                return _guess.pick(jnp, c, L, lay, chan_of)

            def one(t, a):
                c, fx = t
                u = lanes(best, 1, (c, a[0], fx))
                if not lm:
                    return u, ()
                dq = directions(problem, a[1][3].shape[-1])
                return u, lanes(lambda x, y, z: quad(problem, dq, x, y, z, carry_meat), 1,
                                (u, a[1], fx))

            def guess(i, d, c, fx):
                return grouped(one, (c, fx), group, i, d)

            fn = self._guess[key] = self._compile(guess, 4)
        return fn

    def shared_guess(self, lay, chan_of, chunk):
        """Compiled ``starts(i, data, cands, fixed, sub)``: the start of every problem ``i``
        (one per lane, split over the devices) when all of them have one geometry, the same
        candidates ``cands`` (n', p) and fixed values (unbatched) and a metric of
        :data:`~brdf_fit.fitting.guess.SHARED_METRICS`: the candidates' model values on the
        samples ``sub`` (None: all) once, then, ``chunk`` problems at a time, their losses by
        matrix products (:func:`~brdf_fit.fitting.guess.shared_losses`) and the pick; for
        batch-lm also the carried quantities at the starts (:func:`~brdf_fit.fitting._lm.quad`,
        in groups), in the same program, as :meth:`guess` does (one compilation, not two)."""
        key = ("shared", lay, tuple(int(c) for c in chan_of), int(chunk))
        fn = self._guess.get(key)
        if fn is None:
            problem, group = self._problem, self.group
            lm = self.solver == "batch-lm"
            carry_meat = self._carry_meat

            def starts(i, d, cands, fx, sub):
                def take(x):  # all samples (the usual case): no gather
                    return x if sub is None else jnp.take(x, sub, axis=1)

                wi, wo, mul, gf, scale = d
                values = _guess.candidate_values(problem, cands, (take(wi)[0], take(wo)[0]),
                                                 fx, lay, gf.shape[-1])
                m = take(mul)[0]

                def one(ic):
                    terms = _guess.shared_terms(take(gf[ic]),
                                                None if scale is None else take(scale[ic]))
                    L = _guess.shared_losses(problem, values, m, terms)
                    return jax.vmap(lambda ll: _guess.pick(jnp, cands, ll, lay, chan_of))(L)

                u = jax.lax.map(one, i.reshape(-1, chunk)).reshape(i.shape[0], -1)
                if not lm:
                    return u, ()
                dq = directions(problem, gf.shape[-1])
                fxl = {k: jnp.broadcast_to(v, (i.shape[0], *v.shape)) for k, v in fx.items()}

                def q(t, a):
                    return lanes(lambda x, y, z: quad(problem, dq, x, y, z, carry_meat), 1,
                                 (t[0], a, t[1]))
                return u, grouped(q, (u, fxl), group, i, d)

            fn = self._guess[key] = self._compile(starts, 5, lanes_split=False)
        return fn


_RUNNERS: dict = {}


def runner(problem, solver, rtol, atol, shard, group, sigma) -> Runner:
    """The :class:`Runner` of this static problem and these options (cached: a later call with
    the same ones reuses its compiled functions)."""
    if solver == "batch-lm":  # its tolerances and max_steps are data (LMState.tol, .limit)
        rtol = atol = None
    key = (problem.key, solver, rtol if rtol is None else float(rtol),
           atol if atol is None else float(atol), shard,
           len(jax.local_devices()), group, sigma, _solvers.SANDWICH)
    r = _RUNNERS.get(key)
    if r is None:
        if len(_RUNNERS) >= MAX_RUNNERS:
            _RUNNERS.pop(next(iter(_RUNNERS)))
        r = _RUNNERS[key] = Runner(problem, solver, rtol, atol, shard, group, sigma)
    return r


def take(tree, idx):
    """The lanes ``idx`` of every leaf of ``tree`` (NumPy fancy indexing: copies)."""
    return jax.tree.map(lambda x: x[idx], tree)


def blocked(runner, fn, idx, block, inputs, data):
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


def _assign(state: LMState, idx, out: LMState) -> None:
    """``state[idx] = out`` field by field, in place (the fields ``state`` has)."""
    for name in ("u", "lam", "nu", "scale", "steps", "done", "ok", "cost", "A", "g", "meat",
                 "limit", "tol", "stall"):
        x = getattr(state, name)
        if x is not None:
            x[idx] = getattr(out, name)


def run_chunks(runner, state: LMState, data, fixed, schedule, max_steps, solver, single,
               rounds, block, progress=None) -> None:
    """Solve chunk after chunk, compacting the unfinished problems between chunks (in blocks
    of ``block`` lanes); ``state`` (numpy arrays, leading axis B) is updated in place and one
    record per chunk is appended to ``rounds``."""
    B = state.u.shape[0]
    idx = np.arange(B)
    k_chunk = 0
    while True:
        active = idx[~state.done & (state.steps < max_steps)]
        if active.size == 0:
            break
        n = active.size
        n_steps = schedule[min(k_chunk, len(schedule) - 1)]
        if solver != "batch-lm":  # restarted solves: never run past a member's budget
            n_steps = int(min(n_steps, max_steps - state.steps[active].max()))
            n_steps = max(n_steps, 1)
        ts = time.perf_counter()
        before = state.steps[active].copy()

        def inputs(pad, m, n_steps=n_steps):
            sub = take(state, pad)
            sub.done[m:] = True  # padding lanes: a group of padding alone stops at once
            sub = sub.with_budget(np.full(pad.size, n_steps, np.int32))
            return sub, {k: v[pad] for k, v in fixed.items()}

        # without groups the whole block is one while_loop: shrink it to the stragglers'
        # bucket (one more compile per bucket), else compaction would save nothing
        blk = block if runner.group else min(block, bucket(n, runner.unit))
        out = blocked(runner, runner.chunk(n_steps), active, blk, inputs, data)
        _assign(state, active, out)
        lanes = int(math.ceil(n / blk) * blk)
        # iterations each group's while_loop ran (its slowest lane), paid by all its lanes
        ran = np.zeros(lanes, int)
        ran[:n] = state.steps[active] - before
        g = runner.group or blk
        per_group = ran.reshape(-1, g).max(axis=1)
        rec = {"lanes": lanes, "active": int(n), "steps": int(per_group.max()),
               "lane_steps": int(per_group.sum() * g),
               "seconds": round(time.perf_counter() - ts, 4)}
        rounds.append(rec)
        k_chunk += 1
        if progress is not None:
            progress(int(np.sum(state.done | (state.steps >= max_steps))), B,
                     f"chunk {k_chunk}")
        if single:
            break
