"""Fit a model to gonioreflectometer data (:class:`~brdf_fit.data.GonioData`): a registry name
(flat, named parameters) or any built model (an :class:`~brdf_fit.models.AbstractBRDF` pytree,
composed or not; its floating-point leaves, named by attribute path). The problem itself (which
parameters are free, their flat layout and transforms, the residual metrics) is
:class:`brdf_fit.fitting.problem.FitProblem`; see :mod:`brdf_fit.fitting.problem`.

Parameters are optimised in unconstrained space through their intervals (``[lo, hi]``: scaled
logistic; ``[lo, inf)``: ``lo + softplus``), any subset held fixed, with a least-squares solver
from optimistix (Levenberg-Marquardt by default; Gauss-Newton with a backtracking line search,
plain Gauss-Newton and Dogleg selectable). Residual metrics: ``log`` (default), ``cuberoot``,
``relative``, ``absolute`` (:func:`brdf_fit.fitting.problem.metric_parts`); with per-sample
``sigma`` the residual is standardised, otherwise weighted by ``sqrt(weight)``;
``cos_weight`` multiplies by ``cos(theta_i)``; ``max_zenith_deg`` drops samples beyond that
zenith (either direction).

Standard errors come from the Jacobian ``J`` of the residuals with respect to the physical
parameters at the optimum (:func:`covariance`). With per-sample ``sigma`` the residuals are
standardised and ``cov = s^2 (J^T J)^-1``, ``s^2 = RSS/(m - p)`` (the reduced residual
variance, as ``scipy.optimize.curve_fit`` does by default). Without ``sigma`` the residuals'
variance is not constant (1% multiplicative noise gives a log-metric residual of ~1% at the
peak and ~0 in the dark tails), and a pooled ``s^2`` made 3-sigma intervals cover the truth in
only 57-82% of 200 trials (measured for ggx, beckmann, modified-phong); there a
heteroscedasticity-consistent sandwich
``cov = (J^T J)^-1 J^T diag(r_i^2 / (1 - h_i)^2) J (J^T J)^-1`` is used, with the leverages
``h_i = J_i (J^T J)^-1 J_i^T`` (HC3: J. G. MacKinnon and H. White, J. Econometrics 29, 1985;
after H. White, Econometrica 48(4), 1980;
:data:`brdf_fit.fitting.solvers.SANDWICH` says why not HC1's ``m/(m - p)`` factor, whose
intervals were up to 4.4x too narrow on 24 directions, benchmarks/results/coverage.md; large
data solved in chunks keep HC1, their leverages being ~p/m). A standard error is undefined
(NaN, the reason in ``FitResult.stderr_note``) for a parameter at an end of its interval, for
one the data do not determine (a vanishing Jacobian column or a rank-deficient direction of
``J^T J``: :func:`brdf_fit.fitting.problem.stderr_codes`; ``pinv`` would drop that direction
and report a confident, meaningless number), and for every parameter when the residuals or
``J`` are not finite (the fit then ends not converged).

The optimisation itself (:func:`solve`) is pure JAX: it runs under ``jit`` and ``vmap`` and is
differentiable with respect to the data through optimistix's implicit adjoint.

Start-up cost (issue 15): the three jitted functions of a static problem (:func:`_compiled`) are
shared by every fit of that problem in a process and, where ``$BRDF_FIT_EXPORT_DIR`` names a
folder (the command line sets one in its cache folder), kept across processes as exported
programs (:mod:`brdf_fit.fitting._export`): a second process neither traces nor lowers the
model and the solver, and with JAX's persistent compilation cache it compiles nothing either.
The data are prepared, padded and subsampled in NumPy (no eager JAX operation: each is a
dispatch, a compilation or a cache look-up of its own), and optimistix is imported only when a
solver is traced.
"""

from __future__ import annotations

import dataclasses
import math
import time
import warnings
from collections.abc import Callable, Sequence

import jax
import jax.numpy as jnp
import numpy as np

