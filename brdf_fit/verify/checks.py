"""Physical-plausibility and sampling checks, as library code that tests, the CLI and users call.

Every check returns a :class:`CheckResult` (statistic, threshold, passed, details) and never
asserts. :func:`run_checks` runs them on a registry entry and marks the checks the entry declares
it is not meant to pass (``Entry.expected_failures``) as expected failures, with the reason.

Checks (name: statistic <= threshold unless stated):

``non-negative``         min f over random and structured pairs (>= 0)
``reciprocity``          max |f(wi, wo) - f(wo, wi)| / max(f) over random pairs
``energy``               max over wo (grazing included) and channels of the directional albedo
                         E(wo) = Int f cos dwi, quadrature with lobe-adapted rules (<= 1 + tol)
``ndf-normalisation``    max |Int D(m)(n.m) dm - 1| over the model's microfacet lobes
``weak-white-furnace``   max |Int G1(wo, m) max(0, wo.m) D(m) dm / (n.wo) - 1| (Heitz 2014,
                         eq. 18): the visible-normal pdf integrates to 1
``white-furnace``        the microfacet lobes with F = 1 (no absorption): max E(wo) <= 1 + tol;
                         the single-scattering energy loss 1 - E(wo) is reported, not hidden
``pdf-normalisation``    max over wo of |Int_H+ pdf - (1 - P_fail)| / sigma, P_fail estimated
                         from ``sample`` (binomial sigma), threshold 5
``sampling-weight``      max over wo and channels of |mean(weight) - E(wo)| / standard error,
                         threshold 5 (the sampler's weights agree with the quadrature albedo),
                         less the effect of events too rare to be drawn (``RARE_EVENT_COUNT``)
``chi2``                 chi-square test of ``sample`` against ``pdf`` at several wo (statistic:
                         the smallest p-value; passes above the Sidak-corrected level)
``finite``               number of NaN/Inf in values and gradients (w.r.t. both directions and
                         every parameter) on the hard-case grid, float64 and float32 (0)
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable, Iterable
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from brdf_fit import registry
from brdf_fit.core import quadrature
from brdf_fit.core.fresnel import ConstantFresnel
from brdf_fit.core.microfacet import VCavity, vcavity_pdf_visible
from brdf_fit.models import MicrofacetBRDF
from brdf_fit.models._base import AbstractBRDF, evaluate
from brdf_fit.verify import albedo
from brdf_fit.verify.chi2 import chi2_test_brdf
from brdf_fit.verify.hard_cases import (
    HARD_COS,
    HARD_PARAMS,
    edge_values,
    hard_case_directions,
    hard_case_params,
    hard_values,
    unit_direction,
)
from brdf_fit.verify.negative_controls import (
    AbstractNegativeControl,
    DriftingSampler,
    NonReciprocal,
    Overbright,
    OverweightSampler,
    PdfScaled,
)

__all__ = [
    "CheckResult",
    "CHECKS",
    "run_checks",
    "check_non_negative",
    "check_reciprocity",
    "check_energy",
    "check_ndf_normalisation",
    "check_weak_white_furnace",
    "check_white_furnace",
    "check_pdf_normalisation",
    "check_sampling_weight",
    "check_chi2",
    "check_finite",
    "directional_albedo",
    "PdfScaled",
    "NonReciprocal",
    "Overbright",
    "DriftingSampler",
    "hard_values",
    "OverweightSampler",
    "HARD_COS",
    "HARD_PARAMS",
    "edge_values",
    "hard_case_directions",
    "hard_case_params",
]

#: Tolerance of the energy and white-furnace checks: the lobe-adapted quadrature reaches 1e-6
#: (docs/quadrature.md); 1e-5 leaves a margin of ten for the hardest views (cos = 1e-3).
ENERGY_TOL = 1e-5
#: Normalisation identities are computed with lobe-adapted product rules accurate to ~1e-8 for the
#: registry's lobes; 1e-6 is the bar they must clear (a 1.1x pdf misses it by 1e-1).
IDENTITY_TOL = 1e-6
#: Relative reciprocity tolerance, in units of the model's machine epsilon: the models are
#: reciprocal to round-off (measured 2e-14 in float64, 8e-7 in float32); 1e4 eps (2.2e-12 in
#: float64, 1.2e-3 in float32) leaves room for round-off amplified near grazing and still
#: rejects a real asymmetry (the negative control's is 5e-2).
RECIPROCITY_EPS = 1e4
#: Relative floor of the standard error in the sampling-weight check, in units of eps: a
#: zero-variance estimator (Lambert: every weight is rho) differs from the quadrature albedo by
#: round-off only (1e3 eps: 2.2e-13 in float64, 1.2e-4 in float32).
WEIGHT_FLOOR_EPS = 1e3
#: Sampling-weight check: ``|mean - E|`` is first reduced by ``RARE_EVENT_COUNT * max|w| / n``,
#: the effect of events with probability below what ``n`` draws can see (rule of three: no event
#: among ``n`` draws is consistent, at 95%, with a probability up to ``3/n``). Measured case: the
#: original Phong lobe at cos_o = 0.9 loses ~1e-9 of its samples below the horizon, every drawn
#: weight is exactly rho_s, and without this allowance z = 1e4. For an estimator with variance
#: the allowance is ~1% of its standard error at n = 2e5 (``3 max|w| / (sigma sqrt(n))``).
RARE_EVENT_COUNT = 3.0
#: z-score threshold of the statistical checks (pdf normalisation vs sampled failure rate, mean
#: weight vs albedo): a false alarm at 5 sigma is ~6e-7 per comparison.
Z_TOL = 5.0
#: View cosines of the energy / albedo checks: grazing ones included.
ENERGY_COS = (1e-3, 1e-2, 0.05, 0.1, 0.2, 0.35, 0.5, 0.7, 0.85, 1.0)
#: View cosines of the statistical checks.
STAT_COS = (0.9, 0.4, 0.05)


@dataclasses.dataclass(frozen=True)
class CheckResult:
    """Outcome of one check on one model."""

    model: str
    check: str
    passed: bool
    statistic: float
    threshold: float
    details: dict = dataclasses.field(default_factory=dict)
    seconds: float = 0.0
    applicable: bool = True
    #: reason declared in the registry entry, if the model is not meant to pass this check
    expected_failure: str | None = None

    @property
    def status(self) -> str:
        if not self.applicable:
            return "n/a"
        if self.expected_failure is not None:
            # a declared failure that did not happen this time is a pass: say so plainly
            return "expected failure" if not self.passed else "pass (failure declared)"
        return "pass" if self.passed else "FAIL"

    @property
    def ok(self) -> bool:
        """True unless the check failed without a declared reason."""
        return (not self.applicable) or self.passed or self.expected_failure is not None

    def to_dict(self) -> dict[str, Any]:
        def clean(v):
            if isinstance(v, float | np.floating):
                return float(v) if math.isfinite(v) else None
            if isinstance(v, np.ndarray):
                return clean(v.tolist())
            if isinstance(v, list | tuple):
                return [clean(x) for x in v]
            if isinstance(v, dict):
                return {str(k): clean(x) for k, x in v.items()}
            if isinstance(v, np.integer | np.bool_):
                return v.item()
            return v

        return {
            "model": self.model,
            "check": self.check,
            "passed": bool(self.passed),
            "status": self.status,
            "statistic": clean(self.statistic),
            "threshold": clean(self.threshold),
            "applicable": self.applicable,
            "expected_failure": self.expected_failure,
            "seconds": round(self.seconds, 3),
            "details": clean(self.details),
        }


def _na(name, check, why):
    return CheckResult(name, check, True, float("nan"), float("nan"), {"reason": why},
                       applicable=False)


# --------------------------------------------------------------------------- model structure


def _lobes(model: AbstractBRDF) -> list[tuple[Any, AbstractBRDF]]:
    """``[(scale, lobe)]`` with ``model = sum scale * lobe`` (compound models unfolded through
    :meth:`~brdf_fit.models.AbstractBRDF.terms`)."""
    if not model.is_compound():
        return [(1.0, model)]
    return [(scale * s, lobe) for scale, sub in model.terms() for s, lobe in _lobes(sub)]


def _pdf_lobes(model: AbstractBRDF) -> list[tuple[Any, AbstractBRDF]]:
    """``[(probability, lobe)]`` with ``model.pdf = sum p * lobe.pdf`` (through
    :meth:`~brdf_fit.models.AbstractBRDF.pdf_terms`)."""
    if not model.is_compound():
        return [(1.0, model)]
    return [(p * q, lobe) for p, sub in model.pdf_terms() for q, lobe in _pdf_lobes(sub)]


def _microfacet_lobes(model) -> list[MicrofacetBRDF]:
    return [lobe for _, lobe in _lobes(model) if isinstance(lobe, MicrofacetBRDF)]


def _views(model, cosines) -> list[np.ndarray]:
    """View directions: each cosine at one azimuth, and at three for anisotropic models
    (:meth:`~brdf_fit.models.AbstractBRDF.is_anisotropic`: a microfacet lobe with ``alpha_y``, or
    a lobe whose class sets ``anisotropic = True``)."""
    aniso = model.is_anisotropic()
    phis = (0.3, 0.3 + math.pi / 4, 0.3 + math.pi / 2) if aniso else (0.3,)
    return [unit_direction(c, p) for c in cosines for p in phis]


def _rule_for(lobe, wo) -> quadrature.Rule:
    """Quadrature rule over wi adapted to one lobe (:func:`brdf_fit.verify.albedo.lobe_rule`);
    the negative controls get the rule of the lobe they wrap."""
    while isinstance(lobe, AbstractNegativeControl):
        lobe = lobe.inner
    return albedo.lobe_rule(lobe, jnp.asarray(wo))


def _widths(lobe: MicrofacetBRDF) -> tuple[float, float]:
    ax, ay = albedo.lobe_widths(lobe)
    return float(ax), float(ay)


def directional_albedo(model, wo) -> np.ndarray:
    """``E(wo) = Int f(wi, wo) cos(theta_i) dwi`` (shape ``()`` or ``(C,)``), by linearity over the
    lobes of ``model`` with a rule adapted to each (see :mod:`brdf_fit.quadrature`)."""
    return np.asarray(albedo.directional_albedo(model, jnp.asarray(wo)))


# --------------------------------------------------------------------------- deterministic checks


def model_eps(model) -> float:
    """Machine epsilon of the model's floating-point parameters (JAX's default float if none)."""
    dts = [x.dtype for x in jax.tree_util.tree_leaves(model)
           if eqx.is_array(x) and jnp.issubdtype(x.dtype, jnp.floating)]
    dt = dts[0] if dts else jnp.zeros(()).dtype
    return float(jnp.finfo(dt).eps)


def _random_pairs(n, seed, lo=1e-3):
    rng = np.random.default_rng(seed)

    def dirs():
        mu = rng.uniform(lo, 1.0, n)
        phi = rng.uniform(0, 2 * np.pi, n)
        s = np.sqrt(1 - mu * mu)
        return np.stack([s * np.cos(phi), s * np.sin(phi), mu], -1)

    return jnp.asarray(dirs()), jnp.asarray(dirs())


def check_non_negative(model, name="model", n=4096, seed=0) -> CheckResult:
    wi, wo = _random_pairs(n, seed)
    f = np.asarray(evaluate(model, jnp.concatenate([wi, wo]), jnp.concatenate([wo, wo])))
    fmin = float(np.min(f))
    return CheckResult(name, "non-negative", fmin >= 0.0, fmin, 0.0,
                       {"n_pairs": 2 * n, "n_negative": int(np.sum(f < 0))})


def check_reciprocity(model, name="model", n=4096, seed=1, tol=None) -> CheckResult:
    tol = RECIPROCITY_EPS * model_eps(model) if tol is None else tol
    if model.is_delta:
        return _na(name, "reciprocity", "delta lobe: not evaluable pointwise")
    wi, wo = _random_pairs(n, seed)
    a = np.asarray(evaluate(model, wi, wo))
    b = np.asarray(evaluate(model, wo, wi))
    scale = max(float(np.max(np.abs(a))), 1e-300)
    err = np.abs(a - b) / scale
    worst = int(np.argmax(err.reshape(n, -1).max(-1)))
    return CheckResult(name, "reciprocity", float(np.max(err)) <= tol, float(np.max(err)), tol,
                       {"n_pairs": n, "worst_wi": np.asarray(wi[worst]),
                        "worst_wo": np.asarray(wo[worst])})


def check_energy(model, name="model", cosines=ENERGY_COS, tol=ENERGY_TOL) -> CheckResult:
    views = _views(model, cosines)
    E = np.stack([np.atleast_1d(directional_albedo(model, wo)) for wo in views])
    worst = np.unravel_index(int(np.argmax(E)), E.shape)
    return CheckResult(
        name, "energy", float(np.max(E)) <= 1.0 + tol, float(np.max(E)), 1.0 + tol,
        {"cos_o": [float(v[2]) for v in views], "albedo": E,
         "worst_cos_o": float(views[worst[0]][2])},
    )


def _adapted_normal_rule(ax, ay, n_v=256, n_phi=512, cut=None):
    """Rule over microfacet normals m (upper hemisphere) adapted to widths (ax, ay):
    ``tan(theta) = beta(phi) s/(1-s)``, GL in s, periodic trapezoid in phi; ``cut(phi)`` limits
    theta exactly where an integrand has a kink."""
    x, w = np.polynomial.legendre.leggauss(n_v)
    phi = (np.arange(n_phi) + 0.5) * 2 * np.pi / n_phi
    beta = 1.0 / np.sqrt(np.cos(phi) ** 2 / ax**2 + np.sin(phi) ** 2 / ay**2)
    smax = np.ones_like(phi)
    if cut is not None:
        with np.errstate(divide="ignore", invalid="ignore"):
            q = np.tan(cut(phi)) / beta
        smax = np.where(np.isfinite(q), q / (1 + q), 1.0)
    s = 0.5 * (x[None] + 1) * smax[:, None]
    ws = 0.5 * w[None] * smax[:, None]
    t = s / (1 - s)
    th = np.arctan(beta[:, None] * t)
    dth = beta[:, None] / (1 + (beta[:, None] * t) ** 2) / (1 - s) ** 2
    P = np.broadcast_to(phi[:, None], th.shape)
    m = np.stack([np.sin(th) * np.cos(P), np.sin(th) * np.sin(P), np.cos(th)], -1)
    return m.reshape(-1, 3), (ws * dth * np.sin(th) * (2 * np.pi / n_phi)).reshape(-1)


def check_ndf_normalisation(model, name="model", tol=IDENTITY_TOL) -> CheckResult:
    lobes = _microfacet_lobes(model)
    if not lobes:
        return _na(name, "ndf-normalisation", "no microfacet lobe")
    errs = []
    for lobe in lobes:
        m, w = _adapted_normal_rule(*_widths(lobe))
        m = jnp.asarray(m)
        d = lobe.distribution
        errs.append(abs(float(jnp.sum(w * d.D(m[:, 0], m[:, 1], m[:, 2]) * m[:, 2])) - 1.0))
    return CheckResult(name, "ndf-normalisation", max(errs) <= tol, max(errs), tol,
                       {"per_lobe_error": errs})


def _visible_cut(wo):
    theta_o = math.acos(min(1.0, wo[2]))
    phi_o = math.atan2(wo[1], wo[0])

    def cut(phi):
        c = np.cos(phi - phi_o)
        with np.errstate(divide="ignore"):
            return np.where(c < 0, np.arctan(1 / (np.tan(theta_o) * np.abs(c))), np.pi / 2)

    return cut


def check_weak_white_furnace(model, name="model", cosines=(0.95, 0.5, 0.1), tol=1e-5
                             ) -> CheckResult:
    """tol: the V-cavity G1 has a kink inside the domain that the rule resolves to ~3e-7; Smith
    lobes reach 1e-9. A Blinn-Phong NDF with Beckmann-mapped Lambda misses by ~1e-2."""
    lobes = _microfacet_lobes(model)
    if not lobes:
        return _na(name, "weak-white-furnace", "no microfacet lobe")
    rows = []
    for lobe in lobes:
        d = lobe.distribution
        vcav = isinstance(lobe.masking, VCavity)
        for wo in _views(model, cosines):
            m, w = _adapted_normal_rule(*_widths(lobe), cut=_visible_cut(wo))
            m = jnp.asarray(m)
            mx, my, mz = m[:, 0], m[:, 1], m[:, 2]
            if vcav:
                pv = vcavity_pdf_visible(d, *wo, mx, my, mz)
            else:  # the masking's own G1 (not the sampler's): what the BRDF uses
                wm = jnp.maximum(wo[0] * mx + wo[1] * my + wo[2] * mz, 0.0)
                pv = d.G1(*wo) * wm * d.D(mx, my, mz) / wo[2]
            rows.append((float(wo[2]), abs(float(jnp.sum(w * pv)) - 1.0)))
    worst = max(r[1] for r in rows)
    return CheckResult(name, "weak-white-furnace", worst <= tol, worst, tol,
                       {"cos_o": [r[0] for r in rows], "error": [r[1] for r in rows]})


def check_white_furnace(model, name="model", cosines=ENERGY_COS, tol=ENERGY_TOL) -> CheckResult:
    lobes = _microfacet_lobes(model)
    if not lobes:
        return _na(name, "white-furnace", "no microfacet lobe")
    E_all, losses = [], []
    for lobe in lobes:
        white = eqx.tree_at(lambda m: m.fresnel, lobe, ConstantFresnel(1.0))
        E = np.array([float(np.max(directional_albedo(white, wo)))
                      for wo in _views(white, cosines)])
        E_all.append(E)
        losses.append(1.0 - E)
    E_max = float(max(np.max(e) for e in E_all))
    return CheckResult(
        name, "white-furnace", E_max <= 1.0 + tol, E_max, 1.0 + tol,
        {"cos_o": [float(v[2]) for v in _views(lobes[0], cosines)],
         "single_scattering_loss": losses,
         "note": "F = 1: 1 - E(wo) is the energy lost by single scattering (no multiple bounces)"},
    )


@eqx.filter_jit
def _sample(model, wo, uc, u):
    s = model.sample(wo, uc, u)
    return s.pdf, s.weight


def _draw(model, wo, n, seed):
    rng = np.random.default_rng(seed)
    dt = jnp.asarray(wo).dtype
    wob = jnp.broadcast_to(jnp.asarray(wo, dt), (n, 3))
    return _sample(model, wob, jnp.asarray(rng.random(n), dt), jnp.asarray(rng.random((n, 2)), dt))


def check_pdf_normalisation(model, name="model", cosines=STAT_COS, n=200_000, seed=2,
                            z_tol=Z_TOL) -> CheckResult:
    if model.is_delta:
        return _na(name, "pdf-normalisation", "delta lobe: discrete probability, no density")
    rows = []
    for wo in _views(model, cosines):
        integral = 0.0
        for p, lobe in _pdf_lobes(model):
            rule = _rule_for(lobe, wo)
            integral += float(p) * float(quadrature.integrate(
                lambda wi, lobe=lobe, wo=wo: lobe.pdf(wi, jnp.asarray(wo)), rule))
        pdf, _ = _draw(model, wo, n, seed)
        p_fail = float(np.mean(np.asarray(pdf) == 0))
        sigma = math.sqrt(max(p_fail * (1 - p_fail), 1.0 / n) / n)
        z = abs(integral - (1.0 - p_fail)) / sigma
        rows.append({"cos_o": float(wo[2]), "integral": integral, "p_fail": p_fail, "z": z})
    worst = max(r["z"] for r in rows)
    return CheckResult(name, "pdf-normalisation", worst <= z_tol, worst, z_tol, {"views": rows})


def check_sampling_weight(model, name="model", cosines=STAT_COS, n=200_000, seed=3,
                          z_tol=Z_TOL) -> CheckResult:
    rows = []
    for wo in _views(model, cosines):
        _, weight = _draw(model, wo, n, seed)
        w = np.asarray(weight, dtype=np.float64).reshape(n, -1)
        # exactly rounded sums: NumPy's mean along axis 0 of an (n, C) array accumulates naively
        # (error ~ n eps = 2e-11 at n = 2e5), which a zero-variance estimator would expose
        mean = np.array([math.fsum(col) for col in w.T]) / n
        se = w.std(0) / math.sqrt(n)
        E = np.atleast_1d(directional_albedo(model, wo))
        # floor: round-off of a zero-variance estimator (Lambert's weights are exactly rho)
        floor = WEIGHT_FLOOR_EPS * model_eps(model) * np.maximum(np.abs(E), 1e-300)
        # events too rare to be seen among n draws (a lobe losing 1e-9 of its samples below the
        # horizon): the sample standard deviation cannot see them, so allow their effect
        unseen = RARE_EVENT_COUNT * np.max(np.abs(w), axis=0) / n
        z = np.maximum(np.abs(mean - E) - unseen, 0.0) / np.maximum(se, floor)
        rows.append({"cos_o": float(wo[2]), "mean_weight": mean, "albedo": E, "z": z})
    worst = float(max(np.max(r["z"]) for r in rows))
    return CheckResult(name, "sampling-weight", worst <= z_tol, worst, z_tol, {"views": rows})


def check_chi2(model, name="model", cosines=STAT_COS, n=100_000, seed=4, alpha=0.01,
               test_count=None) -> CheckResult:

    if model.is_delta:
        return _na(name, "chi2", "delta lobe: sampling is deterministic")
    views = _views(model, cosines)
    count = test_count or len(views)
    results = [chi2_test_brdf(model, wo, n_samples=n, seed=seed + j, alpha=alpha,
                              test_count=count) for j, wo in enumerate(views)]
    pmin = min(r.p_value for r in results)
    passed = all(r.passed for r in results)
    details = {"views": [{"cos_o": float(wo[2]), "p_value": r.p_value, "passed": r.passed,
                          "reasons": list(r.reasons)} for wo, r in zip(views, results,
                                                                        strict=True)]}
    worst = [r for r in results if not r.passed]
    if worst:
        details["worst_cells"] = worst[0].worst_cells(5)
    return CheckResult(name, "chi2", passed, pmin, results[0].threshold, details)


# --------------------------------------------------------------------------- hard-case grid
# (the grid itself: brdf_fit.verify.hard_cases)


def check_finite(entry, name=None, dtypes=(jnp.float64, jnp.float32)) -> CheckResult:
    """Values and gradients on the hard-case grid, vmapped over the parameter grid."""
    name = name or entry.name
    if not jax.config.jax_enable_x64:
        dtypes = tuple(d for d in dtypes if d != jnp.float64)
    WI, WO = hard_case_directions()
    details, bad_total = {}, 0
    for dt in dtypes:
        grid = {k: jnp.asarray(v, dt) for k, v in hard_case_params(entry).items()}
        wi, wo = jnp.asarray(WI, dt), jnp.asarray(WO, dt)

        def total(p, wi, wo):
            m = entry.build(**p)
            return jnp.sum(m.eval(wi, wo)) + jnp.sum(m.pdf(wi, wo))

        def one(p, wi=wi, wo=wo):
            m = entry.build(**p)
            return m.eval(wi, wo), m.pdf(wi, wo), jax.grad(total, argnums=(0, 1, 2))(p, wi, wo)

        out = jax.jit(jax.vmap(one))(grid)
        leaves = jax.tree_util.tree_leaves(out)
        bad = sum(int(np.sum(~np.isfinite(np.asarray(x)))) for x in leaves)
        negative = int(np.sum(np.asarray(out[0]) < 0) + np.sum(np.asarray(out[1]) < 0))
        details[jnp.dtype(dt).name] = {"non_finite": bad, "negative": negative,
                                      "n_param_sets": int(next(iter(grid.values())).shape[0]),
                                      "n_direction_pairs": int(WI.shape[0])}
        bad_total += bad + negative
    return CheckResult(name, "finite", bad_total == 0, float(bad_total), 0.0, details)


# --------------------------------------------------------------------------- running

CHECKS: dict[str, Callable] = {
    "non-negative": check_non_negative,
    "reciprocity": check_reciprocity,
    "energy": check_energy,
    "ndf-normalisation": check_ndf_normalisation,
    "weak-white-furnace": check_weak_white_furnace,
    "white-furnace": check_white_furnace,
    "pdf-normalisation": check_pdf_normalisation,
    "sampling-weight": check_sampling_weight,
    "chi2": check_chi2,
    "finite": None,  # needs the registry entry (parameter grid): handled in run_checks
}


def run_checks(
    model_or_name,
    params: dict | None = None,
    checks: Iterable[str] | None = None,
    progress: Callable[[str, str], None] | None = None,
    name: str | None = None,
    expected_failures: dict | None = None,
) -> list[CheckResult]:
    """Run ``checks`` (default: all of :data:`CHECKS`) on a registry entry (by name, with optional
    ``params``) or on a model object (then ``finite`` is not applicable and ``expected_failures``
    may be given). ``progress(model, check)`` is called before each check."""

    entry = None
    if isinstance(model_or_name, str):
        entry = registry.get(model_or_name)
        model = entry.build(**(params or {}))
        name = name or entry.name
        declared = dict(entry.expected_failures)
    else:
        model = model_or_name
        name = name or type(model).__name__
        declared = {}
    declared.update(expected_failures or {})
    selected = list(CHECKS) if checks is None else list(checks)
    for c in selected:
        if c not in CHECKS:
            raise ValueError(f"unknown check {c!r}; valid checks: {', '.join(CHECKS)}")
    results = []
    for c in selected:
        if progress:
            progress(name, c)
        t0 = time.perf_counter()
        if c == "finite":
            r = check_finite(entry, name) if entry is not None else _na(
                name, c, "needs a registry entry for its parameter grid")
        else:
            r = CHECKS[c](model, name)
        r = dataclasses.replace(r, seconds=time.perf_counter() - t0,
                                expected_failure=declared.get(c) if r.applicable else None)
        results.append(r)
    return results
