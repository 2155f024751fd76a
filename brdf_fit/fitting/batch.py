"""Batch fitting: B independent problems sharing one model and one sample count.

    res = fit_batch(wi, wo, values, "ggx")       # wi, wo: (B, M, 3) or (M, 3); values: (B, M, C)
    res = fit_batch(wi, wo, values, MicrofacetBRDF(GGX(0.3), SmithHeightCorrelated(),
                                                   SchlickFresnel(f0=jnp.full(3, 0.5))))

The model is a registry name or a built model (the template of every problem; its parameters
are named by attribute path, see :mod:`brdf_fit.fitting.problem`). The residual of problem
``b`` is :meth:`brdf_fit.fitting.problem.FitProblem.residuals` (same metric, weights, sigma,
``cos_weight``, relative floor, parameter transforms) as :func:`brdf_fit.fitting.single.fit`
builds it for that problem alone, up to rounding, so the two agree at the optimum. It is
evaluated as :meth:`~brdf_fit.fitting.problem.FitProblem.residuals_prepared`: the data side of
the metric (for ``log``, ``log1p(f cos)``) is computed once, not at every iteration.

Code: the batched solvers (batch-lm's step, the structured Jacobian, the standard errors) are
:mod:`brdf_fit.fitting._lm`; the groups, chunks, blocks and sharding
:mod:`brdf_fit.fitting._schedule`; this module is the API.

**Cost of one iteration.** The residual, its Jacobian and the normal equations come from one
forward-mode pass per shared parameter plus one per *channel* parameter, not per channel
(:func:`~brdf_fit.fitting._lm.directions`: a channel's residuals depend only on its own entry
of an RGB ``f0``), and only the ``p x p`` normal equations are kept. The data (directions and
prepared metric terms) is placed on the device once per call, and every group gathers its own
lanes from it.

**The straggler problem.** Under ``vmap`` a ``while_loop`` runs until its slowest member stops:
members that have converged are masked, but still computed. In 10,000 GGX fits the median
problem needs ~9 steps and the slowest ~100 (an ``f0`` channel running to its bound of 1), so
one vmapped solve pays ``B x max(steps)`` instead of ``sum(steps)``. Three things bound it here:

- *groups*: the lanes are taken in groups of ``group`` (:data:`GROUP` = 8) problems, one group
  after another (``lax.map``), and each group runs its own while_loop, which stops when *its*
  members are done. This is also faster per step: one vmapped step over thousands of lanes
  materialises every intermediate of the residual and its tangents as a (B, M C) array, far
  larger than the caches (measured: 147 us per problem-step vmapped over 2,000 problems, 62-67
  us in groups of 8-32, see :func:`~brdf_fit.fitting._lm.grouped`);
- *chunks*: the solve runs ``chunk_steps`` iterations at a time; after each chunk the converged
  problems are kept and only the stragglers are gathered into a compact batch and solved on from
  where they stopped;
- *blocks*: every call takes a fixed number of lanes (the batch's bucket ``16 * 2**k``, at most
  :data:`MAX_BLOCK`), so one shape is compiled per batch-size class and the chunk length is data,
  not a static argument; padding lanes are marked done, so a group of padding costs nothing.

``benchmarks/bench_fit_batch.py`` measures this against one plain vmapped solve
(``chunk_steps=None, group=None``).

**Shared geometry.** ``wi, wo`` may be one (M, 3) geometry for every problem (a
gonioreflectometer measuring every texel of a texture the same way). It is kept once on the
device, not once per problem, and vmapped with ``in_axes=None``
(:func:`~brdf_fit.fitting._lm.gather`), so what depends on the directions alone (half vectors,
cosines, the Fresnel factor's ``(1 - cos)^5``) is computed once per group and step. The fits
equal those of the same directions repeated per problem up to rounding (losses to 1e-9
relative, tested).

**One compilation per size class.** Everything a compilation does not need is data: the chunk
length (``LMState.budget``), ``max_steps`` (``LMState.limit``) and batch-lm's tolerances
(``LMState.tol``) travel with the lanes, and the data's problem axis is padded to whole blocks
(repeating the last problem; padding rows are never read), so a batch of 5 and one of 7
problems, or two calls with different ``rtol`` or ``max_steps``, share one compilation.

**Streaming.** More problems than memory holds (10^6 texels of 300 samples: 20 GB of inputs in
float64) go through :func:`brdf_fit.fitting.stream.fit_stream`: blocks of one shape taken from
an array, a memory map or a callable source, a progress bar, each finished block written
atomically to a folder with a manifest, and a killed run resumed where it stopped
(``brdf-fit fit-batch --out-dir DIR [--block-size N] [--resume]``).

**Initial guess.** ``guess="grid"`` (default) starts the parameters without an ``init`` value
from the best of a coarse design evaluated on a subsample (:mod:`brdf_fit.guess`).

**Solvers.** ``solver="batch-lm"`` (the default) is the Levenberg-Marquardt method written here
for batches: Marquardt scaling by the running maximum of ``diag(J^T J)`` (as MINPACK), the
damping update of H. B. Nielsen ("Damping parameter in Marquardt's method", IMM-REP-1999-05,
DTU, 1999: ``lam *= max(1/3, 1 - (2 rho - 1)^3)`` on success, ``lam *= nu; nu *= 2`` on failure),
the residual and Jacobian from one forward-mode pass, the normal equations (``p x p``)
solved by Cholesky, and no step entry longer than ``STEP_MAX`` = 2 in the unconstrained space
(without that cap a first step from the registry default drove a logistic parameter far past
its bound, onto a plateau of zero gradient: 7-18% of 300 problems ended worse than scipy's
``least_squares``, measured; with it none, and the mean step count fell from ~26 to ~11; those
figures are of the cap on the step's length, which is per entry since 2026-12-07, see
:func:`brdf_fit.fitting._lm.lm_propose`). Its
whole state (``u``, ``lam``, ``nu``, the scaling) is carried across chunks, so chunking and
compaction do not change a single iterate. It stops when an accepted step satisfies
optimistix's Cauchy test, ``max|du / (atol + rtol |u|)| < 1`` and
``|d loss| < atol + rtol * loss``, or when the next, undamped Gauss-Newton step from the new
iterate would pass the same two tests by its quadratic model (so the step that would only
confirm convergence is not taken); or when the damping has grown past ``LAM_MAX`` (every step
rejected at machine precision), counted as converged only if the residual is orthogonal to the
Jacobian columns (cosine < 10 sqrt(eps), MINPACK's gtol test); or, not converged, after
``STALL_STEPS`` = 16 accepted steps in a row that each changed the loss by less than
``atol + rtol * loss`` while the step stayed long: a parameter sliding onto the plateau of its
logistic transform, the loss flat to the tolerance. Such lanes (an all-black file, ``f = 1000``
everywhere, a wild outlier) ran to ``LAM_MAX`` or ``max_steps`` (71-256 steps) and added chunks
of a few lanes at the end of every batch; interior minima show at most 5 such steps in a row
(10,000 GGX fits; see :data:`brdf_fit.fitting._lm.STALL_STEPS`).

Any name in :data:`brdf_fit.fitting.single.SOLVERS` (``"lm"``, ...) runs that optimistix
solver through :func:`brdf_fit.fitting.single.solve`, the solver of
:func:`~brdf_fit.fitting.single.fit`; optimistix keeps its state inside one solve, so there
each chunk restarts the solver from the last iterate (the damping restarts; the optimum is the
same). Measured on this 2-core CPU, one optimistix LM step cost ~4x a batch-lm
step (it linearises and evaluates the residual separately and solves by QR).

**Sharding.** With ``shard=True`` the batch axis is laid out over a 1-D
:class:`jax.sharding.Mesh` of ``jax.local_devices()`` with ``NamedSharding(mesh, P("batch"))``
and every call runs under ``jax.shard_map``: each device iterates its own groups, so a device stops
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

from brdf_fit.data import MAX_VALUE
from brdf_fit.fitting import guess as _guess
from brdf_fit.fitting._lm import LMState
from brdf_fit.fitting._schedule import (
    CHUNK_SCHEDULE,
    CHUNK_SCHEDULE_SHARED,
    GROUP,
    MAX_BLOCK,
    block_lanes,
    blocked,
    chunk_schedule,
    run_chunks,
    runner,
)
from brdf_fit.fitting.problem import (
    DATA_SCALE_FLOOR,
    METRICS,
    RELATIVE_FLOOR,
    FitError,
    FitProblem,
    ParamLayout,
    at_bound,
    check_choice,
    model_source,
    resolve_free,
    stderr_notes,
    undetermined,
)
from brdf_fit.fitting.result import json_floats
from brdf_fit.fitting.single import SOLVERS

__all__ = ["BatchFitResult", "fit_batch", "BATCH_SOLVERS", "CHUNK_SCHEDULE", "GROUP",
           "MAX_BLOCK"]

BATCH_SOLVERS = ("batch-lm", *SOLVERS)


@dataclasses.dataclass
class BatchFitResult:
    """Outcome of :func:`fit_batch`; every array has a leading batch axis ``B``."""

    model_name: str
    params: dict[str, np.ndarray]  # (B, ...) per parameter, name or path (fixed ones included)
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
    #: (:func:`brdf_fit.fitting.problem.at_bound`; its standard error means nothing there)
    at_bound: dict = dataclasses.field(default_factory=dict)
    #: per free parameter with some undefined (NaN) standard error, (B, ...) of reasons ("" where
    #: defined): "at bound", "not identifiable", "non-finite normal equations" (as
    #: :attr:`brdf_fit.fitting.single.FitResult.stderr_note`)
    stderr_note: dict = dataclasses.field(default_factory=dict)
    #: where the parameters came from (:class:`~brdf_fit.fitting.problem.ModelSource`)
    source: Any = dataclasses.field(default=None, repr=False)

    @property
    def batch_size(self) -> int:
        return int(self.converged.shape[0])

    def model(self, b: int):
        """The fitted model of problem ``b`` (a built model: the template with problem ``b``'s
        values put back; a registry model: ``entry.build`` of them)."""
        return self.source.build({k: jnp.asarray(v[b]) for k, v in self.params.items()})

    @property
    def undetermined(self) -> dict[str, np.ndarray]:
        """Per free parameter, (B, ...) bool: the data do not determine that entry
        (:func:`brdf_fit.fitting.problem.undetermined`, as
        :attr:`brdf_fit.fitting.single.FitResult.undetermined`)."""
        return {k: undetermined(self.params[k], se, self.stderr_note.get(k))
                for k, se in self.stderr.items()}

    def lane_steps(self) -> int:
        """Solver iterations paid for: per group, its lane count times the iterations its
        while_loop ran, summed over groups and chunks (padding included)."""
        return int(sum(r["lane_steps"] for r in self.rounds))

    def to_dict(self) -> dict:
        return {
            "model": self.model_name,
            "params": {k: np.asarray(v).tolist() for k, v in self.params.items()},
            "stderr": {k: json_floats(v) for k, v in self.stderr.items()},
            "stderr_note": {k: np.asarray(v).tolist() for k, v in self.stderr_note.items()},
            "undetermined": {k: np.asarray(v).tolist() for k, v in self.undetermined.items()},
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


def _clean(name, a) -> bool:
    """True when ``a`` certainly passes :func:`check_inputs`' tests, from its maximum and minimum
    alone (NaN propagates through both, an infinity is one of them): two passes over the data
    and no temporaries. The element-wise tests, which allocate boolean and float copies of the
    whole batch, then run only to name an offender. Measured on 16,144 x 300 x 3 values
    (float64): 15 ms; the element-wise tests took 0.2-2.6 s, most of it page faults of the new
    copies, once per block of a streamed fit (issue 15)."""
    if a.size == 0:
        return True
    hi, lo = np.max(a), np.min(a)
    if not (np.isfinite(hi) and np.isfinite(lo)):
        return False
    if name == "values":
        return bool(max(hi, -lo) <= MAX_VALUE)
    if name in ("weight", "sigma"):
        return bool(lo >= 0)
    return True


def check_inputs(**arrays) -> None:
    """Raise :class:`~brdf_fit.fitting.problem.FitError` naming the first offending problem
    and sample of a batch's inputs (each (B, M, ...) or None) before anything is fitted: a NaN
    or an infinity in any of them, a value beyond :data:`brdf_fit.data.MAX_VALUE` in magnitude
    (as :meth:`brdf_fit.data.GonioData.validate`: its squares would overflow the normal
    equations), a negative weight or sigma. A file read by :func:`brdf_fit.io.read` has passed
    the same tests with its name and line; these are for arrays built in memory."""
    for name, a in arrays.items():
        if a is None or _clean(name, a):
            continue
        tests = [(~np.isfinite(a), "is not finite")]
        if name == "values":
            tests.append((np.abs(np.where(np.isfinite(a), a, 0.0)) > MAX_VALUE,
                          f"exceeds {MAX_VALUE:g} 1/sr in magnitude (brdf_fit.data.MAX_VALUE)"))
        if name in ("weight", "sigma"):
            tests.append((np.where(np.isfinite(a), a, 0.0) < 0, "is negative"))
        for bad, what in tests:
            if bad.any():
                b, m = (int(i) for i in np.argwhere(bad.reshape(a.shape[:2] + (-1,)).any(-1))[0])
                raise FitError(f"problem {b}, sample {m}: {name} {what} "
                               f"({np.asarray(a[b, m]).tolist()})")


def _pad_rows(a, B, rows):
    """``a`` with its leading problem axis ``B`` padded to ``rows`` by repeating its last
    row (None, shared (1, ...) arrays and ``rows == B`` unchanged)."""
    if a is None or rows == B or np.ndim(a) == 0 or np.shape(a)[0] != B:
        return a
    a = np.asarray(a)
    return np.concatenate([a, np.repeat(a[-1:], rows - B, axis=0)])


def fit_batch(
    wi,
    wo,
    values,
    model,
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
    free=None,
    bounds: dict | None = None,
) -> BatchFitResult:
    """Fit ``model`` to B datasets at once: a registry name, or a built model (the template of
    every problem; parameters named by attribute path, as in
    :func:`~brdf_fit.fitting.single.fit`).

    ``wi``, ``wo``: (B, M, 3), or (M, 3) shared by every problem; ``values``, ``weight``,
    ``sigma``: (B, M, C) (or (B, M)).
    ``fix`` / ``init``: parameter values shared by all problems or per problem (leading axis
    B; see :meth:`~brdf_fit.fitting.problem.ParamSpec.batched_value`). ``free`` / ``bounds``:
    as in :func:`~brdf_fit.fitting.single.fit`. ``max_zenith_deg`` masks samples (weight 0)
    instead of dropping them, so the sample count stays M. ``chunk_steps``: iterations per
    chunk before the stragglers are compacted (``"auto"``: the lengths of
    :data:`CHUNK_SCHEDULE`, or :data:`CHUNK_SCHEDULE_SHARED` after the shared-geometry guess,
    then its last; None: one chunk of ``max_steps``). ``group``: lanes
    per while_loop (None: the whole block; with ``chunk_steps=None`` that is one plain vmapped
    solve). ``guess``: ``"grid"`` or ``"none"`` (see :mod:`brdf_fit.fitting.guess`);
    ``max_steps=0`` returns the start itself; with one geometry (wi, wo (M, 3)), the same
    start and fixed values for every problem and a metric of
    :data:`~brdf_fit.fitting.guess.SHARED_METRICS`, the guess is the finer shared one
    (:data:`~brdf_fit.fitting.guess.SHARED_CANDIDATES` candidates on up to
    :data:`~brdf_fit.fitting.guess.SHARED_SAMPLES` samples). ``shard``: lay the batch over all
    ``jax.local_devices()`` (default: when there are several). ``progress``: called as
    ``progress(finished, B, stage)`` at the start and after every chunk (the CLI's progress
    bar). ``dtype``: of the arrays and the solve (default: JAX's default float).
    """

    t0 = time.perf_counter()
    source = model_source(model, bounds)
    check_choice("metric", metric, METRICS)
    check_choice("solver", solver, BATCH_SOLVERS)
    check_choice("guess", guess, _guess.GUESSES, label="valid")
    dtype = jnp.zeros(()).dtype if dtype is None else jnp.dtype(dtype)
    wi = np.asarray(wi, float)
    wo = np.asarray(wo, float)
    f = np.asarray(values, float)
    if f.ndim == 2:
        f = f[..., None]
    if wi.ndim == 2 and f.ndim == 3:  # one geometry shared by every problem: kept (1, M, 3)
        wi, wo = wi[None], wo[None]
    if (wi.ndim != 3 or wi.shape[-1] != 3 or wo.shape != wi.shape or f.ndim != 3
            or wi.shape[1] != f.shape[1] or wi.shape[0] not in (1, f.shape[0])):
        raise FitError(f"expected wi, wo (B, M, 3) or (M, 3) and values (B, M, C); got "
                       f"{wi.shape}, {wo.shape}, {f.shape}")
    B, M, C = f.shape
    w = None if weight is None else np.broadcast_to(
        np.asarray(weight, float).reshape(f.shape[:2] + (-1,)), f.shape).copy()
    sg = None if sigma is None else np.broadcast_to(
        np.asarray(sigma, float).reshape(f.shape[:2] + (-1,)), f.shape).copy()
    check_inputs(wi=wi, wo=wo, values=f, weight=w, sigma=sg)
    if max_zenith_deg is not None:
        cz = math.cos(math.radians(max_zenith_deg))
        keep = (wi[..., 2] >= cz) & (wo[..., 2] >= cz)
        w = np.where(np.broadcast_to(keep[..., None], f.shape), 1.0 if w is None else w, 0.0)
    floor = RELATIVE_FLOOR * np.maximum(np.max(np.abs(f), axis=(1, 2)), DATA_SCALE_FLOOR)
    fix = dict(fix or {})
    init = dict(init or {})
    free = resolve_free(source, fix, init, free)  # unknown names raise with the valid list
    defaults = source.defaults()
    start, fixed = {}, {}
    for p in source.params:
        if p.name in fix:
            v, what = fix[p.name], "fix"
        else:
            v, what = init.get(p.name, defaults[p.name]), "init"
        a = p.batched_value(v, B, C, what)
        for row in (a[0], a[-1]):
            p.check(row, source.name)
        (start if p.name in free else fixed)[p.name] = a
    problem = FitProblem(
        source=source,
        layout=ParamLayout.of(source, free, [start[n].shape[1:] for n in free]),
        fixed={},
        metric=metric,
        cos_weight=cos_weight,
    )
    layout = problem.layout
    u0 = layout.inverse(start, lead=(B,))
    raw = tuple(None if a is None else a.astype(dtype, copy=False)
                for a in (wi, wo, f, w, sg, floor))
    if w is None:
        m_eff, nused = np.full(B, M * C, dtype), np.full(B, M)
    else:
        m_eff = np.sum(w.reshape(B, -1) > 0, axis=1).astype(dtype)
        nused = np.sum(np.any(w > 0, axis=-1), axis=1)
    fixed = {k: v.astype(dtype) for k, v in fixed.items()}

    if shard is None:
        shard = len(jax.local_devices()) > 1
    p = u0.shape[1]
    state = LMState.start(u0, dtype, max_steps, rtol, atol)
    vary = tuple(n for n in free if n not in init) if guess == "grid" else ()
    # one geometry, the same start and fixed values in every problem (no per-problem init or
    # fix) and a metric whose model side is data-free: the guess's candidate model values are
    # the same for every problem, computed once, so a finer design on more samples costs
    # little (guess.shared_losses) and leaves fewer steps (CHUNK_SCHEDULE_SHARED)
    shared = (bool(vary) and wi.shape[0] == 1 and metric in _guess.SHARED_METRICS
              and bool(np.all(state.u == state.u[:1]))
              and all(bool(np.all(v == v[:1])) for v in fixed.values()))
    try:
        schedule = chunk_schedule(chunk_steps, max_steps,
                                  CHUNK_SCHEDULE_SHARED if shared else CHUNK_SCHEDULE)
    except ValueError as e:
        raise FitError(str(e)) from None
    rounds = []
    if group is not None and (not isinstance(group, int | np.integer) or group < 1):
        raise FitError(f"group must be a positive int or None, got {group!r}")
    run = runner(problem, solver, rtol, atol, bool(shard),
                 None if group is None else int(group), sg is not None)
    unit = run.unit
    # one block shape per call (compiled once): the whole batch without groups (a plain
    # vmapped solve), else the batch's bucket up to MAX_BLOCK lanes
    block = (int(math.ceil(B / unit) * unit) if group is None else block_lanes(B, unit))
    every = np.arange(B)
    # the problem axis of the data padded to whole blocks (repeating the last problem; never
    # read: every lane index is < B), so that every batch of one block-size class has the same
    # shapes and reuses one compilation (a batch of 5 and one of 7 problems: both 16 rows)
    rows = int(math.ceil(B / block) * block)
    # (a geometry of leading axis 1 stays shared even when B = 1: gather() then keeps it once
    # per group, and the shared guess sees it as one geometry)
    raw = tuple(a if i < 2 and a.shape[0] == 1 else _pad_rows(a, B, rows)
                for i, a in enumerate(raw))

    # the data side of the metric once (brdf_fit.fitting.problem.metric_parts), on the device
    data = run.prepare(raw)

    def whole(u, *extra):
        return lambda pad, n: (u[pad], *(x[pad] for x in extra),
                               {k: v[pad] for k, v in fixed.items()})

    def record(**kw):
        rounds.append({"lanes": int(math.ceil(B / block) * block), "active": B, "steps": 0,
                       **kw})

    if vary:  # coarse design over the parameters without a start value (fitting.guess)
        ts = time.perf_counter()
        n_cand = _guess.SHARED_CANDIDATES if shared else _guess.GUESS_CANDIDATES
        lay = _guess.layout(problem, vary, n_cand)
        chan_of = _guess.channel_index(problem, C)
        sub = _guess.subsample(M, _guess.SHARED_SAMPLES if shared else _guess.GUESS_SAMPLES)
        if shared:  # one set of candidates for all problems, the whole batch in one call
            cands = _guess.design(problem, state.u[:1], vary, defaults, n_cand).astype(dtype)
            fn = run.shared_guess(lay, chan_of, block // run.ndev)
            u, q = fn(run.put(np.arange(rows, dtype=np.int32)), data, jnp.asarray(cands[0]),
                      {k: jnp.asarray(v[0]) for k, v in fixed.items()},
                      None if sub.size == M else jnp.asarray(sub))
        else:
            cands = _guess.design(problem, state.u, vary, defaults, n_cand).astype(dtype)
            u, q = blocked(run, run.guess(lay, chan_of), every, block,
                           lambda pad, n: (cands[pad], {k: v[pad] for k, v in fixed.items()}),
                           (run.subsample(data, sub), data))
        # the shared call returns every padded row, blocked() the B real ones
        state = dataclasses.replace(state, u=np.array(u[:B]))
        if q:
            state = state.with_quad(tuple(np.asarray(x)[:B] for x in q))
        record(guess=True, candidates=int(cands.shape[1]), samples=int(sub.size), lane_steps=0,
               shared=shared, seconds=round(time.perf_counter() - ts, 4))
    if solver == "batch-lm" and state.A is None:  # the carried quantities at the start
        ts = time.perf_counter()
        state = state.with_quad(blocked(run, run.init, every, block, whole(state.u), data))
        record(init=True, lane_steps=0, seconds=round(time.perf_counter() - ts, 4))
    if progress is not None:
        progress(0, B, "start")
    run_chunks(run, state, data, fixed, schedule, max_steps, solver, chunk_steps is None,
               rounds, block, progress)
    ts = time.perf_counter()
    if run.finalise_carried:
        # from the carried normal equations, no model evaluation (the pooled estimator needs
        # nothing else; the sandwich's HC3 needs each residual's leverage: one more pass, the
        # cost of one step, below)
        args = (state.u, state.cost, state.A, state.meat, m_eff, np.full(B, M * C, dtype),
                fixed)  # padded to the data's rows: one compilation per block-size class
        out = run.finalise_state(*jax.tree.map(lambda a: _pad_rows(a, B, rows), args))
        phys, se, loss, rms, codes = jax.tree.map(lambda a: np.asarray(a)[:B], out)
    else:
        phys, se, loss, rms, codes = blocked(run, run.finalise, every, block,
                                             whole(state.u, m_eff), data)
    params = {name: (np.asarray(phys[name]) if name in phys else fixed[name])
              for name in source.names}
    params = {name: np.broadcast_to(v, (B, *np.shape(v)[1:])) for name, v in params.items()}
    bounds_hit = {n: at_bound(tr, params[n]) for n, tr in zip(free, layout.transforms,
                                                               strict=True)}
    if p:  # undefined standard errors: NaN, with the reason (stderr_codes; at bound first)
        codes = np.asarray(codes, int)
        codes = np.where((codes != 3) & layout.join(bounds_hit, xp=np), 1, codes)
        se = np.where(codes == 0, se, np.nan)
    stderr = layout.split(se)
    notes = {k: v for k, v in layout.split(stderr_notes(np.asarray(codes))).items()
             if (v != "").any()}
    bad = np.asarray(codes).reshape(B, -1) == 3
    record(finalise=True, lane_steps=0, seconds=round(time.perf_counter() - ts, 4))
    return BatchFitResult(
        model_name=source.name,
        params=params,
        stderr=stderr,
        converged=state.ok.astype(bool) & ~bad.any(axis=1),
        steps=state.steps.astype(int),
        loss=loss,
        residual_rms=rms,
        n_samples=nused.astype(int),
        n_params=p,
        metric=metric,
        solver=solver,
        seconds=time.perf_counter() - t0,
        rounds=rounds,
        n_devices=run.ndev,
        at_bound=bounds_hit,
        stderr_note=notes,
        source=source,
    )
