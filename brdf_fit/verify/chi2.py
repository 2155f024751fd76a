"""Chi-square goodness-of-fit test between a direction sampler and its density.

A sampler maps uniforms to a direction ``wi`` and reports its solid-angle pdf; a failed sample
(e.g. reflected below the horizon) reports ``pdf == 0``. A pdf function ``pdf(wi)`` claims to be the
density of the successful samples: it integrates over the sphere to ``1 - P(fail)``. The test
checks the claim statistically, after the design popularised by Mitsuba 3's ``chi2`` harness and
pbrt's ``bsdfs_test``:

1. Draw ``N`` samples from fixed-seed uniforms (NumPy ``PCG64``, float64, then cast).
2. Histogram the successful directions over the whole sphere, parametrised by
   ``(mu, phi) = (cos theta, azimuth)`` in ``[-1, 1] x [0, 2 pi)`` on a ``res_mu x res_phi`` grid
   of cells of equal solid angle (``dw = dmu dphi``). Failures are counted separately.
3. Expected counts: ``N`` times the integral of ``pdf`` over each cell, computed with a
   ``cell_nodes x cell_nodes`` Gauss-Legendre product rule inside the cell. With an even
   ``res_mu`` the horizon ``mu = 0`` is a cell edge, so a pdf cut at the horizon is integrated
   without a discontinuity inside any cell. The expected number of failures is
   ``N (1 - sum_cells integral)`` (clamped at 0), and the failures form one more category.
4. Pearson's statistic ``sum (O - E)^2 / E`` (K. Pearson, "On the criterion that a given system
   of deviations from the probable ...", *Philosophical Magazine* 50:157-175, 1900) over the
   categories, after the usual pooling rule: categories with ``E < min_expected`` (default 5) are
   merged into one bin, and if that bin still expects fewer than ``min_expected`` counts the
   smallest regular bins are merged into it until it does. A direction cell that expects exactly
   zero samples but received some makes the statistic infinite. Under the null hypothesis the
   statistic is asymptotically chi-square distributed with ``bins - 1`` degrees of freedom, and
   the p-value is its survival function, ``Q(dof / 2, stat / 2)`` (regularised upper incomplete
   gamma function, evaluated here in float64 Python arithmetic; SciPy is not required).
5. The significance level ``alpha`` is shared by ``test_count`` repeated tests with the Sidak
   correction ``alpha_1 = 1 - (1 - alpha)^(1 / test_count)`` (Z. Sidak, "Rectangular confidence
   regions for the means of multivariate normal distributions", *JASA* 62:626-633, 1967); the test
   passes when ``p > alpha_1``.

   The ``E >= 5`` pooling rule (W. G. Cochran, "Some methods for strengthening the common chi-square
   tests", *Biometrics* 10:417-451, 1954) makes the chi-square approximation good at the usual
   levels (``alpha ~ 0.05``), not in the far tail where ``alpha_1`` lies for many tests: a bin of
   ``E = 5 .. 20`` has a Poisson right tail much heavier than the normal one, so Pearson's statistic
   exceeds the chi-square quantile more often than claimed. Measured by multinomial simulation with
   the expected counts of 20 registry chi-square tests (100 000 samples, lobes with sparse cells;
   6e5 null draws each): 1.38x the nominal rate at ``alpha_1 = 6.4e-5`` (1067 rejections where
   773 are nominal), 1.0-2.0x per test. Pooling more (``E >= 20``) only brings it to 1.1x on
   average (up to 1.7x with few bins) and costs power in the lobe tails.
   Instead, when the chi-square p-value is inconclusive (``alpha_1 / 1000 < p <= alpha_1``; a
   correct sampler gets there with probability about ``alpha_1``), the p-value is the Monte Carlo
   one of the same statistic under the exact null, multinomial counts with the expected counts of
   the pooled bins (G. A. Barnard, *JRSS B* 25:294, 1963; A. C. A. Hope, *JRSS B* 30:582-598,
   1968): ``p = (1 + #{T_sim >= T}) / (1 + R)`` with ``R = 20 / alpha_1`` draws from a generator
   seeded by ``seed``, which keeps the test's false-alarm rate at most ``alpha_1`` whatever the
   expected counts (same simulation: 0.92x, 709 rejections). Far below the window
   (``p <= alpha_1 / 1000``; the broken samplers of the tests give 1e-18 and less) the statistic is
   beyond the true ``alpha_1`` quantile for any tail inflation measured (at most ~2x there), and
   above it the approximation only errs on the safe side.
6. Secondary criteria, also part of ``passed``: no invalid samples (non-finite or negative pdf,
   non-unit direction), and the failure count agrees with its expectation by a binomial z-test
   ``|z| <= fail_z_threshold`` (default 5).

The pdf is integrated with Gauss-Legendre nodes strictly inside each cell, adaptively: starting
from ``cell_nodes`` per dimension, the node count is doubled until no cell's expected count (and not
the expected failure count) changes by more than ``0.1 sqrt(max(E, 1))``, a tenth of its Poisson
noise, so quadrature error adds at most about 0.01 per category to the statistic. Grazing lobes and
narrow anisotropic lobes (ridges much thinner than a cell) need this: a fixed 12 x 12 rule
mis-predicted a GGX lobe at cos(theta_o) = 0.03 by 10% in one cell. If ``max_cell_nodes`` is
reached first, the result fails with that reason rather than testing against unreliable
expectations. Everything is deterministic for a given seed.

Narrow lobes (a Phong exponent of 1e4 is about 0.6 degrees wide) fall into one or two cells of any
grid over the sphere, and the test then has no power. ``frame`` and ``mu_edges`` histogram in a
rotated frame (``mu = frame[2] . wi``, ``phi`` about that axis) with arbitrary edges in ``mu``;
:func:`lobe_grid` builds one about a lobe axis with edges of equal mass for a power-cosine lobe of
a given exponent, and :func:`chi2_test_brdf` uses it automatically for models whose
``quadrature_lobe()`` declares a lobe about the mirror direction narrower than
:data:`LOBE_GRID_MIN_EXPONENT`. Every cell still covers part of the sphere, so the cells together
with the failure category remain a complete partition and the failure z-test is unchanged.

Modules: this one draws the samples, builds the grid and integrates the pdf over its cells
(:func:`chi2_test`, :func:`chi2_test_brdf`); the statistics (steps 4-5: the survival function,
Sidak's level, pooling, the Monte Carlo p-value) are :mod:`brdf_fit.verify.chi2_stats`, the
outcome and its diagnostics :class:`~brdf_fit.verify.chi2_result.Chi2Result`; both are
importable from here as before.
"""