from brdf_fit.core.validate import ParameterError, PrecisionWarning
from brdf_fit.data import GonioData
from brdf_fit.fitting import bounds as _bounds
from brdf_fit.fitting import chunked as _chunked
from brdf_fit.fitting import guess as _guess
from brdf_fit.fitting._export import ExportedCall, export_key
from brdf_fit.fitting.problem import (
    DATA_SCALE_FLOOR,
    METRICS,
    RELATIVE_FLOOR,
    FitError,
    FitProblem,
    ParamLayout,
    Transform,
    at_bound,
    check_choice,
    entry_labels,
    model_source,
    resolve_free,
    stderr_codes,
    stderr_notes,
    undetermined,
)
from brdf_fit.fitting.result import STRONG_CORRELATION, FitResult, correlation, json_floats
from brdf_fit.fitting.solvers import (
    BUCKETS_PER_OCTAVE,
    MIN_BUCKET,
    SOLVERS,
    _solver_classes,
    bucket,
    covariance,
    covariance_normal,
    dense_bucket,
    solve,
)

__all__ = ["FitResult", "fit", "solve", "covariance", "covariance_normal", "METRICS", "SOLVERS",
           "RELATIVE_FLOOR", "Transform", "FitError", "FitProblem", "at_bound", "bucket",
           "dense_bucket", "BUCKETS_PER_OCTAVE", "MIN_BUCKET", "correlation", "STRONG_CORRELATION",
           "json_floats"]


def __getattr__(name: str):
    if name == "LineSearchGaussNewton":  # made on first use (brdf_fit.fitting.solvers)
        return _solver_classes()["gauss-newton"]
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def _pad(arrays, n: int, at_least: int | None = None):
    """``arrays`` of :func:`_arrays` (``n`` samples) padded to :func:`dense_bucket` (n) samples
    that do not count: weight 0 (their residuals are exactly 0: the metric multiplies by sqrt(w), or
    with sigma sets the scale to 0 where w = 0), at the normal (wi = wo = z, finite for every
    model), value 0 and sigma 1."""
    wi, wo, f, w, sigma, floor = arrays
    extra = dense_bucket(max(n, at_least or 0)) - n
    if extra == 0:
        return arrays

    def grow(a, fill):  # NumPy: an eager jnp op costs a dispatch (and a cache look-up) each
        return np.concatenate([a, np.full((extra, *a.shape[1:]), fill, a.dtype)])

    z = np.zeros((extra, 3), wi.dtype)
    z[:, 2] = 1.0
    return (np.concatenate([wi, z]), np.concatenate([wo, z]), grow(f, 0.0), grow(w, 0.0),
            None if sigma is None else grow(sigma, 1.0), floor)


def _arrays(data: GonioData, max_zenith_deg, dtype):
    keep = np.ones(data.n, bool)
    if max_zenith_deg is not None:
        cz = math.cos(math.radians(max_zenith_deg))
        keep &= (data.wi[:, 2] >= cz) & (data.wo[:, 2] >= cz)
    if not keep.any():
        raise FitError("no samples to fit" if max_zenith_deg is None else
                       f"no samples left after the max_zenith_deg cut ({max_zenith_deg} deg)")
    def kept(a):  # no copy where every sample is kept (a whole MERL file: 100 MB less)
        return None if a is None else np.asarray(a if keep.all() else a[keep], dtype)

    f = kept(data.value)
    floor = RELATIVE_FLOOR * max(float(np.max(np.abs(f))), DATA_SCALE_FLOOR)
    # NumPy arrays (the jitted functions take them as they are): padding and subsampling them
    # are then no eager JAX operations
    return (kept(data.wi), kept(data.wo), f, kept(data.weight), kept(data.sigma),
            floor), int(keep.sum())


@dataclasses.dataclass(frozen=True)
class _Jitted:
    """The compiled functions of one static problem (:func:`_compiled`); each takes the fixed
    parameter values as its last argument, so problems that differ only in them share it.
    ``run``: solve and the final loss; ``per_channel``: the start design's losses;
    ``finish``: the physical parameters, residuals and Jacobian at the optimum (three jitted
    functions, not five: each costs a trace in every new process)."""

    run: Callable
    per_channel: Callable
    finish: Callable


