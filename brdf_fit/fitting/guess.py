"""Initial guesses for fitting: a coarse space-filling design over the free parameters.

Least-squares solvers converge from anywhere near the optimum and wander (or stop on a plateau)
from far away; the registry defaults are typical values, not a start for a particular dataset.
:func:`grid_guess` evaluates the fit's own loss at a small fixed design of candidate parameter
vectors, on a subsample of the data, and starts the solver from the best one.

The design lives in the solver's unconstrained space (:class:`brdf_fit.fitting.problem.Transform`):

- a parameter with an interval ``[lo, hi]`` (scaled logistic) takes ``u`` in
  ``[-U_SPAN, U_SPAN]``: with ``U_SPAN = 4`` the physical value covers 1.8% .. 98.2% of the
  interval, and near ``lo`` the logistic is exponential, so small roughnesses are log-spaced
  (alpha from 0.018 up);
- a parameter bounded on one side (softplus) takes ``(x - lo)`` from ``(d - lo) e^-LOG_SPAN`` to
  ``(d - lo) e^LOG_SPAN`` about its registry default ``d`` (a Phong exponent 100 covers ~5 .. 2000);
- an unbounded one ``d +- LOG_SPAN max(|d|, 1)``.

A channel parameter (an RGB ``f0``) is one design dimension with the same value in every channel:
the solver separates the channels, the design only has to find the level. The design is a Halton
sequence (bases 2, 3, 5, ...; J. H. Halton, Numerische Mathematik 2, 1960), deterministic, with
the start the caller supplied (registry defaults or ``init``) as candidate 0, so the guess is
never worse than that start on the subsample. Parameters given in ``init`` or held fixed are not
varied.

A channel parameter here is one its model declares as such (a registry ``channels`` parameter, a
component field declared ``channels=True``); any other vector parameter is one design dimension
too, with the same value in every entry.

This is a generic coarse grid, not a moment-matching estimator (which needs a closed form per
model); its cost is ``GUESS_CANDIDATES x GUESS_SAMPLES`` residual evaluations (no Jacobians),
about one solver step for 300 samples.

A batch of one geometry (fit_batch with ``wi, wo`` (M, 3)), one start and one set of fixed
values, and a metric of :data:`SHARED_METRICS` (the texture case) has the same candidate model
values in every problem: fit_batch evaluates them once (:func:`candidate_values`) and forms each
problem's losses by matrix products (:func:`shared_losses`), which makes a finer design on all
the samples affordable (:data:`SHARED_CANDIDATES`, :data:`SHARED_SAMPLES`).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from brdf_fit.fitting.problem import METRIC_H

__all__ = ["halton", "design", "layout", "pick", "channel_index", "subsample",
           "candidate_losses", "candidate_values", "losses_of_values", "shared_losses",
           "shared_terms",
           "GUESS_CANDIDATES", "SHARED_CANDIDATES", "SHARED_SAMPLES", "SHARED_METRICS",
           "GUESS_SAMPLES",
           "GUESSES"]

#: Candidate parameter vectors evaluated (the caller's start included).
GUESS_CANDIDATES = 24
#: Candidates of the design when every problem of a batch has the same directions, start and
#: fixed values (:func:`shared_losses`): the model is then evaluated once per batch, and a
#: candidate costs each problem only two multiply-adds per sample and channel. Measured on
#: 16,384 GGX problems (300 samples, 1% noise, float64, one process; 91 candidates in the
#: product design): after 24 candidates on 64 samples a mean of 5.68 LM steps (median 5, p99
#: 14), after 24 on all 300 5.41, after 96 on 64 4.60, after 96 on all 300 4.55 (median 4,
#: p99 9); see :data:`brdf_fit.fitting._schedule.CHUNK_SCHEDULE_SHARED`.
SHARED_CANDIDATES = 96
#: Samples the shared guess compares its candidates on (evenly strided when there are more):
#: all of a 300-sample measurement. A subsample that misses the specular peak favours sharp,
#: bright candidates that it cannot see: on noisy data (30% lognormal noise about the GGX
#: defaults, 64 problems) the best of 96 candidates on 64 samples started 20 problems from a
#: loss up to 440x the defaults' on the full data, and 5 of them converged to a local minimum
#: (loss 5.8x); on all 300 samples none did. Cost per problem: 2 x candidates x samples x
#: channels multiply-adds.
SHARED_SAMPLES = 320
#: Metrics whose model side ``h(m * mul)`` is the same for every problem of one geometry
#: (``mul`` from the directions alone), the condition of :func:`shared_losses`.
SHARED_METRICS = ("log", "cuberoot", "absolute")
#: Samples (direction pairs) of the subsample the candidates are compared on (evenly strided).
GUESS_SAMPLES = 64
#: Half-width of the design in the unconstrained space of a bounded (logistic) parameter.
U_SPAN = 4.0
#: Half-width, in e-folds about the default, for a half-bounded (softplus) parameter.
LOG_SPAN = 3.0
#: Valid values of the ``guess`` argument of fit() / fit_batch().
GUESSES = ("grid", "none")

_PRIMES = (2, 3, 5, 7, 11, 13, 17, 19, 23, 29, 31, 37, 41, 43, 47, 53)


def halton(n: int, d: int) -> np.ndarray:
    """The first ``n`` points (after the origin) of the ``d``-dimensional Halton sequence in
    ``[0, 1)^d`` (radical inverses in the first ``d`` primes)."""
    if d > len(_PRIMES):
        raise ValueError(f"halton: at most {len(_PRIMES)} dimensions, got {d}")
    out = np.zeros((n, d))
    for j in range(d):
        b = _PRIMES[j]
        for i in range(n):
            k, f, x = i + 1, 1.0, 0.0
            while k > 0:
                f /= b
                x += f * (k % b)
                k //= b
            out[i, j] = x
    return out


def _column_design(transform, default, t):
    """Unconstrained values for design coordinates ``t`` in [0, 1] of one parameter."""
    s = 2.0 * t - 1.0  # [-1, 1]
    lo, hi = transform.lo, transform.hi
    d = float(np.mean(np.asarray(default, float)))
    if lo is not None and hi is not None:
        return s * U_SPAN
    if lo is not None:
        y = max(d - lo, 1e-3) * np.exp(s * LOG_SPAN)
        return transform.inverse(lo + y)
    if hi is not None:
        y = max(hi - d, 1e-3) * np.exp(s * LOG_SPAN)
        return transform.inverse(hi - y)
    return d + s * LOG_SPAN * max(abs(d), 1.0)


def _split_vary(problem, vary):
    lay = problem.layout
    # a model that couples its channels has no channel-separable parameter: every one is a
    # design dimension (same value in every entry), none is picked channel by channel
    sep = tuple(c and not lay.coupled for c in lay.channels)
    shared = [n for n, c in zip(lay.names, sep, strict=True) if n in vary and not c]
    chan = [n for n, c in zip(lay.names, sep, strict=True) if n in vary and c]
    return shared, chan


def _fill(problem, out, names, t, defaults):
    """Write the design coordinates ``t`` (rows, len(names)) of ``names`` into ``out``."""
    lay = problem.layout
    for nm, tr, sl in zip(lay.names, lay.transforms, lay.slices, strict=True):
        if nm in names:
            col = _column_design(tr, defaults[nm], t[:, names.index(nm)])
            out[..., sl] = np.asarray(col, float)[:, None]


def layout(problem, vary, n: int = GUESS_CANDIDATES):
    """``(n_shared, n_level)`` of the product design of :func:`design`, or None for a plain
    Halton design (no channel parameter to vary, or no shared one)."""
    shared, chan = _split_vary(problem, vary)
    if not shared or not chan or n < 4:
        return None
    n_level = max(2, int(round(n ** 0.5 / 1.5)))
    return max(2, n // n_level), n_level


def design(problem, u_start: np.ndarray, vary: tuple[str, ...], defaults: dict,
           n: int = GUESS_CANDIDATES) -> np.ndarray:
    """Candidate unconstrained vectors ``(..., n', p)`` for ``problem`` (a
    :class:`brdf_fit.fitting.problem.FitProblem`); the parameters in ``vary`` take design
    values, the others keep their ``u_start`` (``(..., p)``) values. Candidate 0 is ``u_start``.

    With both shared (scalar) and channel parameters to vary (:func:`layout`), the design is a
    product ``n_shared x n_level`` (``n' = n_shared n_level``, row-major): shared values from
    one Halton design, channel levels (equal in every channel) from another; a channel's
    residuals depend only on the shared and its own parameters, so :func:`pick` chooses the
    best level per channel separately at the best shared point. Otherwise ``n' = n``, one
    Halton design over all varied parameters."""
    u_start = np.asarray(u_start, float)
    lay = layout(problem, vary, n)
    if lay is None:
        out = np.repeat(u_start[..., None, :], n, axis=-2)
        names = [nm for nm in problem.layout.names if nm in vary]
        if names and n >= 2:
            _fill(problem, out[..., 1:, :], names, halton(n - 1, len(names)), defaults)
        return out
    ns, nl = lay
    shared, chan = _split_vary(problem, vary)
    S = np.repeat(u_start[..., None, :], ns, axis=-2)  # (..., ns, p): shared points
    _fill(problem, S[..., 1:, :], shared, halton(ns - 1, len(shared)), defaults)
    T = np.repeat(u_start[..., None, :], nl, axis=-2)  # (..., nl, p): channel levels
    _fill(problem, T[..., 1:, :], chan, halton(nl - 1, len(chan)), defaults)
    is_chan = problem.layout.mask(chan)
    out = np.where(is_chan, T[..., None, :, :], S[..., :, None, :])  # (..., ns, nl, p)
    return out.reshape(*u_start.shape[:-1], ns * nl, u_start.shape[-1])


def channel_index(problem, n_channels: int) -> np.ndarray:
    """For each entry of the flat unconstrained vector: the channel it belongs to, or -1 for a
    shared (scalar) parameter (:meth:`~brdf_fit.fitting.problem.ParamLayout.channel_index`)."""
    return problem.layout.channel_index(n_channels)


def pick(xp, cands, losses, lay, chan_of):
    """The start from candidate losses ``losses`` (n', C) per channel (NaN = +inf): the lowest
    total for a plain design; for a product design the shared point of lowest total when each
    channel takes its best level there, with those levels. ``xp``: numpy or jax.numpy."""
    L = xp.where(xp.isfinite(losses), losses, xp.inf)
    if lay is None:
        return cands[xp.argmin(xp.sum(L, axis=-1))]
    ns, nl = lay
    C = L.shape[-1]
    L3 = L.reshape(ns, nl, C)
    s = xp.argmin(xp.sum(xp.min(L3, axis=1), axis=-1))
    t = xp.argmin(L3[s], axis=0)  # (C,) best level per channel
    c3 = cands.reshape(ns, nl, -1)
    base = c3[s, 0]
    per = c3[s][t]  # (C, p): the candidate of each channel's level
    ch = xp.asarray(chan_of)
    take = per[xp.clip(ch, 0, C - 1), xp.arange(ch.shape[0])]
    return xp.where(ch >= 0, take, base)


def subsample(m: int, k: int = GUESS_SAMPLES) -> np.ndarray:
    """Evenly strided indices of ``min(m, k)`` of ``m`` samples."""
    if m <= k:
        return np.arange(m)
    return np.unique(np.linspace(0, m - 1, k).round().astype(int))


def _values_2d(m):
    return m[:, None] if m.ndim == 1 else m


def candidate_values(problem, cands, geom, fixed, lay, n_channels: int):
    """Model values ``(n', M, C)`` (``(n', M, 1)`` for a model without channels) of the
    candidate vectors ``cands`` (n', p) of :func:`design` at the directions ``geom = (wi, wo)``
    (M, 3); JAX, traced by fit_batch.

    For a product design (``lay = (n_shared, n_level)``) one model evaluation per shared point
    serves all its channel levels: level ``l`` of channel ``c`` becomes the pseudo-channel
    ``l C + c`` (every channel parameter tiled ``n_level`` times). It rests on the channel
    separability of :func:`brdf_fit.fitting._lm.directions` (tested for every registry model
    against candidate-by-candidate evaluation); the shared part of the model (a microfacet
    model's D and G) is then computed ``n_shared`` times instead of ``n_shared n_level``
    (measured: 1.02 s -> 0.66 s for 10,000 GGX problems, 24 candidates x 64 samples)."""
    prob = problem.with_fixed(fixed)
    wi, wo = geom

    def each():
        return jax.vmap(lambda uu: _values_2d(prob.build(prob.unflatten(uu)).eval(wi, wo)))(
            cands)

    if lay is None:
        return each()
    try:
        return _pseudo_channel_values(problem, cands, geom, fixed, lay, n_channels)
    except (TypeError, ValueError):
        # a model with per-channel constants of its own (HTSG's wavelengths) cannot take
        # n_level C channels: its shapes do not broadcast, which fails here, at trace time
        return each()


def losses_of_values(problem, m, prep):
    """Per-channel losses ``(n', C)`` (``0.5 sum r^2`` over the samples) of candidate model
    values ``m`` (:func:`candidate_values`) on prepared data ``prep``
    (:meth:`brdf_fit.fitting.problem.FitProblem.prepare`, the same samples)."""
    return 0.5 * jax.vmap(lambda mk: jnp.sum(problem.residuals_of_values(mk, prep) ** 2,
                                             axis=0))(m)


def shared_terms(gf, scale):
    """The per-problem data of :func:`shared_losses`, channel-major: ``(g, s2, const)`` from
    the prepared ``g(f)`` and ``scale`` (B, M, C) (``scale`` None: unit weights): ``g =
    s^2 g(f)`` and ``s2 = s^2`` as (C, B, M) (``s2`` None without weights), ``const = sum_m
    s^2 g(f)^2`` (C, B). Channel-major, so that the products over the samples are batched
    matrix products without a transposed copy of the data (measured, 16,144 problems x 300
    samples x 91 candidates, float64, 2 cores: 0.046 s against 0.111 s in the (B, M, C)
    layout)."""
    if scale is None:
        return jnp.transpose(gf, (2, 0, 1)), None, jnp.sum(gf * gf, axis=1).T
    s2 = jnp.broadcast_to(scale * scale, gf.shape)
    s2g = s2 * gf
    return (jnp.transpose(s2g, (2, 0, 1)), jnp.transpose(s2, (2, 0, 1)),
            jnp.sum(s2g * gf, axis=1).T)


def shared_losses(problem, m, mul, terms):
    """Per-channel losses ``(B, n', C)`` of candidate model values ``m`` (n', M, C) that are the
    same for all B problems (one geometry, one set of candidates), from their
    :func:`shared_terms` ``terms``; ``mul`` (M, k): the metric's multiplier, shared (a metric
    of :data:`SHARED_METRICS`).

    With ``H = h(m * mul)`` the same for every problem, ``0.5 sum_m s^2 (H - g(f))^2`` expands
    into ``0.5 (sum s^2 H^2 - 2 sum (s^2 g(f)) H + sum s^2 g(f)^2)``: matrix products over the
    samples, per channel (one without weights), instead of an element-wise pass over
    ``B n' M C`` values. The expansion cancels: the losses are exact to about
    ``M eps sum s^2 (H^2 + g(f)^2)`` (float64: 1e-16 of it per sample; float32: 1e-7), far
    below the differences between coarse candidates that the guess compares (tested against
    :func:`losses_of_values`). Robust metrics (not quadratic in the residual) and
    ``relative`` (``mul`` depends on the data) take the per-problem path."""
    g, s2, const = terms
    if mul.ndim != 2:
        raise ValueError("shared_losses: mul must be shared (M, k)")
    H = METRIC_H[problem.metric](m * mul)
    H = jnp.transpose(jnp.broadcast_to(H, (m.shape[0], g.shape[2], g.shape[0])), (2, 0, 1))
    cross = jnp.einsum("cbm,ckm->cbk", g, H)
    if s2 is None:
        sq = jnp.sum(H * H, axis=-1)[:, None, :]
    else:
        sq = jnp.einsum("cbm,ckm->cbk", s2, H * H)
    return jnp.transpose(0.5 * (sq - 2.0 * cross + const[..., None]), (1, 2, 0))


def candidate_losses(problem, cands, prep, fixed, lay):
    """Per-channel losses ``(n', C)`` of the candidate vectors ``cands`` (n', p) on prepared
    data ``prep``: :func:`losses_of_values` of :func:`candidate_values`. When every problem of
    a batch has the same directions, candidates and fixed values, fit_batch computes the model
    values once for the batch and only the losses per problem
    (:meth:`brdf_fit.fitting._schedule.Runner.shared_guess`)."""
    C = prep[3].shape[-1]
    m = candidate_values(problem, cands, prep[:2], fixed, lay, C)
    return losses_of_values(problem, m, prep)


def _pseudo_channel_values(problem, cands, geom, fixed, lay, C):
    ns, nl = lay
    c3 = cands.reshape(ns, nl, -1)
    chan = channel_index(problem, C) >= 0
    wi, wo = geom
    source = problem.source
    fixed_t = {k: (jnp.tile(v, nl) if source.param(k).channels and v.shape == (C,) else v)
               for k, v in fixed.items()}
    prob_t = problem.with_fixed(fixed_t)

    is_chan = {n: bool(np.ravel(v)[0]) for n, v in problem.split(chan).items()}

    def one(rows):  # (nl, p): one shared point, its nl levels
        levels = jax.vmap(prob_t.split)(rows)  # {name: (nl, ...)}
        # a channel parameter's (nl, C) levels become the pseudo-channels l C + c; a shared
        # one is the same in every level
        parts = {n: v.reshape(-1) if is_chan[n] else v[0] for n, v in levels.items()}
        m = _values_2d(prob_t.build(prob_t.physical(parts)).eval(wi, wo))
        if m.shape[-1] != nl * C:
            raise ValueError(f"pseudo-channels: model values {m.shape}, not {nl * C} channels")
        return m.reshape(m.shape[0], nl, C).transpose(1, 0, 2)  # (nl, M, C)

    out = jax.vmap(one)(c3)
    return out.reshape(ns * nl, *out.shape[2:])