from __future__ import annotations

import inspect
import math
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from brdf_fit.core.quadrature import gauss_legendre_interval
from brdf_fit.models import AbstractBRDF
from brdf_fit.verify.chi2_result import Chi2Result
from brdf_fit.verify.chi2_stats import (
    MC_EXCEEDANCES,
    MC_WINDOW,
    chi2_sf,
    monte_carlo_sf,
    pooled_bin_expectations,
    pooled_categories,
    pooled_chi2_statistic,
    sidak_threshold,
)

__all__ = [
    "Chi2Result",
    "chi2_sf",
    "chi2_test",
    "chi2_test_brdf",
    "default_resolution",
    "lobe_grid",
    "LOBE_GRID_MIN_EXPONENT",
    "pooled_bin_expectations",
    "pooled_categories",
    "pooled_chi2_statistic",
    "monte_carlo_sf",
    "sidak_threshold",
]

_TWO_PI = 2.0 * math.pi


# --------------------------------------------------------------------------------------------
# The test
# --------------------------------------------------------------------------------------------


def default_resolution(n_samples: int) -> tuple[int, int]:
    """Default grid ``(res_mu, res_phi)`` for ``n_samples``.

    The classic 10 x 20 grid (pbrt's ``bsdfs_test``) up to 200 000 samples; above, the grid grows
    to keep about 1000 samples per cell of the sphere. ``res_mu`` is even (so the horizon is a cell
    edge) and at most 64; ``res_phi = 2 res_mu``. A BRDF lobe covers a fraction of the sphere, so
    its cells hold more samples than the average; sparse cells are pooled.
    """
    r = 2 * int(round(0.5 * math.sqrt(max(n_samples, 1) / 2000.0)))
    r = min(max(r, 10), 64)
    return r, 2 * r


