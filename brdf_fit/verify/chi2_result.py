"""The outcome of a chi-square test of a sampler (:class:`Chi2Result`, made by
:func:`brdf_fit.verify.chi2.chi2_test`): the statistic, its p-value and threshold, the
histogram and expected counts, and the diagnostics over them (pooled cells, the worst cells,
a dictionary for JSON).
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np

from brdf_fit.verify.chi2_stats import pooled_categories

__all__ = ["Chi2Result"]

_TWO_PI = 2.0 * math.pi

# --------------------------------------------------------------------------------------------
# Result
# --------------------------------------------------------------------------------------------


def _json_float(x: float | None) -> float | None:
    """A float for JSON: non-finite values become ``None``."""
    if x is None:
        return None
    x = float(x)
    return x if math.isfinite(x) else None


@dataclasses.dataclass(frozen=True, eq=False)
class Chi2Result:
    """Outcome of :func:`chi2_test`.

    Attributes:
        statistic: Pearson's chi-square statistic (``inf`` if samples fell in zero-pdf cells).
        dof: degrees of freedom (bins - 1).
        p_value: the p-value of ``statistic``: the chi-square survival function (NaN if
            ``dof < 1``), or the Monte Carlo one when that was inconclusive (``mc_draws > 0``; see
            :mod:`brdf_fit.verify.chi2`'s docstring).
        threshold: the Sidak-corrected per-test significance level.
        passed: ``p_value > threshold`` and the secondary criteria (see ``reasons``).
        n_samples: number of samples drawn.
        fail_fraction: observed fraction of samples with ``pdf == 0``.
        expected_fail_fraction: ``1 - sum(expected) / n_samples``, clamped at 0.
        observed: ``(res_mu, res_phi)`` histogram of successful samples (int64); row ``i``
            covers ``mu`` in ``[mu_edges[i], mu_edges[i + 1])`` (uniform edges
            ``-1 + 2 i / res_mu`` unless a grid was given), column ``j`` covers
            ``phi`` in ``[2 pi j / res_phi, 2 pi (j + 1) / res_phi)``.
        expected: ``(res_mu, res_phi)`` expected counts (float64).
        n_fail: number of failed samples (``pdf == 0``).
        n_invalid: samples with a non-finite or negative pdf, or a non-unit / non-finite direction
            with ``pdf > 0``; they are neither binned nor counted as failures.
        n_zero_cell_samples: samples in cells whose expected count is exactly 0.
        fail_z: binomial z-score of the failure count (standard deviation floored at 1).
        fail_z_threshold: largest accepted ``|fail_z|``.
        n_bins: number of bins in the statistic (including the pooled bin).
        n_pooled: number of categories (cells or the failure category) merged into the pooled bin.
        min_expected: the pooling threshold used (see :func:`pooled_chi2_statistic`).
        p_value_chi2: the chi-square approximation of the p-value (``None``: not computed).
        mc_draws: number of multinomial draws of the Monte Carlo p-value (0: not used).
        alpha: the family-wise significance level.
        test_count: number of tests sharing ``alpha``.
        seed: the seed of the uniforms.
        pdf_max_rel_err: largest ``|pdf_sample - pdf_fn| / max(...)`` over successful samples
            (``None`` if not checked). Informational; not part of ``passed``.
        pdf_mismatch_fraction: fraction of successful samples whose relative pdf disagreement
            exceeds ``pdf_rtol`` (``None`` if not checked). Informational.
        reasons: human-readable reasons for a failure (empty when passed).
        cell_nodes_used: Gauss-Legendre nodes per cell and dimension of the converged expectation.
    """

    statistic: float
    dof: int
    p_value: float
    threshold: float
    passed: bool
    n_samples: int
    fail_fraction: float
    expected_fail_fraction: float
    observed: np.ndarray
    expected: np.ndarray
    n_fail: int = 0
    n_invalid: int = 0
    n_zero_cell_samples: int = 0
    fail_z: float = 0.0
    fail_z_threshold: float = 5.0
    n_bins: int = 0
    n_pooled: int = 0
    alpha: float = 0.01
    test_count: int = 1
    seed: int = 0
    pdf_max_rel_err: float | None = None
    pdf_mismatch_fraction: float | None = None
    reasons: tuple[str, ...] = ()
    cell_nodes_used: int = 0
    #: edges in ``mu`` of the histogram (``None``: uniform over ``[-1, 1]``)
    grid_mu_edges: np.ndarray | None = None
    #: rows: the histogram frame's axes in world coordinates (``None``: the shading frame)
    frame: np.ndarray | None = None
    min_expected: float = 5.0
    p_value_chi2: float | None = None
    mc_draws: int = 0

    @property
    def res_mu(self) -> int:
        return int(self.observed.shape[0])

    @property
    def res_phi(self) -> int:
        return int(self.observed.shape[1])

    @property
    def mu_edges(self) -> np.ndarray:
        if self.grid_mu_edges is not None:
            return np.asarray(self.grid_mu_edges)
        return np.linspace(-1.0, 1.0, self.res_mu + 1)

    @property
    def phi_edges(self) -> np.ndarray:
        return np.linspace(0.0, _TWO_PI, self.res_phi + 1)

    def _categories(self) -> tuple[np.ndarray, np.ndarray]:
        """Observed and expected counts of the categories as :func:`chi2_test` pools them: the
        cells (row-major), then the failure category (its expectation floored as there)."""
        e_fail = self.expected_fail_fraction * self.n_samples
        obs = np.append(self.observed.reshape(-1).astype(np.float64), float(self.n_fail))
        exp = np.append(self.expected.reshape(-1), max(e_fail, float(np.finfo(np.float64).tiny)))
        return obs, exp

    def pooled_mask(self) -> np.ndarray:
        """``(res_mu, res_phi)`` bool: the cells merged into the pooled bin of the statistic."""
        _, exp = self._categories()
        return pooled_categories(exp, self.min_expected)[:-1].reshape(self.expected.shape)

    def fail_pooled(self) -> bool:
        """Whether the failure category was merged into the pooled bin."""
        _, exp = self._categories()
        return bool(pooled_categories(exp, self.min_expected)[-1])

    def pooled_bin(self) -> tuple[float, float, int]:
        """``(observed, expected, n_categories)`` of the pooled bin (zeros when nothing is pooled);
        it enters the statistic as one term ``(O - E)^2 / E``."""
        obs, exp = self._categories()
        m = pooled_categories(exp, self.min_expected)
        return float(obs[m].sum()), float(exp[m].sum()), int(m.sum())

    def contributions(self) -> np.ndarray:
        """Per-cell ``(O - E)^2 / E`` before pooling (``inf`` where ``E == 0 < O``).

        These are *not* the statistic's terms for the cells of :meth:`pooled_mask`: a cell with
        ``E = 0.1`` and ``O = 2`` shows 36 here but enters the statistic only through the pooled
        bin (:meth:`pooled_bin`). :meth:`worst_cells` ranks the terms actually summed.
        """
        o = self.observed.astype(np.float64)
        e = self.expected
        pos = e > 0.0
        out = np.zeros_like(e)
        out[pos] = (o[pos] - e[pos]) ** 2 / e[pos]
        out[~pos & (o > 0)] = math.inf
        return out

    def worst_cells(self, k: int = 5) -> str:
        """A table of the ``k`` largest terms of the statistic, plus the failure category.

        A term is an unpooled cell or the pooled bin (one row, ``pooled bin (n cells)``); pooled
        cells are not listed on their own, since their individual ``(O - E)^2 / E`` (which can be
        large for ``E << 1``, see :meth:`contributions`) is not part of the statistic. The failure
        row shows its own term, or ``pooled`` when it is merged into the pooled bin.
        """
        contrib = self.contributions().reshape(-1)
        pooled = self.pooled_mask().reshape(-1)
        # pooled cells, and empty cells that expect nothing (dropped categories), rank below
        # every term
        dropped = pooled | ((self.expected.reshape(-1) <= 0.0) & (contrib == 0.0))
        terms = np.where(dropped, -1.0, contrib)
        pool_o, pool_e, n_pool = self.pooled_bin()
        pool_term = (pool_o - pool_e) ** 2 / pool_e if n_pool else -1.0
        order = list(np.argsort(-terms, kind="stable")[: max(int(k), 0)])
        if n_pool and k > 0:
            # the pooled bin takes its rank among the cells; the table keeps k rows
            pos = int(np.sum(terms[order] >= pool_term))
            order = (order[:pos] + [-1] + order[pos:])[: int(k)]
        mu_e, phi_e = self.mu_edges, self.phi_edges
        lines = [
            f"{'mu range':<15} {'phi range (rad)':<15} {'observed':>10} {'expected':>12} "
            f"{'(O-E)^2/E':>11}"
        ]
        for idx in order:
            if idx < 0:
                n_cells = int(pooled.sum())
                label = f"pooled bin ({n_cells} cells{' + fail.' if n_pool > n_cells else ''})"
                lines.append(f"{label:<31} {pool_o:>10.0f} {pool_e:>12.2f} {pool_term:>11.3g}")
                continue
            if dropped[idx]:
                continue  # fewer terms than k
            i, j = divmod(int(idx), self.res_phi)
            lines.append(
                f"[{mu_e[i]:+.3f},{mu_e[i + 1]:+.3f}) [{phi_e[j]:6.3f},{phi_e[j + 1]:6.3f}) "
                f"{int(self.observed[i, j]):>10d} {self.expected[i, j]:>12.2f} "
                f"{contrib[idx]:>11.3g}"
            )
        e_fail = self.expected_fail_fraction * self.n_samples
        if self.fail_pooled():
            c_fail = f"{'pooled':>11}"
        elif e_fail > 0:
            c_fail = f"{(self.n_fail - e_fail) ** 2 / e_fail:>11.3g}"
        else:
            c_fail = f"{math.inf if self.n_fail else 0.0:>11.3g}"
        lines.append(f"{'failures (pdf = 0)':<31} {self.n_fail:>10d} {e_fail:>12.2f} {c_fail}")
        return "\n".join(lines)

    def __str__(self) -> str:
        verdict = "PASSED" if self.passed else "FAILED"
        rel = ">" if self.p_value > self.threshold else "<="
        s = (
            f"chi2 test {verdict}: statistic {self.statistic:.4g}, dof {self.dof}, "
            f"p = {self.p_value:.4g}"
            + (f" (Monte Carlo, {self.mc_draws} draws; chi-square {self.p_value_chi2:.4g})"
               if self.mc_draws else "")
            + f" {rel} threshold {self.threshold:.3g} "
            f"(alpha {self.alpha:g} over {self.test_count} test(s)); N = {self.n_samples}, "
            f"{self.res_mu}x{self.res_phi} cells, {self.n_bins} bins "
            f"({self.n_pooled} categories pooled); failures {100 * self.fail_fraction:.3f}% "
            f"(expected {100 * self.expected_fail_fraction:.3f}%, z = {self.fail_z:.2f})"
        )
        if self.pdf_mismatch_fraction is not None:
            s += (
                f"; sampler/pdf_fn mismatch on {100 * self.pdf_mismatch_fraction:.3g}% of samples "
                f"(max rel. err. {self.pdf_max_rel_err:.3g})"
            )
        if self.reasons:
            s += "\n  " + "\n  ".join(self.reasons)
        return s

    def to_dict(self) -> dict[str, Any]:
        """JSON-friendly dict (Python ints, floats, bools, lists; non-finite floats -> ``None``)."""
        out: dict[str, Any] = {}
        for f in dataclasses.fields(self):
            v = getattr(self, f.name)
            if isinstance(v, np.ndarray):
                v = (
                    v.astype(np.int64).tolist()
                    if v.dtype.kind in "iu"
                    else np.vectorize(_json_float, otypes=[object])(v).tolist()
                )
            elif isinstance(v, bool | np.bool_):
                v = bool(v)
            elif isinstance(v, int | np.integer):
                v = int(v)
            elif isinstance(v, float | np.floating):
                v = _json_float(v)
            elif isinstance(v, tuple):
                v = list(v)
            out[f.name] = v
        out["res_mu"] = self.res_mu
        out["res_phi"] = self.res_phi
        return out
