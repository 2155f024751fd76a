"""Choose the cheapest model whose rendering error is within a budget.

**The error** (:data:`ERROR_DEFINITION`, defined once): the relative RMS error of the reflected
radiance ``L = f cos(theta_i)`` (unit irradiance from ``wi``) over the data's geometry, every
used sample and channel,

    error = sqrt( sum w (m - f)^2 cos_i^2 / sum w f^2 cos_i^2 ),

so a budget of 0.02 means 2%. It weights the samples by where light actually goes (a far tail
where the radiance is 1e-4 of the peak hardly counts; the peak does), which is the question "which
cheap model renders this material well?".

**Each candidate is fitted in that error** (:func:`brdf_fit.fit` with ``metric="absolute"``,
``cos_weight=True``, the data's sigma set aside), not in the log or chi-square metric: a fit in a
relative metric with per-sample sigma makes the far tails, where a Beckmann or Phong lobe falls
to nothing and GGX does not, outweigh the peak (issue 18). The goodness of fit to the noise is
reported beside it: with per-sample ``sigma``, the reduced chi-square of the same fitted model,
``sum ((m - f)/sigma)^2 / (N - k)``.

**Information criteria** of the fit in the selection error, with ``N`` residuals (samples x
channels), ``k`` free scalars and ``RSS`` the weighted sum of squared radiance residuals:
``AIC = N ln(RSS/N) + 2k`` (Akaike 1974) and ``BIC = N ln(RSS/N) + k ln N`` (Schwarz 1978), the
Gaussian-likelihood forms up to a constant shared by all candidates.

**Cost**: :func:`measure_cost`, nanoseconds per evaluation of the fitted model's ``eval`` under
``jit`` on :data:`COST_PAIRS` seeded direction pairs (parameters as traced arguments, the minimum
of :data:`COST_ROUNDS` timed calls), measured in the same run for every candidate, on this
machine; only ratios between candidates mean anything elsewhere.

**The choice**: the cheapest candidate whose error is within the budget (ties: fewer parameters,
then the lower error); ``None`` when none is. Without a budget the default is stated in the
result: twice the error of the best candidate, at least 1.5 times the noise level when the
data carry sigma (``sqrt(sum w sigma^2 cos_i^2 / sum w f^2 cos_i^2)``, the error a perfect model
would show), and at least :data:`BUDGET_FLOOR` (1%): noise-free samples of a formula (a scene's
MTL or glTF material) would otherwise get a budget of 2e-16, which only the formula itself
meets. The Pareto front (no other candidate both cheaper and more accurate) is reported.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable, Sequence

import jax
import jax.numpy as jnp
import numpy as np

from brdf_fit import registry
from brdf_fit.core.validate import ParameterError
from brdf_fit.data import GonioData
from brdf_fit.fitting.problem import FitError
from brdf_fit.fitting.single import fit, json_floats

__all__ = ["COST_PAIRS", "COST_ROUNDS", "DEFAULT_CANDIDATES", "ERROR_DEFINITION", "FAMILIES",
           "Candidate", "Selection", "family_candidates", "measure_cost", "radiance_error",
           "select"]

ERROR_DEFINITION = (
    "relative RMS error of the reflected radiance f cos(theta_i) over the data's samples and "
    "channels: sqrt(sum w (m - f)^2 cos_i^2 / sum w f^2 cos_i^2)"
)

#: the default candidates: one or two of each family, diffuse to specular, cheap to costly
DEFAULT_CANDIDATES = (
    "lambert", "oren-nayar", "modified-phong", "blinn-phong", "ward", "beckmann", "ggx",
    "ggx-plastic", "ggx-conductor", "cook-torrance",
)

#: named candidate families (``select(..., family=NAME)``, ``brdf-fit select --family NAME``):
#: the registry entries that answer one question each. ``"all"`` is every registry entry that
#: can be fitted (not a delta lobe): 40-odd fits, minutes, for when the question is open.
FAMILIES = {
    "default": DEFAULT_CANDIDATES,
    # a matte surface: how much retro-reflection and darkening at grazing does it need?
    "diffuse": ("lambert", "oren-nayar", "oren-nayar-qualitative", "minnaert", "lewis"),
    # the Phong catalogue, as old renderers and MTL files carry it
    "phong": ("modified-phong", "modified-phong-fresnel", "blinn-phong", "blinn-phong-approx",
              "phong-energy-normalized", "blinn-phong-microfacet"),
    # isotropic microfacet specular lobes: which NDF, which masking, single or multiple scattering
    "microfacet": ("beckmann", "beckmann-walter", "ggx", "ggx-separable", "ggx-ms",
                   "ggx-ms-turquin", "cook-torrance", "cook-torrance-1982"),
    # diffuse base plus a specular coat: summed, coupled or layered
    "plastic": ("ggx-plastic", "torrance-sparrow", "ashikhmin-shirley", "kelemen",
                "granier-heidrich", "ward"),
    # metals: exact conductor Fresnel, single and multiple scattering
    "conductor": ("ggx-conductor", "ggx-conductor-ms", "ggx", "cook-torrance"),
    # brushed surfaces: two widths
    "anisotropic": ("ggx-aniso", "beckmann-aniso", "ward", "ashikhmin-shirley", "lafortune",
                    "ggx-conductor-aniso"),
}


def family_candidates(family: str) -> tuple[str, ...]:
    """The registry names of a named family (:data:`FAMILIES`; ``"all"``: every non-delta
    entry). An unknown family is a ``ValueError`` that lists the known ones."""
    if family == "all":
        return tuple(e.name for e in registry.entries() if "delta" not in e.tags)
    if family not in FAMILIES:
        raise ValueError(f"unknown family {family!r}; known: "
                         + ", ".join([*FAMILIES, "all"]))
    return FAMILIES[family]


#: direction pairs per timed call of :func:`measure_cost` and timed calls per candidate
COST_PAIRS = 16384
COST_ROUNDS = 7
#: the default budget: this many times the best candidate's error ...
BUDGET_FACTOR_BEST = 2.0
#: ... and at least this many times the noise level (data with sigma)
BUDGET_FACTOR_NOISE = 1.5
#: ... and at least this error (a 1% RMS radiance difference: the floor for noise-free samples)
BUDGET_FLOOR = 0.01


def _radiance(data: GonioData):
    w = np.ones_like(data.value) if data.weight is None else np.asarray(data.weight)
    c = np.clip(data.wi[:, 2:3], 0.0, None)
    return w, c


def _as_values(data: GonioData, model_values) -> np.ndarray:
    m = np.asarray(model_values, dtype=np.float64)
    return np.broadcast_to(m[:, None] if m.ndim == 1 else m, data.value.shape)


def _radiance_sums(data: GonioData, m) -> tuple[float, float]:
    """``(sum w (m - f)^2 cos_i^2, sum w f^2 cos_i^2)``: the squared residual radiance (the RSS
    of the selection fit) and its normaliser."""
    w, c = _radiance(data)
    return (float(np.sum(w * ((m - data.value) * c) ** 2)),
            float(np.sum(w * (data.value * c) ** 2)))


def radiance_error(data: GonioData, model_values) -> float:
    """:data:`ERROR_DEFINITION` of model values ``(N, C)`` (or ``(N,)``) against ``data``."""
    num, den = _radiance_sums(data, _as_values(data, model_values))
    return float(math.sqrt(num / den)) if den > 0 else float("inf")


def noise_level(data: GonioData) -> float | None:
    """The error a perfect model would show, from the data's sigma (None without sigma)."""
    if data.sigma is None:
        return None
    w, c = _radiance(data)
    den = np.sum(w * (data.value * c) ** 2)
    return float(math.sqrt(np.sum(w * (data.sigma * c) ** 2) / den)) if den > 0 else None


