"""Models that extend another with one lobe or degree of freedom, and equal it where that is off
(issue 40: a plain plastic was chosen as ``gltf-pbr-sheen`` with a sheen colour standing for
nothing, because the committed table rated the sheen model cheaper than the plain one: every glTF
entry evaluates every layer, and the two measured 16.3x and 17.7x Lambert).

Two rules follow from the nesting, in :func:`brdf_fit.selection.select`:

- **an extension never costs less than its base** in the choice (:func:`choice_costs`): a lobe is
  work on top of the base in every renderer, so a measured cost below the base's is measurement
  noise or a shared kernel, not a saving. With the equal cost, the tie-break (fewer parameters)
  takes the base whenever both are within the budget, unless the next rule applies;
- **what each extra lobe buys** is reported (:func:`lobe_gains`): the base's radiance error
  minus the extension's, absolute and as a fraction of the base's, where both were fitted;
- **a base that misses what its extension finds gives way to it** (:func:`decisive_extension`):
  where both are within the budget, the base would win the tie-break even when the data are
  far from it and the extension reproduces them. A coated blue rendered by Cycles (coat weight
  1, base roughness 0.5, coat roughness 0.1) came back as the uncoated ``blender-principled``
  with the coat's roughness (error 3.5e-4, inside the 1% budget floor) where
  ``blender-principled-coat`` returned the values set (error 1.8e-8). The extension is taken
  when the base misses the data (its error above :func:`reproduced_level`), the extension
  removes at least :data:`DECISIVE_FRACTION` of the base's error or, on data with sigma,
  reproduces them itself (its error within :func:`reproduced_level`, and removing that
  fraction of the base's squared error above the best extension's), and its lobe passes the F
  test below. On a plastic with 1% noise no lobe removes a tenth (test_nesting); on a red
  plastic rendered by Cycles the plain entry reproduces the data (1e-6). With noise the share
  removed is bounded by what the noise leaves: a Mitsuba principled dielectric with tinted
  specular and 2% noise, base 3.1% (above 1.5 x the 2% level), the tinted entry 2.3% (the values
  set give 2.5% on that draw), removes a quarter, and the base was chosen;
- **a lobe stays only where the data support it** (:func:`lobe_test`): an extension that would
  be the choice is tested against its base before it is taken, by the extra-sum-of-squares F
  test of the nested pair (Seber & Wild, "Nonlinear Regression", Wiley 1989, sec. 5.3, eq.
  5.23; exact for linear models, approximate here), ``F = ((RSS_base - RSS_ext) / (k_ext -
  k_base)) / (RSS_ext / (N - k_ext))`` against F(k_ext - k_base, N - k_ext). The test needs
  residuals of equal variance, which the selection's own fits (absolute radiance) do not have
  under a relative noise: there the F test took a lobe in 3 of 12 tests on a plain plastic with
  1% lognormal noise, where 1% was the level. So both models are fitted again for the test, from
  the selection's answers, in the package's default metric: log residuals, divided by the data's
  relative sigma where given, of equal variance under such noise (the same 12 tests: p-values
  0.40-1.0). A lobe whose p-value is not below :data:`LOBE_TEST_ALPHA` removes no more than
  the noise would by chance; the extension is then not chosen (its base may be; when the base is
  outside the budget, the next candidate is). With the lobe "off" at a bound of its parameters
  (a sheen colour of 0) the statistic's null distribution is a mixture below F (Self & Liang,
  JASA 82, 1987): the p-value is conservative, which errs toward the smaller model.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["DECISIVE_FRACTION", "LOBE_TEST_ALPHA", "NESTED", "REPRODUCED_NOISE_FACTOR",
           "REPRODUCED_NOISE_FREE", "base_of", "choice_costs", "decisive_extension", "lobe_gains",
           "lobe_test", "off_params", "refit_lobe_test", "reproduced_level"]

#: significance level of :func:`lobe_test`: a lobe is supported by the data when its p-value is
#: below this. 1% rather than 5%: a selection tests several lobes at once (three glTF
#: extensions of one base), and a lobe taken by chance costs every render of the material
LOBE_TEST_ALPHA = 0.01
#: data without sigma count as reproduced by a model whose radiance error (the selection's
#: cosine-weighted relative RMS) is at most this: a float32 renderer's rounding, with margin.
#: Measured: Cycles' render of a coated Principled BSDF against its JAX transcription, 1.7e-7;
#: selection errors of entries fitted to their own Cycles renders 2e-8 to 1e-6
REPRODUCED_NOISE_FREE = 1e-5
#: data with sigma count as reproduced by a model whose radiance error is at most this many times
#: their noise level (the selection's BUDGET_FACTOR_NOISE)
REPRODUCED_NOISE_FACTOR = 1.5
#: the least fraction of its base's radiance error an extension must remove to be chosen over a
#: base within the budget that misses the data (:func:`decisive_extension`): the lobe then
#: accounts for nine tenths of the misfit, not for a share of a mismatch neither model has (a
#: glTF sheen took 3.5% of a Cycles plastic's 4.3%: a fifth)
DECISIVE_FRACTION = 0.9

_ISO = {"alpha_x": "alpha", "alpha_y": "alpha"}
_ISO_UV = {"alpha_u": "alpha", "alpha_v": "alpha"}

#: extension -> (base, {extension parameter: value (or base parameter name) that turns it off})
NESTED: dict[str, tuple[str, dict]] = {
    "gltf-pbr-sheen": ("gltf-pbr", {"sheen_color": 0.0, "sheen_roughness": 0.5}),
    "gltf-pbr-clearcoat": ("gltf-pbr", {"clearcoat": 0.0, "clearcoat_roughness": 0.5}),
    "gltf-pbr-specular": ("gltf-pbr", {"specular_factor": 1.0, "specular_color": 1.0}),
    "gltf-pbr-anisotropy": ("gltf-pbr", {"anisotropy_strength": 0.0,
                                         "anisotropy_rotation": 0.0}),
    "mitsuba-principled-aniso": ("mitsuba-principled", {"anisotropic": 0.0}),
    "mitsuba-principled-clearcoat": ("mitsuba-principled", {"clearcoat": 0.0,
                                                             "clearcoat_gloss": 0.0}),
    "mitsuba-principled-sheen": ("mitsuba-principled", {"sheen": 0.0}),
    "mitsuba-principled-tinted": ("mitsuba-principled", {"spec_tint": 0.0}),
    "mitsuba-principled-full": ("mitsuba-principled", {
        "anisotropic": 0.0, "sheen": 0.0, "clearcoat": 0.0, "clearcoat_gloss": 0.0,
        "flatness": 0.0}),
    "mitsuba-roughconductor-aniso": ("mitsuba-roughconductor", _ISO_UV),
    "mitsuba-roughconductor-beckmann-aniso": ("mitsuba-roughconductor-beckmann", _ISO_UV),
    "blender-principled-aniso": ("blender-principled", {"anisotropic": 0.0}),
    "blender-principled-coat": ("blender-principled", {"coat_weight": 0.0, "coat_roughness": 0.03,
                                                       "coat_ior": 1.5}),
    "blender-principled-sheen": ("blender-principled", {"sheen_weight": 0.0,
                                                        "sheen_roughness": 0.5}),
    "openpbr-surface-aniso": ("openpbr-surface", {"specular_roughness_anisotropy": 0.0}),
    "openpbr-surface-coat": ("openpbr-surface", {"coat_weight": 0.0, "coat_roughness": 0.0,
                                                 "coat_ior": 1.6}),
    "openpbr-surface-fuzz": ("openpbr-surface", {"fuzz_weight": 0.0, "fuzz_roughness": 0.5}),
    "ggx-aniso": ("ggx", _ISO),
    "ggx-conductor-aniso": ("ggx-conductor", _ISO),
}


def base_of(name: str) -> str | None:
    """The entry ``name`` extends (:data:`NESTED`), or None."""
    return NESTED[name][0] if name in NESTED else None


def off_params(name: str, base_params: dict) -> dict:
    """The parameters of extension ``name`` that make it equal its base at ``base_params``:
    the base's own parameters (those the extension shares), then its extra ones off."""
    base, off = NESTED[name]
    out = {k: v for k, v in base_params.items() if k not in off.values()}
    for k, v in off.items():
        out[k] = base_params[v] if isinstance(v, str) else v
    return out


