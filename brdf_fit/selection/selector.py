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

**The cost that decides** is the committed one (issue 28: the demo chose ``ggx``, ``ggx``, then
``ggx-conductor`` in three runs, because live timings moved 30-50%): each entry's evaluation
cost relative to Lambert from the table ``benchmarks/bench_catalogue_cost.py`` measures and
commits (``brdf_fit/resources/catalogue_cost.json``, float64, the minimum over 15 shuffled
rounds), so the choice is the same from run to run and machine to machine. The live figure
(:func:`measure_cost`, ns per evaluation on this machine, this run) is reported beside it. A
candidate without a committed figure (a user's own entry) makes every candidate's choice cost
the live one, and the result says so (``cost_rule``).

**The choice**: the cheapest candidate whose error is within the budget (ties: fewer parameters,
then the lower error); ``None`` when none is. A model that extends another by a lobe
(:mod:`brdf_fit.selection.nesting`) costs at least its base there, so the base wins whenever
both are within the budget, and each such lobe's gain (the error it removes) is reported. An
extension that would be the choice is first tested against its base (an F test of the nested
pair, :func:`brdf_fit.selection.nesting.lobe_test`, in ``lobe_gain``): one whose lobe the data
do not support (p-value not below 1%) is passed over for the next cheapest.
Without a budget the default is stated in the result: twice the error of the best candidate, at
least 1.5 times the noise level when the data carry sigma (``sqrt(sum w sigma^2 cos_i^2 / sum w
f^2 cos_i^2)``, the error a perfect model would show), and at least :data:`BUDGET_FLOOR` (1%):
noise-free samples of a formula (a scene's MTL or glTF material) would otherwise get a budget of
2e-16, which only the formula itself meets. The Pareto front (no other candidate both cheaper
and more accurate) is reported.

**A ceiling, never a multiple of a bad error.** Above an absolute error no candidate counts as
representing the material, whatever the budget rule says: :data:`CEILING_ABOVE_NOISE` (0.05)
above the noise level (0.05 without sigma). A default budget is capped at the ceiling, and no
candidate above it is within budget (``ceiling=`` changes it; ``math.inf`` turns it off). When
the best candidate exceeds it, ``represented`` is False, ``choice`` is None, and ``message``
names the best candidate, its error and the family to try (issue 28: a 35% fit of brushed
aluminium was "within budget" for 8 of 10 candidates under the 2 x best rule).

**Anisotropy.** :func:`brdf_fit.selection.anisotropy.detect_anisotropy` tests the data for a
second roughness width (a statistic with its threshold, in the result); when it is present and
the candidates are the defaults (of the target, or of the package), the anisotropic candidates
of :data:`ANISOTROPIC_CANDIDATES` join them.

**Targets.** ``target="mitsuba"``, ``"gltf"`` or ``"blender"`` fits in the target's own models
(registry entries whose ``target`` is it, plus the entries that export to it exactly:
:data:`EXACT_EXPORTS`), so that the chosen fit is written to the renderer as it was fitted.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable, Sequence

import jax.numpy as jnp
import numpy as np

from brdf_fit import registry
from brdf_fit.core.validate import ParameterError
from brdf_fit.data import GonioData
from brdf_fit.fitting.problem import FitError
from brdf_fit.fitting.result import json_floats
from brdf_fit.fitting.single import fit
from brdf_fit.models._base import evaluate
from brdf_fit.selection.anisotropy import AnisotropyTest, detect_anisotropy
from brdf_fit.selection.candidates import (
    ANISOTROPIC_CANDIDATES,
    DEFAULT_CANDIDATES,
    EXACT_EXPORTS,
    FAMILIES,
    TARGET_CANDIDATES,
    TARGETS,
    anisotropic_candidates,
    exports_exactly,
    family_candidates,
    target_candidates,
)
from brdf_fit.selection.costs import (  # noqa: F401 (re-exported)
    COST_PAIRS,
    COST_ROUNDS,
    committed_costs,
    live_cost,
    measure_cost,
)
from brdf_fit.selection.nesting import (
    base_of,
    choice_costs,
    decisive_extension,
    lobe_gains,
    refit_lobe_test,
    reproduced_level,
)

__all__ = ["ANISOTROPIC_CANDIDATES", "CEILING_ABOVE_NOISE", "COST_PAIRS", "COST_ROUNDS",
           "DEFAULT_CANDIDATES", "ERROR_DEFINITION", "EXACT_EXPORTS", "FAMILIES", "TARGETS",
           "TARGET_CANDIDATES", "Candidate", "Selection", "committed_costs", "exports_exactly",
           "family_candidates", "measure_cost", "radiance_error", "select",
           "target_candidates"]

ERROR_DEFINITION = (
    "relative RMS error of the reflected radiance f cos(theta_i) over the data's samples and "
    "channels: sqrt(sum w (m - f)^2 cos_i^2 / sum w f^2 cos_i^2)"
)

#: the fewest starts a candidate tagged "layered" is fitted from (lobes mixed by weights whose
#: best values are often an end of their interval: metallic 0 or 1, a coat weight 1). One
#: start fitted a Cycles-rendered copper (metallic 1) with blender-principled at metallic 0.72
#: and base colour 1, 15% error, so the coated extension was chosen for a bare metal; 4 starts
#: find the metal (error 2e-6)
LAYERED_STARTS = 4
#: a candidate tagged "layered" is fitted in this metric first (from LAYERED_STARTS starts),
#: then polished in the selection's absolute metric from there: in the absolute metric a sharp
#: coat peak outweighs the lobes beneath it by orders of magnitude and the solve crawls. A
#: Cycles-rendered coated blue (coat weight 1, coat roughness 0.1, base roughness 0.5) fitted in
#: it from 4 starts stopped at coat weight 0.87 after 256 steps (0.996 after 1024), so the
#: uncoated entry was chosen; the log fit reaches the set values in 305 steps, the polish
#: converges in 16
LAYERED_PREFIT_METRIC = "log"
#: the absolute error above the noise level beyond which no candidate represents a material
CEILING_ABOVE_NOISE = 0.05


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
    #: the committed cost relative to Lambert (module docstring; None: not in the table)
    cost_rel: float | None = None
    checks: dict = dataclasses.field(default_factory=dict)
    within_budget: bool = False
    pareto: bool = False
    seconds: float = 0.0
    #: why the candidate has no fit ("" when it has one): e.g. a fit whose optimum breaks a
    #: joint constraint of the model (modified Phong's rho_d + rho_s <= 1)
    message: str = ""
    #: entries of the fit the data do not determine (as
    #: :attr:`brdf_fit.fitting.single.FitResult.undetermined`)
    undetermined: tuple = ()
    #: the entry this one extends by a lobe (:data:`brdf_fit.selection.nesting.NESTED`), and
    #: what that lobe buys here where the base was fitted too
    #: (:func:`~brdf_fit.selection.nesting.lobe_gains`)
    extends: str | None = None
    lobe_gain: dict | None = None
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
            "cost_rel": None if self.cost_rel is None else round(self.cost_rel, 4),
            "n_params": self.n_params, "aic": _num(self.aic), "bic": _num(self.bic),
            "within_budget": self.within_budget,
            "pareto": self.pareto, "converged": self.converged,
            "reduced_chi2": self.reduced_chi2, "checks": self.checks,
            "seconds": round(self.seconds, 3), "message": self.message,
            "undetermined": list(self.undetermined),
            "extends": self.extends, "lobe_gain": self.lobe_gain,
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
    #: the absolute error above which no candidate represents the material, and how it was set
    ceiling: float = math.inf
    ceiling_rule: str = ""
    #: False when the best candidate exceeds the ceiling (then ``choice`` is None)
    represented: bool = True
    #: one line for a person: what was chosen, or why nothing was and what to try
    message: str = ""
    #: a family to try when nothing represents the material (None otherwise)
    suggestion: str | None = None
    #: how the choice's cost was read: "committed" (the table) or "live"
    cost_rule: str = ""
    target: str | None = None
    anisotropy: AnisotropyTest | None = None

    def candidate(self, name: str) -> Candidate:
        for c in self.candidates:
            if c.model == name:
                return c
        raise KeyError(f"no candidate {name!r}")

    def to_dict(self) -> dict:
        return {
            "choice": self.choice, "represented": self.represented, "message": self.message,
            "suggestion": self.suggestion, "target": self.target,
            "budget": self.budget, "budget_rule": self.budget_rule,
            "ceiling": _num(self.ceiling), "ceiling_rule": self.ceiling_rule,
            "cost_rule": self.cost_rule,
            "anisotropy": None if self.anisotropy is None else self.anisotropy.to_dict(),
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


def _choose_names(candidates, family, target, data, anisotropy):
    """``(names, test)``: the candidate names (module docstring) and the anisotropy test (None
    when it was not run)."""
    if family is not None and candidates is not None:
        raise ValueError("give candidates or a family, not both")
    if target is not None and target not in TARGETS:
        raise ValueError(f"unknown target {target!r}; known: {', '.join(TARGETS)}")
    defaulted = family is None and candidates is None
    if family is not None:
        names = list(family_candidates(family))
    elif candidates is not None:
        names = list(candidates)
    else:
        names = list(DEFAULT_CANDIDATES if target is None else target_candidates(target))
    if not names:
        raise ValueError("give at least one candidate")
    names = [registry.get(n).name for n in names]  # unknown names fail before any fit
    if len(set(names)) != len(names):
        raise ValueError("a candidate is listed twice")
    if target is not None:
        bad = [n for n in names if not exports_exactly(n, target)]
        if bad:
            raise ValueError(
                f"target {target}: {', '.join(bad)} cannot be written to {target} as fitted; "
                f"its models: {', '.join(target_candidates(target))}, "
                f"{', '.join(anisotropic_candidates(target))} (and "
                f"{', '.join(EXACT_EXPORTS[target])})")
    test = None
    if isinstance(anisotropy, AnisotropyTest):
        test = anisotropy
    elif anisotropy:
        test = detect_anisotropy(data)
    if test is not None:
        if test.present and defaulted:
            names += [n for n in anisotropic_candidates(target) if n not in names]
    return names, test


def _fit_candidate(e, plain, data, n_res, checks, max_steps, multistart, seed, costs,
                   measure=True):
    t0 = time.perf_counter()
    try:
        if "layered" in e.tags:
            pre = fit(plain, e.name, metric=LAYERED_PREFIT_METRIC, cos_weight=True,
                      max_steps=max_steps,
                      multistart=max(multistart, LAYERED_STARTS, e.select_starts),
                      seed=seed)
            r = fit(plain, e.name, metric="absolute", cos_weight=True, max_steps=max_steps,
                    init=pre.params)
        else:
            r = fit(plain, e.name, metric="absolute", cos_weight=True, max_steps=max_steps,
                    multistart=max(multistart, e.select_starts), seed=seed)
    except (ParameterError, FitError) as exc:  # one candidate's failure loses no other
        return Candidate(
            model=e.name, params={}, stderr={}, error=float("inf"), cost_ns=float("nan"),
            n_params=0, aic=float("nan"), bic=float("nan"), converged=False,
            seconds=time.perf_counter() - t0, message=f"{type(exc).__name__}: {exc}")
    return _candidate(e.name, r, data, n_res, checks, costs, measure, t0)


def _candidate(name, r, data, n_res, checks, costs, measure, t0) -> Candidate:
    """The :class:`Candidate` of a fit ``r`` (a FitResult) of model ``name``: its radiance
    error on ``data``, information criteria, checks and (``measure``) live cost."""
    m = _as_values(data, evaluate(r.model, jnp.asarray(data.wi), jnp.asarray(data.wo)))
    rss, den = _radiance_sums(data, m)
    err = float(math.sqrt(rss / den)) if den > 0 else float("inf")
    k = int(sum(np.asarray(v).size for v in r.params.values()))
    logs = math.log(max(rss, 1e-300) / n_res)
    aic = n_res * logs + 2 * k
    bic = n_res * logs + k * math.log(n_res)
    chi2 = None
    if data.sigma is not None:
        # samples with a stated noise only: multiplicative noise gives a value of exactly 0
        # (Mitsuba's below the horizon) a sigma of 0, whose z (and so chi2) was infinite for
        # any model, and the scene's JSON answer failed on it after a 4-minute run
        w = (_radiance(data)[0] > 0) & (data.sigma > 0)
        z = (m - data.value)[w] / data.sigma[w]
        chi2 = float(np.sum(z * z) / max(z.size - k, 1)) if z.size else None
    status = {}
    if checks:
        from brdf_fit.verify.checks import run_checks

        for c in run_checks(name, params={p: np.asarray(v) for p, v in r.params.items()},
                            checks=checks):
            status[c.check] = c.status
    cost = live_cost(name, r.model, costs) if measure else float("nan")
    return Candidate(
        model=name, params=r.params, stderr=r.stderr, error=err,
        cost_ns=cost, n_params=k, aic=aic, bic=bic, cost_rel=committed_costs().get(name),
        converged=bool(r.converged), reduced_chi2=chi2, checks=status,
        seconds=time.perf_counter() - t0, undetermined=r.undetermined, fitted=r.model)


#: families to suggest when nothing represents a material, by what the data showed
_SUGGEST_ANISO = "anisotropic"
_SUGGEST_OPEN = "all"


def select(data: GonioData, candidates: Sequence[str] | None = None, budget: float | None = None,
           *, family: str | None = None, target: str | None = None,
           checks: Sequence[str] = ("reciprocity", "energy"),
           max_steps: int = 256, multistart: int = 1, seed: int = 0,
           costs: dict[str, float] | None = None, ceiling: float | None = None,
           anisotropy: bool | AnisotropyTest = True,
           progress: Callable[[int, int, str], None] | None = None,
           workers: int = 1, fits: dict | None = None) -> Selection:
    """Fit each candidate (registry names; default :data:`DEFAULT_CANDIDATES`, or the target's
    :func:`target_candidates`) to ``data`` in the radiance error, measure its cost, and choose
    the cheapest within ``budget`` and the ceiling (module docstring). ``family``: a named set
    of candidates instead (:data:`FAMILIES`, or ``"all"``; not together with ``candidates``).
    ``target``: ``"mitsuba"``, ``"gltf"`` or ``"blender"``: only models written to it with no
    loss.
    ``checks``: registry checks run on each fitted model (their status per check; ``()`` skips
    them). ``costs``: a dict of live costs (ns per evaluation) by model name, shared between
    calls: a model found there is not measured again, a model measured here is added (a scene
    measures each kernel once). ``ceiling``: the absolute error above which nothing represents
    the material (default :data:`CEILING_ABOVE_NOISE` above the noise level). ``anisotropy``:
    run the anisotropy test (and add anisotropic candidates when it finds anisotropy and the
    candidates are the defaults); an :class:`~brdf_fit.selection.anisotropy.AnisotropyTest`
    is taken as the answer (a material whose formula is known needs no test).
    ``progress(done, total, model)`` is called before each candidate. ``workers``: candidates
    fitted at once, in threads (XLA compiles with the interpreter lock released, so on 2 cores
    two workers overlap one candidate's compilation with the next one's tracing: 1.26x on the
    demo's five fits, AMD EPYC 2 cores, same results to the last bit); the live costs are then
    measured after the fits, one at a time, so no timing shares the cores with a compile.
    ``fits``: ``{name: FitResult}`` fitted already (in any metric, e.g. the log chi-square of a
    measurement): the candidates are those fits, each judged in the radiance error as it is,
    without a refit and without the anisotropy test (``error_definition`` says so); a fit in
    another metric is not the candidate's best approximation in this error, so its error is an
    upper bound of what :func:`select` would report for it."""
    t_start = time.perf_counter()
    if budget is not None and not (math.isfinite(budget) and budget > 0):
        raise ValueError(f"budget must be a positive number, got {budget}")
    if ceiling is not None and not (ceiling > 0):
        raise ValueError(f"ceiling must be a positive number (or inf), got {ceiling}")
    data.validate()
    error_definition = ERROR_DEFINITION
    if fits is not None:
        if candidates is not None or family is not None:
            raise ValueError("give fits, or candidates / a family to fit, not both")
        candidates, anisotropy = list(fits), False
        error_definition += (" (of the given fits, each in its own metric, not refitted in "
                             "this error)")
    if progress is not None:
        progress(0, 1, "anisotropy test" if anisotropy is True else "")
    names, aniso = _choose_names(candidates, family, target, data, anisotropy)
    entries = [registry.get(n) for n in names]
    plain = dataclasses.replace(data, sigma=None)  # the selection error ignores sigma
    n_res = int(np.sum((np.ones_like(data.value) if data.weight is None else data.weight) > 0))
    if workers < 1:
        raise ValueError(f"workers must be an integer >= 1, got {workers}")
    out = []
    if fits is not None:
        given = {registry.get(k).name: v for k, v in fits.items()}
        for i, e in enumerate(entries):
            if progress is not None:
                progress(i, len(entries), e.name)
            out.append(_candidate(e.name, given[e.name], data, n_res, checks, costs, True,
                                  time.perf_counter()))
    elif workers == 1 or len(entries) < 2:
        for i, e in enumerate(entries):
            if progress is not None:
                progress(i, len(entries), e.name)
            out.append(_fit_candidate(e, plain, data, n_res, checks, max_steps, multistart,
                                      seed, costs))
    else:
        from concurrent.futures import ThreadPoolExecutor

        started = iter(range(len(entries)))

        def one(e):
            if progress is not None:
                progress(next(started), len(entries), e.name)
            return _fit_candidate(e, plain, data, n_res, checks, max_steps, multistart, seed,
                                  costs, measure=False)

        with ThreadPoolExecutor(min(workers, len(entries))) as pool:
            out = list(pool.map(one, entries))
        for c in out:
            if not c.message:
                c.cost_ns = live_cost(c.model, c.fitted, costs)
    if progress is not None:
        progress(len(entries), len(entries), "done")
    noise = noise_level(data)
    if all(c.message for c in out):
        raise FitError("no candidate could be fitted: " + "; ".join(
            f"{c.model}: {c.message}" for c in out))
    best_c = min((c for c in out if not c.message), key=lambda c: c.error)
    best = best_c.error
    if ceiling is None:
        ceiling = CEILING_ABOVE_NOISE + (noise or 0.0)
        ceiling_rule = (f"default: {CEILING_ABOVE_NOISE:g} above the noise level "
                        f"({noise:.4g})" if noise is not None else
                        f"default: {CEILING_ABOVE_NOISE:g} (no sigma: noise level unknown)")
    else:
        ceiling_rule = "given"
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
        if budget > ceiling:
            budget = ceiling
            rule = f"the ceiling ({ceiling:.4g}), below {rule}"
    else:
        rule = "given"
    for c in out:
        c.within_budget = bool(c.error <= budget and c.error <= ceiling)
    _pareto(out)
    fitted = [c for c in out if not c.message]
    if all(c.cost_rel is not None for c in fitted):
        cost_rule = ("committed: each entry's cost relative to Lambert from "
                     "brdf_fit/resources/catalogue_cost.json (benchmarks/bench_catalogue_cost.py)"
                     "; ns/eval is this run's live figure")
        cost_key = {c.model: c.cost_rel for c in fitted}
    else:
        missing = [c.model for c in fitted if c.cost_rel is None]
        cost_rule = ("live: " + ", ".join(missing) + " not in the committed cost table, so "
                     "every candidate is compared by this run's measured ns/eval")
        cost_key = {c.model: c.cost_ns for c in fitted}
    # an extra lobe never makes a model cheaper (brdf_fit.selection.nesting): with its base's
    # cost an extension loses the tie-break (fewer parameters) whenever both are within budget
    cost_key = choice_costs(cost_key)
    gains = lobe_gains({c.model: c.error for c in fitted})
    for c in out:
        c.extends, c.lobe_gain = base_of(c.model), gains.get(c.model)
    out.sort(key=lambda c: (bool(c.message), cost_key.get(c.model, 0.0), c.n_params, c.error))
    ok = sorted((c for c in out if c.within_budget),
                key=lambda c: (cost_key[c.model], c.n_params, c.error))
    choice, gave_way = None, None
    for c in ok:  # the cheapest, but an extra lobe only where the data support it
        if c.lobe_gain is not None:
            base = next(b for b in out if b.model == c.extends)
            c.lobe_gain.update(refit_lobe_test(data, c, base, n_res, max_steps))
            if not c.lobe_gain["supported"]:
                continue
        ext = decisive_extension(c, ok, noise, data, n_res, max_steps)
        choice, gave_way = (c.model, None) if ext is None else (ext.model, c)
        break
    represented = bool(best <= ceiling)
    suggestion = None
    if not represented:
        suggestion = (_SUGGEST_ANISO if aniso is not None and aniso.present
                      and "anisotropic" not in registry.get(best_c.model).tags
                      else _SUGGEST_OPEN)
        where = "" if target is None else f" of target {target}"
        message = (f"no candidate{where} represents this material: the best, {best_c.model}, "
                   f"leaves a radiance error of {best:.3g}, above the ceiling {ceiling:.3g}; "
                   f"try --family {suggestion}" + (
                       " (the data show anisotropy)" if suggestion == _SUGGEST_ANISO else
                       " (every registry model)"))
        choice = None
    elif choice is None:
        message = (f"no candidate is within the budget {budget:.4g}: the best, {best_c.model}, "
                   f"leaves a radiance error of {best_c.error:.4g}; give a budget above "
                   f"that (--budget), or try --family {_SUGGEST_OPEN} (every registry model)")
    else:
        ch = next(c for c in out if c.model == choice)
        message = (f"choice: {choice}, error {ch.error:.4g} (budget {budget:.4g}), the cheapest "
                   f"within budget by the {cost_rule.split(':')[0]} cost")
        if gave_way is not None:
            message = (f"choice: {choice}, error {ch.error:.4g} (budget {budget:.4g}): "
                       f"{gave_way.model}, the cheapest within budget, leaves {gave_way.error:.4g}"
                       f"; the extra lobe removes "
                       f"{100 * ch.lobe_gain['fraction_removed']:.4g}% of that"
                       + (f", reproduces the data to the noise ({ch.error:.4g} within "
                          f"{reproduced_level(noise):.4g})" if noise is not None
                          and ch.error <= reproduced_level(noise) else "")
                       + " and passes the F test")
    return Selection(choice=choice, budget=float(budget), budget_rule=rule,
                     error_definition=error_definition, candidates=out, noise_level=noise,
                     n_samples=data.n, seconds=time.perf_counter() - t_start,
                     ceiling=float(ceiling), ceiling_rule=ceiling_rule,
                     represented=represented, message=message, suggestion=suggestion,
                     cost_rule=cost_rule, target=target, anisotropy=aniso)
