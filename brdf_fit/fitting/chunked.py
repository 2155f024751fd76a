"""Fits whose memory does not grow with the data: Levenberg-Marquardt on normal equations
accumulated over chunks of samples, from a coarse stage on a random subset to the whole data.

:func:`brdf_fit.fitting.single.fit` takes this path for large data (at least
:data:`CHUNKED_FROM` residuals, samples times channels, with the default solver): a whole MERL
file holds about 1.1 million valid bins per channel, whose full Jacobian (3.3 million rows
by 7 columns for a coloured conductor, with the forward-mode intermediates behind it) took
4.7-5.1 GiB through optimistix's dense solver (issue 44). Here only ``p x p`` quantities are
ever held: the loss ``0.5 |r|^2``, ``J^T J`` and ``J^T r`` (and at the end the sandwich
estimator's ``J^T diag(r^2) J``), each a sum over samples, so they are summed chunk by chunk
(:data:`CHUNK` samples at a time, one structured forward-mode pass per chunk,
:func:`brdf_fit.fitting._lm.quad`), and memory is the data plus a few chunks whatever the
number of samples.

The method is batch-lm's (:mod:`brdf_fit.fitting._lm`: Marquardt scaling, Nielsen's damping,
Cholesky on the normal equations, the Cauchy and Gauss-Newton-decrement stopping tests), one
iteration split in three compiled programs driven from the host: :func:`~brdf_fit.fitting._lm.
lm_propose` (the damped step, ``p x p``), the chunked sums at the trial point (the one program
that touches the data) and :func:`~brdf_fit.fitting._lm.lm_update` (accept, test, damp). The
host loop reports progress after every step and stops at a time limit.

**Coarse to fine.** A seeded random subset of :data:`COARSE_CHUNKS` chunks is copied in front
of the data, and the solver first runs on those chunks alone (which chunks to sum is an
argument of the compiled program, not its shape: the two stages share one compilation), then
continues on every sample from where the subset left off, with the subset's last damping
(Marquardt-scaled, so it means the same on more samples). From a generic start almost all
iterations are the cheap ones; on noise-free data the subset's optimum is the whole data's,
and the full stage is one pass that confirms it. On data with noise (a MERL file rounded to
float32) the subset's optimum is some standard errors from the whole data's, and the full
stage takes one nearly undamped Gauss-Newton step to it: two passes over the data. (With the
damping reset to its initial value, the first steps there were damped along the badly
conditioned directions of eta and k and the stage took three passes: 2.1 s of a
1.1-million-sample fit against 1.6 s, measured.)
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np

from brdf_fit.fitting import _lm
from brdf_fit.fitting._export import ExportedCall, export_key
from brdf_fit.fitting.problem import FitProblem
from brdf_fit.fitting.solvers import bucket

__all__ = ["CHUNK", "CHUNKED_FROM", "COARSE_CHUNKS", "ChunkedData", "ChunkedSolution",
           "chunk_data", "solve_chunked", "finish_chunked"]

#: samples per chunk: one chunk's intermediates (the model and its few forward-mode tangents
#: over CHUNK x channels residuals) stay in the tens of megabytes in float64
CHUNK = 16384
#: residuals (samples x channels) from which fit() solves by chunks: below it the dense
#: Jacobian is small (at most 2^17 x p floats) and optimistix's solver is kept
CHUNKED_FROM = 2**17
#: chunks of the coarse stage (a random subset of COARSE_CHUNKS x CHUNK samples)
COARSE_CHUNKS = 2
#: steps of the coarse stage at most (it stops at its own convergence, usually far sooner)
COARSE_MAX_STEPS = 128


@dataclasses.dataclass(frozen=True)
class ChunkedData:
    """Prepared data in chunks: ``prep`` is :meth:`FitProblem.prepare`'s tuple (JAX arrays)
    with every per-sample leaf reshaped to ``(coarse_chunks + n_chunks, CHUNK, ...)``: first a
    seeded random subset of the samples (:data:`COARSE_CHUNKS` chunks, a copy), then every sample in
    its own order (``n_chunks`` chunks), each part padded at its end with samples of scale 0,
    whose residuals and derivatives are exactly 0; ``n_used`` real samples. Where all samples
    fit in the coarse chunks there is no subset (``coarse_chunks`` 0)."""

    prep: tuple
    coarse_chunks: int
    n_chunks: int
    n_used: int


def _put(x, dtype=None):
    """``x`` (NumPy or a Python number) on the default device, committed: ``jnp.asarray`` of a
    NumPy array compiles a small program per shape and dtype (``jit(stage)``, and
    ``jnp.int32(0)`` one more), and its uncommitted result was committed again before every
    exported program call (:func:`brdf_fit.fitting._export._committed`); ``jax.device_put`` to a
    device compiles nothing. A fresh process's fit loaded ten such programs from the
    persistent cache (issue 44)."""
    return jax.device_put(np.asarray(x, dtype), jax.devices()[0])


def chunk_data(problem: FitProblem, arrays, n_used: int, seed: int = 0,
               chunk: int | None = None) -> ChunkedData:
    """:class:`ChunkedData` of ``arrays`` (``wi, wo, f, w, sigma, floor`` as
    :func:`brdf_fit.fitting.single.fit` makes them, NumPy, ``n_used`` samples). The chunk count
    is rounded up to a size bucket (:func:`brdf_fit.fitting.solvers.bucket` of the samples), so
    files of nearby sizes share one compiled program. The subset is drawn without replacement
    and sorted (a gather of it costs little; a random order of every sample cost 0.43 s of a
    1.1-million-sample fit, measured). ``chunk``: samples per chunk (default :data:`CHUNK`)."""
    chunk = CHUNK if chunk is None else int(chunk)
    wi, wo = arrays[:2]
    n_chunks = -(-bucket(n_used) // chunk)
    coarse = COARSE_CHUNKS if COARSE_CHUNKS * chunk < n_used else 0
    subset = (np.sort(np.random.default_rng(seed).choice(n_used, coarse * chunk, replace=False))
              if coarse else np.zeros(0, int))
    mul, gf, scale = problem.prepare(arrays, np)[2:]
    if scale is None:  # the padding needs a scale of 0; 1 elsewhere changes no residual
        scale = np.ones_like(gf)

    def arrange(a, fill):
        a = np.asarray(a)
        pad = np.full((n_chunks * chunk - n_used, *a.shape[1:]), fill, a.dtype)
        return np.concatenate([a[subset], a, pad]).reshape(coarse + n_chunks, chunk,
                                                           *a.shape[1:])

    normal = np.zeros(3, wi.dtype)
    normal[2] = 1.0  # padded directions at the normal: finite for every model
    # on the device at once: the host copies are freed when this returns (no second copy of
    # the data beside the one the solver reads)
    prep = tuple(_put(arrange(a, fill)) for a, fill in
                 ((wi, normal), (wo, normal), (mul, 0.0), (gf, 0.0), (scale, 0.0)))
    return ChunkedData(prep=prep, coarse_chunks=coarse, n_chunks=n_chunks, n_used=n_used)


def _sums(problem, dq, u, prep, lo, hi, fx, sandwich):
    """``(0.5 |r|^2, J^T J, J^T r, J^T diag(r^2) J)`` at ``u`` summed over the chunks
    ``lo .. hi - 1`` of ``prep`` (traced bounds: the coarse and the full stage run one
    program)."""
    p = u.shape[0]
    zero = (jnp.zeros((), u.dtype), jnp.zeros((p, p), u.dtype), jnp.zeros(p, u.dtype),
            jnp.zeros((p, p), u.dtype))

    def body(i, acc):
        a = jax.tree.map(lambda x: jax.lax.dynamic_index_in_dim(x, i, 0, keepdims=False), prep)
        return jax.tree.map(jnp.add, acc, _lm.quad_pairs(problem, dq, u, a, fx, sandwich))

    return jax.lax.fori_loop(lo, hi, body, zero)


@dataclasses.dataclass(frozen=True)
class _Programs:
    """The compiled programs of one static problem: ``sums`` (the chunked loss and normal
    equations, with the sandwich's meat when ``sandwich``), ``propose`` and ``update`` (the
    two halves of a batch-lm iteration around it), ``converged`` (the Gauss-Newton test of a
    fresh start), ``finish`` (standard errors from the sums,
    :func:`brdf_fit.fitting._lm.finalise_state`)."""

    sums: Callable
    propose: Callable
    update: Callable
    converged: Callable
    finish: Callable


_PROGRAMS: dict = {}
_STATE_FIELDS = tuple(f.name for f in dataclasses.fields(_lm.LMState))


def _fields(s: _lm.LMState) -> tuple:
    """An :class:`~brdf_fit.fitting._lm.LMState` as the tuple of its fields: what the kept
    programs take and return (jax.export serialises tuples, not the equinox class)."""
    return tuple(getattr(s, n) for n in _STATE_FIELDS)


def _state(t) -> _lm.LMState:
    return _lm.LMState(**dict(zip(_STATE_FIELDS, t, strict=True)))


def _gauss_newton_done(s: _lm.LMState):
    """:func:`brdf_fit.fitting._lm.newton_converged` at the state's iterate and tolerances."""
    return _lm.newton_converged(s.u, s.cost, s.A, s.g, s.tol[0], s.tol[1])


