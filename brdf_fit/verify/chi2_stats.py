"""The statistics of the chi-square test (:mod:`brdf_fit.verify.chi2`): the chi-square survival
function, Sidak's per-test level, the pooling of sparse categories and the Monte Carlo p-value
of Pearson's statistic under the exact multinomial null. Pure NumPy and Python float64; the
method, its references and its measurements are in :mod:`brdf_fit.verify.chi2`'s docstring.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = [
    "chi2_sf",
    "sidak_threshold",
    "pooled_categories",
    "pooled_chi2_statistic",
    "pooled_bin_expectations",
    "monte_carlo_sf",
    "MC_WINDOW",
    "MC_EXCEEDANCES",
]

# --------------------------------------------------------------------------------------------
# Distribution functions
# --------------------------------------------------------------------------------------------


def _gammaincc(a: float, x: float) -> float:
    """Regularised upper incomplete gamma function ``Q(a, x)`` for ``a > 0``, ``x >= 0``.

    Power series for ``P = 1 - Q`` when ``x < a + 1`` (there ``Q`` is not small, so ``1 - P`` loses
    no relative accuracy) and Legendre's continued fraction for ``Q``, evaluated with the modified
    Lentz method, otherwise. Relative accuracy ~1e-14 in float64.
    """
    if not a > 0.0:
        raise ValueError(f"a must be positive, got {a}")
    if math.isnan(x):
        return math.nan
    if x <= 0.0:
        return 1.0
    if math.isinf(x):
        return 0.0
    log_prefactor = -x + a * math.log(x) - math.lgamma(a)
    max_iter = 100_000 + int(50.0 * math.sqrt(a))
    if x < a + 1.0:
        term = 1.0 / a
        total = term
        ap = a
        for _ in range(max_iter):
            ap += 1.0
            term *= x / ap
            total += term
            if term < total * 1e-17:
                break
        return max(0.0, 1.0 - total * math.exp(log_prefactor))
    tiny = 1e-300
    b = x + 1.0 - a
    c = 1.0 / tiny
    d = 1.0 / b
    h = d
    for i in range(1, max_iter):
        an = -i * (i - a)
        b += 2.0
        d = an * d + b
        d = tiny if abs(d) < tiny else d
        c = b + an / c
        c = tiny if abs(c) < tiny else c
        d = 1.0 / d
        delta = d * c
        h *= delta
        if abs(delta - 1.0) < 1e-16:
            break
    return math.exp(log_prefactor) * h


def chi2_sf(statistic: float, dof: int) -> float:
    """Survival function of the chi-square distribution: ``P(X > statistic)``, ``X ~ chi2(dof)``.

    Equal to ``Q(dof / 2, statistic / 2)``; NaN when ``dof < 1``.
    """
    if dof < 1:
        return math.nan
    return _gammaincc(0.5 * float(dof), 0.5 * float(statistic))


def sidak_threshold(alpha: float, test_count: int = 1) -> float:
    """Per-test significance ``1 - (1 - alpha)^(1 / test_count)`` (Sidak 1967).

    With it, ``test_count`` independent tests of correct samplers all pass with probability
    ``1 - alpha``.
    """
    if not 0.0 < alpha < 1.0:
        raise ValueError(f"alpha must be in (0, 1), got {alpha}")
    if test_count < 1:
        raise ValueError(f"test_count must be >= 1, got {test_count}")
    return -math.expm1(math.log1p(-alpha) / test_count)


def pooled_categories(expected: np.ndarray, min_expected: float = 5.0) -> np.ndarray:
    """Boolean mask of the categories that :func:`pooled_chi2_statistic` merges into its pooled bin.

    The pooling depends on the expectations only: categories with ``0 < E < min_expected``, plus,
    while the pooled bin expects fewer than ``min_expected`` counts, the regular categories with the
    smallest expectations (ties in index order). Categories with ``E <= 0`` are never pooled.
    """
    exp = np.clip(np.asarray(expected, dtype=np.float64).reshape(-1), 0.0, None)
    zero = exp <= 0.0
    pooled = ~zero & (exp < min_expected)
    if pooled.any():
        pool_e = float(exp[pooled].sum())
        big = np.flatnonzero(~zero & ~pooled)
        for idx in big[np.argsort(exp[big], kind="stable")]:
            if not pool_e < min_expected:
                break
            pooled[idx] = True
            pool_e += exp[idx]
    return pooled


def pooled_chi2_statistic(
    observed: np.ndarray, expected: np.ndarray, min_expected: float = 5.0
) -> tuple[float, int, int]:
    """Pearson's statistic with the pooling rule for small expected counts.

    Categories with ``0 < E < min_expected`` are merged into one bin; if that bin expects fewer
    than ``min_expected`` counts, the regular bins with the smallest expectations are merged into it
    until it does (or none are left); :func:`pooled_categories` gives the merged set. Categories
    with ``E == 0`` are dropped; if any of them has observations the statistic is ``inf``. Negative
    expectations are treated as 0.

    Returns:
        ``(statistic, dof, n_pooled)``: dof = number of bins - 1 (may be < 1: then no test is
        possible), ``n_pooled`` = number of categories merged into the pooled bin.
    """
    obs = np.asarray(observed, dtype=np.float64).reshape(-1)
    exp = np.clip(np.asarray(expected, dtype=np.float64).reshape(-1), 0.0, None)
    if obs.shape != exp.shape:
        raise ValueError(f"observed {obs.shape} and expected {exp.shape} differ in shape")
    zero = exp <= 0.0
    pooled = pooled_categories(exp, min_expected)
    regular = np.flatnonzero(~zero & ~pooled)
    regular = regular[np.argsort(exp[regular], kind="stable")]
    bins_o = list(obs[regular])
    bins_e = list(exp[regular])
    n_pooled = int(pooled.sum())
    if n_pooled > 0:
        # summed in index order over the small categories first, then the absorbed regular ones
        small = pooled & (exp < min_expected)
        absorbed = np.flatnonzero(pooled & ~small)
        absorbed = absorbed[np.argsort(exp[absorbed], kind="stable")]
        pool_o, pool_e = float(obs[small].sum()), float(exp[small].sum())
        for idx in absorbed:
            pool_o += obs[idx]
            pool_e += exp[idx]
        bins_o.append(pool_o)
        bins_e.append(pool_e)
    bo = np.asarray(bins_o, dtype=np.float64)
    be = np.asarray(bins_e, dtype=np.float64)
    stat = float(np.sum((bo - be) ** 2 / be)) if be.size else 0.0
    if np.any(obs[zero] > 0):
        stat = math.inf
    return stat, int(be.size) - 1, n_pooled


def pooled_bin_expectations(expected: np.ndarray, min_expected: float = 5.0) -> np.ndarray:
    """Expected counts of the bins of :func:`pooled_chi2_statistic`: the regular categories, then
    the pooled bin (if any). Categories with ``E <= 0`` are dropped."""
    exp = np.clip(np.asarray(expected, dtype=np.float64).reshape(-1), 0.0, None)
    pooled = pooled_categories(exp, min_expected)
    bins = exp[(exp > 0.0) & ~pooled]
    return np.append(bins, exp[pooled].sum()) if pooled.any() else bins


#: Monte Carlo p-values (:mod:`brdf_fit.verify.chi2`'s docstring, step 5): the window below the
#: threshold where the chi-square p-value is replaced, the expected number of simulated
#: statistics at least as large as the observed one when ``p`` equals the threshold, and the
#: batch size of the draws.
MC_WINDOW = 1e-3
MC_EXCEEDANCES = 20
_MC_BATCH = 16_384


def monte_carlo_sf(statistic: float, bin_expected: np.ndarray, n_samples: int, draws: int,
                   seed: int = 0, stop_above: float | None = None) -> tuple[float, int]:
    """Monte Carlo p-value ``(1 + #{T_j >= statistic}) / (1 + R)`` of Pearson's statistic over
    bins with expectations ``bin_expected`` (e.g. :func:`pooled_bin_expectations`), where the
    ``T_j`` are the statistics of ``R = draws`` multinomial samples of ``n_samples`` counts with
    probabilities ``bin_expected / sum(bin_expected)`` (the null hypothesis). Statistics within
    ``1e-9`` relative of ``statistic`` count as ties (``>=``).

    The test "reject if ``p <= alpha``" has a false-alarm rate of at most ``alpha`` for any ``R``
    (Hope 1968). ``stop_above``: stop drawing once ``p`` is certain to exceed it whatever the
    remaining draws give (the decision ``p > stop_above`` is the same as with all draws; the
    returned ``p`` and ``R`` are then those of the draws made). Deterministic for a given ``seed``.

    Returns:
        ``(p, R)``: the p-value and the number of draws it rests on.
    """
    be = np.asarray(bin_expected, dtype=np.float64).reshape(-1)
    if be.size < 2 or not np.all(be > 0.0):
        raise ValueError("need at least two bins with positive expectations")
    probs = be / be.sum()
    rng = np.random.Generator(np.random.PCG64(np.random.SeedSequence([int(seed), 0x6D63])))
    tie = float(statistic) - 1e-9 * max(1.0, abs(float(statistic)))
    hits = done = 0
    draws = int(draws)
    while done < draws:
        m = min(_MC_BATCH, draws - done)
        counts = rng.multinomial(int(n_samples), probs, size=m).astype(np.float64)
        stats = np.sum((counts - be) ** 2 / be, axis=1)
        hits += int(np.count_nonzero(stats >= tie))
        done += m
        if stop_above is not None and (1 + hits) > stop_above * (1 + draws):
            break
    return (1 + hits) / (1 + done), done
