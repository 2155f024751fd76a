"""Dataset recipes: one JSON or TOML file names everything a synthetic dataset depends on.

Example (TOML)::

    name = "ggx-gold-4axis"          # optional
    description = "..."              # optional
    model = "ggx-conductor"          # a brdf_fit.registry name or alias
    seed = 7                         # decides all the noise (and random plans without a seed)
    channels = ["R", "G", "B"]       # optional; or wavelengths in nm: [450, 550, 650]

    [params]                         # model parameters (unspecified ones take the defaults)
    alpha = 0.2

    [plan]                           # data_synth.plans.make_plan(name, args)
    name = "four_axis"
    args = { max_zenith_deg = 80.0, min_separation_deg = 5.0 }

    [[noise]]                        # data_synth.noise.make_noise, applied in list order
    type = "lognormal"
    args = { sigma = 0.02 }

    [[noise]]
    type = "dark"
    sigma = 1e-4                     # arguments may also sit beside "type"

:func:`synthesize` builds the model, the plan and the noise pipeline and returns a validated
:class:`~brdf_fit.data.GonioData` whose metadata holds the normalised recipe, the plan
description, the noise specs and the drawn systematic quantities (``truth``, e.g. the gain
factors). The result is a deterministic function of the recipe. A ``random_sparse`` plan without
its own ``seed`` argument takes the recipe's seed.

``channels`` defaults to ``R, G, B`` for a three-channel model and ``Y`` for a one-channel one;
a model whose parameters carry another number of channels needs ``channels`` (names, or
wavelengths for spectral data). Every problem raises :class:`RecipeError` naming the recipe, the
section and the valid choices.
"""

from __future__ import annotations

import json
import os
import pathlib
import tomllib
from typing import Any

import numpy as np

from brdf_fit.data import DataError, GonioData, wavelength_channels

from .noise import NoiseError, make_noise, run_pipeline
from .plans import PlanError, make_plan

__all__ = ["RecipeError", "RECIPE_KEYS", "load_recipe", "normalize_recipe", "synthesize"]

RECIPE_KEYS = ("name", "description", "model", "params", "plan", "noise", "seed", "channels",
               "bsdf")
#: ``model`` of a recipe rendered by Mitsuba 3 itself: ``bsdf`` then holds the plugin's scene
#: dict (``type`` and its properties; a list of three numbers is an ``rgb`` value)
RENDERER_MODELS = ("mitsuba",)
_REQUIRED = ("model", "plan", "seed")


class RecipeError(ValueError):
    """Invalid dataset recipe (the message names the recipe, the section and the problem)."""


def load_recipe(source) -> dict[str, Any]:
    """A recipe dict from a path (``.json`` or ``.toml``) or a dict (copied). Not yet checked;
    see :func:`normalize_recipe`."""
    if isinstance(source, dict):
        recipe = json.loads(json.dumps(source, default=_jsonable))
        recipe.setdefault("_source", "<dict>")
        return recipe
    if not isinstance(source, (str, os.PathLike)):
        raise RecipeError(f"a recipe is a path to a .json/.toml file or a dict, got "
                          f"{type(source).__name__}")
    path = pathlib.Path(source)
    suffix = path.suffix.lower()
    if suffix not in (".json", ".toml"):
        raise RecipeError(f"{path}: recipe files must end in .json or .toml")
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as e:
        raise RecipeError(f"{path}: cannot read recipe ({e.strerror or e})") from None
    try:
        recipe = json.loads(text) if suffix == ".json" else tomllib.loads(text)
    except (ValueError, tomllib.TOMLDecodeError) as e:
        kind = "JSON" if suffix == ".json" else "TOML"
        raise RecipeError(f"{path}: invalid {kind} ({e})") from None
    if not isinstance(recipe, dict):
        raise RecipeError(f"{path}: a recipe must be a JSON object / TOML table")
    recipe["_source"] = str(path)
    return recipe


def _jsonable(obj):
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, np.generic):
        return obj.item()
    raise TypeError(f"{type(obj).__name__} is not JSON serialisable")