def _on_state(fn, returns_state: bool = False):
    """``fn`` (a program on the state's fields) called with a state (and returning one)."""
    def call(s, *rest):
        out = fn(_fields(s), *rest)
        return _state(out) if returns_state else out
    return call


def _programs(problem: FitProblem, n_channels: int, sandwich: bool) -> _Programs:
    key = (problem.key, problem.fixed_signature(), int(n_channels), bool(sandwich), "chunked")
    got = _PROGRAMS.get(key)
    if got is not None:
        return got
    template = problem.with_fixed({})
    dq = _lm.directions(template, n_channels)

    def P(fx):
        return template.with_fixed(fx)

    static = export_key(problem, key)

    def kept(fn, name):  # kept between processes as exported programs (fitting._export)
        return ExportedCall(jax.jit(fn), f"chunked-{name}", static)

    got = _Programs(
        sums=kept(lambda u, prep, lo, hi, fx: _sums(P(fx), dq, u, prep, lo, hi, fx, sandwich),
                  "sums"),
        propose=_on_state(kept(lambda t: _lm.lm_propose(_state(t)), "propose")),
        update=_on_state(kept(lambda t, *rest: _fields(_lm.lm_update(_state(t), *rest)),
                              "update"), returns_state=True),
        converged=_on_state(kept(lambda t: _gauss_newton_done(_state(t)), "converged")),
        finish=kept(lambda u, cost, A, meat, m_eff, n_res, fx: _lm.finalise_state(
            P(fx), u, cost, A, meat, m_eff, n_res, fx, sandwich, with_cov=True), "finish"),
    )
    _PROGRAMS[key] = got
    return got