def _run_and_loss(problem, u, a, solver, rtol, atol, max_steps):
    u1, ok, steps = solve(problem, u, a, solver, rtol, atol, max_steps)
    return u1, ok, steps, 0.5 * jnp.sum(problem.residuals(u1, a) ** 2)


def _finish(problem, u, a):
    phys = problem.unflatten(u)
    x = problem.layout.join(phys)
    r = problem.residuals_phys(x, a)
    J = (jax.jacfwd(problem.residuals_phys)(x, a) if x.shape[0]
         else jnp.zeros((r.shape[0], 0), r.dtype))
    return phys, x, r, J


_JITTED: dict = {}
#: compiled problems kept (oldest dropped first); a select over ten candidates uses ten
MAX_JITTED = 64


def _compiled(problem: FitProblem, n_channels: int, solver, rtol, atol, max_steps) -> _Jitted:
    """The jitted solver, loss, start-design loss, residuals and Jacobian of ``problem``,
    shared by every :func:`fit` of the same static problem (``problem.key``: model source,
    layout, metric, cos_weight; the names and shapes of the fixed values; the options). A
    fresh ``jax.jit`` per call, as before, traced and compiled anew each time even for
    the same model and data shape: 1-5 s per fit, most of a warm ``select``."""
    key = (problem.key, problem.fixed_signature(), int(n_channels), solver, float(rtol),
           float(atol), int(max_steps))
    got = _JITTED.get(key)
    if got is not None:
        return got
    template = problem.with_fixed({})

    def P(fx):
        return template.with_fixed(fx)

    C = int(n_channels)
    static = export_key(problem, key)
    got = _Jitted(
        run=ExportedCall(jax.jit(lambda u, a, fx: _run_and_loss(P(fx), u, a, solver, rtol, atol,
                                                                max_steps)), "run", static),
        per_channel=ExportedCall(jax.jit(jax.vmap(lambda u, a, fx: 0.5 * jnp.sum(
            P(fx).residuals(u, a).reshape(-1, C) ** 2, axis=0), in_axes=(0, None, None))),
            "per_channel", static),
        finish=ExportedCall(jax.jit(lambda u, a, fx: _finish(P(fx), u, a)), "finish", static),
    )
    if len(_JITTED) >= MAX_JITTED:
        _JITTED.pop(next(iter(_JITTED)))
    _JITTED[key] = got
    return got


#: what a fit that did not converge tells its user to try
NOT_CONVERGED_ADVICE = ("; try a start nearer the answer (init), holding fixed what the data do "
                        "not determine (fix; see the undetermined entries), a fit of a subset "
                        "first, or a model that represents the data")


def _dense_stderr(jitted, u, arrays, fx, real: int, m_eff: int, sandwich: bool, p: int):
    """``(physical parameters, standard errors (flat), residual rms, stderr codes, finite,
    covariance (p, p) or None)`` of the dense path at ``u``: the residuals and their Jacobian
    in the physical parameters, jitted (eagerly, each of the ~90 operations compiles on its
    own: 3-5 s per fit, measured); the padded samples' residuals (zero) and Jacobian rows are
    dropped (``real`` rows)."""
    phys, flat_phys, r, J = jitted.finish(u, arrays, fx)
    r = np.asarray(r)[:real]
    params = {k: np.asarray(v) for k, v in phys.items()}
    rms = float(np.sqrt(np.mean(r**2))) if r.size else 0.0
    if not p:
        return params, np.zeros(0), rms, np.zeros(0, int), True, None, None
    J = np.asarray(J)[:real]
    grad = (np.asarray(flat_phys), J, r)
    finite = bool(np.all(np.isfinite(J)) and np.all(np.isfinite(r)))
    # J^T J of finite J may still overflow: stderr_codes tests the product itself
    with np.errstate(over="ignore"):
        codes = (stderr_codes(J.T @ J) if finite
                 else stderr_codes(np.full((p, p), np.nan), False))
    try:
        cov = covariance(J, r, m_eff, sandwich=sandwich) if finite else None
        se = np.sqrt(np.maximum(np.diag(cov), 0.0)) if finite else np.full(p, np.nan)
    except np.linalg.LinAlgError:
        cov, se = None, np.full(p, np.nan)
    return params, se, rms, codes, finite, cov, grad