def _directions(n: int, seed: int = 0):
    rng = np.random.default_rng(seed)

    def hemi(k):
        u1, u2 = rng.random(k), rng.random(k)
        r = np.sqrt(u1)
        return np.stack([r * np.cos(2 * np.pi * u2), r * np.sin(2 * np.pi * u2),
                         np.sqrt(1.0 - u1)], -1)

    return hemi(n), hemi(n)


def measure_cost(model, n: int = COST_PAIRS, rounds: int = COST_ROUNDS) -> float:
    """Nanoseconds per evaluation of ``model.eval`` under ``jit`` (module docstring)."""
    wi, wo = (jnp.asarray(a) for a in _directions(n))
    leaves, treedef = jax.tree_util.tree_flatten(model)

    @jax.jit
    def run(leaves, wi, wo):
        return jax.tree_util.tree_unflatten(treedef, leaves).eval(wi, wo)

    jax.block_until_ready(run(leaves, wi, wo))  # compile
    best = float("inf")
    for _ in range(rounds):
        t0 = time.perf_counter()
        jax.block_until_ready(run(leaves, wi, wo))
        best = min(best, time.perf_counter() - t0)
    return best / n * 1e9


def _num(x):
    """A float for strict JSON: NaN and inf (a candidate without a fit) as None."""
    return float(x) if math.isfinite(x) else None