@dataclasses.dataclass
class ChunkedSolution:
    """What :func:`solve_chunked` ends with: the unconstrained iterate ``u``, whether it
    converged, the steps of each stage (``coarse_steps``, ``steps`` in all), the loss and the
    normal equations at ``u`` on the whole data, and why it stopped where it did not converge
    (``stopped``: "", "max_steps", "time_limit", "stalled": the loss no longer decreasing and
    not at a constrained optimum, :func:`converged_at_bounds`)."""

    u: np.ndarray
    converged: bool
    steps: int
    coarse_steps: int
    cost: float
    A: np.ndarray
    meat: np.ndarray
    stopped: str = ""


def _run_stage(progs, state, prep, rows, fx, budget, deadline, progress, stage):
    """batch-lm iterations on the chunks ``rows`` (lo, hi) from ``state`` (its sums taken on those
    chunks) until the state is done, ``budget`` steps were taken or the clock passes
    ``deadline``; returns ``(state, steps, why)``. A start that the undamped Gauss-Newton step
    would not improve beyond the tolerances is converged before any step
    (:func:`brdf_fit.fitting._lm.newton_converged`): the full stage after a coarse one on
    noise-free data costs one pass over the data."""
    if bool(progs.converged(state)):
        return dataclasses.replace(state, done=_put(np.True_), ok=_put(np.True_)), 0, ""
    steps = 0
    while steps < budget:
        if bool(state.done):
            return state, steps, "" if bool(state.ok) else "stalled"
        if deadline is not None and time.perf_counter() > deadline:
            return state, steps, "time_limit"
        du, u_new, lam, scale = progs.propose(state)
        q = progs.sums(u_new, prep, *rows, fx)
        state = progs.update(state, du, u_new, lam, scale, q)
        steps += 1
        if progress is not None:
            progress(stage, steps, float(state.cost))
    return state, steps, "stalled" if bool(state.done) else "max_steps"