def fit(
    data: GonioData,
    model,
    fix: dict | None = None,
    init: dict | None = None,
    metric: str = "log",
    solver: str = "lm",
    cos_weight: bool = False,
    max_zenith_deg: float | None = None,
    multistart: int = 1,
    seed: int = 0,
    max_steps: int = 256,
    rtol: float = 1e-10,
    atol: float = 1e-10,
    checks: Sequence[str] = (),
    guess: str = "grid",
    free: Sequence[str] | None = None,
    bounds: dict | None = None,
    pad_to: int | None = None,
    time_limit: float | None = None,
    progress: Callable | None = None,
) -> FitResult:
    """Fit ``model`` to ``data``: a registry name (or :class:`~brdf_fit.core.params.Entry`),
    or any built model (an :class:`~brdf_fit.models.AbstractBRDF` pytree, composed or not),
    whose floating-point leaves are its parameters, named by attribute path
    (``"distribution.alpha_x"``, ``"fresnel.f0"``, ``"lobes.1.distribution.alpha_x"``; see
    :mod:`brdf_fit.fitting.problem`). ``FitResult.model`` is the fitted model (for a built one:
    the template with the fitted values put back); ``params`` and ``stderr`` are keyed by name
    or path.

    ``fix``: parameters held at given values. ``init``: start values (default: the registry
    defaults, broadcast to the data's channel count for channel parameters; for a built model
    its own values). ``free``: the parameters to fit (default: all that are not in ``fix``;
    the others stay at their ``init``/default values); for a built model a path may name a
    component, selecting every parameter under it. ``bounds``: built models only,
    ``{path: (lo, hi)}`` (None: open on that side) overriding or supplying a leaf's interval; a
    leaf whose component declares no interval and that has no ``bounds`` entry is fitted
    unbounded. ``multistart``: additional random starts (normal perturbations of the start in
    unconstrained space, seeded); the lowest final loss wins. ``checks``: names of
    :mod:`brdf_fit.verify.checks` to run on the fitted model (reported in the result).
    ``guess``: ``"grid"`` (default) starts the parameters that have no ``init`` value from the
    best of a coarse design evaluated on a subsample of the data (:mod:`brdf_fit.fitting.guess`;
    the defaults are one of its candidates); ``"none"`` starts them at the defaults.
    ``pad_to``: pad the samples (weight 0, not counted anywhere) to the bucket of at least this
    many, so that a series of fits of different sizes shares one compiled solver (every fit pads
    to :func:`dense_bucket` of its own size anyway).

    Large data (at least :data:`brdf_fit.fitting.chunked.CHUNKED_FROM` residuals) with the
    default solver are fitted by :mod:`brdf_fit.fitting.chunked`: normal equations summed over
    chunks of samples (memory flat in the number of samples), a coarse stage on a random subset
    first. There ``time_limit`` (seconds) stops a solve that has not converged by then
    (reported as such), and ``progress(stage, step, loss)`` is called after every step.
    """

    t0 = time.perf_counter()
    source = model_source(model, bounds)
    check_choice("metric", metric, METRICS)
    check_choice("solver", solver, SOLVERS)
    check_choice("guess", guess, _guess.GUESSES, label="valid")
    fix = dict(fix or {})
    init = dict(init or {})
    free = resolve_free(source, fix, init, free)  # unknown names raise with the valid list
    data.validate()
    dtype = np.dtype(jax.dtypes.canonicalize_dtype(np.float64))  # float32 without x64
    if dtype != np.float64:
        # a first-contact trap: the README's gold fit from a neutral start, run in a fresh
        # interpreter without x64, ended at eta = 0 (a constraint error) in float32, and fits
        # to the noise in float64
        warnings.warn(PrecisionWarning(
            f"fit({source.name}): jax_enable_x64 is off, so this fit runs in float32, whose "
            "solver tolerances and standard errors are not trustworthy; call "
            "jax.config.update('jax_enable_x64', True) first (the command line does)"),
            stacklevel=2)
    arrays, n_used = _arrays(data, max_zenith_deg, dtype)
    C = data.n_channels
    defaults = source.defaults()
    start, fixed = {}, {}
    for p in source.params:
        v = p.start_value(fix.get(p.name, init.get(p.name, defaults[p.name])), C)
        p.check(v, source.name)
        (start if p.name in free else fixed)[p.name] = v
    problem = FitProblem(
        source=source,
        layout=ParamLayout.of(source, free, [start[n].shape for n in free]),
        fixed={k: jnp.asarray(v, dtype) for k, v in fixed.items()},
        metric=metric,
        cos_weight=cos_weight,
    )
    layout = problem.layout
    u0 = layout.inverse(start)
    jitted = _compiled(problem, C, solver, rtol, atol, max_steps)
    fx = problem.fixed

    vary = tuple(n for n in free if n not in init) if guess == "grid" else ()
    if vary:
        cands = _guess.design(problem, u0, vary, defaults)
        sub = _guess.subsample(n_used)
        sub_arrays = _pad(tuple(a[sub] if isinstance(a, np.ndarray) else a for a in arrays),
                          len(sub))
        losses = np.asarray(jitted.per_channel(jnp.asarray(cands, dtype), sub_arrays, fx))
        u0 = np.asarray(_guess.pick(np, cands, losses, _guess.layout(problem, vary),
                                    _guess.channel_index(problem, C)))
    rng = np.random.default_rng(seed)
    starts = [u0 if s == 0 else u0 + rng.normal(0.0, 1.0, u0.shape)
              for s in range(max(1, multistart))]
    m_eff = int(np.sum(np.asarray(arrays[3]).reshape(-1) > 0))
    sandwich = arrays[4] is None
    p = int(layout.size)
    stopped = ""
    if solver == "lm" and n_used * C >= _chunked.CHUNKED_FROM and p:
        # large data: normal equations summed over chunks, coarse to fine (fitting.chunked)
        cdata = _chunked.chunk_data(problem, arrays, n_used, seed)
        del arrays  # the chunks hold the data now (on the device)
        best = None
        for u_start in starts:
            sol = _chunked.solve_chunked(problem, np.asarray(u_start, dtype), cdata, C,
                                         sandwich, max_steps, rtol, atol, time_limit,
                                         progress)
            if best is None or sol.cost < best.cost:
                best = sol
        ok, steps, stopped = best.converged, best.steps, best.stopped
        params, se, loss, rms, codes, cov = _chunked.finish_chunked(problem, best, C, m_eff,
                                                                   n_used * C, sandwich)
        finite = bool(np.isfinite(best.A).all() and math.isfinite(best.cost))
    else:
        arrays = _pad(arrays, n_used, pad_to)
        best = None
        for u_start in starts:
            *sol, loss = jitted.run(jnp.asarray(u_start, dtype), arrays, fx)
            loss = float(loss)
            if best is None or loss < best[1]:
                best = (sol, loss)
        (u, ok, steps), loss = best
        params, se, rms, codes, finite, cov, grad = _dense_stderr(
            jitted, u, arrays, fx, n_used * C, m_eff, sandwich, p)
        if grad is not None and layout.at_bound(params).any():
            # an optimum on a bound (brdf_fit.fitting.bounds). Not converged: the entries there
            # are put far onto their transform's plateau (Jacobian column ~0, so the solver's
            # step in them ~0) and the same compiled solver goes on. Converged or not: an entry
            # the loss pulls inward (a start on a bound stalls there: its Jacobian column is
            # ~0 too) is released just inside and the solver goes on; converged only where no
            # bound entry would lower the loss by moving inward
            def again(u_new):
                nonlocal u, ok, steps, loss, params, se, rms, codes, finite, cov, grad
                *sol, loss_new = jitted.run(jnp.asarray(u_new, dtype), arrays, fx)
                if float(loss_new) <= loss:
                    (u, ok, steps_new), loss = sol, float(loss_new)
                    steps = int(steps) + int(steps_new)
                    params, se, rms, codes, finite, cov, grad = _dense_stderr(
                        jitted, u, arrays, fx, n_used * C, m_eff, sandwich, p)

            if not bool(ok):
                again(_bounds.onto_plateau(layout, np.asarray(u), grad[0]))
            ok = bool(ok) and _bounds.inward_gradient_free(layout, *grad)
            u_in = None if ok else _bounds.release_inward(layout, np.asarray(u), *grad)
            if u_in is not None:
                ok = False
                again(u_in)
                ok = bool(ok) and _bounds.inward_gradient_free(layout, *grad)
            if not ok:
                ok = _bounds.converged_at_bounds(layout, *grad, rtol, atol)
    stderr, bound_names = {}, ()
    if p:
        bound = layout.at_bound(params)
        bound_names = tuple(n for n, b in layout.split(bound).items() if b.any())
        if not finite:
            codes = np.full(p, 3)
        codes = np.where((codes != 3) & bound, 1, codes)  # the more specific reason
        se = np.where(codes == 0, se, np.nan)
        stderr = layout.split(se)
    converged = bool(ok) and not (codes == 3).any()
    notes = {k: v for k, v in layout.split(stderr_notes(codes)).items() if (v != "").any()}
    try:
        fitted = source.build({k: jnp.asarray(v) for k, v in params.items()})
    except ParameterError as exc:
        # the optimum breaks a joint constraint the per-parameter intervals do not express
        # (modified Phong's rho_d + rho_s <= 1): the solver never sees it (tracers are not
        # validated), the concrete model refuses it; say so instead of a bare ParameterError
        shown = ", ".join(f"{k}={np.round(np.asarray(v), 4).tolist()}" for k, v in params.items())
        raise FitError(f"{source.name}: the fitted parameters ({shown}) break a constraint of "
                       f"the model ({exc}); fix a parameter (--fix), start elsewhere or fit "
                       "another metric") from None
    result = FitResult(
        model_name=source.name,
        model=fitted,
        params={k: params[k] for k in source.names},
        stderr=stderr,
        converged=converged,
        steps=int(steps),
        metric=metric,
        loss=loss,
        residual_rms=rms,
        n_samples=n_used,
        n_params=p,
        seconds=0.0,
        fixed={k: np.asarray(v) for k, v in fixed.items()},
        starts=max(1, multistart),
        message="" if converged else (
            "non-finite residuals or Jacobian at the optimum: standard errors undefined"
            if (codes == 3).any() else
            (f"stopped at the time limit ({time_limit:g} s) before converging"
             if stopped == "time_limit" else
             f"stopped after {int(steps)} steps without converging: the loss no longer "
             "decreases while parameters still move"
             + (f" ({', '.join(bound_names)} at an end of its interval)" if bound_names else "")
             if stopped == "stalled" else
             f"did not converge in {max_steps} steps")
            + NOT_CONVERGED_ADVICE),
        stderr_note=notes,
        at_bound=bound_names,
        undetermined=tuple(
            lab for n, se in stderr.items()
            for lab, bad in zip(entry_labels(n, np.shape(params[n]), tuple(data.channels)),
                                undetermined(params[n], se, notes.get(n)).reshape(-1),
                                strict=True) if bad),
        correlation=correlation(cov, codes) if p else None,
        correlation_labels=tuple(lab for n in layout.names for lab in entry_labels(
            n, np.shape(params[n]), tuple(data.channels))),
    )
    if checks:
        from brdf_fit.verify.checks import run_checks

        result.checks = run_checks(fitted, checks=list(checks), name=source.name,
                                   expected_failures=source.expected_failures)
    result.seconds = time.perf_counter() - t0
    return result