@dataclasses.dataclass
class Candidate:
    """One fitted candidate (see :func:`select`)."""

    model: str
    params: dict
    stderr: dict
    error: float
    cost_ns: float
    n_params: int
    aic: float
    bic: float
    converged: bool
    reduced_chi2: float | None = None
    checks: dict = dataclasses.field(default_factory=dict)
    within_budget: bool = False
    pareto: bool = False
    seconds: float = 0.0
    #: why the candidate has no fit ("" when it has one): e.g. a fit whose optimum breaks a
    #: joint constraint of the model (modified Phong's rho_d + rho_s <= 1)
    message: str = ""
    fitted: object = None  # the fitted model object (not serialised)

    def to_dict(self) -> dict:
        def tolist(v):
            a = np.asarray(v)
            return a.tolist() if a.ndim else float(a)

        return {
            "model": self.model,
            "params": {k: tolist(v) for k, v in self.params.items()},
            "stderr": {k: json_floats(v) for k, v in self.stderr.items()},
            "error": _num(self.error), "cost_ns": _num(round(self.cost_ns, 3)),
            "n_params": self.n_params, "aic": _num(self.aic), "bic": _num(self.bic),
            "within_budget": self.within_budget,
            "pareto": self.pareto, "converged": self.converged,
            "reduced_chi2": self.reduced_chi2, "checks": self.checks,
            "seconds": round(self.seconds, 3), "message": self.message,
        }


@dataclasses.dataclass
class Selection:
    """The outcome of :func:`select`: ``choice`` (a model name or None), the ``budget`` used and
    how it was set, and every candidate (sorted by cost)."""

    choice: str | None
    budget: float
    budget_rule: str
    error_definition: str
    candidates: list[Candidate]
    noise_level: float | None
    n_samples: int
    seconds: float

    def candidate(self, name: str) -> Candidate:
        for c in self.candidates:
            if c.model == name:
                return c
        raise KeyError(f"no candidate {name!r}")

    def to_dict(self) -> dict:
        return {
            "choice": self.choice, "budget": self.budget, "budget_rule": self.budget_rule,
            "error_definition": self.error_definition, "noise_level": self.noise_level,
            "n_samples": self.n_samples, "seconds": round(self.seconds, 3),
            "pareto": [c.model for c in self.candidates if c.pareto],
            "candidates": [c.to_dict() for c in self.candidates],
        }


def _pareto(cands: list[Candidate]) -> None:
    for c in cands:
        if c.message:
            c.pareto = False
            continue
        c.pareto = not any(
            (o.cost_ns <= c.cost_ns and o.error <= c.error)
            and (o.cost_ns < c.cost_ns or o.error < c.error)
            for o in cands if o is not c and not o.message)


