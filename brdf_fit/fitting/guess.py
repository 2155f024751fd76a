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
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

__all__ = ["halton", "design", "layout", "pick", "channel_index", "subsample",
           "candidate_losses", "GUESS_CANDIDATES", "GUESS_SAMPLES", "GUESSES"]

#: Candidate parameter vectors evaluated (the caller's start included).
GUESS_CANDIDATES = 24
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
    shared = [n for n, c in zip(lay.names, lay.channels, strict=True) if n in vary and not c]
    chan = [n for n, c in zip(lay.names, lay.channels, strict=True) if n in vary and c]
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


def candidate_losses(problem, cands, prep, fixed, lay, chan_of):
    """Per-channel losses ``(n', C)`` (``0.5 sum r^2`` over the samples) of the candidate
    vectors ``cands`` (n', p) of :func:`design` on prepared data ``prep``
    (:meth:`brdf_fit.fitting.problem.FitProblem.prepare`); JAX, traced by fit_batch.

    For a product design (``lay = (n_shared, n_level)``) one model evaluation per shared point
    serves all its channel levels: level ``l`` of channel ``c`` becomes the pseudo-channel
    ``l C + c`` (every channel parameter and the per-channel data tiled ``n_level`` times). It
    rests on the channel separability of :func:`brdf_fit.fitting._lm.directions` (tested for
    every registry model against candidate-by-candidate evaluation); the shared part of the
    model (a microfacet model's D and G) is then computed ``n_shared`` times instead of
    ``n_shared n_level`` (measured: 1.02 s -> 0.66 s for 10,000 GGX problems, 24 candidates x
    64 samples)."""
    prob = problem.with_fixed(fixed)

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
        r = prob_t.residuals_prepared(prob_t.physical(parts), prep_t)
        return 0.5 * jnp.sum(r * r, axis=0).reshape(nl, C)

    return jax.vmap(one)(c3).reshape(ns * nl, C)