def choice_costs(costs: dict[str, float]) -> dict[str, float]:
    """``costs`` (a cost per candidate name) with each extension's cost raised to its base's
    where that is higher (the base's from ``costs``). Bases of bases are followed."""
    out = dict(costs)
    for name in costs:
        base = base_of(name)
        while base is not None:
            if base in costs:
                out[name] = max(out[name], costs[base])
            base = base_of(base)
    return out


def lobe_test(rss_base: float, k_base: int, rss_ext: float, k_ext: int, n_res: int) -> dict:
    """The nested-model F test of an extension against its base (module docstring), from each
    fit's residual sum of squares ``rss`` and free scalars ``k`` on ``n_res`` residuals:
    ``{"f_statistic", "df", "p_value", "supported"}`` (``df``: the two degrees of freedom). No
    residual degree of freedom left, or an extension that fitted no better: p-value 1, not
    supported. The statistic is None where it is undefined (no degree of freedom) or infinite
    (an exact extension), so that the result is strict JSON."""
    from jax.scipy.special import betainc

    d1, d2 = int(k_ext) - int(k_base), int(n_res) - int(k_ext)
    if d1 <= 0 or d2 <= 0 or not (rss_ext >= 0 and rss_base >= rss_ext):
        f, p = (0.0 if d1 > 0 and d2 > 0 else float("nan")), 1.0
    elif rss_ext == 0.0:  # an exact fit of the extension, not of its base
        f, p = float("inf"), 0.0 if rss_base > 0 else 1.0
    else:
        f = ((rss_base - rss_ext) / d1) / (rss_ext / d2)
        p = float(betainc(0.5 * d2, 0.5 * d1, d2 / (d2 + d1 * f)))  # F(d1, d2)'s tail at f
    f = float(f)
    return {"f_statistic": f if math.isfinite(f) else None,  # None: undefined or infinite
            "df": [d1, d2], "p_value": p, "supported": bool(p < LOBE_TEST_ALPHA)}