#: :func:`chi2_test_brdf` switches to a :func:`lobe_grid` about the mirror direction for lobes with
#: an (equivalent) power-cosine exponent at or above this: at n = 50 the lobe's half-mass angle
#: (~0.17 rad) is already below the 10 x 20 sphere grid's cell size (~0.3 rad).
LOBE_GRID_MIN_EXPONENT = 50.0


def _frame_rows(axis) -> np.ndarray:
    """Rows ``(t, b, axis)``: an orthonormal frame about ``axis`` (Duff et al. 2017)."""
    n = np.asarray(axis, dtype=np.float64)
    n = n / np.linalg.norm(n)
    sign = 1.0 if n[2] >= 0 else -1.0
    a = -1.0 / (sign + n[2])
    b = n[0] * n[1] * a
    t = np.array([1.0 + sign * n[0] * n[0] * a, sign * b, -sign * n[0]])
    return np.stack([t, np.cross(n, t), n])


#: Lobe-mass fractions of the tail edges of :func:`lobe_grid` (below the first equal-mass ring):
#: each tail cell spans two decades of ``mu^(n+1)``, about 4.6 e-folds of the integrand, which a
#: Gauss-Legendre rule of 8-16 nodes integrates well; one cell from ``mu = 0`` to the first
#: equal-mass edge would hide the lobe's rise at its upper end from every node and converge to a
#: wrong value.
_LOBE_TAIL_MASS = (1e-6, 1e-4, 1e-2)


def lobe_grid(axis, exponent: float, res_mu: int = 20) -> tuple[np.ndarray, np.ndarray]:
    """``(frame, mu_edges)`` of a histogram about ``axis`` for a lobe ``~ max(0, axis.wi)^n``.

    The back hemisphere of the axis gets 2 cells in ``mu`` (edges -1, -0.5, 0). The front one is
    cut where the power-cosine lobe's mass below ``mu``, ``F(mu) = mu^(n+1)``, takes the tail
    values :data:`_LOBE_TAIL_MASS` and then ``k / K`` (``K = res_mu - 5`` rings of equal mass), at
    ``mu = F^(1/(n+1))`` computed as ``exp(log(F)/(n+1))``; every ring of the lobe expects about
    the same number of samples.
    """
    if res_mu < 7:
        raise ValueError(f"res_mu must be >= 7 for a lobe grid, got {res_mu}")
    k = res_mu - 2 - len(_LOBE_TAIL_MASS)
    mass = np.concatenate([_LOBE_TAIL_MASS, np.arange(1, k) / k])
    front = np.exp(np.log(mass) / (float(exponent) + 1.0))
    edges = np.concatenate([[-1.0, -0.5, 0.0], front, [1.0]])
    if np.any(np.diff(edges) <= 0):
        raise ValueError(f"lobe grid edges are not increasing for exponent {exponent}")
    return _frame_rows(axis), edges


def _takes_lobe_uniform(fn: Callable) -> bool:
    """Whether ``fn`` has at least two required positional parameters: ``fn(uc, u)``."""
    try:
        sig = inspect.signature(fn)
    except (TypeError, ValueError):
        return False
    kinds = (inspect.Parameter.POSITIONAL_ONLY, inspect.Parameter.POSITIONAL_OR_KEYWORD)
    required = [
        p
        for p in sig.parameters.values()
        if p.kind in kinds and p.default is inspect.Parameter.empty
    ]
    return len(required) >= 2


def _unpack_sample(res) -> tuple[Any, Any]:
    """``(wi, pdf)`` from a tuple or from an object with ``.wi`` and ``.pdf``."""
    if hasattr(res, "wi") and hasattr(res, "pdf"):
        return res.wi, res.pdf
    wi, pdf = res
    return wi, pdf


def _pad_rows(a: np.ndarray, rows: int, fill: np.ndarray) -> np.ndarray:
    """``a`` with rows of ``fill`` appended up to ``rows`` rows."""
    if a.shape[0] == rows:
        return a
    pad = np.broadcast_to(fill, (rows - a.shape[0],) + a.shape[1:]).astype(a.dtype)
    return np.concatenate([a, pad], axis=0)