def normalize_recipe(source) -> dict[str, Any]:
    """Check a recipe's structure and fill defaults: ``params`` {}, ``noise`` [], ``plan.args``
    {}. Returns a new dict (JSON-able) without the internal ``_source`` key."""
    recipe = load_recipe(source)
    where = recipe.pop("_source")
    unknown = [k for k in recipe if k not in RECIPE_KEYS]
    if unknown:
        raise RecipeError(f"recipe {where}: unknown key(s) {', '.join(map(repr, unknown))}; "
                          f"valid keys: {', '.join(RECIPE_KEYS)}")
    missing = [k for k in _REQUIRED if k not in recipe]
    if missing:
        raise RecipeError(f"recipe {where}: missing required key(s) {', '.join(missing)} "
                          "(a recipe names model, plan and seed)")
    if not isinstance(recipe["model"], str):
        raise RecipeError(f"recipe {where}: 'model' must be a registry name (a string), got "
                          f"{recipe['model']!r}")
    seed = recipe["seed"]
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise RecipeError(f"recipe {where}: 'seed' must be a non-negative integer, got {seed!r}")
    params = recipe.setdefault("params", {})
    if not isinstance(params, dict):
        raise RecipeError(f"recipe {where}: 'params' must be a table/dict of model parameters, "
                          f"got {params!r}")
    plan = recipe["plan"]
    if isinstance(plan, str):
        plan = recipe["plan"] = {"name": plan}
    if not isinstance(plan, dict) or "name" not in plan:
        raise RecipeError(f"recipe {where}: 'plan' must be a table with a 'name' (and optional "
                          f"'args'), got {plan!r}")
    extra = [k for k in plan if k not in ("name", "args")]
    if extra:
        raise RecipeError(f"recipe {where}: [plan] has unknown key(s) {extra}; put plan "
                          "arguments in plan.args")
    plan.setdefault("args", {})
    if not isinstance(plan["args"], dict):
        raise RecipeError(f"recipe {where}: plan.args must be a table/dict, got {plan['args']!r}")
    noise = recipe.setdefault("noise", [])
    if isinstance(noise, dict):
        noise = recipe["noise"] = [noise]
    if not isinstance(noise, list):
        raise RecipeError(f"recipe {where}: 'noise' must be a list of tables, got {noise!r}")
    channels = recipe.get("channels")
    if channels is not None and (not isinstance(channels, list) or not channels):
        raise RecipeError(f"recipe {where}: 'channels' must be a non-empty list of names or "
                          f"wavelengths in nm, got {channels!r}")
    return recipe


def _channel_names(spec, n_channels: int, where: str) -> tuple[str, ...]:
    if spec is None:
        if n_channels == 3:
            return ("R", "G", "B")
        if n_channels == 1:
            return ("Y",)
        raise RecipeError(f"recipe {where}: the model gives {n_channels} channels; name them "
                          "with 'channels' (names, or wavelengths in nm)")
    if all(isinstance(c, (int, float)) and not isinstance(c, bool) for c in spec):
        names = wavelength_channels(spec)
    elif all(isinstance(c, str) for c in spec):
        names = tuple(spec)
    else:
        raise RecipeError(f"recipe {where}: 'channels' must be all names or all wavelengths, "
                          f"got {spec!r}")
    if len(set(names)) != len(names):
        raise RecipeError(f"recipe {where}: duplicate channel names {list(names)}")
    if len(names) != n_channels:
        raise RecipeError(f"recipe {where}: {len(names)} channel name(s) {list(names)} but the "
                          f"model gives {n_channels} channel(s)")
    return names


