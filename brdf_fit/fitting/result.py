"""What a fit returns: :class:`FitResult` (the fitted parameters and model, their standard
errors and why any is undefined, the correlation of the estimates, the convergence and the
loss), with :func:`correlation` (a covariance scaled to unit diagonal, NaN where a standard error
is undefined) and :func:`json_floats` (NaN and inf as JSON's null). Made by
:func:`brdf_fit.fitting.single.fit`, which re-exports them."""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from brdf_fit.data import GonioData

__all__ = ["FitResult", "correlation", "json_floats", "STRONG_CORRELATION"]


#: the magnitude of correlation from which :meth:`FitResult.strongly_correlated` names a pair:
#: at 0.99 the better-determined combination of the two (their sum or difference, scaled) has a
#: standard error sqrt((1 - r) / (1 + r)) = 0.07 of the worse one's, i.e. the data fix one
#: combination some 14 times better than the other
STRONG_CORRELATION = 0.99


def correlation(cov, codes) -> np.ndarray:
    """The correlation matrix of ``cov`` (p, p), NaN in the rows and columns of the entries
    whose ``codes`` (:func:`brdf_fit.fitting.problem.stderr_codes`, at-bound flags included)
    are not 0 or whose variance is not positive; all NaN when ``cov`` is None."""
    codes = np.asarray(codes)
    p = codes.size
    if cov is None:
        return np.full((p, p), np.nan)
    cov = np.asarray(cov, float)
    var = np.diagonal(cov)
    ok = (codes == 0) & np.isfinite(var) & (var > 0)
    s = np.sqrt(np.where(ok, var, 1.0))
    with np.errstate(invalid="ignore"):
        c = np.clip(cov / (s[:, None] * s[None, :]), -1.0, 1.0)
    c = np.where(ok[:, None] & ok[None, :], 0.5 * (c + c.T), np.nan)  # exactly symmetric
    np.fill_diagonal(c, np.where(ok, 1.0, np.nan))
    return c


@dataclasses.dataclass
class FitResult:
    """Outcome of :func:`fit`."""

    model_name: str
    model: Any
    params: dict[str, np.ndarray]
    stderr: dict[str, np.ndarray]
    converged: bool
    steps: int
    metric: str
    loss: float
    residual_rms: float
    n_samples: int
    n_params: int
    seconds: float
    fixed: dict[str, np.ndarray] = dataclasses.field(default_factory=dict)
    starts: int = 1
    message: str = ""
    checks: list = dataclasses.field(default_factory=list)
    #: free parameters whose fitted value (any channel) sits at an end of its interval
    #: (:func:`brdf_fit.fitting.problem.at_bound`): a limit, not an optimum; its standard
    #: error means nothing
    at_bound: tuple[str, ...] = ()
    #: free parameters with an undefined (NaN) standard error, the reason per entry (shape of
    #: the parameter; "" where defined): "at bound", "not identifiable" (a vanishing Jacobian
    #: column or a rank-deficient direction of ``J^T J``,
    #: :func:`brdf_fit.fitting.problem.stderr_codes`), "non-finite normal equations"
    stderr_note: dict[str, np.ndarray] = dataclasses.field(default_factory=dict)
    #: entries the data do not determine (:func:`brdf_fit.fitting.problem.undetermined`:
    #: relative standard error above :data:`~brdf_fit.fitting.problem.UNDETERMINED_REL_STDERR`,
    #: or not identifiable), labelled ``name`` or ``name[channel]``, e.g. ``("eta[R]", "k[R]")``
    undetermined: tuple[str, ...] = ()
    #: correlation matrix of the free entries' estimates (their covariance, the one the standard
    #: errors come from, scaled to unit diagonal), in the order of ``correlation_labels``; NaN in
    #: the rows and columns of entries whose standard error is undefined. Two entries
    #: correlated near +-1 are determined as a combination, not each on its own (a conductor's
    #: eta and k where the data fix only the reflectance they give)
    correlation: np.ndarray | None = None
    correlation_labels: tuple[str, ...] = ()
    #: the fit against its data by region of the geometry, where asked for
    #: (:meth:`residuals_by_region`; ``brdf-fit fit`` does): rows of
    #: :func:`brdf_fit.fitting.regions.residuals_by_region`
    regions: list | None = None

    def strongly_correlated(self, threshold: float = STRONG_CORRELATION):
        """``[(label_a, label_b, r), ...]``: the pairs of entries whose correlation reaches
        ``threshold`` in magnitude, strongest first."""
        if self.correlation is None:
            return []
        c = np.asarray(self.correlation)
        labels = self.correlation_labels
        pairs = [(labels[i], labels[j], float(c[i, j])) for i in range(len(labels))
                 for j in range(i + 1, len(labels))
                 if np.isfinite(c[i, j]) and abs(c[i, j]) >= threshold]
        return sorted(pairs, key=lambda t: -abs(t[2]))

    def residuals_by_region(self, data: GonioData) -> list[dict]:
        """The fitted model against ``data`` (the fitted data, or other data of the same
        material) by region of the geometry: grazing, specular peak, retro-reflection,
        off-specular (:func:`brdf_fit.fitting.regions.residuals_by_region`). Evaluates the
        model at every sample (one compiled program per model); not part of :func:`fit`, so
        a fit that does not ask pays nothing."""
        from brdf_fit.fitting.regions import residuals_by_region

        return residuals_by_region(self.model, data.wi, data.wo, data.value)

    def to_dict(self) -> dict:
        def tolist(v):
            a = np.asarray(v)
            return a.tolist() if a.ndim else float(a)

        return {
            "model": self.model_name,
            "params": {k: tolist(v) for k, v in self.params.items()},
            "stderr": {k: json_floats(v) for k, v in self.stderr.items()},
            "fixed": {k: tolist(v) for k, v in self.fixed.items()},
            "converged": bool(self.converged),
            "steps": int(self.steps),
            "metric": self.metric,
            "loss": float(self.loss),
            "residual_rms": float(self.residual_rms),
            "n_samples": int(self.n_samples),
            "n_params": int(self.n_params),
            "seconds": round(float(self.seconds), 4),
            "starts": int(self.starts),
            "at_bound": list(self.at_bound),
            "undetermined": list(self.undetermined),
            "message": self.message,
            "checks": [c.to_dict() for c in self.checks],
            "correlation": ({"labels": list(self.correlation_labels),
                             "matrix": json_floats(self.correlation)}
                            if self.correlation is not None else None),
            **({"regions": [{k: (json_floats(v) if isinstance(v, float) else v)
                             for k, v in row.items()} for row in self.regions]}
               if self.regions is not None else {}),
            # only where some standard error is undefined (null in "stderr"): the reasons
            **({"stderr_note": {k: np.asarray(v).tolist() for k, v in self.stderr_note.items()}}
               if self.stderr_note else {}),
        }


def json_floats(v):
    """A float array as JSON-ready lists (a scalar as a float), NaN and inf as None (strict
    JSON has neither; the reason is in ``stderr_note``)."""
    a = np.asarray(v, float)
    if not a.ndim:
        return float(a) if np.isfinite(a) else None
    return [json_floats(x) for x in a]
