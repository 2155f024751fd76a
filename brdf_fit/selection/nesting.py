"""Models that extend another with one lobe or degree of freedom, and equal it where that is off
(issue 40: a plain plastic was chosen as ``gltf-pbr-sheen`` with a sheen colour standing for
nothing, because the committed table rated the sheen model cheaper than the plain one: every glTF
entry evaluates every layer, and the two measured 16.3x and 17.7x Lambert).

Two rules follow from the nesting, in :func:`brdf_fit.selection.select`:

- **an extension never costs less than its base** in the choice (:func:`choice_costs`): a lobe is
  work on top of the base in every renderer, so a measured cost below the base's is measurement
  noise or a shared kernel, not a saving. With the equal cost, the tie-break (fewer parameters)
  takes the base whenever both are within the budget: an extra lobe is chosen only when the base
  alone does not represent the material within the budget;
- **what each extra lobe buys** is reported (:func:`lobe_gains`): the base's radiance error
  minus the extension's, absolute and as a fraction of the base's, where both were fitted.

:data:`NESTED` says, per extension, its base and the values of the extension's own parameters
that turn the extra lobe off (a number, or the name of the base's parameter it then equals);
``tests/selection/test_nesting.py`` checks each claim as an identity of the two models.
"""

from __future__ import annotations

__all__ = ["NESTED", "base_of", "choice_costs", "lobe_gains", "off_params"]

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
    "mitsuba-principled-full": ("mitsuba-principled", {
        "anisotropic": 0.0, "sheen": 0.0, "clearcoat": 0.0, "clearcoat_gloss": 0.0,
        "flatness": 0.0}),
    "mitsuba-roughconductor-aniso": ("mitsuba-roughconductor", _ISO_UV),
    "mitsuba-roughconductor-beckmann-aniso": ("mitsuba-roughconductor-beckmann", _ISO_UV),
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