def lobe_gains(errors: dict[str, float]) -> dict[str, dict]:
    """Per extension fitted beside its base (``errors``: radiance error per candidate name,
    finite where fitted): ``{"base", "error_removed", "fraction_removed"}``, the base's error
    minus the extension's and that as a fraction of the base's (negative: the extension fitted
    worse, e.g. a start its optimiser did not leave)."""
    out = {}
    for name, err in errors.items():
        base = base_of(name)
        if base is None or base not in errors:
            continue
        eb = errors[base]
        if not (err == err and eb == eb) or err == float("inf") or eb == float("inf"):
            continue
        out[name] = {"base": base, "error_removed": eb - err,
                     "fraction_removed": (eb - err) / eb if eb > 0 else 0.0}
    return out


def refit_lobe_test(data, ext, base, n_res: int, max_steps: int) -> dict:
    """The F test of ``ext``'s extra lobe against ``base`` (:func:`lobe_test`; both selection
    candidates: ``model``, ``params``, ``n_params``) on ``data`` (a GonioData, ``n_res``
    residuals with weight, as the selection counts them), the two models
    fitted again from their answers in the default metric (log residuals, over the data's
    sigma where given: of equal variance under a relative noise, as the test needs; module
    docstring). A model that cannot be refitted leaves the lobe untested and not supported."""
    from brdf_fit.core.validate import ParameterError
    from brdf_fit.fitting.problem import FitError
    from brdf_fit.fitting.single import fit

    metric = "log" + (" / sigma" if data.sigma is not None else "")
    rss = {}
    for c in (base, ext):
        try:
            r = fit(data, c.model, init={p: np.asarray(v) for p, v in c.params.items()},
                    max_steps=max_steps)
        except (ParameterError, FitError) as exc:  # untestable: the lobe is not taken
            return {"f_statistic": None, "df": [ext.n_params - base.n_params, None],
                    "p_value": None, "supported": False, "metric": metric,
                    "message": f"{c.model} could not be refitted for the test: {exc}"}
        rss[c.model] = 2.0 * r.loss
    test = lobe_test(rss[base.model], base.n_params, rss[ext.model], ext.n_params, n_res)
    return {**test, "metric": metric}


def reproduced_level(noise: float | None) -> float:
    """The radiance error at which a model reproduces data of noise level ``noise`` (None: data
    without sigma): :data:`REPRODUCED_NOISE_FACTOR` x the noise, or
    :data:`REPRODUCED_NOISE_FREE`."""
    return REPRODUCED_NOISE_FREE if noise is None else REPRODUCED_NOISE_FACTOR * noise


def decisive_extension(base, candidates, noise, data, n_res: int, max_steps: int):
    """The extension of ``base`` to choose instead of it (module docstring), or None: where
    ``base`` misses the data (error above :func:`reproduced_level`), the first of ``candidates``
    (within the budget, cheapest first) that extends it, removes at least
    :data:`DECISIVE_FRACTION` of its error or (data with sigma, ``noise`` given) reproduces the
    data itself and removes that fraction of the base's squared error above the best
    extension's, and whose lobe passes :func:`refit_lobe_test` (recorded in its
    ``lobe_gain``)."""
    level = reproduced_level(noise)
    if not base.error > level:
        return None
    extensions = [c for c in candidates
                  if base_of(c.model) == base.model and c.lobe_gain is not None]
    # with noise: the best extension's error stands for the noise floor, and an extension must
    # remove DECISIVE_FRACTION of the base's squared error above it (a sheen that took 22% of
    # what a tint removed, 2.96% against the base's 3.11% and the tint's 2.34%, also lay
    # within 1.5 x the 2% level)
    floor = min((c.error for c in extensions), default=0.0)
    for c in extensions:
        reproduces = (noise is not None and c.error <= level
                      and base.error ** 2 - c.error ** 2
                      >= DECISIVE_FRACTION * (base.error ** 2 - floor ** 2))
        if not (c.lobe_gain["fraction_removed"] >= DECISIVE_FRACTION or reproduces):
            continue
        c.lobe_gain.update(refit_lobe_test(data, c, base, n_res, max_steps))
        if c.lobe_gain["supported"]:
            return c
    return None