def solve_chunked(problem: FitProblem, u0, data: ChunkedData, n_channels: int,
                  sandwich: bool, max_steps: int = 256, rtol: float = 1e-10,
                  atol: float = 1e-10, time_limit: float | None = None,
                  progress: Callable | None = None) -> ChunkedSolution:
    """Minimise ``0.5 |r(u)|^2`` over the chunked ``data`` from ``u0`` (module docstring):
    the coarse stage on the random subset (:attr:`ChunkedData.coarse_chunks` chunks), then
    every sample.
    ``max_steps`` bounds the steps of both stages together; ``time_limit`` (seconds) stops the
    solve, not converged, when it is passed; ``progress(stage, step, loss)`` is called after
    every step (``stage``: "coarse" or "full")."""
    progs = _programs(problem, n_channels, sandwich)
    fx = problem.fixed
    dtype = np.asarray(u0).dtype
    deadline = None if time_limit is None else time.perf_counter() + float(time_limit)
    prep = data.prep
    # device arrays from the start (NumPy scalars would give the first step's programs another
    # signature than the later steps', so two programs each)
    start = jax.tree.map(lambda x: _put(x[0]), _lm.LMState.start(
        np.asarray(u0)[None], dtype, max_steps, rtol, atol))

    def begin(u, rows, steps_so_far, lam):
        """A fresh state at ``u`` with its sums on the chunks ``rows`` and damping ``lam``."""
        u = _put(u, dtype)
        cost, A, g, meat = progs.sums(u, prep, *rows, fx)
        return dataclasses.replace(start, u=u, lam=lam, steps=_put(np.int32(steps_so_far)),
                                   cost=cost, A=A, g=g, meat=meat)

    coarse_steps, why = 0, ""
    u, lam = np.asarray(u0), start.lam  # the initial damping
    c = data.coarse_chunks
    if c:
        rows = (_put(np.int32(0)), _put(np.int32(c)))
        state, coarse_steps, why = _run_stage(
            progs, begin(u, rows, 0, lam), prep, rows, fx, min(COARSE_MAX_STEPS, max_steps),
            deadline, progress, "coarse")
        # the full stage goes on with the subset's damping, but never more damped than a fresh
        # start (LM_TAU, relative to diag(J^T J) as lam is): a subset solved to rounding ends
        # with a run of rejected steps that each multiply lam (to 1e21 on a MERL plastic fitted
        # with GGX), which says nothing about the whole data and there damped every step to
        # nothing, so the full stage stopped at once, not converged (issue 44). On the host:
        # jnp.minimum would compile (and a fresh process load) one more program
        u, lam = np.asarray(state.u), _put(np.minimum(np.asarray(state.lam), _lm.LM_TAU))
    rows = (_put(np.int32(c)), _put(np.int32(c + data.n_chunks)))
    state, steps = begin(u, rows, coarse_steps, lam), 0
    if why != "time_limit":
        state, steps, why = _run_stage(progs, state, prep, rows, fx, max_steps - coarse_steps,
                                       deadline, progress, "full")
    ok = bool(state.ok)
    if not ok and why == "stalled" and converged_at_bounds(problem, state):
        ok, why = True, ""
    # the carried sums are those of the last accepted iterate (the meat too, with sandwich)
    return ChunkedSolution(u=np.asarray(state.u), converged=ok,
                           steps=coarse_steps + steps, coarse_steps=coarse_steps,
                           cost=float(state.cost), A=np.asarray(state.A),
                           meat=np.asarray(state.meat), stopped="" if ok else why)


def converged_at_bounds(problem: FitProblem, state) -> bool:
    """Whether a solve that stopped without converging (batch-lm's stall: accepted steps that no
    longer change the loss while the iterate moves) is at a constrained optimum: the entries
    sitting at an end of their interval (:func:`brdf_fit.fitting.problem.at_bound`) held
    there, the undamped Gauss-Newton step of the others passes the convergence test
    (:func:`brdf_fit.fitting._lm.newton_converged` on the normal equations without the
    bound entries). A parameter pushed onto its bound slides along the plateau of its
    logistic transform, where batch-lm's stall rule stops it; the dense solver reports the
    same point converged, with the parameter at bound (a lambert fit of a metal: rho at 1 in
    every channel; a GGX fit of gold: f0 at 1 in red)."""
    bound = problem.layout.at_bound(problem.unflatten(jnp.asarray(state.u)))
    if not bound.any():
        return False
    free = ~bound
    if not free.any():
        return True
    u, A, g = (np.asarray(x) for x in (state.u, state.A, state.g))
    rtol, atol = (float(x) for x in np.asarray(state.tol))
    return bool(_lm.newton_converged(jnp.asarray(u[free]), jnp.asarray(state.cost),
                                     jnp.asarray(A[np.ix_(free, free)]),
                                     jnp.asarray(g[free]), rtol, atol))


def finish_chunked(problem: FitProblem, sol: ChunkedSolution, n_channels: int, m_eff: int,
                   n_res: int, sandwich: bool):
    """``(physical parameters, standard errors (flat), loss, residual rms, stderr codes,
    covariance (p, p))`` of a :class:`ChunkedSolution` (:func:`brdf_fit.fitting._lm.
    finalise_state`: from the summed normal equations, no further pass over the data);
    ``m_eff`` residuals carry weight, the rms is over ``n_res``."""
    progs = _programs(problem, n_channels, sandwich)
    dtype = sol.u.dtype
    phys, se, cost, rms, code, cov = progs.finish(
        _put(sol.u), _put(sol.cost, dtype), _put(sol.A), _put(sol.meat), _put(m_eff, dtype),
        _put(max(n_res, 1), dtype), problem.fixed)
    return ({k: np.asarray(v) for k, v in phys.items()}, np.asarray(se), float(cost),
            float(rms) if math.isfinite(float(rms)) else float("nan"), np.asarray(code),
            np.asarray(cov))