def select(data: GonioData, candidates: Sequence[str] | None = None, budget: float | None = None,
           *, family: str | None = None, checks: Sequence[str] = ("reciprocity", "energy"),
           max_steps: int = 256, multistart: int = 1, seed: int = 0,
           costs: dict[str, float] | None = None,
           progress: Callable[[int, int, str], None] | None = None) -> Selection:
    """Fit each candidate (registry names; default :data:`DEFAULT_CANDIDATES`) to ``data`` in
    the radiance error, measure its cost, and choose the cheapest within ``budget`` (module
    docstring). ``family``: a named set of candidates instead (:data:`FAMILIES`, or ``"all"``;
    not together with ``candidates``). ``checks``: registry checks run on each fitted model
    (their status per check; ``()`` skips them). ``costs``: a dict of measured costs (ns per
    evaluation) by model name, shared between calls: a model found there is not measured again,
    a model measured here is added (a scene measures each kernel once). ``progress(done, total,
    model)`` is called before each candidate."""
    t_start = time.perf_counter()
    if family is not None and candidates is not None:
        raise ValueError("give candidates or a family, not both")
    if family is not None:
        names = list(family_candidates(family))
    else:
        names = list(DEFAULT_CANDIDATES if candidates is None else candidates)
    if not names:
        raise ValueError("give at least one candidate")
    entries = [registry.get(n) for n in names]  # unknown names fail before any fit
    if len({e.name for e in entries}) != len(entries):
        raise ValueError("a candidate is listed twice")
    if budget is not None and not (math.isfinite(budget) and budget > 0):
        raise ValueError(f"budget must be a positive number, got {budget}")
    data.validate()
    plain = dataclasses.replace(data, sigma=None)  # the selection error ignores sigma
    n_res = int(np.sum((np.ones_like(data.value) if data.weight is None else data.weight) > 0))
    out = []
    for i, e in enumerate(entries):
        if progress is not None:
            progress(i, len(entries), e.name)
        t0 = time.perf_counter()
        try:
            r = fit(plain, e.name, metric="absolute", cos_weight=True, max_steps=max_steps,
                    multistart=multistart, seed=seed)
        except (ParameterError, FitError) as exc:  # one candidate's failure loses no other
            out.append(Candidate(
                model=e.name, params={}, stderr={}, error=float("inf"), cost_ns=float("nan"),
                n_params=0, aic=float("nan"), bic=float("nan"), converged=False,
                seconds=time.perf_counter() - t0, message=f"{type(exc).__name__}: {exc}"))
            continue
        m = _as_values(data, r.model.eval(jnp.asarray(data.wi), jnp.asarray(data.wo)))
        rss, den = _radiance_sums(data, m)
        err = float(math.sqrt(rss / den)) if den > 0 else float("inf")
        k = int(sum(np.asarray(v).size for v in r.params.values()))
        rss = max(rss, 1e-300)
        aic = n_res * math.log(rss / n_res) + 2 * k
        bic = n_res * math.log(rss / n_res) + k * math.log(n_res)
        chi2 = None
        if data.sigma is not None:
            w = _radiance(data)[0] > 0
            z = (m - data.value)[w] / np.maximum(data.sigma[w], 1e-300)
            chi2 = float(np.sum(z * z) / max(z.size - k, 1))
        status = {}
        if checks:
            from brdf_fit.verify.checks import run_checks

            for c in run_checks(e.name, params={p: np.asarray(v) for p, v in r.params.items()},
                                checks=checks):
                status[c.check] = c.status
        if costs is not None and e.name in costs:
            cost = costs[e.name]
        else:
            cost = measure_cost(r.model)
            if costs is not None:
                costs[e.name] = cost
        out.append(Candidate(
            model=e.name, params=r.params, stderr=r.stderr, error=err,
            cost_ns=cost, n_params=k, aic=aic, bic=bic,
            converged=bool(r.converged), reduced_chi2=chi2, checks=status,
            seconds=time.perf_counter() - t0, fitted=r.model))
    if progress is not None:
        progress(len(entries), len(entries), "done")
    noise = noise_level(data)
    if all(c.message for c in out):
        raise FitError("no candidate could be fitted: " + "; ".join(
            f"{c.model}: {c.message}" for c in out))
    best = min(c.error for c in out if not c.message)
    if budget is None:
        budget = BUDGET_FACTOR_BEST * best
        rule = f"default: {BUDGET_FACTOR_BEST:g} x the best candidate's error ({best:.4g})"
        if noise is not None and BUDGET_FACTOR_NOISE * noise > budget:
            budget = BUDGET_FACTOR_NOISE * noise
            rule = (f"default: {BUDGET_FACTOR_NOISE:g} x the noise level ({noise:.4g}), above "
                    f"{BUDGET_FACTOR_BEST:g} x the best error ({best:.4g})")
        if BUDGET_FLOOR > budget:
            budget = BUDGET_FLOOR
            rule = (f"default: the floor {BUDGET_FLOOR:g}, above {BUDGET_FACTOR_BEST:g} x the "
                    f"best error ({best:.4g})" + ("" if noise is None else
                                                  f" and {BUDGET_FACTOR_NOISE:g} x the noise"))
    else:
        rule = "given"
    for c in out:
        c.within_budget = bool(c.error <= budget)
    _pareto(out)
    out.sort(key=lambda c: (bool(c.message), c.cost_ns if not c.message else 0.0, c.n_params,
                            c.error))
    ok = [c for c in out if c.within_budget]
    choice = min(ok, key=lambda c: (c.cost_ns, c.n_params, c.error)).model if ok else None
    return Selection(choice=choice, budget=float(budget), budget_rule=rule,
                     error_definition=ERROR_DEFINITION, candidates=out, noise_level=noise,
                     n_samples=data.n, seconds=time.perf_counter() - t_start)