def synthesize(recipe) -> GonioData:
    """The dataset a recipe (path or dict, see the module docstring) describes."""
    import jax  # the model is a JAX BRDF

    from brdf_fit import registry
    from brdf_fit.core.validate import ParameterError

    where = recipe if not isinstance(recipe, dict) else recipe.get("name", "<dict>")
    r = normalize_recipe(recipe)
    seed = int(r["seed"])

    rendered = str(r["model"]).strip().lower() in RENDERER_MODELS
    if rendered:
        evaluate_pairs = _mitsuba_evaluator(r, where)
        model_name = f"mitsuba:{r['bsdf']['type']}"
    else:
        if "bsdf" in r:
            raise RecipeError(f"recipe {where}: 'bsdf' goes with model = \"mitsuba\" (a scene "
                              f"dict Mitsuba 3 renders), not with model {r['model']!r}")
        try:
            entry = registry.get(r["model"])
        except registry.UnknownModelError as e:
            raise RecipeError(f"recipe {where}: model: {e}") from None
        try:
            model = entry.build(**{k: np.asarray(v, dtype=float)
                                   for k, v in r["params"].items()})
        except (ParameterError, ValueError, TypeError) as e:
            raise RecipeError(f"recipe {where}: params: {e}") from None
        model_name = entry.name

    plan_args = dict(r["plan"]["args"])
    key = str(r["plan"]["name"]).strip().lower().replace("-", "_")
    if key == "random_sparse" and "seed" not in plan_args:
        plan_args["seed"] = seed
    try:
        plan = make_plan(r["plan"]["name"], plan_args)
    except PlanError as e:
        raise RecipeError(f"recipe {where}: plan: {e}") from None
    if plan.n == 0:
        raise RecipeError(f"recipe {where}: plan: the plan {plan.info} has no samples")

    try:
        noise = [make_noise(m) for m in r["noise"]]
    except NoiseError as e:
        raise RecipeError(f"recipe {where}: noise: {e}") from None

    if rendered:
        def evaluate(wi, wo):
            return evaluate_pairs(np.asarray(wi), np.asarray(wo))
    else:
        f = jax.jit(lambda a, b: model.eval(a, b))

        def evaluate(wi, wo):
            v = np.asarray(f(wi, wo), dtype=np.float64)
            return v[:, None] if v.ndim == 1 else v

    clean, values, sigma, truth = run_pipeline(noise, plan.wi, plan.wo, evaluate, seed)
    channels = _channel_names(r.get("channels"), values.shape[1], where)
    metadata = {
        "recipe": r,
        "model": model_name,
        "params": {k: np.asarray(v).tolist() for k, v in r["params"].items()},
        "plan": plan.info,
        "noise": [m.spec() for m in noise],
        "seed": seed,
        "truth": json.loads(json.dumps(truth, default=_jsonable)),
        "synthetic": True,
    }
    data = GonioData(wi=plan.wi, wo=plan.wo, value=values, sigma=sigma, channels=channels,
                     metadata=metadata)
    try:
        return data.validate()
    except DataError as e:
        raise RecipeError(f"recipe {where}: the synthesised data is invalid ({e})") from None


def _mitsuba_dict(value):
    """A recipe's ``bsdf`` table as ``mi.load_dict`` takes it: a list of three numbers is an
    ``rgb`` value, nested tables (textures, nested BSDFs) are converted alike."""
    if isinstance(value, dict):
        return {k: _mitsuba_dict(v) for k, v in value.items()}
    if isinstance(value, list) and len(value) == 3 and all(
            isinstance(x, (int, float)) and not isinstance(x, bool) for x in value):
        return {"type": "rgb", "value": [float(x) for x in value]}
    return value


def _mitsuba_evaluator(r: dict, where):
    """``evaluate(wi, wo) -> (N, 3)``: the recipe's ``bsdf`` rendered by Mitsuba 3's own
    ``BSDF.eval`` (:func:`brdf_fit.convert.mitsuba.mitsuba_eval`, ``scalar_rgb``)."""
    from brdf_fit.convert.mitsuba import mitsuba_eval

    bsdf = r.get("bsdf")
    if not isinstance(bsdf, dict) or not isinstance(bsdf.get("type"), str):
        raise RecipeError(f"recipe {where}: model = \"mitsuba\" needs a [bsdf] table with a "
                          "'type' (a Mitsuba 3 plugin name) and its properties")
    if r["params"]:
        raise RecipeError(f"recipe {where}: a Mitsuba-rendered recipe takes its properties in "
                          "[bsdf], not [params]")
    scene = _mitsuba_dict(bsdf)
    try:
        import mitsuba  # noqa: F401
    except ImportError:
        raise RecipeError(f"recipe {where}: rendering with Mitsuba 3 needs it installed "
                          "(pip install 'brdf_fit[mitsuba]')") from None
    try:
        mitsuba_eval(scene, np.array([[0.0, 0.0, 1.0]]), np.array([[0.0, 0.0, 1.0]]))
    except Exception as e:  # Mitsuba raises RuntimeError/TypeError for a bad scene dict
        raise RecipeError(f"recipe {where}: bsdf: Mitsuba refused it: "
                          f"{str(e).splitlines()[0] if str(e) else type(e).__name__}") from None

    def evaluate(wi, wo):
        return mitsuba_eval(scene, wi, wo)

    return evaluate