def _eval_pdf_chunked(pdf_fn, dirs: np.ndarray, chunk: int, dtype) -> np.ndarray:
    """``pdf_fn`` on ``dirs`` (float64 NumPy, (M, 3)) in fixed-size, padded chunks -> float64."""
    out = np.empty(dirs.shape[0], dtype=np.float64)
    north = np.array([0.0, 0.0, 1.0])
    for s in range(0, dirs.shape[0], chunk):
        part = dirs[s : s + chunk]
        m = part.shape[0]
        vals = pdf_fn(jnp.asarray(_pad_rows(part, chunk, north), dtype=dtype))
        out[s : s + m] = np.asarray(vals, dtype=np.float64).reshape(-1)[:m]
    return out


def _cell_integrals(pdf_fn, mu_e, res_phi: int, nodes: int, chunk: int, dtype,
                    frame=None) -> np.ndarray:
    """``(res_mu, res_phi)`` integrals of ``pdf_fn`` over the cells (GL product rule per cell);
    ``mu_e`` the edges in ``mu``, ``frame`` (rows: axes) the histogram frame or ``None``."""
    x, w = gauss_legendre_interval(nodes, -1.0, 1.0)
    res_mu = len(mu_e) - 1
    phi_e = np.linspace(0.0, _TWO_PI, res_phi + 1)
    mu_half = 0.5 * np.diff(mu_e)
    phi_half = 0.5 * np.diff(phi_e)
    mu = (0.5 * (mu_e[:-1] + mu_e[1:]))[:, None] + mu_half[:, None] * x  # (res_mu, k)
    phi = (0.5 * (phi_e[:-1] + phi_e[1:]))[:, None] + phi_half[:, None] * x  # (res_phi, k)
    w_mu = mu_half[:, None] * w
    w_phi = phi_half[:, None] * w
    sin_t = np.sqrt(np.clip(1.0 - mu * mu, 0.0, None))
    cos_p, sin_p = np.cos(phi)[None, None], np.sin(phi)[None, None]
    out = np.empty((res_mu, res_phi), dtype=np.float64)
    # Blocks of mu rows of about one chunk of nodes each: memory stays O(chunk).
    rows = max(1, chunk // (nodes * res_phi * nodes))
    for r0 in range(0, res_mu, rows):
        sl = slice(r0, min(r0 + rows, res_mu))
        st, m = sin_t[sl, :, None, None], mu[sl, :, None, None]
        shape = (st.shape[0], nodes, res_phi, nodes)
        dirs = np.stack(
            [
                np.broadcast_to(st * cos_p, shape),
                np.broadcast_to(st * sin_p, shape),
                np.broadcast_to(m, shape),
            ],
            axis=-1,
        ).reshape(-1, 3)
        if frame is not None:
            dirs = dirs @ frame  # local (rows of frame are the axes) -> world
        vals = _eval_pdf_chunked(pdf_fn, dirs, chunk, dtype).reshape(shape)
        out[sl] = np.einsum("ak,bl,akbl->ab", w_mu[sl], w_phi, vals)
    return out


def chi2_test(
    sample_fn: Callable,
    pdf_fn: Callable[[jax.Array], jax.Array],
    n_samples: int = 200_000,
    res_mu: int | None = None,
    res_phi: int | None = None,
    seed: int = 0,
    alpha: float = 0.01,
    test_count: int = 1,
    cell_nodes: int = 8,
    *,
    max_cell_nodes: int = 1024,
    min_expected: float = 5.0,
    monte_carlo: bool = True,
    mc_max_draws: int = 4_000_000,
    fail_z_threshold: float = 5.0,
    chunk_size: int = 65_536,
    lobe_uniform: bool | None = None,
    check_pdf: bool = True,
    pdf_rtol: float = 1e-3,
    norm_tol: float = 1e-3,
    dtype=None,
    mu_edges=None,
    frame=None,
) -> Chi2Result:
    """Chi-square test that ``sample_fn`` draws directions with the density ``pdf_fn``.

    See the module docstring for the method. Nothing is asserted: inspect ``result.passed``,
    ``str(result)`` and ``result.worst_cells()``.

    Args:
        sample_fn: ``sample_fn(u) -> (wi, pdf)`` with ``u`` of shape ``(n, 2)`` in ``[0, 1)^2``, or
            ``sample_fn(uc, u)`` with an extra lobe-choice uniform ``uc`` of shape ``(n,)``.
            ``wi`` is ``(n, 3)``, ``pdf`` is ``(n,)`` (0 for a failed sample). An object with
            ``.wi`` and ``.pdf`` attributes is accepted instead of the tuple.
        pdf_fn: ``pdf_fn(wi) -> (m,)`` solid-angle densities for directions ``(m, 3)``.
        n_samples: number of samples ``N``.
        res_mu, res_phi: histogram resolution in ``mu = cos theta`` over ``[-1, 1]`` and in
            ``phi`` over ``[0, 2 pi)``; default from :func:`default_resolution` (10 x 20 up to 2e5
            samples). Keep ``res_mu`` even for pdfs cut at the horizon.
        seed: seed of the ``PCG64`` generator of the uniforms.
        alpha: family-wise significance level.
        test_count: number of tests sharing ``alpha`` (Sidak correction).
        cell_nodes: initial Gauss-Legendre nodes per cell and dimension for the expected counts
            (doubled until converged, see the module docstring).
        max_cell_nodes: largest node count tried before giving up (the test then fails).
        min_expected: pooling threshold of the expected counts.
        monte_carlo: replace an inconclusive chi-square p-value (``threshold * MC_WINDOW < p <=
            threshold``) by the Monte Carlo one (module docstring); used only when
            ``MC_EXCEEDANCES / threshold <= mc_max_draws``.
        mc_max_draws: most multinomial draws allowed for it.
        fail_z_threshold: largest accepted ``|z|`` of the failure count.
        chunk_size: samples (and quadrature nodes) per call of ``sample_fn`` / ``pdf_fn``; every
            call gets exactly ``min(chunk_size, n_samples)`` rows (the last chunk is padded), so a
            jitted function compiles once.
        lobe_uniform: whether ``sample_fn`` takes ``(uc, u)``; default: inferred from its
            signature (two or more required positional parameters).
        check_pdf: also evaluate ``pdf_fn`` at the samples and record the disagreement with the
            sampler's pdf (``pdf_max_rel_err``, ``pdf_mismatch_fraction``; informational).
        pdf_rtol: relative tolerance of that check.
        norm_tol: largest accepted ``| |wi| - 1 |`` of a successful sample.
        dtype: float dtype of the uniforms and the quadrature directions passed to the functions
            (default: JAX's default float dtype).
        mu_edges: increasing edges in ``mu`` from -1 to 1 (overrides ``res_mu``); default uniform.
        frame: ``(3, 3)`` orthonormal rows ``(x', y', z')``: histogram ``mu = z'.wi`` and ``phi``
            about ``z'`` from ``x'`` (default: the shading frame). See :func:`lobe_grid`.
    """
    n_samples = int(n_samples)
    if n_samples < 1:
        raise ValueError(f"n_samples must be >= 1, got {n_samples}")
    if res_mu is None and res_phi is None:
        res_mu, res_phi = default_resolution(n_samples)
    elif res_mu is None:
        res_mu = max(2, 2 * int(round(0.25 * res_phi)))  # type: ignore[operator]
    elif res_phi is None:
        res_phi = 2 * int(res_mu)
    if mu_edges is not None:
        mu_e = np.asarray(mu_edges, dtype=np.float64)
        if (mu_e.ndim != 1 or mu_e.size < 2 or mu_e[0] != -1.0 or mu_e[-1] != 1.0
                or np.any(np.diff(mu_e) <= 0)):
            raise ValueError("mu_edges must increase from -1 to 1")
        res_mu = mu_e.size - 1
    res_mu, res_phi = int(res_mu), int(res_phi)
    if res_mu < 1 or res_phi < 1 or cell_nodes < 1:
        raise ValueError("res_mu, res_phi and cell_nodes must be positive")
    if mu_edges is None:
        mu_e = np.linspace(-1.0, 1.0, res_mu + 1)
    if frame is not None:
        frame = np.asarray(frame, dtype=np.float64)
        if frame.shape != (3, 3) or not np.allclose(frame @ frame.T, np.eye(3), atol=1e-12):
            raise ValueError("frame must be a (3, 3) matrix with orthonormal rows")
    threshold = sidak_threshold(alpha, test_count)
    dt = jax.dtypes.canonicalize_dtype(np.float64 if dtype is None else dtype)
    if lobe_uniform is None:
        lobe_uniform = _takes_lobe_uniform(sample_fn)
    chunk = min(int(chunk_size), n_samples)
    below_one = float(np.nextafter(np.array(1.0, dtype=dt), np.array(0.0, dtype=dt)))

    # --- sampling and histogram -----------------------------------------------------------
    rng = np.random.Generator(np.random.PCG64(seed))
    observed = np.zeros(res_mu * res_phi, dtype=np.int64)
    n_fail = n_invalid = n_checked = n_mismatch = 0
    max_rel = 0.0
    done = 0
    while done < n_samples:
        m = min(chunk, n_samples - done)
        # One (m, 3) draw per chunk: the stream does not depend on the chunk size.
        u3 = np.minimum(rng.random((m, 3)).astype(dt), np.asarray(below_one, dtype=dt))
        u3 = _pad_rows(u3, chunk, np.full(3, 0.5))
        u = jnp.asarray(u3[:, :2])
        res = sample_fn(jnp.asarray(u3[:, 2]), u) if lobe_uniform else sample_fn(u)
        wi_j, pdf_j = _unpack_sample(res)
        wi = np.asarray(wi_j, dtype=np.float64).reshape(chunk, 3)[:m]
        pdf = np.asarray(pdf_j, dtype=np.float64).reshape(chunk)[:m]
        done += m

        finite_pdf = np.isfinite(pdf)
        bad_pdf = ~finite_pdf | (pdf < 0.0)
        ok = finite_pdf & (pdf > 0.0)
        with np.errstate(invalid="ignore", over="ignore"):
            norm = np.sqrt(np.sum(wi * wi, axis=1))
            bad_dir = ok & ~(np.abs(norm - 1.0) <= norm_tol)  # also catches NaN
        good = ok & ~bad_dir
        n_fail += int(np.sum(pdf == 0.0))
        n_invalid += int(np.sum(bad_pdf | bad_dir))

        d = wi[good] / norm[good, None]
        if frame is not None:
            d = d @ frame.T  # world -> histogram frame
        mu = np.clip(d[:, 2], -1.0, 1.0)
        phi = np.mod(np.arctan2(d[:, 1], d[:, 0]), _TWO_PI)
        if mu_edges is None:
            i = np.minimum(np.floor((mu + 1.0) * (0.5 * res_mu)).astype(np.int64), res_mu - 1)
        else:
            i = np.clip(np.searchsorted(mu_e, mu, side="right") - 1, 0, res_mu - 1)
        j = np.minimum(np.floor(phi * (res_phi / _TWO_PI)).astype(np.int64), res_phi - 1)
        observed += np.bincount(i * res_phi + j, minlength=res_mu * res_phi)

        if check_pdf and np.any(good):
            pf = np.asarray(pdf_fn(jnp.asarray(wi_j)), dtype=np.float64).reshape(chunk)[:m]
            ps, pe = pdf[good], pf[good]
            with np.errstate(invalid="ignore", divide="ignore"):
                rel = np.abs(ps - pe) / np.maximum(np.abs(ps), np.abs(pe))
            rel = np.where(np.isfinite(rel), rel, np.inf)
            max_rel = max(max_rel, float(np.max(rel)))
            n_mismatch += int(np.sum(~(rel <= pdf_rtol)))
            n_checked += int(ps.size)

    # --- expected counts ------------------------------------------------------------------
    nodes = int(cell_nodes)
    integrals = _cell_integrals(pdf_fn, mu_e, res_phi, nodes, chunk, dt, frame)
    converged = False
    while 2 * nodes <= max_cell_nodes:
        nodes *= 2
        finer = _cell_integrals(pdf_fn, mu_e, res_phi, nodes, chunk, dt, frame)
        change = n_samples * np.abs(finer - integrals)
        fail_change = n_samples * abs(float(np.sum(finer - integrals)))
        noise = 0.1 * np.sqrt(np.maximum(n_samples * finer, 1.0))
        fail_noise = 0.1 * math.sqrt(max(n_samples * (1.0 - float(np.sum(finer))), 1.0))
        integrals = finer
        if np.all(change <= noise) and fail_change <= fail_noise:
            converged = True
            break
    expected = n_samples * integrals
    expected_fail_fraction = max(0.0, 1.0 - float(np.sum(integrals)))
    e_fail = n_samples * expected_fail_fraction

    # --- statistics -----------------------------------------------------------------------
    obs_flat = observed.astype(np.float64)
    exp_flat = expected.reshape(-1)
    n_zero = int(np.sum(obs_flat[exp_flat <= 0.0]))
    # The failure category is one more category. When its expectation is small (possibly 0 through
    # quadrature overshoot) it joins the pooled bin: it gets a positive infinitesimal expectation,
    # since a category with E == 0 would be dropped. Gross failure-count errors are caught by the
    # z-test below.
    e_fail_cat = max(e_fail, float(np.finfo(np.float64).tiny))
    stat, dof, n_pooled = pooled_chi2_statistic(
        np.append(obs_flat, n_fail), np.append(exp_flat, e_fail_cat), min_expected
    )
    p_value = p_chi2 = chi2_sf(stat, dof)
    mc_draws = 0
    mc_needed = int(math.ceil(MC_EXCEEDANCES / threshold))
    if (monte_carlo and dof >= 1 and math.isfinite(stat) and mc_needed <= mc_max_draws
            and threshold * MC_WINDOW < p_value <= threshold):
        bins_e = pooled_bin_expectations(np.append(exp_flat, e_fail_cat), min_expected)
        p_value, mc_draws = monte_carlo_sf(stat, bins_e, n_samples, mc_needed, seed=seed,
                                           stop_above=threshold)

    p = expected_fail_fraction
    sd = math.sqrt(max(n_samples * p * (1.0 - p), 1.0))
    fail_z = (n_fail - n_samples * p) / sd

    reasons = []
    if n_invalid:
        reasons.append(f"{n_invalid} invalid samples (non-finite/negative pdf or non-unit wi)")
    if not np.all(np.isfinite(integrals)) or np.any(integrals < 0.0):
        reasons.append("pdf_fn is negative or non-finite on some cells")
    if n_zero:
        reasons.append(f"{n_zero} samples in cells where pdf_fn integrates to exactly 0")
    if dof < 1:
        reasons.append(f"only {dof + 1} bin(s) after pooling: increase n_samples or resolution")
    elif not p_value > threshold:
        reasons.append(f"p-value {p_value:.4g} <= threshold {threshold:.4g}")
    if not converged:
        reasons.append(
            f"expected counts did not converge with {nodes} nodes per cell and dimension "
            "(raise max_cell_nodes or the resolution)"
        )
    if not abs(fail_z) <= fail_z_threshold:
        reasons.append(
            f"failure count {n_fail} vs expected {n_samples * p:.1f}: |z| = {abs(fail_z):.2f} "
            f"> {fail_z_threshold:g}"
        )

    return Chi2Result(
        statistic=float(stat),
        dof=int(dof),
        p_value=float(p_value),
        threshold=float(threshold),
        passed=not reasons,
        n_samples=n_samples,
        fail_fraction=n_fail / n_samples,
        expected_fail_fraction=expected_fail_fraction,
        observed=observed.reshape(res_mu, res_phi),
        expected=expected,
        n_fail=n_fail,
        n_invalid=n_invalid,
        n_zero_cell_samples=n_zero,
        fail_z=float(fail_z),
        fail_z_threshold=float(fail_z_threshold),
        n_bins=int(dof) + 1,
        n_pooled=int(n_pooled),
        alpha=float(alpha),
        test_count=int(test_count),
        seed=int(seed),
        pdf_max_rel_err=float(max_rel) if check_pdf and n_checked else None,
        pdf_mismatch_fraction=n_mismatch / n_checked if check_pdf and n_checked else None,
        reasons=tuple(reasons),
        cell_nodes_used=nodes,
        grid_mu_edges=None if mu_edges is None else mu_e,
        frame=frame,
        min_expected=float(min_expected),
        p_value_chi2=float(p_chi2),
        mc_draws=int(mc_draws),
    )


def _lobe_exponent(model):
    """Equivalent power-cosine exponent of a lobe about the mirror direction that ``model``
    declares through ``quadrature_lobe()`` (``None`` if it declares none): ``("mirror", n)`` is
    ``n``; ``("half", w)`` (a half-vector lobe of Beckmann-equivalent width ``w``, i.e. Blinn-Phong
    exponent ``2/w^2 - 2``, Walter et al. 2007 sec. 5.2) is a quarter of that, since the reflected
    direction moves twice as fast as the half vector (``alpha_r ~ 2 theta_h`` near normal view)."""
    if not isinstance(model, AbstractBRDF):  # a bare sampler (chi2_test takes any callables)
        return None
    kind, value = model.quadrature_lobe()
    if kind not in ("mirror", "half"):
        return None
    if kind == "half" and isinstance(value, (tuple, list)):
        try:  # anisotropic half-vector lobe: the grid is isotropic, use the narrower width
            value = min(float(np.asarray(w)) for w in value)
        except (TypeError, ValueError, jax.errors.ConcretizationTypeError):
            return None
    try:
        v = float(np.asarray(value))
    except (TypeError, ValueError, jax.errors.ConcretizationTypeError):
        return None
    if kind == "mirror":
        return v
    if kind == "half" and v > 0:
        return max(2.0 / (v * v) - 2.0, 0.0) / 4.0
    return None


def chi2_test_brdf(model, wo, lobe: str | None = "auto", **kw) -> Chi2Result:
    """:func:`chi2_test` for a BRDF model at one outgoing direction ``wo``.

    ``model.sample(wo, uc, u)`` must return an object with ``.wi`` ``(n, 3)`` and ``.pdf``
    ``(n,)``, and ``model.pdf(wi, wo)`` the ``(n,)`` densities; ``wo`` (a single ``(3,)``
    direction) is broadcast to the batch. Both functions are jitted once (the chunks have a fixed
    size). Keyword arguments go to :func:`chi2_test`.

    ``lobe="auto"``: when the model declares a lobe about the mirror direction (``quadrature_lobe``)
    with an equivalent exponent of at least :data:`LOBE_GRID_MIN_EXPONENT`, and no ``mu_edges`` /
    ``frame`` are given, the histogram is a :func:`lobe_grid` about the mirror direction of ``wo``
    (``res_mu`` rings, default 20). ``lobe=None``: the sphere grid.
    """
    wo = jnp.asarray(wo)
    if wo.shape != (3,):
        raise ValueError(f"wo must have shape (3,), got {wo.shape}")
    if lobe not in ("auto", None):
        raise ValueError(f"lobe must be 'auto' or None, got {lobe!r}")
    if lobe == "auto" and "mu_edges" not in kw and "frame" not in kw:
        n_eq = _lobe_exponent(model)
        if n_eq is not None and n_eq >= LOBE_GRID_MIN_EXPONENT:
            w = np.asarray(wo, dtype=np.float64)
            axis = np.array([-w[0], -w[1], w[2]])
            frame, edges = lobe_grid(axis, n_eq, int(kw.pop("res_mu", None) or 20))
            kw["frame"], kw["mu_edges"] = frame, edges

    @jax.jit
    def sample_fn(uc, u):
        s = model.sample(jnp.broadcast_to(wo, u.shape[:-1] + (3,)), uc, u)
        return s.wi, s.pdf

    @jax.jit
    def pdf_fn(wi):
        return model.pdf(wi, jnp.broadcast_to(wo, wi.shape))

    kw.setdefault("lobe_uniform", True)
    return chi2_test(sample_fn, pdf_fn, **kw)
